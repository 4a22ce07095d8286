"""Signed distance and narrow band against exact distances to boxes, spheres and an open plane."""

import numpy as np
import pytest

from apt_filters.core.mesh import TriMesh
from apt_filters.analysis.distance import EDGE, FACE, VERTEX, NarrowBand, SurfaceDistance
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
    assert np.count_nonzero((sd.distance[clear] > 0) != (truth[clear] > 0)) == 0
    assert np.abs(sd.distance - truth).max() < 1e-4
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
    assert np.count_nonzero((sd.distance > 0)[clear] != inside[clear]) == 0
    result = surface._scene.compute_closest_points(surface._tensor(pts))
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
    assert np.abs(sd.distance - truth).max() < 0.015
    far = np.abs(truth) > 0.015
    assert np.all((sd.distance[far] > 0) == (truth[far] > 0))


def test_open_plane_rim_and_sign():
    rng = np.random.default_rng(4)
    pts = rng.uniform([-14, -14, -4], [14, 14, 4], size=(40000, 3)).astype(np.float32)
    sd = SurfaceDistance(plane(10.0, n=20)).query(pts)
    beyond = np.any(np.abs(pts[:, :2]) > 10.0, axis=1)
    np.testing.assert_array_equal(sd.on_boundary, beyond)
    np.testing.assert_allclose(sd.distance[~beyond], -pts[~beyond, 2], atol=1e-5)  # inside is z < 0


@pytest.mark.parametrize("mesh, truth", [
    (cube(HALF, 2, CENTER), lambda p: box_distance(p, HALF, CENTER)),
    (icosphere(4.0, 3, CENTER), lambda p: sphere_distance(p, 4.0, CENTER)),
])
@pytest.mark.parametrize("max_distance, voxel", [(3.0, 0.5), (1.0, 0.5), (2.0, 0.9)])
def test_narrow_band_is_conservative_and_narrow(mesh, truth, max_distance, voxel):
    rng = np.random.default_rng(5)
    pts = (rng.uniform(-12, 12, size=(200000, 3)) + CENTER).astype(np.float32)
    d = truth(pts.astype(np.float64))
    band = NarrowBand.build(mesh, max_distance, voxel=voxel)
    inside = band.contains(pts)
    # faceting of the sphere (< 0.05 nm at 1280 faces) is allowed for in the reach
    assert not np.any(~inside & (np.abs(d) <= max_distance - 0.05))
    # and it is a band: nothing beyond the proven reach of max + sqrt(3) + 1/2 voxels (+ voxel slack)
    assert not np.any(inside & (np.abs(d) > max_distance + (np.sqrt(3) + 2) * voxel))
