"""Walked closest points (remesh.walk) and the check's exact farthest distance built on them."""

import numpy as np
from scipy.spatial import cKDTree

from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import verify
from apt_filters.remesh.walk import face_neighbours, vertex_rings, walk_closest
from tests import remesh_shapes as shapes


def _exact_farthest(mesh: TriMesh, other: TriMesh, group: np.ndarray, k: int) -> np.ndarray:
    """The farthest vertex, edge midpoint or centroid of each group from ``other``, every probe searched."""
    surface, top, v = SurfaceDistance(other), mesh.topology, mesh.vertices
    d = [np.abs(surface.query(p).distance.astype(np.float64)) for p in
         (v, 0.5 * (v[top.edge_vertices[:, 0]] + v[top.edge_vertices[:, 1]]), v[mesh.faces].mean(axis=1))]
    worst = np.maximum(np.maximum(d[0][mesh.faces].max(axis=1), d[1][top.face_edge].max(axis=1)), d[2])
    out = np.zeros(k)
    np.maximum.at(out, group, worst)
    return out


def test_walk_bounds_the_distance_and_mostly_reaches_it():
    """A local search: never closer than the surface, and at the closest face for nearly every point
    near a smooth surface (4 % stop short on this sphere: see the module's note)."""
    mesh = shapes.sphere(6.0)
    rng = np.random.default_rng(0)
    face = rng.integers(0, mesh.n_faces, 2000)
    bary = rng.dirichlet([1.0, 1.0, 1.0], 2000)
    points = np.einsum("nk,nkj->nj", bary, mesh.vertices[mesh.faces[face]]) + rng.normal(0.0, 0.2, (2000, 3))
    faces = np.ascontiguousarray(mesh.faces, np.int64)
    start = cKDTree(mesh.vertices).query(points + rng.normal(0.0, 0.5, (2000, 3)))[1]  # a vertex a step or two off
    _, _, near = walk_closest(np.ascontiguousarray(mesh.vertices, np.float64), faces,
                              face_neighbours(faces, mesh.n_vertices), *vertex_rings(faces, mesh.n_vertices),
                              start, points)
    walked = np.linalg.norm(points - near, axis=1)
    exact = np.abs(SurfaceDistance(mesh).query(points).distance.astype(np.float64))
    assert (walked >= exact - 1e-5).all()
    assert np.mean(walked <= exact + 1e-5) > 0.9


def test_farthest_is_exact_where_walks_stop_short():
    """Bumps strand walks in local minima, so the bounds exceed the distances; the result must not."""
    mesh = shapes.bumpy(shapes.sphere(5.0), 0.3)
    other = shapes.bumpy(shapes.sphere(5.2), 0.3, seed=1)
    group = (mesh.vertices[mesh.faces].mean(axis=1)[:, 0] > 0).astype(np.int64)
    got = verify.farthest(mesh, other, group, 2, 0.1, chunk=500)
    assert np.allclose(got, _exact_farthest(mesh, other, group, 2), rtol=1e-6, atol=1e-6)
    each = np.arange(mesh.n_faces)  # a group per face: every face's own farthest probe, 68 vertex bounds too far
    assert np.allclose(verify.farthest(mesh, other, each, mesh.n_faces, 0.1),
                       _exact_farthest(mesh, other, each, mesh.n_faces), rtol=1e-6, atol=1e-6)
    group[::7] = -1  # faces left out count for no group
    kept = group >= 0
    sub = TriMesh(mesh.vertices, mesh.faces[kept])
    assert np.allclose(verify.farthest(mesh, other, group, 2, 0.1),
                       _exact_farthest(sub, other, group[kept], 2), rtol=1e-6, atol=1e-6)


def test_farthest_with_a_floor_is_exact_above_it():
    """A group within the floor reports the floor unsearched; above it, its exact farthest distance (the
    retries' question: which faces miss by more than half the tolerance)."""
    mesh = shapes.bumpy(shapes.sphere(5.0), 0.3)
    other = shapes.bumpy(shapes.sphere(5.2), 0.3, seed=1)
    each = np.arange(mesh.n_faces)
    exact = _exact_farthest(mesh, other, each, mesh.n_faces)
    floor = float(np.median(exact))
    got = verify.farthest(mesh, other, each, mesh.n_faces, 0.1, floor=floor)
    assert np.allclose(got, np.maximum(exact, floor), rtol=1e-6, atol=1e-6)
    assert (exact > floor).any() and (exact < floor).any()


def test_farthest_gives_exact_vertex_distances_at_the_faces_above_the_floor():
    """missed() pins each missing face's farthest corner by the distances farthest() measured: bit for bit the
    exact search's (float32, as mesh_distance gives them) at every corner of a face above the floor, walked bounds
    (never below the distance) at the other vertices measured, and nothing written at vertices of no face measured."""
    from apt_filters.core.distance import mesh_distance

    mesh = shapes.bumpy(shapes.sphere(5.0), 0.3)
    other = shapes.bumpy(shapes.sphere(5.2), 0.3, seed=1)
    each = np.arange(mesh.n_faces)
    floor = float(np.median(_exact_farthest(mesh, other, each, mesh.n_faces)))
    each[mesh.vertices[mesh.faces].mean(axis=1)[:, 2] > 3.0] = -1  # a cap left out
    at = np.full(mesh.n_vertices, np.nan)
    got = verify.farthest(mesh, other, each, mesh.n_faces, 0.1, floor=floor, vertex_distance=at)
    above = np.unique(mesh.faces[(each >= 0) & (got > floor)])
    assert len(above) > 100
    assert np.array_equal(at[above], mesh_distance(other, mesh.vertices[above]))
    measured = np.unique(mesh.faces[each >= 0])
    assert (at[measured] >= mesh_distance(other, mesh.vertices[measured]) - 1e-6).all()
    unmeasured = np.setdiff1d(np.arange(mesh.n_vertices), measured)
    assert len(unmeasured) and np.isnan(at[unmeasured]).all()


def test_farthest_searches_each_probe_within_its_walked_bound_never_without_bound(monkeypatch):
    """Probes farther than ``near`` (the misses a mend asks about: 0.2-0.3 nm of two spheres 0.2 nm apart, near
    0.05) are searched within near, then within their class of walked bounds (near 2^j), never without bound (main
    searched them again without bound: a plan of 17 cells each way per small engine), and every face's
    result is bit for bit the exact search's where it is above the floor, the walked sphere's engine given or
    built per batch."""
    mesh = shapes.bumpy(shapes.sphere(5.0), 0.3)
    other = shapes.bumpy(shapes.sphere(5.2), 0.3, seed=1)
    each = np.arange(mesh.n_faces)
    exact = _exact_farthest(mesh, other, each, mesh.n_faces)
    floor = float(np.median(exact))
    reaches = []
    query = SurfaceDistance.query

    def recorded(self, points, max_distance=None, closest=False):
        reaches.append(max_distance)
        return query(self, points, max_distance, closest)

    monkeypatch.setattr(SurfaceDistance, "query", recorded)
    for surface in (None, SurfaceDistance(other)):
        reaches.clear()
        got = verify.farthest(mesh, other, each, mesh.n_faces, 0.05, floor=floor, surface=surface)
        above = got > floor
        assert above.sum() > 100 and np.array_equal(got[above], exact[above])
        assert reaches and all(r is not None and np.isfinite(r) for r in reaches)
        assert max(reaches) > 0.2  # the far probes' classes


def test_farthest_takes_an_earlier_calls_walks_where_they_cover_the_faces_measured(monkeypatch):
    """The check's walked bounds, taken again by missed(): a call on the same two meshes with the walks of a call
    that measured all faces walks nothing and gives bit for bit what walking again gives; walks of other meshes, or
    of fewer faces than are measured now, are not taken (the call walks, and fills them with its own)."""
    import apt_filters.remesh.walk as walk

    mesh = shapes.bumpy(shapes.sphere(5.0), 0.3)
    other = shapes.bumpy(shapes.sphere(5.2), 0.3, seed=1)
    each = np.arange(mesh.n_faces)
    half = np.where(mesh.vertices[mesh.faces].mean(axis=1)[:, 0] > 0, each, -1)
    floor = float(np.median(_exact_farthest(mesh, other, each, mesh.n_faces)))
    fresh = [verify.farthest(mesh, other, g, mesh.n_faces, 0.1, floor=floor) for g in (each, half)]
    walks = verify.Walks()
    verify.farthest(mesh, other, half, mesh.n_faces, 0.1, walks=walks)
    assert walks.mesh is mesh and walks.faces.sum() == (half >= 0).sum()
    verify.farthest(mesh, other, each, mesh.n_faces, 0.1, walks=walks)  # more faces than walked: walks them all
    assert walks.faces.all()
    other_walks = verify.Walks()
    verify.farthest(mesh, shapes.sphere(5.2), each, mesh.n_faces, 0.1, walks=other_walks)
    calls = []
    real = walk.walk_closest
    monkeypatch.setattr(walk, "walk_closest", lambda *a: calls.append(1) or real(*a))
    for g, want in zip((each, half), fresh):
        assert np.array_equal(verify.farthest(mesh, other, g, mesh.n_faces, 0.1, floor=floor, walks=walks), want)
    assert not calls
    assert np.array_equal(verify.farthest(mesh, other, each, mesh.n_faces, 0.1, floor=floor, walks=other_walks),
                          fresh[0])
    assert calls and other_walks.other is other
