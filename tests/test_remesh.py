"""Remesher against ground truth: analytic shapes as sliver-rich meshes (voxel = 1 nm)."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from apt_filters.contour.metrics import face_quality
from apt_filters.core.checks import self_intersecting_faces
from apt_filters.core.deps import open3d
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import cvt, extract, features as feat, optimize, quality, remesh, repair, sampling
from apt_filters.remesh.remesh import curve_slivers, pin_corners
from apt_filters.core.distance import SurfaceDistance
from apt_filters.remesh.sampling import refine, split
from tests import remesh_shapes as shapes

SHAPES = ["sphere", "torus", "capped_cylinder", "open_sphere", "rotated_box", "box_minus_sphere"]
EDGE = 1.0  # voxels


@pytest.fixture(scope="module")
def results():
    cache = {}

    def get(name):
        if name not in cache:
            mesh = getattr(shapes, name)()
            mesh.vertex_scalars["value"] = mesh.vertices @ np.array([1.0, 2.0, -0.5]) + 3.0
            before = mesh.copy()
            result = remesh(mesh, edge_length=EDGE, max_iter=20)
            assert np.array_equal(mesh.vertices, before.vertices) and np.array_equal(mesh.faces, before.faces)
            cache[name] = (mesh, result, quality.assess(result.mesh, mesh, 50_000))
        return cache[name]

    return get


@pytest.mark.parametrize("name", SHAPES)
def test_triangle_quality(results, name):
    _, _, q = results(name)
    assert q.frac_ge_30 >= 0.995, q
    assert q.mean_q >= 0.9, q  # the target, sharp shapes included


@pytest.mark.parametrize("name", ["sphere", "torus", "open_sphere", "rotated_box", "box_minus_sphere"])
def test_hausdorff_below_0_3_voxel(results, name):
    _, _, q = results(name)
    assert q.hausdorff <= 0.3, q


@pytest.mark.parametrize("name", SHAPES)
def test_manifold_oriented_topology_preserved(results, name):
    mesh, result, q = results(name)
    topo = quality.topology(mesh)
    assert (q.non_manifold_edges, q.non_manifold_vertices, q.orientation_conflicts) == (0, 0, 0), q
    assert q.self_intersections == 0, q
    assert (q.components, q.boundary_loops, q.genus) == (topo.components, topo.boundary_loops, topo.genus), q
    assert result.mesh.signed_volume() * mesh.signed_volume() > 0  # same orientation as the input


@pytest.mark.parametrize("name", ["sphere", "rotated_box"])
def test_edge_length_near_target(results, name):
    _, result, _ = results(name)
    e = result.mesh.vertices[result.mesh.faces] - result.mesh.vertices[np.roll(result.mesh.faces, 1, axis=1)]
    assert abs(np.linalg.norm(e, axis=2).mean() / EDGE - 1) < 0.15


@pytest.mark.parametrize("name", ["rotated_box", "box_minus_sphere"])
def test_sharp_features_survive(results, name):
    mesh, result, _ = results(name)
    reference = quality.sample_edges(mesh.vertices, quality.feature_edges(mesh), 0.1)
    ours = quality.sample_edges(result.mesh.vertices, quality.feature_edges(result.mesh), 0.1)
    assert quality.edge_f1(reference, reference, 0.1) == 1.0
    assert quality.edge_f1(ours, reference, 0.1 * EDGE) >= 0.95


def test_box_corners_are_pinned(results):
    mesh, result, _ = results("rotated_box")
    half = np.array([9.0, 7.0, 5.0])
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
    corners = (signs * half) @ shapes.rotation().T
    d = np.linalg.norm(result.mesh.vertices[None] - corners[:, None], axis=2).min(axis=1)
    assert d.max() < 1e-9


def test_open_boundary_kept_on_input_boundary(results):
    mesh, result, _ = results("open_sphere")
    ref_edges = mesh.boundary_edges()
    out_b = np.unique(result.mesh.boundary_edges())
    ref = quality.sample_edges(mesh.vertices, ref_edges, 0.01)
    from scipy.spatial import cKDTree

    assert cKDTree(ref).query(result.mesh.vertices[out_b])[0].max() < 0.02
    outline = quality.sample_edges(result.mesh.vertices, result.mesh.boundary_edges(), 0.05)
    assert cKDTree(outline).query(mesh.vertices[np.unique(ref_edges)])[0].max() < 0.3


@pytest.mark.parametrize("name", ["sphere", "rotated_box"])
def test_vertex_scalars_interpolated_exactly_for_linear_field(results, name):
    mesh, result, _ = results(name)
    # the scalars are the input surface's, at the closest point of it (vertices straddle it)
    expected = SurfaceDistance(mesh).closest(result.mesh.vertices)[0] @ np.array([1.0, 2.0, -0.5]) + 3.0
    assert np.allclose(result.mesh.vertex_scalars["value"], expected, atol=1e-4)


# Small closed objects as the pipeline hands them over (3-3.5 nm spheres, bumps of 0.1-0.4 nm from
# the refinement, 0.5 nm edges): Euclidean Voronoi cells reached across bumps and came out in
# pieces, whose duals left holes and non-manifold vertices (the demo specimen lost 1-3 objects).
# Each case failed before cells were made connected.
# The last case (3.0, 0.4, 0, 40) kept a hole until lone corner cells were dissolved too: one of the
# 87 corners its bumps make at 40 deg had a cell bordered by two cells only.
@pytest.mark.parametrize("radius, amplitude, seed, angle", [(3.5, 0.1, 2, 40.0), (3.0, 0.2, 2, 40.0),
                                                            (3.0, 0.4, 1, 180.0), (3.0, 0.4, 3, 180.0),
                                                            (3.0, 0.4, 0, 40.0)])
def test_small_bumpy_closed_object_stays_closed(radius, amplitude, seed, angle):
    mesh = shapes.bumpy(shapes.sphere(radius), amplitude, seed)
    out = remesh(mesh, edge_length=0.5, feature_angle=angle).mesh
    topo = quality.topology(out)
    assert topo == quality.Topology(components=1, boundary_loops=0, genus=0, non_manifold_edges=0,
                                    non_manifold_vertices=0), topo
    assert quality.orientation_conflicts(out) == 0
    assert out.signed_volume() > 0


def test_small_bumpy_torus_keeps_its_genus():
    mesh = shapes.bumpy(shapes.torus(3.0, 1.5), 0.1, 0)
    assert quality.topology(mesh).genus == 1
    out = remesh(mesh, edge_length=0.5).mesh
    topo = quality.topology(out)
    assert (topo.components, topo.boundary_loops, topo.genus, topo.non_manifold_vertices) == (1, 0, 1, 0), topo


# The 100 M-ion Al15 object (1,200 faces) that still opened: a patch cell of 3 samples squeezed
# between two feature-curve cells touched only those two, so its dual was two triangles on the
# same three generators with opposite orientations, which repair cannot mend. Constructed here:
# a refined face of cell A with one edge on cell B and its third corner inside A gets a cell of
# its own.
def test_cell_bordered_by_two_cells_is_dissolved():
    samples = refine(shapes.sphere(3.0), 0.2)
    faces = samples.corners()
    k = np.arange(60) + 0.5
    z, phi = 1 - 2 * k / 60, np.pi * (3 - np.sqrt(5)) * k  # even sites on the sphere
    sites = 3.0 * np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], axis=1)
    labels = cKDTree(sites).query(samples.points())[1]
    seen = [set() for _ in range(samples.n_vertices)]
    for v, label in zip(faces.ravel(), np.repeat(labels, 3)):
        seen[v].add(label)
    around = [set().union(*(seen[v] for v in face)) for face in faces]
    pick = next(f for f in range(len(faces)) if sorted(len(seen[v]) for v in faces[f]) == [1, 2, 2]
                and len(around[f]) == 2)
    a = labels[pick]
    b = (around[pick] - {a}).pop()
    lens = len(sites)
    labels[pick] = lens
    n = lens + 1
    gens = cvt.Generators(np.vstack([sites, samples.points()[pick]]), np.full(n, cvt.CURVE), np.zeros(n, np.int64),
                          np.full(n, np.nan))
    gens.kind[lens] = cvt.PATCH
    no = np.zeros(n, bool)
    group = np.zeros(len(faces), np.int64)

    dual = extract.dual_faces(samples, labels, gens.positions, no)[0]
    pillow = dual[(dual == lens).any(axis=1)]
    assert len(pillow) == 2 and all(set(f) == {a, b, lens} for f in pillow.tolist())
    assert any(np.array_equal(np.roll(pillow[0], s), pillow[1][::-1]) for s in range(3))  # opposite turns
    bad = repair.defects(gens.positions, dual, no)
    assert bad[[a, b, lens]].all()
    lone = repair.lone_generators(dual, n)
    assert np.flatnonzero(lone).tolist() == [lens]
    # keeping each cell's main piece alone does not help: the lens is one piece
    kept = cvt.connect_cells(samples, labels, group, gens, 1, bad, no)
    assert np.array_equal(kept, labels)

    fixed = cvt.connect_cells(samples, labels, group, gens, 1, bad, bad & lone)
    assert fixed[pick] in (a, b) and np.array_equal(np.delete(fixed, pick), np.delete(labels, pick))
    dual = extract.dual_faces(samples, fixed, gens.positions, no)[0]
    assert not repair.defects(gens.positions, dual, no).any()
    out = TriMesh(gens.positions, repair.repair(gens.positions, dual, no, no))
    assert quality.topology(out) == quality.Topology(components=1, boundary_loops=0, genus=0,
                                                     non_manifold_edges=0, non_manifold_vertices=0)


def test_voronoi_fans_are_the_label_runs_round_each_meeting_vertex():
    # the extraction's compiled fans (its table holds each refined face with the vertex's corner in it) against
    # walking every meeting vertex's faces in Python: faces (v, x, y) in ascending id, from the one no face ends
    # at (an open fan) or else the first, each followed by the face that starts where it ends; runs of one label
    # (cyclically) are one corner. A sphere labelled by 60 even sites, every refined vertex in order
    samples = refine(shapes.sphere(3.0), 0.2)
    faces = samples.corners()
    k = np.arange(60) + 0.5
    z, phi = 1 - 2 * k / 60, np.pi * (3 - np.sqrt(5)) * k
    sites = np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], axis=1)
    labels = cKDTree(3.0 * sites).query(samples.points())[1].astype(np.int32)
    counts, corners = extract._voronoi_fans(samples.lattice.args(), labels, samples.n_vertices)
    order = np.argsort(faces.ravel(), kind="stable")  # (face, corner) pairs by vertex, faces ascending
    bounds = np.searchsorted(faces.ravel()[order], np.arange(samples.n_vertices + 1))
    expect_counts, expect = [], []
    for v in range(samples.n_vertices):
        around = order[bounds[v]:bounds[v + 1]] // 3
        if len(set(labels[around].tolist())) < 3:
            continue
        corner = [int(np.flatnonzero(faces[f] == v)[0]) for f in around]
        nxt = [faces[f, (c + 1) % 3] for f, c in zip(around, corner)]
        prv = [faces[f, (c + 2) % 3] for f, c in zip(around, corner)]
        first = next((j for j in range(len(around)) if nxt[j] not in prv), 0)
        walk = [first]
        while len(walk) < len(around):
            succ = next((i for i in range(len(around)) if nxt[i] == prv[walk[-1]]), -1)
            if succ < 0 or succ == first:
                break
            walk.append(succ)
        run = [int(labels[around[j]]) for j in walk]
        fan = [label for j, label in enumerate(run) if label != run[j - 1]]
        expect_counts.append(len(fan))
        expect += fan
    assert len(expect_counts) > 100  # a test of many meeting vertices
    assert counts.tolist() == expect_counts and corners.tolist() == expect


def test_two_cells_flapped_on_an_edge_are_lone():
    # a retry of the bumpy gyroid: two small cells (0.07 nm apart) side by side on the border of two others
    # made a flap of two faces on the edge between those two; each of the pair has three neighbours but two
    # faces, which no closed manifold holds, while extraction makes the flap again and the hole fill cannot
    # close it (the remesh came out with one more boundary loop and was given back)
    octahedron = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    vertices = np.vstack([np.eye(3), -np.eye(3), [[0.55, 0.55, 0.05], [0.6, 0.5, 0.05]]])[[0, 3, 1, 4, 2, 5, 6, 7]]
    x, y, a, b = 6, 7, 0, 2  # the flap (y, x, a), (y, b, x) on the octahedron's edge a-b
    faces = np.vstack([octahedron, [[y, x, a], [y, b, x]]])
    no = np.zeros(len(vertices), bool)
    bad = repair.defects(vertices, faces, no)
    assert bad[[x, y]].all()
    assert np.flatnonzero(bad & repair.lone_generators(faces, len(vertices))).tolist() == [x, y]
    assert not repair.lone_generators(octahedron, 6).any()


def test_cap_of_three_curve_generators_is_flipped_and_the_curve_kept():
    # extraction joined three consecutive generators of one straight feature curve into a triangle of zero
    # area (a remesh of a refined cube: 0.21 and 0.14 nm apart on a line); flips skip edges between pinned
    # vertices and curve vertices only slide along their line, so nothing after it mended it
    vertices = np.array([[0.0, 0.0, 0.0], [0.21, 0.0, 0.0], [0.35, 0.0, 0.0],  # a, b, c on the curve
                         [0.2, 0.3, 0.0], [0.1, -0.3, 0.0], [0.3, -0.3, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 1], [1, 4, 5], [1, 5, 2]])
    pinned = np.array([True, True, True, False, False, False])
    before = TriMesh(vertices, faces)
    assert face_quality(before)[0].min() < 1e-6  # the cap

    out = TriMesh(vertices, optimize.flip_caps(vertices, faces, pinned))
    assert face_quality(out)[0].min() > 20  # degrees
    assert np.isclose(out.area(), before.area())
    assert (out.face_normals()[:, 2] > 0.99).all()  # same side up: no face turned over
    edges = {tuple(sorted(e)) for e in out.edges().tolist()}
    assert {(0, 1), (1, 2)} <= edges and (0, 2) not in edges  # the curve runs a-b-c, the cap's long edge is gone
    assert quality.topology(out) == quality.topology(before)
    # a free apex is left to the optimiser, which moves it
    free = pinned.copy()
    free[1] = False
    assert np.array_equal(optimize.flip_caps(vertices, faces, free), faces)


def test_caps_in_a_row_are_all_flipped():
    # a retry of the bumpy gyroid: six generators of one straight curve after the first joined to it in a fan of
    # caps, each cap's long edge shared with the next cap; only the last one's neighbour is no cap, so they
    # open one per round (4 rounds left 2 of these 6)
    k = 7  # generators g0 .. g6 on the x axis; q_i below them, p above
    line = np.stack([np.arange(k) * 0.1, np.zeros(k), np.zeros(k)], axis=1)
    below = np.stack([np.arange(k - 1) * 0.1 + 0.05, np.full(k - 1, -0.1), np.zeros(k - 1)], axis=1)
    vertices = np.vstack([line, below, [[0.3, 0.15, 0.0]]])
    q, p = k + np.arange(k - 1), 2 * k - 1
    faces = [[0, i, i + 1] for i in range(1, k - 1)]  # the caps, all of zero area
    faces += [[i, q[i], i + 1] for i in range(k - 1)] + [[q[i], q[i + 1], i + 1] for i in range(k - 2)]
    faces += [[0, k - 1, p]]
    faces = np.array(faces)
    pinned = np.arange(len(vertices)) < k
    before = TriMesh(vertices, faces)
    assert (before.face_areas() < 1e-12).sum() == k - 2

    out = TriMesh(vertices, optimize.flip_caps(vertices, faces, pinned))
    assert (out.face_areas() > 1e-6).all()
    assert np.isclose(out.area(), before.area())
    assert (out.face_normals()[:, 2] > 0.99).all()
    edges = {tuple(sorted(e)) for e in out.edges().tolist()}
    assert {(i, i + 1) for i in range(k - 1)} <= edges  # the curve runs g0-g1-...-g6
    assert quality.topology(out) == quality.topology(before)


def test_flips_make_no_sliver_along_a_curve():
    # a curve's middle vertex 0.1 nm off the line of its neighbours: the Delaunay flip of its edge to the
    # patch vertex would join the three into one face; once they slide along their straight curve that face
    # has zero area (gamma-prime seed 3's start remeshed at 0.5 nm, adaptive: two such, angles of 180 degrees)
    vertices = np.array([[0.0, 0.0, 0.0], [0.17, -0.1, 0.0], [0.34, 0.0, 0.0], [0.17, 0.3, 0.0]])
    faces = np.array([[0, 1, 3], [1, 2, 3]])
    pinned = np.array([True, True, True, False])

    def fixed(a, b):
        return pinned[a] & pinned[b]

    def sliver(p, q, r):  # the curve's three vertices
        return pinned[p] & pinned[q] & pinned[r]

    assert optimize.delaunay_pass(vertices, faces, fixed, sliver=sliver)[1] == 0
    flipped, count = optimize.delaunay_pass(vertices, faces, fixed)  # the flip that would be made
    assert count == 1 and {tuple(sorted(f)) for f in flipped.tolist()} == {(0, 1, 2), (0, 2, 3)}
    # the remesher's rule: three of one curve, or a corner and two of one curve; not two curves at a corner
    # and one generator of a curve with the curve's two end corners; not with another curve's corner
    kind = np.array([cvt.CURVE, cvt.CURVE, cvt.CURVE, cvt.CORNER, cvt.CURVE, cvt.PATCH, cvt.CORNER, cvt.CORNER])
    owner = np.array([4, 4, 4, 0, 5, 0, 1, 2])
    ends = np.array([[-1, -1]] * 4 + [[0, 1], [0, 2]])  # curve 4 runs from corner 0 to corner 1, curve 5 to 2
    rule = curve_slivers(kind, owner, ends)
    tris = np.array([[0, 1, 2], [3, 0, 1], [3, 0, 4], [0, 1, 5], [0, 1, 4], [3, 0, 6], [3, 4, 7], [3, 0, 7]])
    assert rule(*tris.T).tolist() == [True, True, False, False, False, True, True, False]
    # two pieces of one curve split at a pin (corner 1) go on straight through it: theirs with the pin too
    pieces = curve_slivers(kind, owner, ends, line=np.array([0, 1, 2, 3, 4, 4]))
    assert pieces(*np.array([[0, 3, 4]]).T).tolist() == [True] and rule(*np.array([[0, 3, 4]]).T).tolist() == [False]


def test_four_cells_meeting_at_a_curve_make_no_sliver():
    # three consecutive generators of a straight feature curve and a patch generator around one Voronoi vertex
    # (a middle cell pinched to a point, as curve cells a few samples wide are): the diagonal between the two
    # pinned ends skips the middle one and made a face without area, which no flip mends
    positions = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.1, 0.2, 0.0]])
    kind = np.array([cvt.CURVE, cvt.CURVE, cvt.CURVE, cvt.PATCH])
    owner = np.array([0, 0, 0, 0])
    pinned = kind != cvt.PATCH
    sliver = curve_slivers(kind, owner, np.array([[-1, -1]]))
    for quad in ([0, 1, 2, 3], [1, 2, 3, 0], [3, 0, 1, 2]):
        faces = extract.triangulate_quads(np.array([quad]), positions, pinned, sliver)
        assert (TriMesh(positions, faces).face_areas() > 1e-3).all()
        poly = extract.triangulate_polygon(quad, positions, pinned, sliver)
        assert (TriMesh(positions, np.array(poly)).face_areas() > 1e-3).all()


def test_a_curve_from_a_corner_back_to_it_gets_no_generator_on_the_corner():
    # a feature curve that leaves a corner and comes back to it (a teardrop) was taken for a closed loop: its
    # first generator sat on the corner (two output vertices at one point, faces without area), and pinning a
    # vertex on it (a retry) turned it to start there and split it again at its middle: the corner once more
    # (held-out superellipsoid 10000's third object, remeshed at a retry)
    grid = np.stack(np.meshgrid(np.arange(7.0), np.arange(7.0), indexing="ij"), -1).reshape(-1, 2)
    vertices = np.column_stack([grid, np.zeros(len(grid))])
    idx = np.arange(49).reshape(7, 7)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    mesh = TriMesh(vertices, np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]))
    ring = idx[[1, 1, 1, 1, 2, 3, 4, 5, 5, 5, 5, 4, 3, 2, 1], [1, 2, 3, 4, 5, 5, 5, 5, 4, 3, 2, 1, 1, 1, 1]]
    corner = int(ring[0])
    top = mesh.topology
    on_ring = {tuple(sorted(e)) for e in zip(ring[:-1].tolist(), ring[1:].tolist())}
    edge = np.array([tuple(e) in on_ring for e in np.sort(top.edge_vertices, axis=1).tolist()])
    features = feat.Features(np.zeros(mesh.n_faces, np.int64), np.array([corner]), [ring], [np.array([0])],
                             [np.array([0])], np.array([False]), edge)
    samples = refine(mesh, 0.25)
    ones = np.ones(mesh.n_faces)
    # pinned opposite the corner, the loop's middle (where a loop with one pin is split again) is the corner
    for found in (features, pin_corners(mesh, features, np.array([ring[7]]), 0.1)[0]):
        assert len(np.unique(found.corners)) == len(found.corners)
        for c in found.curves:  # corners only at the ends of curves
            assert not np.isin(c[1:-1], found.corners).any()
        gens, _ = cvt.initialise(mesh, found, samples, 1.0, ones, lambda p: np.ones(len(p)))
        on_curves = gens.positions[gens.kind == cvt.CURVE]
        assert len(on_curves) >= 2
        assert cKDTree(on_curves).query(vertices[found.corners])[0].min() > 0.1


def test_vertex_count_target():
    mesh = shapes.sphere(8.0)
    result = remesh(mesh, n_vertices=500, max_iter=10)
    assert abs(result.mesh.n_vertices / 500 - 1) < 0.1


def test_edges_shrink_at_rims_to_stay_within_tolerance():
    """Marching cubes rounds the cylinder's rims (radius about 1 voxel): triangles of edge 1.5 there
    would leave the input by more than a quarter edge, so edges shrink at the rims even when uniform;
    the curvature-adaptive density shrinks them further and brings the remesh closer still."""
    mesh = shapes.capped_cylinder()
    axis = shapes.rotation(5)[:, 2]
    rim_lengths, flat_lengths, distances = [], [], []
    for adaptive in (0.0, 1.0):
        out = remesh(mesh, edge_length=1.5, adaptive=adaptive, max_iter=10, verify=False).mesh
        v, f = out
        mid = v[f].mean(axis=1)
        height = mid @ axis
        radius = np.linalg.norm(mid - np.outer(height, axis), axis=1)
        rim = np.abs(np.abs(height) - 8.0) + np.abs(radius - 8.0) < 1.5
        flat = (np.abs(np.abs(height) - 8.0) < 0.3) & (radius < 5.0)
        lengths = np.linalg.norm(v[f] - v[np.roll(f, 1, axis=1)], axis=2).mean(axis=1)
        rim_lengths.append(lengths[rim].mean())
        flat_lengths.append(lengths[flat].mean())
        distances.append(quality.hausdorff(out, mesh, 20_000))
    assert rim_lengths[0] < 0.9 * flat_lengths[0], (rim_lengths, flat_lengths)
    assert rim_lengths[1] < rim_lengths[0]
    assert distances[1] < distances[0] <= 0.25 * 1.5, distances


def test_bad_parameters_raise_one_line_errors():
    mesh = shapes.sphere(5.0)
    with pytest.raises(AptFiltersError, match="not both"):
        remesh(mesh, edge_length=1.0, n_vertices=100)
    with pytest.raises(AptFiltersError, match="positive"):
        remesh(mesh, edge_length=-1.0)
    with pytest.raises(AptFiltersError, match="no faces"):
        remesh(TriMesh(np.zeros((3, 3)), np.zeros((0, 3))))


def test_quality_measures_on_known_triangles():
    tri = TriMesh(np.array([[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0], [0.5, -0.01, 0]]),
                  np.array([[0, 1, 2], [1, 0, 3]]))
    angles, q = face_quality(tri)
    assert np.allclose(q[0], 1.0)
    assert q[1] < 0.05
    assert np.allclose(angles[0], 60.0)
    assert quality.topology(tri).boundary_loops == 1


def test_self_intersections_ignore_separated_coplanar_triangles():
    # two triangles of one face of the rotated box (a remesh output), 0.8 nm apart in their
    # plane: open3d's triangle-triangle test reports them as intersecting; the count that
    # quality.assess reports (core.checks.self_intersecting_faces) must not
    gap = np.array([[1.9187254905700684, -2.125217914581299, 7.3052754402160645],
                    [2.655438184738159, -1.7179865837097168, 8.028884887695312],
                    [1.9861036539077759, -1.7230888605117798, 8.237363815307617],
                    [2.5706634521484375, -2.364898920059204, 6.521633148193359],
                    [3.739675998687744, -2.145174980163574, 6.6577982902526855],
                    [3.092186689376831, -1.9393960237503052, 7.359521389007568]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    o3d = open3d()
    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(gap), o3d.utility.Vector3iVector(faces.astype(np.int32)))
    assert len(np.asarray(legacy.get_self_intersecting_triangles())) == 1  # the false report this guards against
    assert self_intersecting_faces(gap, faces).sum() == 0
    # moved into the first one's plane over it, and crossing it: both count
    centre_shift = gap[:3].mean(axis=0) - gap[3:].mean(axis=0)
    overlapping = np.vstack([gap[:3], gap[3:] + centre_shift])
    assert self_intersecting_faces(overlapping, faces).all()
    normal = np.cross(gap[1] - gap[0], gap[2] - gap[0])
    crossing = np.vstack([gap[:3], gap[:3].mean(axis=0) + np.array([normal, -normal, np.cross(normal, gap[1] - gap[0])])])
    assert self_intersecting_faces(crossing, faces).all()


@pytest.mark.parametrize("max_edge", [2.0, 0.6, 0.3])
def test_lattice_refinement_is_conforming_and_exact(max_edge):
    # every input face split into n² congruent faces: same surface, same area and orientation,
    # closed input stays closed (edge points shared), every sample inside its own input face
    mesh = shapes.sphere(3.0)
    samples = refine(mesh, max_edge)
    n2 = samples.per_face
    fine = samples.mesh()
    assert fine.n_faces == n2 * mesh.n_faces
    # the samples made face by face are the centroids of the refined mesh's faces
    assert np.allclose(samples.points(), fine.vertices[fine.faces].mean(axis=1), rtol=0, atol=1e-12)
    assert len(fine.boundary_edges()) == 0 and fine.topology.genus == 0 and fine.topology.n_components == 1
    assert np.isclose(fine.area(), mesh.area(), rtol=1e-12)
    assert np.allclose(fine.face_areas(), samples.weights(), rtol=1e-9, atol=1e-15)
    normals = fine.face_normals()
    assert np.allclose(normals[fine.face_areas() > 1e-12], samples.face_normal[samples.parent()][fine.face_areas() > 1e-12])
    # centroids of the children of a face average to its centroid
    centre = samples.points().reshape(mesh.n_faces, n2, 3).mean(axis=1)
    assert np.allclose(centre, mesh.vertices[mesh.faces].mean(axis=1))
    lengths = np.linalg.norm(fine.vertices[fine.faces] - fine.vertices[np.roll(fine.faces, 1, axis=1)], axis=2)
    assert np.quantile(lengths, 0.9) < max_edge


@pytest.mark.parametrize("n", [1, 2, 4])
def test_lattice_ids_are_one_per_exact_refined_point(n):
    # the refined vertex ids made face by face (lattice_ids; corners() of refined faces in any order) against the
    # refined points themselves, exact: integer input vertices, so n times lattice point (p, q) of a face (a, b, c)
    # is (n - p - q)·a + p·b + q·c in integers. One id per point and one point per id, input vertices keep their
    # ids; an open patch whose shared edges run both ways and whose rim edges have one face
    vertices = np.array([[0, 0, 0], [3, 0, 1], [1, 4, 0], [5, 3, 2], [-2, 3, 1], [2, -3, 2]])
    faces = np.array([[0, 1, 2], [1, 3, 2], [0, 2, 4], [0, 5, 1]])
    samples = split(TriMesh(vertices.astype(float), faces), n)
    lattice, per_face = samples.lattice, samples.per_face
    ids, key_of, keys = np.empty(len(lattice.point), np.int64), {}, []
    for f in range(len(faces)):
        sampling.lattice_ids(lattice.args(), f, ids)
        a, b, c = vertices[faces[f]]
        keys.append([tuple((n - p - q) * a + p * b + q * c) for p, q in sampling._lattice(n)[0].tolist()])
        for v, key in zip(ids.tolist(), keys[-1]):
            assert key_of.setdefault(v, key) == key
    assert sorted(key_of) == list(range(samples.n_vertices))
    id_of = {key: v for v, key in key_of.items()}
    assert len(id_of) == samples.n_vertices
    assert all(id_of[tuple(n * vertices[v])] == v for v in range(len(vertices)))
    expect = np.array([[id_of[keys[i // per_face][k]] for k in lattice.pattern[i % per_face]]
                       for i in range(samples.n_samples)])
    order = np.r_[np.random.default_rng(0).permutation(samples.n_samples), np.arange(samples.n_samples)]
    assert np.array_equal(samples.corners(order), expect[order])


def test_interior_edges_and_absent_edges_match_their_definition():
    # the compiled twin search against the definition: every edge of two faces once, a < b, f1 holding a->b,
    # f2 b->a, c and d their third corners, in f1's half-edge order; an open sheet's rim edges are not interior
    sheet = shapes.tilted_sheet()
    faces = sheet.faces
    (a, b, c, d, f1, f2), rings = optimize._interior_edges(faces, sheet.n_vertices)
    half = {(int(p), int(q)): (f, k) for f, row in enumerate(faces) for k, (p, q) in
            enumerate(zip(row, np.roll(row, -1)))}
    expect = [(p, q, faces[f, (k + 2) % 3], faces[half[q, p][0], (half[q, p][1] + 2) % 3], f, half[q, p][0])
              for (p, q), (f, k) in sorted(half.items(), key=lambda kv: 3 * kv[1][0] + kv[1][1])
              if p < q and (q, p) in half]
    assert np.array_equal(np.stack([a, b, c, d, f1, f2], 1), np.array(expect).reshape(-1, 6))
    assert len(a) < 1.5 * len(faces)  # the rims' edges left out
    pairs = np.array([[0, 1], [0, 2], [1, 2]])
    edges = {tuple(sorted((int(row[i]), int(row[j])))) for row in faces for i, j in pairs}
    rng = np.random.default_rng(0)
    p, q = rng.integers(0, sheet.n_vertices, 400), rng.integers(0, sheet.n_vertices, 400)
    p[:200], q[:200] = b[:200], a[:200]  # half of them existing edges, given either way round
    assert optimize._absent(faces, rings, p, q).tolist() == [tuple(sorted((int(x), int(y)))) not in edges
                                                             for x, y in zip(p, q)]


def test_small_neighbour_searches_match_the_kd_tree():
    # the candidate table's k nearest of small groups (compared pair by pair) are the KD-tree's, nearest first
    rng = np.random.default_rng(3)
    for n in (1, 5, cvt._BRUTE_KNN):
        reference, queries = rng.normal(size=(n, 3)), rng.normal(size=(50, 3))
        k = min(10, n)
        expected = cKDTree(reference).query(queries, k)[1].reshape(50, k)
        assert np.array_equal(cvt._knn(reference, queries, k), expected)
        assert np.array_equal(cvt._knn(reference, reference, k)[:, 0], np.arange(n))


def test_curve_steps_are_the_one_dimensional_lloyd_step():
    # one compiled pass over every curve: each generator moves to the density's centroid of its arc cell
    # (midpoints to its neighbours; open curves end at fixed corners, loops wrap), here a uniform density
    points = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 3.0, 0.0]])  # an open curve 7 long
    curve = cvt._Curve(points, False, 0.01)
    curve.weigh(np.ones(len(curve.t)))
    arc = np.array([1.0, 2.0, 6.5])
    positions = np.zeros((3, 3))
    cvt._CurveSteps([curve], [np.arange(3)]).step(arc, positions)
    cells = [(0.5, 1.5), (1.5, 4.25), (4.25, 6.75)]  # between midpoints to the neighbours, end corners included
    assert np.allclose(arc, [0.5 * (a + b) for a, b in cells])
    assert np.allclose(positions, [[1.0, 0, 0], [2.875, 0, 0], [4.0, 1.5, 0]])


def _full_ring_score(out, faces, ring, v, point, old, cos_turn, floor):
    """The ring score of :func:`optimize._ring_score` by its definition, in its arithmetic (scalar IEEE doubles,
    one arccos per face): every face scored, no early exit."""
    worst, total = np.inf, 0.0
    for s, f in enumerate(ring):
        q = [float(x) for u in faces[f] for x in (point if u == v else out[u])]
        ux, uy, uz, wx, wy, wz = q[3] - q[0], q[4] - q[1], q[5] - q[2], q[6] - q[0], q[7] - q[1], q[8] - q[2]
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        length = max(math.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
        if (nx * old[s][0] + ny * old[s][1] + nz * old[s][2]) / length <= cos_turn:
            return -np.inf, worst
        if floor < 0:
            worst = min(worst, *(optimize._angle_at(*q[3 * k:], *q[:3 * k]) for k in range(3)))
            continue
        a2, c2 = ux * ux + uy * uy + uz * uz, wx * wx + wy * wy + wz * wz
        e2 = (q[6] - q[3]) ** 2 + (q[7] - q[4]) ** 2 + (q[8] - q[5]) ** 2
        a, c, e = math.sqrt(a2), math.sqrt(c2), math.sqrt(e2)
        cosine = max((a2 + c2 - e2) / max(2 * a * c, 1e-300), (a2 + e2 - c2) / max(2 * a * e, 1e-300),
                     (c2 + e2 - a2) / max(2 * c * e, 1e-300))
        worst = min(worst, math.acos(min(cosine, 1.0)))
        total += 6 / math.sqrt(3) * (length / 2) / max((a + c + e) / 2 * max(a, c, e), 1e-300)
    if floor < 0:
        return worst, worst
    return (total if worst >= floor else -np.inf), worst


@pytest.mark.parametrize("floor, max_turn", [(-1.0, 45.0), (33.0, 10.0)])
def test_candidate_choice_is_that_of_scoring_every_candidate_in_full(floor, max_turn):
    # the sweeps' choice (_choose, whose scoring stops once a candidate surely loses) against scoring every
    # candidate on every face of its ring, on a jittered sheet: the same vertices move to the same candidates
    sheet = shapes.tilted_sheet()
    rng = np.random.default_rng(5)
    vertices = sheet.vertices + rng.normal(scale=0.15, size=sheet.vertices.shape)
    faces = np.ascontiguousarray(sheet.faces, np.int64)
    start, ring_of = optimize.vertex_rings(faces, len(vertices))
    inside = np.flatnonzero(~optimize.boundary_vertices(TriMesh(vertices, faces)) & (np.diff(start) > 0))
    batch = optimize._independent(inside, faces, start, ring_of, len(vertices))[0]
    ptr, cands = optimize._candidates(vertices, faces, start, ring_of, batch, optimize.QUALITY_STEPS)
    cos_turn, low = np.cos(np.radians(max_turn)), np.radians(floor) if floor >= 0 else -1.0
    out = vertices.copy()
    went = optimize._choose(out, faces, start, ring_of, batch, ptr, cands, cos_turn, low,
                            optimize._rings(out, faces, start, ring_of, batch, low))
    expect, moved = vertices.copy(), []
    for b, v in enumerate(batch):
        ring = ring_of[start[v]:start[v + 1]]
        old = []
        for f in ring:
            n = np.cross(expect[faces[f, 1]] - expect[faces[f, 0]], expect[faces[f, 2]] - expect[faces[f, 0]])
            old.append(n / max(np.sqrt((n**2).sum()), 1e-300))
        now, smallest = _full_ring_score(expect, faces, ring, v, expect[v], old, -2.0, -1.0 if low < 0 else 0.0)
        least = min(low, smallest) if low >= 0 else low
        scores = [_full_ring_score(expect, faces, ring, v, c, old, cos_turn, least)[0]
                  for c in cands[ptr[b]:ptr[b + 1]]]
        best = int(np.argmax(scores))
        if scores[best] > now + (1e-3 if low < 0 else 1e-4 * len(ring)):
            expect[v] = cands[ptr[b] + best]
            moved.append(b)
    assert len(moved) > 0.2 * len(batch)  # a test of moves, not of none
    assert np.flatnonzero(went).tolist() == moved
    assert np.array_equal(out, expect)


@pytest.mark.parametrize("floor", [-1.0, 33.0])
def test_sweep_rings_are_each_ring_as_it_is(floor):
    # _rings, computed once per part of a batch for _winners and _choose: each vertex's ring's unit face normals
    # (bit for bit those of numpy's cross product), rows past its ring zero, its score and floor as scoring the
    # ring in full gives them, on a jittered sheet
    sheet = shapes.tilted_sheet()
    vertices = sheet.vertices + np.random.default_rng(6).normal(scale=0.15, size=sheet.vertices.shape)
    faces = np.ascontiguousarray(sheet.faces, np.int64)
    start, ring_of = optimize.vertex_rings(faces, len(vertices))
    batch = np.flatnonzero(np.diff(start) > 0)[::3]
    low = np.radians(floor) if floor >= 0 else -1.0
    normals, now, least = optimize._rings(vertices, faces, start, ring_of, batch, low)
    assert normals.shape == (len(batch), np.diff(start)[batch].max(), 3)
    for b, v in enumerate(batch):
        ring = ring_of[start[v]:start[v + 1]]
        tri = vertices[faces[ring]]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        old = n / np.maximum(np.sqrt((n**2).sum(axis=1)), 1e-300)[:, None]
        assert np.array_equal(normals[b, :len(ring)], old) and not normals[b, len(ring):].any()
        score, smallest = _full_ring_score(vertices, faces, ring, v, vertices[v], old, -2.0, -1.0 if low < 0 else 0.0)
        assert now[b] == pytest.approx(score, rel=1e-12)
        assert least[b] == (pytest.approx(min(low, smallest), rel=1e-12) if low >= 0 else low)
