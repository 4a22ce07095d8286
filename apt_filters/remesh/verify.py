"""Checks that a remesh kept the surface it was given, one input component at a time.

Each connected component of the input is compared with the output faces that stand for it:
the same Euler characteristic (hence genus) and number of boundary loops, one output
component for it, the output's open rims on the input's boundary, two-sided Hausdorff
distance and area change within tolerances. A component that fails is given back as it was
(:func:`keep_input`), so one bad object never costs the others their remesh, and no remesh
ever changes the surface beyond the tolerances.

Distances are measured from every vertex, edge midpoint and face centroid of one mesh to the
other (exact point-to-triangle distances: walked bounds, then :mod:`apt_filters.core.distance`
where a face may hold the farthest point, :func:`farthest`): on triangles no larger than the edge
length, this misses a farther point by at most a quarter of an edge's sagitta.
Peak memory: the distance engine's grid of each mesh, one distance per vertex, edge and face of the
measured mesh (8 bytes each), and the probes a chunk at a time (:func:`~apt_filters.remesh.sampling.chunk_length`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.distance import mesh_distance
from apt_filters.core.mesh import TriMesh, topology
from apt_filters.remesh._arrays import unique_rows
from apt_filters.remesh.sampling import chunk_length

# Two-sided Hausdorff distance allowed between a component and its remesh, as a fraction of the
# target edge length, and the relative area change allowed (the targets).
HAUSDORFF_FRACTION = 0.25
AREA_TOLERANCE = 0.01
# An output face with less area than this fraction of the target edge squared counts as without area
# (a well-shaped face has ~0.43; floating-point noise on a collapsed one is many orders below this).
FLAT_AREA = 1e-9


@dataclass
class ComponentCheck:
    """How one input component came out of the remesh. Lengths in nm."""

    component: int
    faces_in: int
    faces_out: int
    euler_in: int
    euler_out: int
    loops_in: int
    loops_out: int
    hausdorff_out_in: float  # farthest output point from the input
    hausdorff_in_out: float  # farthest input point from the output
    rim: float  # farthest open-rim point of either from the other's rim (0 when closed)
    area_change: float  # (output - input) / input
    reasons: list = field(default_factory=list)
    # False where only the area is off: remeshing again finer where points were missed does not mend it
    mendable: bool = True
    # True where only distances (Hausdorff, rim) are off, not the pieces, Euler characteristic, boundary loops,
    # faces' areas or the area (a remesh flattening bumps of its own size): vertices inserted where it missed
    # can mend that (apt_filters.remesh.mend)
    distances_only: bool = True

    @property
    def ok(self) -> bool:
        return not self.reasons


@dataclass
class Walks:
    """:func:`farthest`'s walked bounds (nm) of ``mesh``'s vertices, edge midpoints and centroids from ``other``,
    (v,), (e,) and (f,), those of the faces ``faces`` (f,) bool (0 elsewhere): kept by a caller that measures the
    same two meshes again (the check, then :func:`apt_filters.remesh.remesh.missed` where a component is remeshed
    again), so that no probe is walked twice. A bound depends on the two meshes and the probe alone. Empty until
    a :func:`farthest` call fills it."""

    mesh: TriMesh | None = None
    other: TriMesh | None = None
    faces: np.ndarray | None = None
    bounds: list | None = None


def euler_and_loops(mesh: TriMesh, component: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(k,) Euler characteristic V - E + F and (k,) number of boundary loops of each face group.

    ``component`` (f,) assigns every face to a group 0 .. k-1 (-1: left out). Boundary loops are the
    circles of the boundary-edge graph (:attr:`Topology.boundary_loops`): a rim that touches itself at a vertex
    counts two, so an output pinched there (a non-manifold vertex, Euler characteristic unchanged: a wide
    interface's disc came out so) fails the check, where its connected pieces (one) passed it.
    """
    chi, loops = np.zeros(k, np.int64), np.zeros(k, np.int64)
    order = np.argsort(component, kind="stable")
    groups, starts = np.unique(component[order], return_index=True)
    for j, part in zip(groups, np.split(order, starts[1:])):
        if j < 0:
            continue
        # a group of every face (one component): the mesh's own topology, which the distances built; a copy of the
        # faces and a topology of its own were the check's peak on the box-sphere-plate (715 bytes per input face)
        whole = len(part) == mesh.n_faces
        faces = mesh.faces if whole else mesh.faces[part]
        topo = mesh.topology if whole else topology(faces, mesh.n_vertices)
        chi[j] = len(np.unique(faces)) - len(topo.edge_vertices) + len(faces)
        loops[j] = topo.boundary_loops
    return chi, loops


def farthest(mesh: TriMesh, other: TriMesh, group: np.ndarray, k: int, near: float, chunk: int = 1 << 14,
             surface=None, floor: float = 0.0, vertex_distance: np.ndarray | None = None,
             walks: Walks | None = None) -> np.ndarray:
    """(k,) for each group of ``mesh``'s faces (``group`` (f,) in 0 .. k-1, -1 left out), the farthest
    distance (nm) of their vertices, edge midpoints and centroids from ``other`` (exact; searched within
    ``near`` nm first), or ``floor`` (nm) where that is farther: a group whose walked bounds (below) are all
    within ``floor`` is not searched (:func:`apt_filters.remesh.remesh.missed` asks which faces, each its own
    group, miss by more than half the tolerance: searched all, that was two thirds of the check's time). Each
    vertex and edge midpoint is measured once (not once per face around it: 7 probes per face became about 3),
    ``chunk`` points at a time; a face takes the largest of its own. ``surface``: ``other``'s
    :class:`~apt_filters.core.distance.SurfaceDistance`, built if not given. ``vertex_distance`` (v,) float64,
    optional, is filled with the distance (nm) of every vertex of the faces measured: exact where a face round it
    was searched (every face of a group whose result exceeds ``floor`` was), its walked bound elsewhere
    (:func:`apt_filters.remesh.remesh.missed` pins the farthest corner of each face that misses: measured
    again, that was a third of its time). ``walks``: the bounds of an earlier call on the same two meshes that
    walked every probe measured now, taken instead of walking again; otherwise filled with this call's.

    Every probe is first measured to the face of ``other`` reached by walking from the nearest vertex
    of ``other`` (:func:`apt_filters.remesh.walk.walk_closest`): an upper bound of its distance, and
    nearly always the distance itself. Faces are then searched exactly, worst bound first, in doubling
    batches, until no face left has a bound above its group's farthest exact distance so far: those
    cannot hold a farther point, so the result is exact. (The exact search for every probe was a
    tenth of the remesh.) Each batch is searched in an engine over the faces of ``other`` near its probes
    (``engine``), or over all of ``other`` where that is most of it (built once then) or ``surface`` is given.

    Memory: 8 bytes per probe of ``mesh`` for the bounds and as many for the exact distances, ``other``'s face
    neighbours and vertex rings (48 bytes per face) and the engine over the faces a batch needs (on a thin plate
    remeshed 7.5 times finer, the first batch's engine was a third of the output)."""
    from scipy.spatial import cKDTree

    from apt_filters.core.distance import SurfaceDistance
    from apt_filters.remesh.walk import face_neighbours, vertex_rings, walk_closest

    out = np.full(k, float(floor))
    if other.n_faces == 0 or mesh.n_faces == 0:
        return out
    v, faces, top = mesh.vertices, mesh.faces, mesh.topology
    ends, face_edge = top.edge_vertices, top.face_edge
    o_vertices = np.ascontiguousarray(other.vertices, np.float64)
    o_faces = np.ascontiguousarray(other.faces, np.int64)
    used = np.unique(o_faces)
    o_tree = cKDTree(o_vertices[used])
    # only the probes of the faces measured: the mend measures again only where it changed the output
    measured = group >= 0
    ids_of = [np.unique(faces[measured]), np.unique(face_edge[measured]), np.flatnonzero(measured)]

    def probes(kind, ids):
        if kind == 0:
            return np.ascontiguousarray(v[ids], np.float64)
        if kind == 1:
            return 0.5 * (v[ends[ids, 0]] + v[ends[ids, 1]])
        return v[faces[ids]].mean(axis=1)

    if walks is not None and walks.mesh is mesh and walks.other is other and walks.faces[measured].all():
        bounds = walks.bounds
    else:
        neighbour = face_neighbours(o_faces, len(o_vertices))
        ring_start, ring = vertex_rings(o_faces, len(o_vertices))
        start = np.zeros(len(v), np.int64)
        start[ids_of[0]] = used[o_tree.query(v[ids_of[0]])[1]]  # a vertex of other near each vertex of mesh
        corner = [lambda ids: ids, lambda ids: ends[ids, 0], lambda ids: faces[ids, 0]]  # a walk's start vertex

        def walked(kind, n):
            d = np.zeros(n)
            todo = ids_of[kind]
            for first in range(0, len(todo), chunk):
                ids = todo[first:first + chunk]
                points = probes(kind, ids)
                d[ids] = np.linalg.norm(points - walk_closest(o_vertices, o_faces, neighbour, ring_start, ring,
                                                              start[corner[kind](ids)], points)[2], axis=1)
            return d

        bounds = [walked(0, len(v)), walked(1, len(ends)), walked(2, len(faces))]
        if walks is not None:
            walks.mesh, walks.other, walks.faces, walks.bounds = mesh, other, measured, bounds
    exact = [b.copy() for b in bounds]
    surface = [surface]
    longest = np.zeros(len(o_faces))  # of each face of other
    for c in range(3):
        np.maximum(longest, np.linalg.norm(o_vertices[o_faces[:, c]] - o_vertices[o_faces[:, c - 1]], axis=1),
                   out=longest)
    pad = 1e-9 + 1e-9 * float(longest.max())  # against rounding

    def engine(sets):
        """The distance engine over the faces of ``other`` that can hold the closest point of a probe of ``sets``.

        A probe's closest point is within its walked bound b, and every point of a face within the face's
        longest edge of a corner: a face none of whose corners is within b + its longest edge of any probe
        cannot hold it. Probes are taken in classes of b (``near`` times powers of 2), each class within its
        largest b. (The engine over the whole output was the peak of the remesh: 5.2 kB per input face of a
        thin plate remeshed 7.5 times finer; a few walks that end on the plate's far side set the largest b.)"""
        if surface[0] is not None:
            return surface[0]
        slack = np.full(len(o_vertices), np.inf)  # least |vertex - probe| - b over the probes, per class's b
        reach = float(longest.max()) + pad
        level = [classes(kind, ids) for kind, ids in sets]
        for j in np.unique(np.concatenate(level)):
            b = max(float(bounds[kind][ids[at == j]].max(initial=0.0)) for (kind, ids), at in zip(sets, level)) + pad
            points = np.vstack([probes(kind, ids[at == j]) for (kind, ids), at in zip(sets, level)])
            step = max(chunk // 16, 256)  # tens of (probe, vertex) pairs of 24 bytes per probe
            for first in range(0, len(points), step):
                pairs = cKDTree(points[first:first + step]).sparse_distance_matrix(o_tree, b + reach,
                                                                                   output_type="ndarray")
                np.minimum.at(slack, used[pairs["j"]], pairs["v"] - b)
        sub = (slack[o_faces].min(axis=1) <= longest + pad)
        if 2 * sub.sum() > len(o_faces):  # most of it: built once, for every later batch too
            surface[0] = SurfaceDistance(other)
            return surface[0]
        kept, local = np.unique(o_faces[sub], return_inverse=True)
        return SurfaceDistance(TriMesh(o_vertices[kept], local.reshape(-1, 3)))

    def classes(kind, ids):
        """The class j of each probe's walked bound b: b <= ``near`` 2^j."""
        return np.maximum(np.ceil(np.log2(np.maximum(bounds[kind][ids], near) / near)), 0)

    def search(face_ids):
        sets = ((0, np.unique(faces[face_ids])), (1, np.unique(face_edge[face_ids])), (2, face_ids))
        near_part = engine(sets)
        for kind, ids in sets:
            for first in range(0, len(ids), chunk):
                part = ids[first:first + chunk]
                points = probes(kind, part)
                found = near_part.query(points, max_distance=near)
                d = np.abs(found.distance.astype(np.float64))
                # the probes farther than ``near`` (the misses a mend asks about), each class within its bounds'
                # reach, which holds every closest point: searched again without bound, their plan (17 cells each
                # way) was most of a small engine's cost (0.11 s of the bumpy sheet's mend)
                far = np.flatnonzero(found.face < 0)
                level = classes(kind, part[far])
                for j in np.unique(level):
                    at = far[level == j]
                    d[at] = np.abs(near_part.nearest(points[at], near * 2.0 ** j + pad).distance.astype(np.float64))
                exact[kind][part] = d

    def worst(d, ids=slice(None)):
        return np.maximum(np.maximum(d[0][faces[ids]].max(axis=1), d[1][face_edge[ids]].max(axis=1)), d[2][ids])

    bound = worst(bounds)
    keep = np.flatnonzero(group >= 0)
    keep = keep[np.argsort(-bound[keep], kind="stable")]  # by the bounds, worst first
    batch = 64
    while len(keep):  # search the worst faces, a doubling batch at a time, until no bound exceeds its group's
        search(keep[:batch])
        np.maximum.at(out, group[keep[:batch]], worst(exact, keep[:batch]))
        keep = keep[batch:]
        keep = keep[bound[keep] > out[group[keep]]]
        batch *= 2
    if vertex_distance is not None:
        vertex_distance[ids_of[0]] = exact[0][ids_of[0]]
    return out


def _rim_points(mesh: TriMesh, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``spacing`` along the open boundary edges of ``mesh``, and their faces."""
    edges, index, _, counts = unique_rows(np.sort(mesh.edges(), axis=1))
    lone = counts == 1
    rim, face = edges[lone], index[lone] // 3
    if len(rim) == 0:
        return np.empty((0, 3)), np.empty(0, np.int64)
    a, b = mesh.vertices[rim[:, 0]], mesh.vertices[rim[:, 1]]
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(np.int64), 1)
    seg = np.repeat(np.arange(len(rim)), n + 1)
    t = np.arange(len(seg)) - np.repeat(np.r_[0, np.cumsum(n + 1)[:-1]], n + 1)
    t = t / n[seg]
    return a[seg] + t[:, None] * (b[seg] - a[seg]), face[seg]


def check_components(source: TriMesh, result: TriMesh, source_component: np.ndarray,
                     result_component: np.ndarray, *, edge: float,
                     hausdorff_fraction: float = HAUSDORFF_FRACTION,
                     area_tolerance: float = AREA_TOLERANCE, source_surface=None,
                     only: np.ndarray | None = None, walks: tuple | None = None) -> list[ComponentCheck]:
    """Compare every input component with the output faces that stand for it.

    Parameters
    ----------
    source, result : TriMesh
        The input and the remeshed surface (nm).
    source_component : (f_in,) int
        Connected component of each input face, 0 .. k-1.
    result_component : (f_out,) int
        Input component each output face stands for; -1 where its vertices came from several.
    edge : float
        Target edge length (nm); the distance tolerance is ``hausdorff_fraction * edge``.
    source_surface : SurfaceDistance, optional
        ``source``'s closest-point engine (:mod:`apt_filters.core.distance`), built if not given.
    only : (k,) bool, optional
        The components to check (the mended ones, after a mend that changed nothing else); all by default.
    walks : (Walks, Walks), optional
        Filled with the walked bounds of ``source`` from ``result`` and of ``result`` from ``source``
        (:class:`Walks`), for a caller that measures the two again.

    Returns
    -------
    list of ComponentCheck
        One per input component checked, in order; ``reasons`` says what failed.
    """
    k = int(source_component.max()) + 1 if len(source_component) else 0
    tol = hausdorff_fraction * edge
    out_labels = result.face_components() if result.n_faces else np.zeros(0, np.int64)
    # which output components each input component got, and which are shared
    pairs = unique_rows(np.stack([out_labels, result_component + 1], 1))[0]  # (piece, component + 1)
    shared = np.bincount(pairs[:, 0])[pairs[:, 0]] > 1
    real = pairs[:, 1] > 0
    pieces = np.bincount(pairs[real, 1] - 1, minlength=k)
    mixed = np.zeros(k, bool)
    mixed[pairs[real & shared, 1] - 1] = True
    chunk = chunk_length(source.n_faces)  # probes per distance query: temporaries in proportion to the input
    only = np.ones(k, bool) if only is None else np.asarray(only, bool)
    # the distances of the components checked only: the farthest probes' searches are most of a check
    walks = (None, None) if walks is None else walks
    d_in = farthest(source, result, np.where(only[source_component], source_component, -1), k, tol, chunk,
                    walks=walks[0])
    d_out = farthest(result, source, np.where(only[np.maximum(result_component, 0)], result_component, -1), k, tol,
                     chunk, surface=source_surface, walks=walks[1])
    rim = np.zeros(k)
    r_in, rf_in = _rim_points(source, edge / 8)
    r_out, rf_out = _rim_points(result, edge / 8) if result.n_faces else (np.empty((0, 3)), np.empty(0, np.int64))
    if len(r_in) or len(r_out):
        from scipy.spatial import cKDTree

        if len(r_in) and len(r_out):
            np.maximum.at(rim, source_component[rf_in], cKDTree(r_out).query(r_in)[0])
            own = result_component[rf_out] >= 0
            np.maximum.at(rim, result_component[rf_out][own], cKDTree(r_in).query(r_out[own])[0])
        else:  # a rim on one side only: as far as its points are from the other surface
            pts, comps, other = (r_in, source_component[rf_in], result) if len(r_in) else \
                (r_out, result_component[rf_out], source)
            own = comps >= 0
            if other.n_faces and own.any():
                np.maximum.at(rim, comps[own], mesh_distance(other, pts[own]))
    area_in = np.bincount(source_component, source.face_areas(), minlength=k)
    own = result_component >= 0
    area_out = np.bincount(result_component[own], result.face_areas()[own], minlength=k)
    faces_in = np.bincount(source_component, minlength=k)
    faces_out = np.bincount(result_component[own], minlength=k)
    # a face without area (two corners at one place) has no normal: the pseudo-normals of its corners and
    # edges, and so the sign of every distance measured to them, are undefined (an ion 7 nm outside an
    # object read as 7 nm inside), which no distance check sees
    flat = ~(result.face_areas() > FLAT_AREA * edge ** 2)
    degenerate = np.bincount(result_component[own & flat], minlength=k)
    chi_in, loops_in = euler_and_loops(source, source_component, k)
    chi_out, loops_out = euler_and_loops(result, result_component, k)
    checks = []
    for c in np.flatnonzero(only):
        change = area_out[c] / area_in[c] - 1.0 if area_in[c] > 0 else 0.0
        reasons = []
        if pieces[c] != 1 or mixed[c]:
            reasons.append(f"{pieces[c]} output pieces" + (", joined to another component" if mixed[c] else ""))
        if chi_out[c] != chi_in[c]:
            reasons.append(f"Euler characteristic {chi_in[c]} -> {chi_out[c]}")
        if loops_out[c] != loops_in[c]:
            reasons.append(f"boundary loops {loops_in[c]} -> {loops_out[c]}")
        if max(d_in[c], d_out[c]) > tol:
            reasons.append(f"Hausdorff {max(d_in[c], d_out[c]):.3g} nm > {tol:.3g}")
        if rim[c] > tol:
            reasons.append(f"open rim {rim[c]:.3g} nm off the input's")
        if degenerate[c]:
            reasons.append(f"faces without area: {degenerate[c]}")
        if abs(change) > area_tolerance:
            reasons.append(f"area {100 * change:+.2f} %")
        checks.append(ComponentCheck(int(c), int(faces_in[c]), int(faces_out[c]), int(chi_in[c]), int(chi_out[c]),
                                     int(loops_in[c]), int(loops_out[c]),
                                     float(d_out[c]), float(d_in[c]), float(rim[c]), float(change), reasons,
                                     mendable=not (len(reasons) == 1 and abs(change) > area_tolerance),
                                     distances_only=bool(pieces[c] == 1 and not mixed[c] and chi_out[c] == chi_in[c]
                                                         and loops_out[c] == loops_in[c] and not degenerate[c]
                                                         and abs(change) <= area_tolerance)))
    return checks


def keep_input(source: TriMesh, result: TriMesh, source_component: np.ndarray, result_component: np.ndarray,
               keep: np.ndarray) -> TriMesh:
    """``result`` with the components flagged in ``keep`` ((k,) bool over input components) replaced
    by the input's own faces of them (with the input's vertex and face scalars); ``source_component`` -1: a
    face of none (never taken).

    Output faces of a kept component, and those joined to several components (-1), are dropped.
    Scalars present on only one of the two meshes are left out.
    """
    drop, mine = _taken(source_component, result_component, keep)
    parts = []
    for mesh, faces in ((result, result.faces[~drop]), (source, source.faces[mine])):
        used, local = np.unique(faces, return_inverse=True)
        parts.append((mesh, used, local.reshape(-1, 3)))
    (m1, u1, f1), (m2, u2, f2) = parts
    out = TriMesh(np.vstack([m1.vertices[u1], m2.vertices[u2]]), np.vstack([f1, f2 + len(u1)]))
    # In the remeshed mesh's order: a set's order follows string hashing, which changes from run to run
    # (and with it the order of the PLY's properties).
    for name in (n for n in m1.vertex_scalars if n in m2.vertex_scalars):
        out.vertex_scalars[name] = np.concatenate([np.asarray(m1.vertex_scalars[name])[u1],
                                                   np.asarray(m2.vertex_scalars[name])[u2]])
    for name in (n for n in m1.face_scalars if n in m2.face_scalars):
        out.face_scalars[name] = np.concatenate([np.asarray(m1.face_scalars[name])[~drop],
                                                 np.asarray(m2.face_scalars[name])[mine]])
    return out


def kept_component(source_component: np.ndarray, result_component: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """(f',) input component of every face of :func:`keep_input`'s mesh for the same arguments, in its order."""
    drop, mine = _taken(source_component, result_component, keep)
    return np.concatenate([result_component[~drop], source_component[mine]])


def _taken(source_component: np.ndarray, result_component: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(f_out,) bool faces of ``result`` that :func:`keep_input` drops, (f_in,) bool faces of ``source`` it takes."""
    drop = (result_component < 0) | keep[np.maximum(result_component, 0)]
    return drop, (source_component >= 0) & keep[np.maximum(source_component, 0)]
