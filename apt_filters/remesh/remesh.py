"""The remesher: feature-preserving centroidal Voronoi tessellation of a triangle mesh."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from apt_filters.remesh._arrays import isin, unique, unique_rows
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh, vertex_normals
from apt_filters.remesh import cvt, extract, features as feat, optimize, repair, verify as check
from apt_filters.remesh.mend import mend
from apt_filters.remesh.sampling import refine


# Refined edges (90th percentile) are at most L / SAMPLES_PER_EDGE: about 40 samples per generator
# for marching-cubes input at L = 1 voxel. Measured against 4 (a further 4x samples, Lloyd on the
# level below and a final labelling on all of them): the same quality on the test shapes, half
# the time and a quarter of the memory.
SAMPLES_PER_EDGE = 2.0
# Connecting cells can leave (or make) a defect next to the one it mended on bumpy input; a few
# rounds close them (a 3 nm sphere with 0.4 nm bumps kept a hole after one round).
CONNECT_ROUNDS = 3
# Edges shrink at most this many times below the target where the surface bends.
MAX_SHRINK = 4.0
GRADATION, GRADATION_PASSES = 1.3, 6
# Components that fail the check are remeshed again, finer where the last try missed, at most this many times.
RETRIES = 3
# How far a curve vertex may slide towards the next one on its curve, as a fraction of the arc between them:
# in the relaxation (all vertices at once) and in the sweeps of improve_quality / improve_angles (one of
# two neighbours at a time).
SLIDE_REACH = (0.4, 0.9)


@dataclass
class RemeshResult:
    """The remeshed surface and how it was reached."""

    mesh: TriMesh
    edge_length: float
    iterations: int
    energy: list
    skipped_voronoi_vertices: int
    n_corners: int  # corners where feature curves meet
    n_curves: int
    timings: dict = field(default_factory=dict)
    checks: list = field(default_factory=list)  # one verify.ComponentCheck per input component
    n_apexes: int = 0  # corners off the curves: cone apexes and turns of the open rim

    @property
    def kept_input(self) -> int:
        """Input components given back unchanged because their remesh failed a check."""
        return sum(not c.ok for c in self.checks)


def _edge_length(mesh: TriMesh, edge_length: float | None, n_vertices: int | None) -> float:
    if edge_length is not None and n_vertices is not None:
        raise AptFiltersError("give an edge length or a vertex count, not both")
    if n_vertices is not None:
        if n_vertices < 4:
            raise AptFiltersError(f"vertex count must be at least 4, got {n_vertices}")
        return float(np.sqrt(mesh.area() / (n_vertices * np.sqrt(3.0) / 2.0)))
    if edge_length is None:
        e = mesh.vertices[mesh.faces] - mesh.vertices[np.roll(mesh.faces, 1, axis=1)]
        return float(np.linalg.norm(e, axis=2).mean())
    if not edge_length > 0:
        raise AptFiltersError(f"edge length must be positive, got {edge_length}")
    return float(edge_length)


def curvature_density(mesh: TriMesh, edge: float, adaptive: float, tolerance: float,
                      patch: np.ndarray, boost: np.ndarray | None = None) -> np.ndarray:
    """(v,) density ρ per input vertex; edges scale as ρ^-1/4, shrinking by at most ``MAX_SHRINK``.

    Edges shrink by the larger of two factors, κ the curvature (1/nm) from the turn of vertex
    normals along the input's edges inside a patch (``patch`` (f,) per face; sharp features are
    kept by their curves, not by shorter edges): ``1 + adaptive·L·κ`` (finer where the surface bends, a user's
    choice) and ``sqrt(L·κ / (3·tolerance))``, the shrink at which a triangle with vertices on a
    surface of curvature κ stays within ``tolerance·L`` of it: an equilateral one's sagitta is
    κL²/6 at its circumcentre; CVT triangles are not all equilateral, and a circumradius 1.4 times
    as large (angles of 30-90°) doubles it. Without the second, the remesh at 0.5 nm of the
    pipeline's refined cuboid (bends of radius 0.2-0.3 nm) left input points 0.20 nm from it
    (0.4 edge; 0.14 with the sagitta of equilateral triangles only). A third factor,
    :func:`crease_shrink`, covers the turns between input faces that vertex normals spread out.
    ``boost`` (v,), optional: a further factor per vertex (:func:`miss_boost`, where a first remesh missed).
    """
    normals = vertex_normals(mesh.vertices, mesh.faces)
    edges = unique_rows(np.sort(mesh.edges(), axis=1))[0]
    # vertices of two patches (on a feature curve or the rim) have normals mixed across the crease
    lo = np.full(mesh.n_vertices, np.iinfo(np.int64).max)
    hi = np.full(mesh.n_vertices, -1)
    np.minimum.at(lo, mesh.faces.ravel(), np.repeat(patch, 3))
    np.maximum.at(hi, mesh.faces.ravel(), np.repeat(patch, 3))
    lone = (lo == hi) & ~optimize.boundary_vertices(mesh)
    edges = edges[lone[edges].all(axis=1)]
    length = np.linalg.norm(mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]], axis=1)
    turn = np.linalg.norm(normals[edges[:, 0]] - normals[edges[:, 1]], axis=1)
    kappa = turn / np.clip(length, 0.25 * edge, edge)  # short sliver edges would inflate κ
    k = np.zeros(len(mesh.vertices))
    np.maximum.at(k, edges[:, 0], kappa)
    np.maximum.at(k, edges[:, 1], kappa)
    shrink = np.maximum(1.0 + adaptive * edge * k, np.sqrt(edge * k / (3.0 * tolerance)))
    # creases inside a patch: a turn θ between two faces that the input's edges do not resolve
    shrink = np.clip(np.maximum(shrink, crease_shrink(mesh, patch, edge, tolerance)), 1.0, MAX_SHRINK)
    if boost is not None:  # past MAX_SHRINK too where a remesh missed, but no finer than the input's own edges
        ends = mesh.topology.edge_vertices
        span = np.linalg.norm(mesh.vertices[ends[:, 0]] - mesh.vertices[ends[:, 1]], axis=1)
        shortest = np.full(mesh.n_vertices, np.inf)
        np.minimum.at(shortest, ends[:, 0], span)
        np.minimum.at(shortest, ends[:, 1], span)
        shrink = np.maximum(shrink, np.minimum(shrink * boost, edge / shortest))
    # graded: the factor falls by at most GRADATION per target edge away from where it is needed, so
    # that Lloyd is not asked for a jump in size it can only meet with poor triangles
    edges = unique_rows(np.sort(mesh.edges(), axis=1))[0]
    length = np.linalg.norm(mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]], axis=1)
    step = GRADATION ** (length / edge)
    for _ in range(GRADATION_PASSES):
        np.maximum.at(shrink, edges[:, 0], shrink[edges[:, 1]] / step)
        np.maximum.at(shrink, edges[:, 1], shrink[edges[:, 0]] / step)
    return shrink**4


def crease_shrink(mesh: TriMesh, patch: np.ndarray, edge: float, tolerance: float) -> np.ndarray:
    """(v,) edge shrink factor ``θ / (2·tolerance)`` at the ends of every input edge whose two faces
    (of one patch, ``patch`` (f,)) turn by θ (radians) across it and are both at least L = ``edge``
    (nm) high over it; 0 elsewhere.

    A piecewise-flat input bends at its edges. Where its faces are narrower than the target edge,
    the curvature from vertex normals (:func:`curvature_density`: the turn over an input edge, at
    most L long) sees such a bend at the output's resolution; where they are wider (coarse input),
    it spreads the turn over the input's edge and hides it. A triangle of edge L' across a crease of
    turn θ misses it by up to θ·L'/4 when equilateral, twice that with angles of 30-90° (as in
    :func:`curvature_density`): within ``tolerance``·L this asks for L' = L · 2·tolerance / θ.
    Without it a marching-cubes plate remeshed at 0.4 of its edge length came out 0.32 edge inside
    its rim, and was given back.
    """
    top = mesh.topology
    pairs = top.face_pairs
    ends = top.edge_vertices[top.edge_faces == 2]
    same = patch[pairs[:, 0]] == patch[pairs[:, 1]]
    pairs, ends = pairs[same], ends[same]
    area2 = mesh.face_normals(normalize=False)
    length2 = np.linalg.norm(area2, axis=1)
    normal = area2 / np.maximum(length2, 1e-300)[:, None]
    theta = np.arccos(np.clip(np.einsum("ij,ij->i", normal[pairs[:, 0]], normal[pairs[:, 1]]), -1.0, 1.0))
    base = np.maximum(np.linalg.norm(mesh.vertices[ends[:, 0]] - mesh.vertices[ends[:, 1]], axis=1), 1e-300)
    height = np.minimum(length2[pairs[:, 0]], length2[pairs[:, 1]]) / base
    factor = np.where(height >= edge, theta / (2.0 * tolerance), 0.0)
    out = np.zeros(mesh.n_vertices)
    np.maximum.at(out, ends[:, 0], factor)
    np.maximum.at(out, ends[:, 1], factor)
    return out


def remesh(mesh: TriMesh, edge_length: float | None = None, n_vertices: int | None = None,
           feature_angle: float = 40.0, adaptive: float = 0.0, max_iter: int = 30, tol: float = 1e-3,
           smooth_rounds: int = 5, seed: int = 0, bridge_gaps: bool = False,
           verify: bool = True) -> RemeshResult:
    """Remesh ``mesh`` into near-equilateral triangles, keeping sharp features and boundaries.

    Parameters
    ----------
    mesh : TriMesh
        Input surface (nm), 2-manifold, consistently oriented; not modified.
    edge_length, n_vertices : float or int, optional
        Target edge length (nm) or vertex count; default: the input's mean edge length.
    feature_angle : float
        Dihedral angle (degrees) above which an edge is sharp; 180 disables sharp features.
    bridge_gaps : bool
        Join gaps in creases whose bend is spread over two edges under ``feature_angle``
        (dual contouring with estimated normals); off by default because on noisy refined
        surfaces it turns noise creases into features.
    adaptive : float
        0 for uniform triangles; > 0 shrinks edges where the surface bends (see
        :func:`curvature_density`).
    max_iter, tol : int, float
        Lloyd stops after ``max_iter`` steps or when the CVT energy changes by less than ``tol``.
    verify : bool
        Check every input component against its remesh (:func:`apt_filters.remesh.verify.check_components`:
        Euler characteristic, boundary loops, open rims, two-sided Hausdorff distance within
        a quarter of the edge, area within 1 %); mend each component off in distances only where it missed
        (:func:`apt_filters.remesh.mend.mend`: vertices inserted there, every other face kept), and remesh each
        component that still fails again, on its own,
        finer where it missed and with the input vertices it missed pinned (:func:`missed`, at most
        ``RETRIES`` times, each try mended as the first; not one off in area alone, which that does not mend),
        and give back the input's
        own faces of each one that still fails.

    Returns
    -------
    RemeshResult
        ``mesh`` carries the input's vertex scalars interpolated at the new vertices and its
        face scalars from the nearest input face; ``checks`` and ``kept_input`` say which
        components were given back unchanged and why.

    Memory: the refined copy of the input (:func:`apt_filters.remesh.sampling.refine`: n² faces per
    input face so that the 90th percentile of edge lengths is under L/2, 16 for marching-cubes input
    at L = 1 voxel; 12 bytes per refined face and 24 per refined vertex) plus an int32 label and
    group per sample; the rest scales with the output (docs/remesh.md, "Memory and time").
    """
    if mesh.n_faces == 0:
        raise AptFiltersError("mesh has no faces")
    edge = _edge_length(mesh, edge_length, n_vertices)
    options = dict(feature_angle=feature_angle, adaptive=adaptive, max_iter=max_iter, tol=tol,
                   smooth_rounds=smooth_rounds, bridge_gaps=bridge_gaps)
    result, out_component, surface = _cvt_remesh(mesh, edge, seed=seed, **options)
    if not verify:
        return result
    clock = time.perf_counter()
    component = mesh.face_components()
    walks = (check.Walks(), check.Walks())  # the check's walked bounds, which the mend and missed() take again
    checks = check.check_components(mesh, result.mesh, component, out_component, edge=edge, source_surface=surface,
                                    walks=walks)
    failed = np.array([not c.ok for c in checks])
    # remeshed again: the failed components but those off in area alone (triangles of the target edge that
    # flatten bumps of their own size; a finer remesh where points were missed leaves that as it is)
    retry = failed & np.array([c.mendable for c in checks], bool)
    out, kept = _mend_misses(mesh, result.mesh, component, out_component, checks, edge, surface, walks)
    failed = np.array([not c.ok for c in checks])
    retry &= failed
    if failed.any():
        # the remesh's faces of the components remeshed again, which missed() measures
        last_out_mask = (out_component < 0) | retry[np.maximum(out_component, 0)]
        out = check.keep_input(mesh, out, component, kept, failed)
    out_component = check.kept_component(component, kept, failed) if failed.any() else kept
    if retry.any():
        # the failed components again, on their own, finer where the last remesh missed and with another seed:
        # a miss the density did not foresee (a kink of a feature curve, a spike of the refined surface) or a
        # sampling that fell badly
        boost, pins = np.ones(mesh.n_vertices), np.zeros(mesh.n_vertices, bool)
        part, last, last_mask, last_surface = mesh, result.mesh, retry[component], surface
        del surface
        last_used = np.arange(mesh.n_vertices)
        for attempt in range(1, RETRIES + 1):
            more, corners = missed(part, last, mask=last_mask, out_mask=last_out_mask,
                                   edge=edge, tolerance=check.HAUSDORFF_FRACTION, surface=last_surface, walks=walks)
            # the last try's closest-point engine goes before this try builds its own: two held at once were 0.26
            # kB per input face of the bumpy gyroid's remesh peak (2.9 kB, in its retry)
            last_surface = part_surface = None
            walks = (check.Walks(), check.Walks())  # this try's check's, the last ones let go before the remesh
            boost[last_used] *= more
            pins[last_used[corners]] = True
            mask = retry[component]
            part, used = _part(mesh, mask)
            again, again_component, part_surface = _cvt_remesh(part, edge, seed=seed + attempt, boost=boost[used],
                                                               pins=np.flatnonzero(pins[used]), **options)
            original = np.empty(int(retry.sum()), np.int64)
            part_component = part.face_components()
            original[part_component] = component[mask]
            passed = np.zeros(len(checks), bool)
            part_checks = check.check_components(part, again.mesh, part_component, again_component, edge=edge,
                                                 source_surface=part_surface, walks=walks)
            # mended where it missed before a further whole try, as the first try is
            taken_mesh, taken_component = _mend_misses(part, again.mesh, part_component, again_component,
                                                       part_checks, edge, part_surface, walks)
            for c in part_checks:
                if c.ok:
                    passed[original[c.component]] = True
                    checks[original[c.component]] = replace(c, component=int(original[c.component]))
                elif not c.mendable:
                    retry[original[c.component]] = False
            if passed.any():
                taken = np.where(taken_component >= 0, original[np.maximum(taken_component, 0)], -1)
                out = check.keep_input(taken_mesh, out, taken, out_component, passed)
                out_component = check.kept_component(taken, out_component, passed)
                failed &= ~passed
                retry &= ~passed
            if not retry.any():
                break
            last, last_surface, last_used = again.mesh, part_surface, used
            last_mask = retry[original[part_component]]
            last_out_mask = (again_component < 0) | retry[original[np.maximum(again_component, 0)]]
    result.timings["verify"] = time.perf_counter() - clock
    result.mesh, result.checks = out, checks
    return result


def _cvt_remesh(mesh: TriMesh, edge: float, *, feature_angle: float, adaptive: float, max_iter: int, tol: float,
                smooth_rounds: int, seed: int, bridge_gaps: bool,
                boost: np.ndarray | None = None,
                pins: np.ndarray | None = None) -> tuple[RemeshResult, np.ndarray, SurfaceDistance]:
    """:func:`remesh` without the check: the result (no ``checks``), the input component each output face
    stands for ((f_out,), -1 where its corners come from several) and the input's closest-point engine.
    ``boost``: :func:`curvature_density`'s; ``pins``: input vertices made corners (:func:`pin_corners`)."""
    timings = {}
    clock = [time.perf_counter()]

    def mark(phase: str) -> None:
        now = time.perf_counter()
        timings[phase] = timings.get(phase, 0.0) + now - clock[0]
        clock[0] = now

    features = feat.detect(mesh, feature_angle, min_area=edge**2, bridge=bridge_gaps,
                           miss=check.HAUSDORFF_FRACTION * edge)
    line = np.arange(len(features.curves))
    if pins is not None:
        # pins nearer each other than the tries pin for (a miss of half the tolerance) stand for one
        features, line = pin_corners(mesh, features, pins, 0.5 * check.HAUSDORFF_FRACTION * edge)
    mark("features")
    samples = refine(mesh, edge / SAMPLES_PER_EDGE)
    rho_v = curvature_density(mesh, edge, adaptive, check.HAUSDORFF_FRACTION, features.patch, boost)
    density = rho_v[mesh.faces].mean(axis=1)  # per input face
    from scipy.spatial import cKDTree

    tree = cKDTree(mesh.vertices)
    # along feature curves, generators no closer than the first try's finest (L / MAX_SHRINK), where a retry's
    # boost lifts the density past it: the samples (L / SAMPLES_PER_EDGE apart) do not resolve a narrower curve
    # cell, and its neighbours' labels meet it at one sample vertex, whose dual joins three generators on a line,
    # a face without area (44 on a try of the bumpy gyroid)
    vertex_density = lambda p: np.minimum(rho_v[tree.query(p)[1]], MAX_SHRINK**4)  # noqa: E731
    mark("sampling")
    gens, curves = cvt.initialise(mesh, features, samples, edge, density, vertex_density, seed)
    group = cvt.sample_groups(mesh, samples, features)
    mark("init")
    surfaces = cvt.PatchSurfaces(mesh, features.patch)  # closest points per patch, for Lloyd and smoothing
    result = cvt.lloyd(mesh, features, samples, group, gens, curves, density, max_iter, tol, near=edge,
                       surfaces=surfaces)
    labels, energy = result.labels, result.energy
    del result  # its labels are replaced where cells are connected: one per-sample array held, not two
    mark("lloyd")
    pinned = gens.kind != cvt.PATCH
    sliver = curve_slivers(gens.kind, gens.owner, curve_ends(features, mesh.n_vertices), line)
    on_boundary = _on_boundary(features, gens)
    faces, skipped = extract.dual_faces(samples, labels, gens.positions, pinned, sliver)
    mark("extraction")
    for _ in range(CONNECT_ROUNDS):
        bad = repair.defects(gens.positions, faces, on_boundary)
        if not bad.any():
            break
        # cells in pieces (bumps, folds): keep each one's main piece, then extract again;
        # cells with only two neighbours cannot be manifold vertices: they go entirely, corners and
        # curve generators too (a corner among the dozens a bumpy 3 nm sphere has at 40 deg kept a
        # hole), but never a generator of the open boundary
        lone = bad & repair.lone_generators(faces, len(gens.positions)) & ~on_boundary
        del faces  # not held through the connection and the next extraction (180 bytes per input face, thin plate)
        labels = cvt.connect_cells(samples, labels, group, gens, features.n_patches, bad, lone)
        faces, skipped = extract.dual_faces(samples, labels, gens.positions, pinned, sliver)
    del group
    mark("connect")
    faces = optimize.flip_caps(gens.positions, repair.repair(gens.positions, faces, on_boundary, pinned, sliver),
                               pinned)
    faces = repair.drop_rim_caps(gens.positions, faces, pinned)
    used, faces = np.unique(faces, return_inverse=True)
    faces = faces.reshape(-1, 3)
    mark("repair")
    kind, owner = gens.kind[used], gens.owner[used]
    extracted = gens.positions[used]
    # the centring needs only the cells of the samples it visits (flips keep the face count): the per-sample
    # labels (4 bytes a sample, 256 per input face at 64 samples a face) go before the optimisation's peak
    stride = optimize.centring_stride(samples.n_samples, len(faces))
    vertex_of = np.full(len(gens.positions), -1, np.int32)  # int32 as the labels: held through the optimisation
    vertex_of[used] = np.arange(len(used))
    start = vertex_of[labels[::stride]]
    del labels
    vertices, faces = _optimise(mesh, features, extracted, faces, kind, owner, gens.arc[used], smooth_rounds, edge,
                                surfaces, line)
    vertices = optimize.centre_on_samples(vertices, faces, kind == cvt.PATCH, samples, start, stride)
    vertices = optimize.undo_crossings(extracted, vertices, faces)
    mark("optimise")
    out = _transfer_scalars(mesh, TriMesh(vertices, faces), edge, surfaces.whole)
    mark("scalars")
    generator_component = _generator_components(mesh, features, gens, mesh.face_components())[used]
    corner = generator_component[faces]
    out_component = np.where((corner == corner[:, :1]).all(axis=1), corner[:, 0], -1)
    on_curve = isin(features.corners, np.concatenate([c[[0, -1]] for c in features.curves] or [np.empty(0, np.int64)]))
    return (RemeshResult(out, edge, len(energy) - 1, energy, skipped, int(on_curve.sum()),
                         len(features.curves), timings, [], int((~on_curve).sum())), out_component, surfaces.whole)


def missed(mesh: TriMesh, out: TriMesh, *, mask: np.ndarray, out_mask: np.ndarray, edge: float,
           tolerance: float, surface: SurfaceDistance, walks: tuple = (None, None)) -> tuple[np.ndarray, np.ndarray]:
    """Where a remesh ``out`` of ``mesh`` missed it by d > ``tolerance``·L / 2 (L = ``edge``, nm): (v,) the factor by
    which edges shrink again at ``mesh``'s vertices within L of such a face, 2d / (``tolerance``·L), the shrink
    that brings a miss in proportion to the edge (a chord across a kink) to half the tolerance (a sagitta, in
    proportion to its square, falls further), 1 elsewhere; and the vertices of ``mesh`` to pin as corners: of
    each such face of ``mesh``, the vertex farthest from ``out`` (a needle's tip, a kink of a feature curve,
    which no finer sampling need hit).

    Faces: those of ``mesh`` in ``mask`` (f,) measured to ``out`` and those of ``out`` in ``out_mask`` measured
    to ``mesh`` (``surface``, its closest-point engine), each by the farthest of its vertices, edge midpoints
    and centroid (:func:`~apt_filters.remesh.verify.farthest`, the check's own measure). ``walks``: the check's
    walked bounds of ``mesh`` from ``out`` and of ``out`` from ``mesh`` (:class:`~apt_filters.remesh.verify.Walks`),
    taken where they cover the faces measured.
    """
    from scipy.spatial import cKDTree

    tol = tolerance * edge
    points, miss, far_faces = [], [], []
    corner_distance = np.zeros(mesh.n_vertices)  # exact at the corners of every face of mesh that misses
    for a, b, sel, engine, at, walked in ((mesh, out, mask, None, corner_distance, walks[0]),
                                          (out, mesh, out_mask, surface, None, walks[1])):
        d = check.farthest(a, b, np.where(sel, np.arange(a.n_faces), -1), a.n_faces, tol, surface=engine,
                           floor=0.5 * tol, vertex_distance=at, walks=walked)
        far = d > 0.5 * tol  # where the factor below exceeds 1
        points.append(a.vertices[a.faces[far]].mean(axis=1))
        miss.append(d[far])
        far_faces.append(a.faces[far])
    points, miss = np.vstack(points), np.concatenate(miss)
    boost = np.ones(mesh.n_vertices)
    if len(miss):
        ids = cKDTree(mesh.vertices).query_ball_point(points, edge)
        counts = np.array([len(i) for i in ids])
        np.maximum.at(boost, np.concatenate(ids).astype(np.int64), np.repeat(2.0 * miss / tol, counts))
    corners = far_faces[0]
    if len(corners):
        corners = corners[np.arange(len(corners)), corner_distance[corners].argmax(axis=1)]
    return boost, unique(corners)


def pin_corners(mesh: TriMesh, features: feat.Features, vertices: np.ndarray,
                spacing: float) -> tuple[feat.Features, np.ndarray]:
    """``features`` with ``vertices`` (input vertex ids) made corners, and (n_curves,) the curve of ``features``
    each of its curves is a piece of: a feature curve through one is split there
    (a closed loop through one only is split again at its middle, so that its pieces have two ends). A curve
    from a corner back to it is not a loop: turned to start at a pinned vertex, it would run through that
    corner, and a generator placed on it could sit on the corner's own.

    A vertex within ``spacing`` (nm) of a corner or of a vertex pinned before it (in id order) is left out: an
    output vertex stands that near already, and two corners on one short input edge with its midpoint
    between them (the bumpy gyroid's tries: 0.025 nm apart) made a face without area, which no flip mends."""
    vertices = np.setdiff1d(vertices, features.corners)
    if len(vertices):
        from scipy.spatial import cKDTree

        if len(features.corners):
            vertices = vertices[cKDTree(mesh.vertices[features.corners]).query(mesh.vertices[vertices])[0] > spacing]
        keep = np.ones(len(vertices), bool)
        for i, j in sorted(cKDTree(mesh.vertices[vertices]).query_pairs(spacing)):
            if keep[i]:
                keep[j] = False
        vertices = vertices[keep]
    if not len(vertices):
        return features, np.arange(len(features.curves))
    extra, curves, curve_patches, boundary, origin = [vertices], [], [], [], []
    pin = np.zeros(mesh.n_vertices, bool)  # a lookup per curve (an isin per curve was a tenth of a try's CPU)
    pin[vertices] = True
    for i, (c, patches, on_rim) in enumerate(zip(features.curves, features.curve_patches, features.boundary_curve)):
        cut = np.flatnonzero(pin[c])
        if cvt.is_loop(c, features.corners) and len(cut):  # a loop: start it at a pinned vertex
            c = np.concatenate([c[cut[0]:-1], c[:cut[0] + 1]])
            cut = np.flatnonzero(pin[c])
            if len(unique(c[cut])) == 1:
                extra.append(c[[len(c) // 2]])
                cut = np.union1d(cut, [len(c) // 2])
        ends = np.union1d(np.union1d(cut, [0]), [len(c) - 1])
        for a, b in zip(ends[:-1], ends[1:]):
            curves.append(c[a:b + 1])
            origin.append(i)
            curve_patches.append(patches)
            boundary.append(on_rim)
    new = unique(np.concatenate(extra))
    # the patches round each new corner, from its faces' (vertex, patch) pairs sorted once
    at = isin(mesh.faces.ravel(), new)
    pairs = unique_rows(np.stack([mesh.faces.ravel()[at], np.repeat(features.patch, 3)[at]], 1))[0]
    around = np.split(pairs[:, 1], np.searchsorted(pairs[:, 0], new[1:]))
    return replace(features, corners=np.concatenate([features.corners, new]), curves=curves,
                   curve_patches=curve_patches, corner_patches=list(features.corner_patches) + around,
                   boundary_curve=np.array(boundary, bool)), np.array(origin, np.int64)


def _part(mesh: TriMesh, mask: np.ndarray) -> tuple[TriMesh, np.ndarray]:
    """The faces ``mask`` (f,) of ``mesh`` as a mesh of their own, with their scalars, and (v',) the vertex of
    ``mesh`` each of its vertices is."""
    used, local = np.unique(mesh.faces[mask], return_inverse=True)
    part = TriMesh(mesh.vertices[used], local.reshape(-1, 3),
                   {k: np.asarray(v)[used] for k, v in mesh.vertex_scalars.items()},
                   {k: np.asarray(v)[mask] for k, v in mesh.face_scalars.items()})
    return part, used


def _generator_components(mesh: TriMesh, features: feat.Features, gens: cvt.Generators,
                          face_component: np.ndarray) -> np.ndarray:
    """(n,) input component of every generator: of its patch, corner vertex or curve."""
    patch = np.empty(features.n_patches, np.int64)
    patch[features.patch] = face_component
    vertex = np.full(mesh.n_vertices, -1, np.int64)
    vertex[mesh.faces.ravel()] = np.repeat(face_component, 3)
    curve = np.array([vertex[c[0]] for c in features.curves], np.int64)
    out = np.empty(len(gens.kind), np.int64)
    for kind, table in ((cvt.PATCH, patch), (cvt.CORNER, vertex[features.corners]), (cvt.CURVE, curve)):
        sel = gens.kind == kind
        out[sel] = table[gens.owner[sel]]
    return out


def _on_boundary(features: feat.Features, gens: cvt.Generators) -> np.ndarray:
    """(n,) bool: generators on a boundary curve of the input (its open boundary)."""
    boundary_curves = np.flatnonzero(features.boundary_curve)
    on_boundary = (gens.kind == cvt.CURVE) & isin(gens.owner, boundary_curves)
    corner_ids = features.corners[gens.owner[gens.kind == cvt.CORNER]]
    on_boundary[gens.kind == cvt.CORNER] = isin(corner_ids, np.concatenate(
        [features.curves[i] for i in boundary_curves] or [np.empty(0, np.int64)]))
    return on_boundary


def _optimise(mesh: TriMesh, features: feat.Features, vertices: np.ndarray, faces: np.ndarray,
              kind: np.ndarray, owner: np.ndarray, arc: np.ndarray, rounds: int, edge: float,
              surfaces: cvt.PatchSurfaces, line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Valence flips and tangential relaxation, then Delaunay flips; curve vertices slide along their curve
    in order (:class:`CurveSlides`; ``arc`` (v,) their arc lengths), corners stay. Patch vertices are projected
    onto their patch (``surfaces``), searched within ``edge`` (nm) first. ``line``: :func:`curve_slivers`'."""
    if rounds == 0 or len(faces) == 0:
        return vertices, faces
    pinned = kind != cvt.PATCH
    boundary = optimize.boundary_vertices(TriMesh(vertices, faces))
    valence = np.bincount(faces.ravel(), minlength=len(vertices)).astype(float)
    target = np.where(boundary, 3.0, 6.0)
    target[kind == cvt.CORNER] = valence[kind == cvt.CORNER]

    def fixed(a, b):
        return pinned[a] & pinned[b]

    sliver = curve_slivers(kind, owner, curve_ends(features, mesh.n_vertices), line)

    hint = np.full(len(vertices), -1, np.int64)  # each vertex's face at its last projection, walked from
    slides = CurveSlides(mesh.vertices, features.curves, features.corners, kind, owner, arc)

    def projection(reach, commit):
        def project(points, ids):
            out = points.copy()
            sel = kind[ids] == cvt.PATCH
            out[sel], hint[ids[sel]] = surfaces.closest(points[sel], owner[ids][sel], edge, hint[ids[sel]])
            sel = kind[ids] == cvt.CURVE
            out[sel] = slides.project(points[sel], ids[sel], reach)
            if commit:  # every point given is where its vertex goes (the relaxation's)
                slides.moved(ids[sel], out[sel])
            return out
        return project

    # all vertices move at once in the relaxation: two curve neighbours, each less than half way to the other,
    # stay apart; in the sweeps one of two neighbours moves at a time
    project, sweep_project = projection(SLIDE_REACH[0], True), projection(SLIDE_REACH[1], False)

    def relax(vertices, faces):
        vertices = optimize.relax(vertices, faces, movable, project)
        # three vertices of one curve in a face, which the curve's bend gave area when extracted, come to lie on
        # a line as they slide along a straight stretch: such a cap's long edge is flipped as at extraction
        return vertices, optimize.flip_caps(vertices, faces, pinned)

    movable = kind != cvt.CORNER
    for r in range(rounds):
        for k in range(3):
            faces, flipped = optimize.flip_pass(vertices, faces, fixed, target, seed=r * 3 + k, sliver=sliver)
            if flipped == 0:
                break
        vertices, faces = relax(vertices, faces)
    # Delaunay flips once the valences settled (in every round they undo valence flips: mean Q fell
    # by 0.01), then one more relaxation: +0.002 mean Q, fewer triangles under 30 degrees
    for k in range(5):
        faces, flipped = optimize.delaunay_pass(vertices, faces, fixed, seed=rounds * 3 + k, sliver=sliver)
        if flipped == 0:
            break
    vertices, faces = relax(vertices, faces)
    vertices = optimize.improve_quality(vertices, faces, movable, sweep_project, moved=slides.moved)
    return optimize.improve_angles(vertices, faces, movable, sweep_project, moved=slides.moved), faces


def curve_slivers(kind: np.ndarray, owner: np.ndarray, ends: np.ndarray, line: np.ndarray | None = None):
    """``sliver(p, q, r)`` -> (k,) bool: faces of three vertices along one feature curve (three of its
    generators, a corner and two of them, or one of them and the curve's two end corners), which
    extraction and flips must not make: on a straight stretch of the curve they have no area, and the
    edge between two pinned vertices is never flipped away. ``kind``, ``owner``: (v,) per vertex, as
    :class:`~apt_filters.remesh.cvt.Generators`; ``ends``: (n_curves, 2) the corner (its owner id) at each
    end of every curve, -1 for a closed loop (:func:`curve_ends`); ``line``: (n_curves,) the curve each one
    continues (:func:`pin_corners`' pieces of one curve, which go on straight through the pin between
    them: a piece's generator, the pin and the next piece's made a face without area), by default itself."""
    line = np.arange(len(ends)) if line is None else line
    pinned = kind != cvt.PATCH
    on_line = np.where(kind == cvt.CURVE, line[np.minimum(owner, len(line) - 1)] if len(line) else -1, -1)
    corner = np.where(kind == cvt.CORNER, owner, -1)
    n_corners = int(max(owner.max(initial=0), ends.max(initial=0))) + 2
    # (line, corner) for every end corner of every piece of the line
    at_end = np.unique(np.concatenate([line * n_corners + ends[:, 0], line * n_corners + ends[:, 1]])) \
        if len(ends) else np.empty(0, np.int64)

    def sliver(p, q, r):
        ids = np.stack([on_line[p], on_line[q], on_line[r]], axis=1)
        on = ids >= 0
        curve = ids.max(axis=1)
        same = (np.where(on, ids, curve[:, None]) == curve[:, None]).all(axis=1)
        at = np.stack([corner[p], corner[q], corner[r]], axis=1)
        at_ends = ((at < 0) | isin((curve[:, None] * n_corners + at).ravel(), at_end).reshape(at.shape)).all(axis=1)
        n_on = on.sum(axis=1)
        return pinned[p] & pinned[q] & pinned[r] & same & ((n_on >= 2) | ((n_on == 1) & at_ends))

    return sliver


def curve_ends(features: feat.Features, n_vertices: int) -> np.ndarray:
    """(n_curves, 2) int64: the corner (index into ``features.corners``) at each end of every feature curve
    of a mesh of ``n_vertices``; -1 at both for a closed loop without a corner."""
    corner_of = np.full(n_vertices, -1, np.int64)
    corner_of[features.corners] = np.arange(len(features.corners))
    return corner_of[np.array([c[[0, -1]] for c in features.curves], np.int64).reshape(-1, 2)]


class CurveSlides:
    """Where the curve vertices of a remesh sit along their feature curve, and the moves that keep them in order.

    A curve vertex may only slide along its curve, and never onto or past the next vertex of its curve. Put
    back on the curve by the closest point of the whole polyline, two vertices beside a kink of a bumpy
    surface's noise crease both went to the kink's apex (two output vertices at one point: faces without
    area, which the check counts and no flip mends; the bumpy gyroid's seed 3 was given back after four
    tries so). So every curve vertex keeps its arc length along its curve and is put back on the curve within
    a window: no more than ``reach`` of the way to the vertex before or after it on its curve (the curve's
    ends, fixed corners, at 0 and its length; a loop wraps). In the relaxation all vertices move at once and
    a reach under 1/2 keeps two neighbours apart; in the sweeps (:func:`apt_filters.remesh.optimize.
    improve_quality`, :func:`~apt_filters.remesh.optimize.improve_angles`) no two neighbours move together,
    and the sweeps say where each went (:meth:`moved`).

    ``points`` (n, 3): the input's vertices, ``curves`` its feature curves (vertex ids), ``corners`` its
    corner vertices; ``kind``, ``owner`` (v,) of the remesh's vertices (a curve vertex's owner is its curve)
    and ``arc`` (v,) their arc lengths along it (nm; :class:`cvt.Generators`' own, nan off the curves).
    """

    def __init__(self, points: np.ndarray, curves: list, corners: np.ndarray, kind: np.ndarray,
                 owner: np.ndarray, arc: np.ndarray):
        self.ptr = np.r_[0, np.cumsum([len(c) for c in curves])].astype(np.int64)
        self.points = points[np.concatenate(curves)] if curves else np.empty((0, 3))
        seg = [np.linalg.norm(np.diff(points[c], axis=0), axis=1) for c in curves]
        self.s = np.concatenate([np.r_[0.0, np.cumsum(d)] for d in seg]) if curves else np.empty(0)
        self.length = np.array([d.sum() for d in seg], np.float64)
        self.closed = np.array([cvt.is_loop(c, corners) for c in curves], np.bool_)
        self.ids = np.flatnonzero(kind == cvt.CURVE)
        self.curve = owner[self.ids].astype(np.int64)
        self.index = np.full(len(kind), -1, np.int64)  # position of each curve vertex in ``ids``
        self.index[self.ids] = np.arange(len(self.ids))
        self.arc = np.asarray(arc, np.float64)[self.ids].copy()
        # the sweeps ask for the windows once per batch, and curve vertices stay in their order along the curve
        # (within their windows): the windows are kept until a move, the order until it no longer sorts
        self._order = np.lexsort((self.arc, self.curve))
        self._windows = None

    def _sorted(self, order: np.ndarray) -> bool:
        """Whether ``order`` is :func:`numpy.lexsort`'s of (arc, curve) (ties by index, as its stable sort)."""
        c, a = self.curve[order], self.arc[order]
        same_arc = (a[1:] == a[:-1]) & (order[1:] > order[:-1])
        return bool(((c[1:] > c[:-1]) | ((c[1:] == c[:-1]) & ((a[1:] > a[:-1]) | same_arc))).all())

    def _neighbours(self) -> tuple[np.ndarray, np.ndarray]:
        """(m,) arc lengths of the vertex before and after each curve vertex on its curve (loops unwrapped)."""
        if self._windows is not None:
            return self._windows
        if not self._sorted(self._order):
            self._order = np.lexsort((self.arc, self.curve))
        order = self._order
        a, c = self.arc[order], self.curve[order]
        m = len(a)
        first = np.r_[True, c[1:] != c[:-1]] if m else np.zeros(0, bool)
        last = np.r_[c[1:] != c[:-1], True] if m else np.zeros(0, bool)
        head = np.maximum.accumulate(np.where(first, np.arange(m), 0))
        tail = np.minimum.accumulate(np.where(last, np.arange(m), m)[::-1])[::-1]
        before, after = np.empty(m), np.empty(m)
        before[1:], after[:-1] = a[:-1], a[1:]
        closed, length = self.closed[c], self.length[c]
        before[first] = np.where(closed, a[tail] - length, 0.0)[first]
        after[last] = np.where(closed, a[head] + length, length)[last]
        out_before, out_after = np.empty(m), np.empty(m)
        out_before[order], out_after[order] = before, after
        self._windows = out_before, out_after
        return self._windows

    def project(self, points: np.ndarray, ids: np.ndarray, reach: float) -> np.ndarray:
        """(k, 3) the closest point to each of ``points`` on the curve of vertex ``ids`` (curve vertices)
        within its window: no more than ``reach`` of the way to the vertex before or after it on its curve."""
        before, after = self._neighbours()
        i = self.index[ids]
        lo, hi = self.arc[i] - reach * (self.arc[i] - before[i]), self.arc[i] + reach * (after[i] - self.arc[i])
        return _closest_in_window(points, self.curve[i], lo, hi, self.ptr, self.s, self.points, self.length,
                                  self.closed)[0]

    def moved(self, ids: np.ndarray, points: np.ndarray) -> None:
        """Record that the vertices ``ids`` (any kind) went to ``points`` (k, 3), which :meth:`project` gave."""
        sel = self.index[ids] >= 0
        if not sel.any():
            return
        i = self.index[ids[sel]]
        before, after = self._neighbours()
        self.arc[i] = _closest_in_window(points[sel], self.curve[i], before[i], after[i], self.ptr, self.s,
                                         self.points, self.length, self.closed)[1]
        self._windows = None


@njit(cache=True)
def _points_at(arc, curve, ptr, s, points):
    """(n, 3) the points at arc lengths ``arc`` (n,) along polylines ``curve`` (n,) (``points[ptr[c]:ptr[c + 1]]``
    at arc lengths ``s[ptr[c]:ptr[c + 1]]``)."""
    out = np.empty((len(arc), 3))
    for i in range(len(arc)):
        a, b = ptr[curve[i]], ptr[curve[i] + 1]
        j = min(max(np.searchsorted(s[a:b], arc[i]) - 1, 0), b - a - 2) + a
        t = (arc[i] - s[j]) / max(s[j + 1] - s[j], 1e-300)
        t = min(max(t, 0.0), 1.0)
        for k in range(3):
            out[i, k] = points[j, k] + t * (points[j + 1, k] - points[j, k])
    return out


@njit(cache=True)
def _closest_in_window(p, curve, lo, hi, ptr, s, points, length, closed):
    """The closest point to each of ``p`` (n, 3) on its polyline ``curve`` (n,) among those of arc length in
    [``lo``, ``hi``] (n,; a loop's taken modulo its length), and its arc length: (n, 3), (n,)."""
    out = np.empty((len(p), 3))
    where = np.empty(len(p))
    for i in range(len(p)):
        c = curve[i]
        best = np.inf
        # element by element, not a row copy: numba's shape check of that copy compiles its error message's
        # string formatting, seconds of a fresh install's CPU
        out[i, 0], out[i, 1], out[i, 2] = p[i, 0], p[i, 1], p[i, 2]
        where[i] = lo[i]
        shifts = 3 if closed[c] else 1
        for h in range(shifts):
            shift = (h - 1) * length[c] if closed[c] else 0.0
            for j in range(ptr[c], ptr[c + 1] - 1):
                s0, s1 = s[j] + shift, s[j + 1] + shift
                if s1 < lo[i] or s0 > hi[i]:
                    continue
                d0, d1 = points[j + 1, 0] - points[j, 0], points[j + 1, 1] - points[j, 1]
                d2 = points[j + 1, 2] - points[j, 2]
                seg = max(d0 * d0 + d1 * d1 + d2 * d2, 1e-300)
                t = ((p[i, 0] - points[j, 0]) * d0 + (p[i, 1] - points[j, 1]) * d1
                     + (p[i, 2] - points[j, 2]) * d2) / seg
                # the part of the segment inside the window
                t0 = max((lo[i] - s0) / max(s1 - s0, 1e-300), 0.0)
                t1 = min((hi[i] - s0) / max(s1 - s0, 1e-300), 1.0)
                t = min(max(t, t0), t1)
                x0, x1, x2 = points[j, 0] + t * d0, points[j, 1] + t * d1, points[j, 2] + t * d2
                d = (x0 - p[i, 0]) ** 2 + (x1 - p[i, 1]) ** 2 + (x2 - p[i, 2]) ** 2
                if d < best:
                    best = d
                    out[i, 0], out[i, 1], out[i, 2] = x0, x1, x2
                    where[i] = s0 + t * (s1 - s0)
        if closed[c]:
            where[i] = where[i] % length[c]
    return out, where


def _mend_misses(mesh: TriMesh, out: TriMesh, component: np.ndarray, out_component: np.ndarray, checks: list,
                 edge: float, surface: SurfaceDistance, walks: tuple) -> tuple[TriMesh, np.ndarray]:
    """``out`` (a remesh of ``mesh``) mended (:func:`_mend`) where components that fail only in distances missed,
    faces elsewhere as they were: a retry remeshes a whole component again. Where the mend leaves no miss by its
    own measure, the mended components are checked in full, and those that pass replace their entries of
    ``checks`` (changed in place). Returns the mesh, mended or ``out``, and its faces' input components.
    ``walks``: the check's walked bounds of ``mesh`` and ``out`` (:class:`~apt_filters.remesh.verify.Walks`)."""
    local = np.array([not c.ok and c.mendable and c.distances_only for c in checks], bool)
    if not local.any():
        return out, out_component
    mended, mended_component, done = _mend(mesh, out, component, out_component, np.flatnonzero(local), edge,
                                           surface, walks)
    if not done:
        return out, out_component
    for c in check.check_components(mesh, mended, component, mended_component, edge=edge, source_surface=surface,
                                    only=local):
        if c.ok:
            checks[c.component] = c
    return mended, mended_component


def _mend(mesh: TriMesh, out: TriMesh, component: np.ndarray, out_component: np.ndarray, components: np.ndarray,
          edge: float, surface: SurfaceDistance, walks: tuple) -> tuple[TriMesh, np.ndarray, bool]:
    """:func:`apt_filters.remesh.mend.mend` of ``out``'s ``components`` (input component ids) where they miss
    ``mesh``, with scalars: a new or moved vertex's interpolated from ``mesh``, a face's from the face it is a
    piece of. Returns the mesh, its faces' input components and whether no miss is left (:func:`mend`'s).
    ``walks``: the check's walked bounds, which the mend's first measure takes (:func:`mend`'s)."""
    m = mend(mesh, out, component, out_component, components, edge=edge, tolerance=check.HAUSDORFF_FRACTION,
             surface=surface, walks=walks)
    mended = TriMesh(m.vertices, m.faces, {}, {k: np.asarray(v)[m.parent] for k, v in out.face_scalars.items()})
    if out.vertex_scalars:
        old = m.origin >= 0
        changed = ~old
        changed[old] = (m.vertices[old] != out.vertices[m.origin[old]]).any(axis=1)
        at = _vertex_scalars(mesh, m.vertices[changed], edge, surface)
        for name, values in out.vertex_scalars.items():
            values = np.asarray(values, np.float64)[np.maximum(m.origin, 0)]
            values[changed] = at[name]
            mended.vertex_scalars[name] = values
    return mended, m.component, m.done


def _vertex_scalars(source: TriMesh, points: np.ndarray, edge: float, surface: SurfaceDistance) -> dict:
    """``source``'s vertex scalars interpolated at ``points`` (n, 3) nm (``surface``: its closest-point engine)."""
    _, face, weights = surface.closest(points, edge)
    corners = source.faces[face]
    return {name: np.einsum("nk,nk->n", weights, np.asarray(values, np.float64)[corners])
            for name, values in source.vertex_scalars.items()}


def _transfer_scalars(source: TriMesh, target: TriMesh, edge: float, surface: SurfaceDistance) -> TriMesh:
    """Interpolate ``source``'s vertex scalars at ``target``'s vertices; face scalars from the nearest face
    (``surface``: ``source``'s closest-point engine)."""
    if not source.vertex_scalars and not source.face_scalars:
        return target
    if source.vertex_scalars:
        target.vertex_scalars.update(_vertex_scalars(source, target.vertices, edge, surface))
    if source.face_scalars:
        nearest = surface.closest(target.vertices[target.faces].mean(axis=1), edge)[1]
        for name, values in source.face_scalars.items():
            target.face_scalars[name] = np.asarray(values)[nearest]
    return target
