"""The signed-distance engine (apt_filters.core.distance; positive outside, along the normals) and its narrow
band against exact distances to boxes, spheres and an open plane, and against open3d's BVH."""

import numpy as np
import pytest

from apt_filters.core.mesh import TriMesh
from apt_filters.core.deps import open3d
from apt_filters.core.distance import EDGE, FACE, VERTEX, SurfaceDistance
from tests.proxigram_specimens import box_distance, cube, icosphere, plane, sphere_distance

HALF = (3.0, 4.0, 5.0)  # asymmetric, so that an x/y/z mix-up shows
CENTER = (1.0, -2.0, 0.5)


def near_edges_and_corners(rng, n):
    """Points within 1 nm of the box's edges and corners (where face normals give wrong signs)."""
    half = np.asarray(HALF)
    corner_sign = rng.choice([-1.0, 1.0], size=(n, 3))
    p = corner_sign * half + rng.normal(scale=0.4, size=(n, 3))
    along = rng.integers(0, 3, size=n)  # half of them slide along an edge
    slide = rng.random(n) < 0.5
    p[slide, along[slide]] = rng.uniform(-half[along[slide]], half[along[slide]])
    return p + np.asarray(CENTER)


def test_cube_signs_and_distances_exact_at_edges_and_corners():
    rng = np.random.default_rng(7)
    mesh = cube(HALF, subdivisions=2, center=CENTER)
    pts = np.concatenate([near_edges_and_corners(rng, 60000),
                          rng.uniform(-6, 6, size=(20000, 3)) + CENTER]).astype(np.float32)
    truth = box_distance(pts.astype(np.float64), HALF, CENTER)
    sd = SurfaceDistance(mesh).query(pts)
    clear = np.abs(truth) > 1e-4  # the sign of a point on the surface is moot
    assert np.count_nonzero((sd.distance[clear] < 0) != (truth[clear] > 0)) == 0  # truth: positive inside
    assert np.abs(-sd.distance - truth).max() < 1e-4
    # the test exercises all three kinds of closest feature
    assert min(np.count_nonzero(sd.feature == k) for k in (FACE, EDGE, VERTEX)) > 1000
    assert not sd.on_boundary.any()  # closed mesh: no rim


def test_sharp_tetrahedron_signs_where_face_normals_fail():
    """Acute dihedral angles: the face normal of the closest triangle misjudges many points there."""
    rng = np.random.default_rng(8)
    corners = np.array([[0.0, 0.0, 0.0], [8.0, 0.0, 0.0], [0.0, 9.0, 0.0], [2.5, 2.5, 0.7]])
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]])
    mesh = TriMesh(corners, faces)
    assert mesh.signed_volume() > 0
    edge = rng.integers(0, 4, size=(40000, 2))
    t = rng.random((40000, 1))
    pts = (corners[edge[:, 0]] * t + corners[edge[:, 1]] * (1 - t) + rng.normal(scale=0.3, size=(40000, 3)))
    pts = pts.astype(np.float32)
    centroids = corners[faces].mean(axis=1)
    side = np.einsum("fk,nfk->nf", mesh.face_normals(), pts[:, None, :] - centroids[None])
    inside, clear = np.all(side < 0, axis=1), np.abs(side).min(axis=1) > 1e-4
    surface = SurfaceDistance(mesh)
    sd = surface.query(pts)
    assert np.count_nonzero((sd.distance < 0)[clear] != inside[clear]) == 0
    result = _scene(mesh).compute_closest_points(open3d().core.Tensor(pts))
    offset = pts - result["points"].numpy()
    naive = np.einsum("ij,ij->i", offset, mesh.face_normals()[result["primitive_ids"].numpy()]) < 0
    assert np.count_nonzero(naive[clear] != inside[clear]) > 100


def test_sphere_distances():
    rng = np.random.default_rng(3)
    mesh = icosphere(4.0, subdivisions=4, center=CENTER)
    pts = (rng.uniform(-7, 7, size=(30000, 3)) + CENTER).astype(np.float32)
    sd = SurfaceDistance(mesh).query(pts)
    truth = sphere_distance(pts.astype(np.float64), 4.0, CENTER)
    # faceting: the chords of a 5120-face icosphere of radius 4 sit at most ~0.01 nm inside the sphere
    assert np.abs(-sd.distance - truth).max() < 0.015
    far = np.abs(truth) > 0.015
    assert np.all((sd.distance[far] < 0) == (truth[far] > 0))


def test_open_plane_rim_and_sign():
    rng = np.random.default_rng(4)
    pts = rng.uniform([-14, -14, -4], [14, 14, 4], size=(40000, 3)).astype(np.float32)
    sd = SurfaceDistance(plane(10.0, n=20)).query(pts)
    beyond = np.any(np.abs(pts[:, :2]) > 10.0, axis=1)
    np.testing.assert_array_equal(sd.on_boundary, beyond)
    np.testing.assert_allclose(sd.distance[~beyond], pts[~beyond, 2], atol=1e-5)  # inside is z < 0


@pytest.mark.parametrize("mesh, truth", [
    (cube(HALF, 2, CENTER), lambda p: box_distance(p, HALF, CENTER)),
    (icosphere(4.0, 3, CENTER), lambda p: sphere_distance(p, 4.0, CENTER)),
])
@pytest.mark.parametrize("max_distance, home", [(3.0, 2), (1.0, 2), (2.0, 3)])
def test_narrow_band_is_conservative_and_narrow(mesh, truth, max_distance, home):
    """Points are rejected by their search block: none within range is lost, few beyond are searched."""
    rng = np.random.default_rng(5)
    pts = (rng.uniform(-12, 12, size=(200000, 3)) + CENTER).astype(np.float32)
    d = truth(pts.astype(np.float64))
    surface = SurfaceDistance(mesh, home=home)
    sd = surface.query(pts, max_distance=max_distance)
    # faceting of the sphere (< 0.05 nm at 1280 faces) is allowed for at the range's ends
    assert np.all(np.isfinite(sd.distance[np.abs(d) <= max_distance - 0.05]))
    assert np.all(np.isnan(sd.distance[np.abs(d) > max_distance + 0.05]))
    # searched: the block's diagonal plus a triangle's bounding box (a row's box) beyond the range
    tri = mesh.vertices[mesh.faces]
    slack = np.sqrt(3) * home * surface.grid.cell + np.linalg.norm(np.ptp(tri, axis=1), axis=1).max()
    within = np.count_nonzero(np.abs(d) <= max_distance + slack)
    assert np.count_nonzero(np.abs(d) <= max_distance) < sd.searched <= within


def _scene(mesh):
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return scene


def _reference(mesh, pts):
    """open3d's unsigned distance (BVH, float32): an independent peer for the closest point."""
    return _scene(mesh).compute_distance(open3d().core.Tensor(pts.astype(np.float32))).numpy()


def _segment_distance(p, a, b):
    t = np.clip(np.einsum("ij,ij->i", p - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
    return np.linalg.norm(p - a - t[:, None] * (b - a), axis=1)


def _triangle_distance(p, tri):
    """(N,) distance of points (N, 3) to triangles (N, 3, 3): projection if inside, else edges."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    h = np.einsum("ij,ij->i", p - a, n)
    q = p - h[:, None] * n
    inside = np.all([np.einsum("ij,ij->i", np.cross(y - x, q - x), n) >= 0 for x, y in ((a, b), (b, c), (c, a))], axis=0)
    edges = np.min([_segment_distance(p, x, y) for x, y in ((a, b), (b, c), (c, a))], axis=0)
    return np.where(inside, np.abs(h), edges)


@pytest.mark.parametrize("name", ["cube", "plane", "tetrahedron"])
def test_grid_search_matches_open3d_and_the_shapes_signs(name):
    """Our grid search against open3d's BVH: same distances, signs, features and rim flags."""
    rng = np.random.default_rng(11)
    if name == "cube":
        mesh = cube(HALF, subdivisions=2, center=CENTER)
        pts = np.concatenate([near_edges_and_corners(rng, 20000), rng.uniform(-7, 7, size=(20000, 3)) + CENTER])
    elif name == "plane":  # open surface: points beyond the rim, near its corners and edges
        mesh = plane(10.0, n=20)
        pts = rng.uniform([-13, -13, -3], [13, 13, 3], size=(40000, 3))
    else:
        mesh = TriMesh(np.array([[0.0, 0, 0], [8, 0, 0], [0, 9, 0], [2.5, 2.5, 0.7]]),
                       np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [2, 0, 3]]))
        pts = rng.uniform(-3, 11, size=(40000, 3))
    pts = pts.astype(np.float32)
    ours, ref = SurfaceDistance(mesh).query(pts), _reference(mesh, pts)
    np.testing.assert_allclose(np.abs(ours.distance), ref, atol=1e-5)
    # the face returned realises the distance (checked by an independent point-triangle distance)
    own = _triangle_distance(pts.astype(np.float64), mesh.vertices[mesh.faces[ours.face]])
    np.testing.assert_allclose(own, np.abs(ours.distance), atol=1e-5)
    # signs against the shape itself: outside positive
    p = pts.astype(np.float64)
    if name == "cube":
        truth = -box_distance(p, HALF, CENTER)
    elif name == "plane":
        truth = np.where(np.any(np.abs(p[:, :2]) > 10.0, axis=1), np.nan, p[:, 2])
    else:
        corners = mesh.vertices
        side = np.einsum("fk,nfk->nf", mesh.face_normals(), p[:, None, :] - corners[mesh.faces].mean(axis=1)[None])
        truth = np.where(np.all(side < 0, axis=1), -1.0, 1.0) * np.where(np.abs(side).min(axis=1) > 1e-4, 1, np.nan)
    clear = np.isfinite(truth) & (np.abs(truth) > 1e-4)
    np.testing.assert_array_equal(ours.distance[clear] > 0, truth[clear] > 0)
    assert min(np.count_nonzero(ours.feature == k) for k in (FACE, EDGE, VERTEX)) > 50


def test_grid_search_cut_off_at_max_distance():
    rng = np.random.default_rng(12)
    mesh = icosphere(3.0, subdivisions=3, center=CENTER)
    pts = (rng.uniform(-8, 8, size=(30000, 3)) + CENTER).astype(np.float32)
    full = SurfaceDistance(mesh).query(pts)
    cut = SurfaceDistance(mesh).query(pts, max_distance=1.5)
    near = np.abs(full.distance) < 1.5 - 1e-6
    far = np.abs(full.distance) > 1.5 + 1e-6
    np.testing.assert_array_equal(cut.distance[near], full.distance[near])
    np.testing.assert_array_equal(cut.feature[near], full.feature[near])  # faces may differ at ties
    assert np.all(np.isnan(cut.distance[far])) and np.all(cut.face[far] == -1)
    assert near.sum() > 2000 and far.sum() > 20000


def test_grid_search_far_points_and_degenerate_triangles():
    """Points far outside the grid (brute-force fallback) and zero-area triangles (no NaN)."""
    rng = np.random.default_rng(13)
    box = cube(HALF, subdivisions=1, center=CENTER)
    v = np.concatenate([box.vertices, [[20.0, 0, 0], [21.0, 0, 0], [22.0, 0, 0]]])
    n = len(box.vertices)
    faces = np.concatenate([box.faces, [[n, n + 1, n + 2], [n, n, n + 1]]])  # collinear, repeated corner
    mesh = TriMesh(v, faces)
    pts = np.concatenate([rng.normal(scale=60.0, size=(5000, 3)),
                          rng.uniform([19, -1, -1], [23, 1, 1], size=(5000, 3))]).astype(np.float32)
    ours, ref = SurfaceDistance(mesh, cell=0.5).query(pts), _reference(mesh, pts)
    assert not np.isnan(ours.distance).any()
    np.testing.assert_allclose(np.abs(ours.distance), ref, atol=1e-4, rtol=1e-6)
    segment = _segment_distance(pts[5000:].astype(np.float64), np.array([[20.0, 0, 0]]), np.array([[22.0, 0, 0]]))
    np.testing.assert_allclose(np.abs(ours.distance[5000:]), segment, atol=1e-5)
