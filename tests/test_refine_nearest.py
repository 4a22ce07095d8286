"""Ions near a mesh without a KD-tree (apt_filters.core.nearby, refine.nearest, NearIons) and fold removal, against
brute force."""

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from apt_filters.core.mesh import topology, vertex_normals
from apt_filters.contour import marching_cubes
from apt_filters.core.checks import folded_pairs
from apt_filters.core.nearby import select_near
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.refine.subdivide import subdivide
from apt_filters.refine.untangle import unfold
from apt_filters.refine.band import NearIons, Pairs, adjacency, pooled, profile_reach
from apt_filters.refine.nearest import descend
from apt_filters.refine.surface import umbrella
from apt_filters.voxel import ConcentrationBasis


def _blob():
    """A lumpy, asymmetric closed marching-cubes surface (sliver triangles included), subdivided once."""
    x, y, z = np.meshgrid(*(np.arange(-6.0, 6.5, 0.5),) * 3, indexing="ij")
    f = np.sqrt((x / 1.3) ** 2 + (y / 1.0) ** 2 + (z / 0.8) ** 2) + 0.3 * np.sin(1.7 * x) * np.cos(1.3 * y)
    return subdivide(marching_cubes(-f, -3.0, spacing=(0.5, 0.5, 0.5), origin=(-6.0, -6.0, -6.0)))


def _near_uniform_al(mesh, seed: int, half: float, n: int, reach: float):
    """Al ions uniform in the cube [-half, half]^3 selected within ``reach`` of ``mesh``, with the generator used."""
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-half, half, size=(n, 3)).astype(np.float32)
    ions = IonTable(positions, np.full(len(positions), 27.0, np.float32))
    ranges = RangeTable([Range(26.5, 27.5, (("Al", 1),))])
    return NearIons.select(ions, ranges, ConcentrationBasis(), mesh.vertices, mesh.faces, reach), rng


def test_selection_keeps_every_point_whose_nearest_vertex_is_within_reach():
    mesh = _blob()
    rng = np.random.default_rng(1)
    points = rng.uniform(-9, 9, size=(60_000, 3)).astype(np.float32)
    reach = 1.7
    nearest = cKDTree(mesh.vertices).query(points)[0]
    near = select_near(points, mesh, reach, chunk=7_001)
    assert set(np.flatnonzero(nearest <= reach)) <= set(near.rows.tolist())
    assert len(near.rows) < len(points) / 2  # and it does filter


def test_descend_finds_the_nearest_vertex_near_the_surface():
    mesh = _blob()
    adj = adjacency(mesh.faces, mesh.n_vertices)
    rng = np.random.default_rng(2)
    points = mesh.vertices[rng.integers(0, mesh.n_vertices, 20_000)] + rng.normal(0, 0.8, size=(20_000, 3))
    near = select_near(points, mesh, 4.0)
    assert len(near.rows) == len(points)
    start = mesh.faces[near.face, 0]  # a corner of the face holding the closest point, as NearIons.select starts
    vertex, d2 = descend(points, mesh.vertices, adj.indptr, adj.indices, start, exact=2.5)
    true_d, true_v = cKDTree(mesh.vertices).query(points)
    near = true_d < 1.5
    found = np.sqrt(d2)
    assert np.allclose(found, np.linalg.norm(points - mesh.vertices[vertex], axis=1))
    assert np.mean(vertex[near] == true_v[near]) > 0.99
    excess = found[near] - true_d[near]  # a near miss lands on a vertex barely farther than the nearest
    assert excess.mean() < 0.005 and excess.max() < 1.0


def test_near_ions_follow_a_moved_mesh():
    mesh = _blob()
    rng = np.random.default_rng(3)
    positions = rng.uniform(-8, 8, size=(80_000, 3)).astype(np.float32)
    ranges = RangeTable([Range(26.5, 27.5, (("Al", 1),)), Range(57.5, 58.5, (("Ni", 1),))])
    ions = IonTable(positions, rng.choice(np.array([27.0, 58.0, 99.0], dtype=np.float32), len(positions)))
    near = NearIons.select(ions, ranges, ConcentrationBasis(), mesh.vertices, mesh.faces, 3.0)
    assert near.atoms.atoms.shape == (len(near.positions), 2)
    moved = mesh.vertices * 1.05  # every vertex moves by < 0.3 nm
    band = near.band(moved, vertex_normals(moved, mesh.faces), 2.0, "tangent")  # the mesh distance: test_refine_bias
    d, v = cKDTree(moved).query(near.positions[band.index])
    assert np.mean(band.vertex == v) > 0.98
    assert np.all(d <= 2.0 + 1e-9)
    signed = np.einsum("ij,ij->i", near.positions[band.index] - moved[band.vertex],
                       vertex_normals(moved, mesh.faces)[band.vertex])
    assert np.allclose(band.distance, signed)


def test_selected_ions_run_in_the_order_of_their_vertices_in_table_order_within_each():
    # the table's rows are in no spatial order (as a synthetic specimen's are): the selection keeps its ions in the
    # order of their nearest vertices, so that a pass over them reads each vertex's fan for a run of ions; ties in
    # the table's order, so that the order is the same whatever order the search met them in
    mesh = _blob()
    near, _ = _near_uniform_al(mesh, 11, 9.0, 80_000, 2.0)
    pairs = np.column_stack([near.vertex, near.rows])
    assert len(pairs) > 5_000 and np.all(np.diff(near.vertex) >= 0)
    assert np.array_equal(pairs, pairs[np.lexsort((near.rows, near.vertex))])
    # the positions and atoms follow the rows, and the ions are those of the table's order, each once
    rng = np.random.default_rng(11)
    positions = rng.uniform(-9.0, 9.0, size=(80_000, 3)).astype(np.float32)
    assert np.array_equal(near.positions, positions[near.rows].astype(np.float64))
    assert len(np.unique(near.rows)) == len(near.rows) and np.all(near.atoms.atoms[:, 0] == 1.0)
    # each is assigned to its nearest vertex (the walk's 2-ring leaves < 1 % elsewhere)
    assert np.mean(cKDTree(mesh.vertices).query(near.positions)[1] == near.vertex) > 0.99


def test_near_ions_completed_for_a_mesh_moved_beyond_the_margin_hold_every_ion_a_new_selection_holds():
    mesh = _blob()
    rng = np.random.default_rng(5)
    positions = rng.uniform(-10, 10, size=(120_000, 3)).astype(np.float32)
    ranges = RangeTable([Range(26.5, 27.5, (("Al", 1),)), Range(57.5, 58.5, (("Ni", 1),))])
    ions = IonTable(positions, rng.choice(np.array([27.0, 58.0, 99.0], dtype=np.float32), len(positions)))
    near = NearIons.select(ions, ranges, ConcentrationBasis(exclude=("Ni",)), mesh.vertices, mesh.faces, 2.5)
    assert near.atoms.elements == ["Al"] and near.everything.elements == ["Al", "Ni"]
    # one side of the blob moves out by up to 3 nm, beyond the 1.5 nm the selection's margin covers
    moved = mesh.vertices + np.clip(mesh.vertices[:, [0]], 0, None) * np.array([[0.8, 0.0, 0.0]])
    before = set(near.rows.tolist())
    near.cover(moved, 1.0)
    fresh = NearIons.select(ions, ranges, ConcentrationBasis(exclude=("Ni",)), moved, mesh.faces, 2.5)
    d = cKDTree(moved).query(positions)[0]
    within = set(np.flatnonzero(d <= 1.0).tolist())
    assert within <= set(near.rows.tolist()) and not within <= before  # completed: what was missing was added
    assert within <= set(fresh.rows.tolist())
    assert len(set(near.rows.tolist())) == len(near.rows)  # no ion twice
    # the atoms follow the rows, the basis columns those of every element
    k = np.argsort(near.rows)
    expected = np.where(ions.mz[near.rows[k]] == 27.0, 1.0, 0.0)
    assert np.array_equal(near.atoms.atoms[k, 0], expected)
    assert np.array_equal(near.everything.atoms[k, 1], (ions.mz[near.rows[k]] == 58.0).astype(float))
    # and the halves by row parity stay halves when completed
    half = NearIons.select(ions, ranges, ConcentrationBasis(), mesh.vertices, mesh.faces, 2.5).half(1, mesh.vertices)
    half.cover(moved, 1.0)
    assert np.all(half.rows % 2 == 1) and {r for r in within if r % 2} <= set(half.rows.tolist())


def test_pooled_profiles_match_the_dense_weights():
    mesh = _blob()
    n = mesh.n_vertices
    normals = vertex_normals(mesh.vertices, mesh.faces)
    comps = topology(mesh.faces, n).vertex_components
    profiles = np.random.default_rng(4).random((n, 5))
    pairs = Pairs.find(mesh.vertices, comps, 1.2)
    got = pooled(profiles, mesh.vertices, normals, pairs, 8.0)
    r = np.linalg.norm(mesh.vertices[:, None] - mesh.vertices[None], axis=2)
    w = np.exp(-0.5 * (r / 0.6) ** 2) * np.maximum(normals @ normals.T, 0) ** 8 * (r <= 1.2)
    np.fill_diagonal(w, 1.0)
    assert np.allclose(got, w @ profiles)


def test_unfold_removes_the_folds_of_a_mesh():
    mesh = _blob()
    v = mesh.vertices.copy()
    j = adjacency(mesh.faces, mesh.n_vertices)[100].indices[0]
    v[100] = v[j] + 1.5 * (v[j] - v[100])  # dragged across a neighbour: its triangles flip
    assert len(folded_pairs(v, mesh.faces)) > 0
    out, rounds = unfold(v, mesh.faces, umbrella(adjacency(mesh.faces, mesh.n_vertices)))
    assert len(folded_pairs(out, mesh.faces)) == 0 and rounds >= 1
    far = np.linalg.norm(mesh.vertices - mesh.vertices[100], axis=1) > 2.0
    assert np.array_equal(out[far], v[far])  # a local repair


def test_second_ring_lists_the_vertices_two_edges_away_once():
    from apt_filters.refine.nearest import second_ring

    mesh = _blob()
    adj = adjacency(mesh.faces, mesh.n_vertices)
    ptr, ring = second_ring(adj.indptr, adj.indices)
    one = (adj > 0).astype(np.int64)
    two = ((one @ one) > 0).toarray() & ~(one > 0).toarray()
    np.fill_diagonal(two, False)
    for v in range(0, mesh.n_vertices, 7):
        listed = ring[ptr[v]:ptr[v + 1]]
        assert len(set(listed.tolist())) == len(listed)
        assert set(listed.tolist()) == set(np.flatnonzero(two[v]).tolist())


def test_band_distance_is_the_nearest_face_of_the_fan():
    from apt_filters.core.triangle import closest_on_triangle
    from apt_filters.refine.band import EXACT

    mesh = _blob()
    near, _ = _near_uniform_al(mesh, 6, 8, 40_000, 3.0)
    normals = vertex_normals(mesh.vertices, mesh.faces)
    band = near.band(mesh.vertices, normals, 3.0)
    p = near.positions[band.index]
    q = mesh.vertices[band.vertex]
    exact = np.abs(np.einsum("ij,ij->i", p - q, normals[band.vertex])) <= EXACT
    for i in np.flatnonzero(exact)[::10]:
        fan = mesh.faces[(mesh.faces == band.vertex[i]).any(axis=1)]
        best = min(closest_on_triangle(*p[i], *mesh.vertices[f[0]], *mesh.vertices[f[1]], *mesh.vertices[f[2]])[0]
                   for f in fan)
        assert abs(abs(band.distance[i]) - np.sqrt(best)) <= 1e-9


def test_band_shell_keeps_every_bin_window_and_side_of_the_exact_distances():
    mesh = _blob()
    near, _ = _near_uniform_al(mesh, 6, 9, 120_000, 5.0)
    moved = mesh.vertices * 1.03
    normals = vertex_normals(moved, mesh.faces)
    exact = near.band(moved, normals, 4.0)
    lo, hi = 1.5, 3.0
    shell = near.band(moved, normals, 4.0, shell=(lo, hi))
    assert np.array_equal(shell.index, exact.index) and np.array_equal(shell.vertex, exact.vertex)
    d, s = exact.distance, shell.distance
    spared = d != s
    assert spared.mean() > 0.05  # the planes spare some ions the closest-point search
    assert np.array_equal(d[np.abs(d) <= lo], s[np.abs(d) <= lo])  # within lo: exact
    assert np.array_equal(np.sign(d), np.sign(s))
    assert np.all(np.abs(s[spared]) > lo) and np.all(np.abs(s[spared]) <= np.abs(d[spared]) + 1e-12)
    assert np.array_equal(np.abs(d) <= hi, np.abs(s) <= hi)  # the same place relative to hi
    # both bands from one pass: each what its own pass gives
    for one, alone in zip(near.bands(moved, normals, 4.0, shell=(lo, hi)), (shell, exact)):
        assert all(np.array_equal(getattr(one, f), getattr(alone, f)) for f in ("index", "vertex", "distance"))


def test_a_band_at_the_profile_reach_holds_every_ion_of_the_profiles_as_the_wide_band_has_it():
    mesh = _blob()
    near, _ = _near_uniform_al(mesh, 6, 9, 120_000, 5.0)
    half_width, shell = 1.5, (1.5, np.inf)  # the whole placement's band: levels fixed, only the profiles count
    for scale in (1.03, 0.97):
        moved = mesh.vertices * scale
        normals = vertex_normals(moved, mesh.faces)
        reach = profile_reach(moved, mesh.faces, half_width)
        wide, narrow = near.band(moved, normals, 4.0, shell=shell), near.band(moved, normals, reach, shell=shell)
        inside = np.isin(wide.index, narrow.index)
        # a part of the wide band, each ion as the wide band has it, in the same order
        assert np.array_equal(narrow.index, wide.index[inside])
        assert np.array_equal(narrow.vertex, wide.vertex[inside])
        assert np.array_equal(narrow.distance, wide.distance[inside])
        # holding every ion of the profiles, and far fewer of the others
        assert np.all(inside[np.abs(wide.distance) < half_width])
        assert len(narrow.index) < 0.7 * len(wide.index)
        # the fan's extent matters: at half_width alone some ions of the profiles are lost
        short = near.band(moved, normals, half_width, shell=shell)
        assert np.count_nonzero(np.abs(short.distance) < half_width) < np.count_nonzero(np.abs(wide.distance)
                                                                                        < half_width)


def test_taken_ions_get_what_they_get_among_all():
    mesh = _blob()
    near, rng = _near_uniform_al(mesh, 7, 8, 60_000, 3.0)
    keep = np.flatnonzero(rng.random(len(near.rows)) < 0.3)
    part = near.take(keep)
    for scale in (1.01, 1.1, 1.12):  # below and above the moves that find the nearest vertices again
        moved = mesh.vertices * scale
        normals = vertex_normals(moved, mesh.faces)
        whole, mine = near.band(moved, normals, 2.5), part.band(moved, normals, 2.5)
        inside = np.isin(whole.index, keep)
        assert np.array_equal(keep[mine.index], whole.index[inside])
        assert np.array_equal(mine.vertex, whole.vertex[inside]) and np.array_equal(mine.distance, whole.distance[inside])


def test_pairs_csr_is_scipys_canonical_upper_triangle():
    from scipy.sparse import csr_matrix, triu

    from apt_filters.refine.band import _upper_csr

    v = np.random.default_rng(8).random((3000, 3)) * 8
    ij = cKDTree(v).query_pairs(1.1, output_type="ndarray")
    m = csr_matrix((np.ones(2 * len(ij)), (np.r_[ij[:, 0], ij[:, 1]], np.r_[ij[:, 1], ij[:, 0]])), shape=(3000, 3000))
    m = triu(m).tocsr()
    m.sort_indices()
    flipped = ij[:, ::-1].copy()
    flipped[::2] = ij[::2]  # either order of a pair's vertices
    indptr, indices = _upper_csr(flipped.astype(np.int64), 3000)
    assert np.array_equal(indptr, m.indptr) and np.array_equal(indices, m.indices)


@njit
def _pooled_row_by_row(profiles, vertices, normals, radius, power):
    """The oracle of :func:`pooled` (compiled, so that exp and pow are numba's): every vertex's full row of the other
    vertices, in ascending order, each pair's weight measured from that row's side."""
    n, k = profiles.shape
    out = profiles.copy()
    inv = 2.0 / (radius * radius)
    for i in range(n):
        for j in range(n):
            r2 = ((vertices[i, 0] - vertices[j, 0]) ** 2 + (vertices[i, 1] - vertices[j, 1]) ** 2
                  + (vertices[i, 2] - vertices[j, 2]) ** 2)
            if j != i and r2 <= radius * radius:
                c = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
                w = np.exp(-r2 * inv) * max(c, 0.0) ** power
                for col in range(k):
                    out[i, col] += w * profiles[j, col]
    return out


def test_pooled_sums_each_row_in_ascending_order_bit_for_bit():
    # each pair's weight found once and added to both of its rows: the bits of a pass over every full row
    mesh = _blob()
    n = mesh.n_vertices
    normals = vertex_normals(mesh.vertices, mesh.faces)
    comps = np.zeros(n, dtype=np.int64)
    profiles = np.random.default_rng(5).random((n, 4))
    got = pooled(profiles, mesh.vertices, normals, Pairs.find(mesh.vertices, comps, 0.9), 8.0)
    want = _pooled_row_by_row(profiles, mesh.vertices, normals, 0.9, 8.0)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64))


def test_binned_sums_each_bin_in_the_ions_order_as_bincount_does():
    from apt_filters.refine.band import binned

    rng = np.random.default_rng(6)
    b, n, half_width, bin_width = 50_000, 300, 1.5, 0.25
    vertex = rng.integers(0, n, b)
    distance = rng.uniform(-2.0, 2.0, b)  # a quarter outside the bins
    distance[:5] = [-1.5, 1.5, -1.5 - 1e-12, 1.25, 0.0]  # the edges: first bin in, last edge out
    weights = (rng.normal(size=b), rng.random(b) * 1e3)
    got = binned(vertex, distance, weights, n, half_width, bin_width)
    at = np.floor((distance + half_width) / bin_width).astype(np.int64)
    ok = (at >= 0) & (at < 12)
    for w, g in zip(weights, got):
        want = np.bincount(vertex[ok] * 12 + at[ok], weights=w[ok], minlength=n * 12).reshape(n, 12)
        assert g.shape == (n, 12) and np.array_equal(g.view(np.uint64), want.view(np.uint64))


def test_subset_on_the_assigned_mesh_skips_the_walk_with_the_walks_result():
    """Oracle: the walk itself (``settled`` off) on the same vertices, after a selection, a completion that moves the
    mesh (whose new ions walked on other vertices than the old ones) and a band that finds the vertices again."""
    from dataclasses import replace

    mesh = _blob()
    near, rng = _near_uniform_al(mesh, 9, 8, 60_000, 3.0)
    keep = rng.random(len(near.rows)) < 0.5

    def both(ions, vertices, radius):
        fast, slow = ions.subset(keep[:len(ions.rows)], vertices, radius), replace(ions, settled=False).subset(
            keep[:len(ions.rows)], vertices, radius)
        assert np.array_equal(fast.rows, slow.rows) and np.array_equal(fast.vertex, slow.vertex)
        assert fast.settled and slow.settled
        return fast

    assert near.settled
    both(near, mesh.vertices, 2.0)
    moved = mesh.vertices + np.clip(mesh.vertices[:, [0]], 0, None) * np.array([[0.5, 0.0, 0.0]])
    near.cover(moved, 2.5)
    assert not near.settled  # the ions added walked on ``moved``, the others on the start
    keep = np.concatenate([keep, rng.random(len(near.rows) - len(keep)) < 0.5])
    both(near, near.assigned, 2.0)
    near.band(moved, vertex_normals(moved, mesh.faces), 2.5)  # moved far: every ion walks again
    assert near.settled
    both(near, moved, 2.0)
    sub = both(near, moved, 2.5)
    both(sub, moved, 1.0)


def test_the_nearest_corner_of_each_face_is_numpys_argmin_bit_for_bit():
    # the walks' start (NearIons.cover): the compiled loop against numpy's own expression (kept here as the oracle),
    # with ties (corners at one place, points equidistant from two corners) and coordinates of mixed magnitude
    from apt_filters.refine.band import _nearest_corner
    rng = np.random.default_rng(5)
    vertices = np.vstack([rng.normal(0, 30, (500, 3)), np.zeros((1, 3)), np.zeros((1, 3)), [[2.0, 0, 0]]])
    ring = rng.integers(0, len(vertices), (20_000, 3))
    ring[:100] = [500, 501, 0]  # two corners at one place: the first of them
    points = vertices[ring[:, 0]] + rng.normal(0, 5, (len(ring), 3))
    points[100:200] = [1.0, 3.0, 0.0]
    ring[100:200] = [502, 500, 1]  # (1, 3, 0) equidistant from (0, 0, 0) and (2, 0, 0)
    oracle = ring[np.arange(len(ring)), np.argmin(((vertices[ring] - points[:, None]) ** 2).sum(axis=2), axis=1)]
    assert np.array_equal(_nearest_corner(points, vertices, ring), oracle)
