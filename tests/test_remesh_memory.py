"""The remesher's per-face temporaries (issue #24, peak memory per input face): the forms that hold less are the
same numbers, bit for bit, as the (f, 3, 3) forms they replace, and hold less (``tracemalloc``: numpy's own
allocations, the same on every machine)."""

import tracemalloc

import numpy as np

from apt_filters.core import mesh as core_mesh
from apt_filters.core.mesh import face_normals
from apt_filters.remesh import features as feat, optimize, repair
from tests import remesh_shapes as shapes


def _traced(fn, *args):
    """``fn(*args)`` and the bytes its allocations peaked at (run once before, so that nothing is loaded then)."""
    fn(*args)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        out = fn(*args)
        return out, tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_corner_by_corner_normals_and_flat_rings_are_the_corner_arrays_own():
    """Face normals and the flat-ring test taken corner by corner equal the (f, 3, 3) forms bit for bit on a bumpy
    open sheet, at under 180 bytes per face (those forms: 200 and 216)."""
    mesh = shapes.bumpy(shapes.tilted_sheet(), 0.25)
    v, f = mesh.vertices, mesh.faces
    p = v[f]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    unit = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
    normals, peak = _traced(face_normals, v, f, False)
    assert np.array_equal(normals, cross) and peak < 180 * len(f), peak / len(f)
    normals, peak = _traced(optimize._face_normals, v, f)
    assert np.array_equal(normals, unit) and peak < 180 * len(f), peak / len(f)
    area = np.linalg.norm(cross, axis=1)
    mean = np.stack([np.bincount(f.ravel(), np.repeat(unit[:, k] * area, 3), minlength=len(v)) for k in range(3)], 1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    least = np.ones(len(v))
    np.minimum.at(least, f.ravel(), np.einsum("ij,ij->i", np.repeat(unit, 3, axis=0), mean[f.ravel()]))
    for bend in (5.0, 20.0):
        flat, peak = _traced(optimize._flat_rings, v, f, bend)
        assert np.array_equal(flat, least > np.cos(np.radians(bend))) and peak < 180 * len(f), peak / len(f)
        assert 0 < flat.sum() < len(v)


def _naive_apexes(mesh, threshold: float, spacing: float) -> set:
    """The oracle of ``features._apexes`` with no feature curve: a face at a time, the clusters by union-find."""
    v, faces = mesh.vertices, mesh.faces
    deficit = np.full(len(v), 2 * np.pi)
    area = np.array([0.5 * np.linalg.norm(np.cross(v[b] - v[a], v[c] - v[a])) for a, b, c in faces])
    parent = list(range(len(v)))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for f, face_area in zip(faces, area):
        angles = []
        for k in range(3):
            u, w = v[f[(k + 1) % 3]] - v[f[k]], v[f[k - 1]] - v[f[k]]
            angles.append(np.arctan2(np.linalg.norm(np.cross(u, w)), u @ w))
        deficit[f] -= np.array(angles) + (np.pi - sum(angles)) / 3
        for k in range(3):
            if np.linalg.norm(v[f[(k + 1) % 3]] - v[f[k]]) < spacing or face_area < 0.01 * area.mean():
                parent[root(f[k])] = root(f[(k + 1) % 3])
    clusters = {}
    for i in range(len(v)):
        clusters.setdefault(root(i), []).append(i)
    return {max(c, key=lambda i: abs(deficit[i])) for c in clusters.values() if abs(deficit[c].sum()) > threshold}


def test_apexes_hold_no_corner_copies():
    """The cone apexes of the box-sphere-plate (24 or 25 at 17°, as pymeshlab's boolean union triangulates it:
    the count is the naive oracle's, a face at a time) at under 420 bytes per face (the (f, 3, 3) form: 492)."""
    mesh = shapes.box_minus_sphere_plate(0.5)
    apex, peak = _traced(feat._apexes, mesh, 0.3, 0.01, np.zeros(mesh.n_vertices, bool))
    assert set(np.flatnonzero(apex)) == _naive_apexes(mesh, 0.3, 0.01) and apex.sum() >= 24
    assert peak < 420 * mesh.n_faces, peak / mesh.n_faces


def test_boundary_loops_leave_no_topology_cached():
    """The hole fill's loops: the faces' edge tables go when the loops are found (cached, they lived as long as
    the faces did, through the next round's trim), and the loops are the rim's."""
    mesh = shapes.tilted_sheet()
    faces = np.array(mesh.faces)
    loops = repair.boundary_loops(faces)
    assert not any(entry[0]() is faces for entry in core_mesh._cache)
    rim = np.unique(mesh.topology.boundary_half_edges)
    assert sorted(v for loop in loops for v in loop) == sorted(rim.tolist())


def test_edge_tables_are_np_uniques_at_half_the_bytes():
    """The topology's edge tables (one key per half-edge, lower vertex first) equal np.unique's of those keys, and
    the boundary half-edges the rows of the (f, 3, 2) half-edge stack that no other face uses, bit for bit, on a
    gyroid open on the cube's faces; built together at under 130 bytes per face (np.unique and the stack: 233)."""
    mesh = shapes.gyroid(half=8.0)
    f, n = mesh.faces, mesh.n_vertices
    following = np.roll(f, -1, axis=1)
    keys, inverse, counts = np.unique(np.minimum(f, following) * n + np.maximum(f, following), return_inverse=True,
                                      return_counts=True)
    half = np.stack([f, following], axis=2)[counts[inverse] == 1]

    def build():
        top = core_mesh.Topology.of(f, n)
        return top, top.boundary_half_edges

    (top, rim), peak = _traced(build)
    assert np.array_equal(top.edge_vertices, np.stack([keys // n, keys % n], axis=1))
    assert np.array_equal(top.face_edge, inverse.reshape(-1, 3)) and np.array_equal(top.edge_faces, counts)
    assert np.array_equal(rim, half) and 0 < len(rim) < len(f)
    assert peak < 130 * len(f), peak / len(f)



def test_pseudo_normals_corner_by_corner_are_the_corner_arrays_own():
    """The distance engine's corner angles, edge and vertex pseudo-normals taken a corner and a coordinate at a time
    equal the (f, 3, 3) forms bit for bit on a bumpy open sheet, at under 260 bytes per face (those forms: 481)."""
    from apt_filters.core.distance import PseudoNormals

    mesh = shapes.bumpy(shapes.tilted_sheet(), 0.25)
    f, top = mesh.faces, mesh.topology
    tri = mesh.vertices[f]
    a, b = np.roll(tri, -1, axis=1) - tri, np.roll(tri, 1, axis=1) - tri
    angles = np.arctan2(np.linalg.norm(np.cross(a, b), axis=2), np.einsum("ijk,ijk->ij", a, b))
    nf = mesh.face_normals()
    rows = np.repeat(nf, 3, axis=0)
    edge = np.stack([np.bincount(top.face_edge.ravel(), rows[:, k], minlength=len(top.edge_vertices))
                     for k in range(3)], 1)
    rows = (angles[:, :, None] * nf[:, None, :]).reshape(-1, 3)
    vertex = np.stack([np.bincount(f.ravel(), rows[:, k], minlength=mesh.n_vertices) for k in range(3)], 1)
    normals, peak = _traced(PseudoNormals.of, mesh)
    assert np.array_equal(normals.corner_angles, angles) and np.array_equal(normals.face_normals, nf)
    assert np.array_equal(normals.edge_normals, edge) and np.array_equal(normals.vertex_normals, vertex)
    assert peak < 260 * len(f), peak / len(f)
