import numpy as np
import pytest

from apt_filters.core import AptFiltersError, TriMesh, atomic_output, atomic_write_text
from apt_filters.core.mesh import merge
from apt_filters.io import Range, RangeTable, UNRANGED


def unit_cube() -> TriMesh:
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * [2.0, 3.0, 5.0]
    # vertex index = 4x + 2y + z; faces counter-clockwise seen from outside
    f = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return TriMesh(v, f)


def test_trimesh_box_volume_area_and_unpacking():
    m = unit_cube()
    assert m.signed_volume() == pytest.approx(30.0)
    assert m.area() == pytest.approx(2 * (6 + 10 + 15))
    v, f = m
    assert v.shape == (8, 3) and f.shape == (12, 3)
    assert len(m.boundary_edges()) == 0 and m.non_manifold_edge_count() == 0
    # normals point outward: the +x face's normal is +x
    n = m.face_normals()
    assert np.allclose(n[2], [1, 0, 0])
    flipped = TriMesh(m.vertices, m.faces[:, ::-1])
    assert flipped.signed_volume() == pytest.approx(-30.0)


def test_face_normals_exact_and_numpys_numbers_bit_for_bit():
    from apt_filters.core.mesh import face_normals

    # exact truth: a right triangle of legs 3 and 4 in the plane z = 1 (twice its area 12), its reversed winding, a
    # degenerate face (zeros, not NaN)
    v = np.array([[0, 0, 1], [3, 0, 1], [0, 4, 1], [6, 0, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 1], [0, 1, 3]])
    assert face_normals(v, f, normalize=False).tolist() == [[0, 0, 12], [0, 0, -12], [0, 0, 0]]
    assert face_normals(v, f).tolist() == [[0, 0, 1], [0, 0, -1], [0, 0, 0]]
    # the compiled pass gives numpy's expression's numbers (cross product, norm, division), in either precision, over
    # scales from 1e-3 to 1e3 nm and faces with repeated corners
    rng = np.random.default_rng(3)
    v = rng.normal(size=(5000, 3)) * 10.0 ** rng.uniform(-3, 3, size=(5000, 1))
    f = rng.integers(0, len(v), size=(20000, 3))
    f[:500, 2] = f[:500, 0]
    for dtype in (np.float64, np.float32):
        p = v.astype(dtype)
        corner = p[f[:, 0]]
        raw = np.cross(p[f[:, 1]] - corner, p[f[:, 2]] - corner)
        length = np.linalg.norm(raw, axis=1, keepdims=True)
        unit = np.divide(raw, length, out=np.zeros_like(raw), where=length > 0)
        for normalize, expected in ((False, raw), (True, unit)):
            got = face_normals(p, f, normalize=normalize)
            assert got.dtype == dtype and np.array_equal(got, expected)


def test_trimesh_rejects_mismatched_scalars():
    with pytest.raises(ValueError):
        TriMesh(np.zeros((3, 3)), [[0, 1, 2]], vertex_scalars={"value": np.zeros(2)})


def test_atomic_output_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("crash")
    assert list(tmp_path.iterdir()) == []
    atomic_write_text(target, "done")
    assert target.read_text() == "done"
    with pytest.raises(AptFiltersError, match="exists"):
        atomic_write_text(target, "again")
    atomic_write_text(target, "again", overwrite=True)
    assert target.read_text() == "again"


def table() -> RangeTable:
    return RangeTable([
        Range(27.5, 28.5, (("Si", 1),)),
        Range(13.8, 14.3, (("Si", 1),)),
        Range(83.5, 86.5, (("Cr", 1), ("O", 2))),
        Range(15.8, 16.5, (("O", 1),)),
    ], source="t.rrng")


def test_ranging_is_vectorised_and_keeps_unranged():
    t = table()
    assert t.ions == ["Si", "CrO2", "O"]
    assert t.elements == ["Si", "Cr", "O"]
    mz = np.array([14.0, 28.5, 85.0, 16.0, 1.0, 20.0, 90.0, 13.8], np.float32)
    assert t.range_index(mz).tolist() == [1, 0, 2, 3, UNRANGED, UNRANGED, UNRANGED, 1]
    assert t.ion_index(mz).tolist() == [0, 0, 1, 2, UNRANGED, UNRANGED, UNRANGED, 0]
    assert t.element_matrix().tolist() == [[1, 0, 0], [0, 1, 2], [0, 0, 1]]


def test_overlapping_ranges_name_both():
    with pytest.raises(AptFiltersError, match=r"t.rrng: ranges overlap: Si \[27.5, 28.5\] Da and O \[28, 29\] Da"):
        RangeTable(table().ranges + [Range(28.0, 29.0, (("O", 1),))], source="t.rrng")


def test_pos_epos_rrng_writers(tmp_path):
    from apt_filters.io.ions import IonTable
    from apt_filters.io.writers import EPOS_DTYPE, format_rrng, write_epos, write_pos

    rng = np.random.default_rng(0)
    ions = IonTable(rng.normal(size=(10, 3)).astype(np.float32), rng.uniform(1, 100, 10).astype(np.float32),
                    extra={"multiplicity": np.arange(10, dtype=np.int32)})
    write_pos(tmp_path / "a.pos", ions, chunk=3)
    raw = np.fromfile(tmp_path / "a.pos", ">f4").reshape(-1, 4)
    assert np.array_equal(raw[:, :3], ions.positions) and np.array_equal(raw[:, 3], ions.mz)
    write_epos(tmp_path / "a.epos", ions, chunk=4)
    rec = np.fromfile(tmp_path / "a.epos", EPOS_DTYPE)
    assert EPOS_DTYPE.itemsize == 44
    assert np.array_equal(rec["y"], ions.positions[:, 1]) and rec["multiplicity"].tolist() == list(range(10))
    text = format_rrng(table())
    assert "Range3=83.5000 86.5000 Cr:1 O:2" in text and "Ion2=Cr" in text


def test_atomic_output_gives_ordinary_permissions(tmp_path):
    import os

    umask = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "p.txt", "x")
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644


def test_face_components_numbered_by_first_face():
    a = unit_cube()
    b = TriMesh(a.vertices + 10, a.faces)
    both = TriMesh(np.vstack([b.vertices, a.vertices]), np.vstack([b.faces, a.faces + 8]))
    labels = both.face_components()
    assert labels.tolist() == [0] * 12 + [1] * 12
    shuffled = TriMesh(both.vertices, both.faces[::-1])
    assert shuffled.face_components().tolist() == [0] * 12 + [1] * 12


def test_merge_keeps_used_vertices_and_the_scalars_every_part_has():
    a = unit_cube()
    # a spare vertex that no face uses, and a scalar only the first part carries
    a = TriMesh(np.vstack([a.vertices, [[9.0, 9.0, 9.0]]]), a.faces,
                {"value": np.arange(9.0), "only_a": np.zeros(9)}, {"rank": np.arange(12)})
    b = TriMesh(a.vertices[:8] + 10, a.faces[::-1], {"value": -np.arange(8.0)}, {"rank": np.arange(12) + 100})
    out = merge([a, b])
    assert out.n_vertices == 16 and out.n_faces == 24
    assert np.array_equal(out.vertices, np.vstack([a.vertices[:8], b.vertices]))
    assert list(out.vertex_scalars) == ["value"]
    assert np.array_equal(out.vertex_scalars["value"], np.concatenate([np.arange(8.0), -np.arange(8.0)]))
    assert np.array_equal(out.face_scalars["rank"], np.concatenate([np.arange(12), np.arange(12) + 100]))
    assert out.face_scalars["component"].tolist() == [0] * 12 + [1] * 12
    assert np.array_equal(out.vertices[out.faces[12:]], b.vertices[b.faces])

def _box(half, center=(0.0, 0.0, 0.0)) -> TriMesh:
    m = unit_cube()
    v = (m.vertices / [2.0, 3.0, 5.0] * 2 - 1) * np.asarray(half) + np.asarray(center)
    return TriMesh(v, m.faces)


def _box_sdf(p, half, center=(0.0, 0.0, 0.0)):
    q = np.abs(p - np.asarray(center)) - np.asarray(half)
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def test_topology_of_a_cube_a_holed_cube_and_a_torus():
    from tests.meshlab_shapes import torus

    cube = unit_cube()
    top = cube.topology
    assert (top.n_components, top.boundary_loops, top.genus, len(top.face_pairs)) == (1, 0, 0, 18)
    assert top.closed_component.tolist() == [True] and cube.topology is top  # cached on the faces array
    holed = TriMesh(cube.vertices, cube.faces[1:])
    assert (holed.topology.boundary_loops, holed.topology.closed_component.tolist()) == (1, [False])
    assert holed.topology.boundary_vertex.sum() == 3
    ring = torus().topology
    assert (ring.n_components, ring.boundary_loops, ring.genus) == (1, 0, 1)
    with pytest.raises(ValueError):
        top.components[0] = 5  # shared by every caller: read-only


def test_faces_around_vertices_and_pairs_of_faces_against_brute_force():
    from tests.meshlab_shapes import torus

    holed = TriMesh(torus().vertices, torus().faces[3:])  # boundary edges: faces with fewer than three pairs
    top = holed.topology
    rng = np.random.default_rng(2)
    for size in (1, 5, 40):
        verts = rng.choice(holed.n_vertices, size, replace=False)
        assert np.array_equal(top.faces_around(verts), np.flatnonzero(np.isin(holed.faces, verts).any(axis=1)))
        faces = rng.choice(len(holed.faces), size, replace=False)
        want = np.flatnonzero(np.isin(top.face_pairs, faces).any(axis=1))
        assert np.array_equal(top.pairs_of(faces), want)
    indptr, corner = top.vertex_corners
    slots = holed.faces.T.ravel()
    assert all(np.array_equal(corner[indptr[v]:indptr[v + 1]], np.flatnonzero(slots == v)) for v in range(20))


def test_topology_cache_lets_go_of_faces_nobody_else_holds():
    import weakref

    from apt_filters.core import mesh as core_mesh

    faces = unit_cube().faces.copy()
    top = core_mesh.topology(faces, 8)
    assert core_mesh.topology(faces, 8) is top  # still held by the caller: cached
    gone, tables = weakref.ref(faces), weakref.ref(top)
    del faces, top  # was: the cache's Topology held the array, so its weak key never died
    core_mesh.topology(unit_cube().faces, 8)
    assert gone() is None and tables() is None


def test_topology_cache_drops_the_tables_of_faces_as_they_die():
    import weakref

    from apt_filters.core import mesh as core_mesh

    faces = unit_cube().faces.copy()
    tables = weakref.ref(core_mesh.topology(faces, 8))
    assert tables() is not None  # cached while the faces live
    del faces
    assert tables() is None  # was: held until the next lookup (a remesh's flips' tables through its centring)


def _traced_peak(build) -> float:
    """Bytes ``build()`` allocates at its peak (``tracemalloc``; run once before, so that nothing loads inside)."""
    import tracemalloc

    build()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        build()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def test_building_the_distance_grid_and_the_edge_tables_takes_little_besides_what_they_keep():
    from apt_filters.core.distance import TriangleGrid
    from apt_filters.core.mesh import Topology
    from tests.remesh_shapes import sphere

    mesh = sphere(20.0)  # 15k faces
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.ascontiguousarray(mesh.faces, np.int64)
    # the grid keeps 156 bytes per triangle; its build peaked at 436 (corner arrays and their sorted copies)
    assert _traced_peak(lambda: TriangleGrid.build(vertices, faces)) < 330 * len(faces)
    # the edge tables keep 60 bytes per face; their build peaked at 231 (a (3m, 2) half-edge stack, sorted)
    assert _traced_peak(lambda: Topology.of(faces, len(vertices)).face_edge) < 210 * len(faces)


def test_signed_distance_is_positive_along_the_normals_and_exact_on_a_box():
    half = np.array([1.0, 2.0, 3.0])
    rng = np.random.default_rng(0)
    p = rng.uniform(-5, 5, size=(20_000, 3))
    from apt_filters.core.distance import SurfaceDistance

    d = SurfaceDistance(_box(half)).query(p).distance
    np.testing.assert_allclose(d, _box_sdf(p, half), atol=1e-5)  # outside > 0, inside < 0


def test_near_surface_selection_streams_a_memory_map_and_serves_a_moved_mesh(tmp_path):
    from apt_filters.core.nearby import select_near

    half, reach = np.array([2.0, 3.0, 4.0]), 1.5
    rng = np.random.default_rng(1)
    path = tmp_path / "p.f32"
    rng.uniform(-7, 7, size=(50_000, 3)).astype(np.float32).tofile(path)
    positions = np.memmap(path, dtype=np.float32, mode="r").reshape(-1, 3)
    near = select_near(positions, _box(half), reach, chunk=6_007)
    truth = np.flatnonzero(np.abs(_box_sdf(positions.astype(np.float64), half)) <= reach)
    assert np.array_equal(near.rows, truth) and len(truth) > 5_000
    np.testing.assert_allclose(near.positions, positions[truth])
    # the same mesh moved by 0.3 nm: every ion within 1.0 nm of it is among those selected within 1.5 nm
    moved = _box(half, center=(0.3, 0.0, 0.0))
    index, sd = near.within(moved, 1.0)
    again = np.flatnonzero(np.abs(_box_sdf(positions.astype(np.float64), half, (0.3, 0, 0))) <= 1.0)
    assert np.array_equal(near.rows[index], again)
    np.testing.assert_allclose(sd.distance, _box_sdf(near.positions[index], half, (0.3, 0, 0)), atol=1e-5)
    with pytest.raises(ValueError):
        near.within(moved, 1.4)  # 1.4 + 0.3 > 1.5: ions outside the selection could be missed


def test_near_surface_selection_keeps_what_it_is_also_asked_and_carries_columns(tmp_path):
    """``also`` adds rows beyond the reach (distance NaN, face -1) in the same pass; ``carry`` reads
    further columns (a memory map too) for the selected rows."""
    from apt_filters.core.nearby import select_near

    half, reach = np.array([2.0, 3.0, 4.0]), 1.0
    rng = np.random.default_rng(2)
    positions = rng.uniform(-7, 7, size=(30_000, 3)).astype(np.float32)
    path = tmp_path / "mz.f32"
    rng.uniform(1, 100, size=len(positions)).astype(np.float32).tofile(path)
    mz = np.memmap(path, dtype=np.float32, mode="r")
    far = positions[:, 0] > 6.0
    near = select_near(positions, _box(half), reach, chunk=4_001, also=lambda p: p[:, 0] > 6.0, carry=(mz,))
    within = np.abs(_box_sdf(positions.astype(np.float64), half)) <= reach
    assert np.array_equal(near.rows, np.flatnonzero(within | far)) and far.sum() > 1_000
    assert np.array_equal(near.carried[0], mz[near.rows])
    extra = ~within[near.rows]
    assert np.all(np.isnan(near.distance[extra])) and np.all(near.face[extra] == -1)


def test_near_surface_selection_flags_the_ions_beyond_an_open_meshs_rim():
    """On the square z = 0, |x|, |y| <= 2 (two triangles, normal +z) an ion's closest point is on the rim
    exactly where |x| > 2 or |y| > 2; over the square it lies across the surface (unflagged)."""
    from apt_filters.core.nearby import select_near

    square = TriMesh(np.array([[-2.0, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    positions = np.random.default_rng(3).uniform(-4, 4, size=(20_000, 3))
    near = select_near(positions, square, 1.5)
    beyond = (np.abs(near.positions[:, :2]) > 2).any(axis=1)
    assert 1_000 < beyond.sum() < len(near.rows) - 1_000
    assert np.array_equal(near.on_boundary, beyond)


def test_selection_without_distances_keeps_the_same_rows_and_searches_only_near_the_reach():
    """``distances=False``: the reach grid's Lipschitz bounds decide most ions (a FAR or WITHIN verdict is
    never wrong against the box's exact distance); the rows are those the exact search keeps, the ions
    decided within reach carry NaN, and only a shell about the reach is searched. ``distances=0.5`` on a
    closed mesh: exact within 0.5 nm, the right side beyond."""
    from apt_filters.core.nearby import FAR, SEARCH, WITHIN, ReachGrid, select_near
    from apt_filters.core.distance import SurfaceDistance

    half, reach = np.array([2.0, 3.0, 4.0]), 1.5
    rng = np.random.default_rng(3)
    positions = rng.uniform(-7, 7, size=(60_000, 3)).astype(np.float32)
    exact = np.abs(_box_sdf(positions.astype(np.float64), half))
    # ions at the reach itself, up to float32 rounding: the bound must leave them to the search
    on = rng.uniform(-1, 1, size=(500, 3)) * half
    on[:, 2] = half[2] + reach
    positions[:500] = on
    exact[:500] = np.abs(_box_sdf(positions[:500].astype(np.float64), half))
    kind, _ = ReachGrid.of(SurfaceDistance(_box(half), reach=reach), reach).classify(positions)
    assert np.all(exact[kind == FAR] > reach) and np.all(exact[kind == WITHIN] <= reach)
    assert np.mean(kind == SEARCH) < 0.25 and np.all(kind[:500] == SEARCH)
    fast = select_near(positions, _box(half), reach, chunk=7_001, distances=False)
    slow = select_near(positions, _box(half), reach, chunk=7_001)
    assert np.array_equal(fast.rows, slow.rows) and np.array_equal(fast.rows, np.flatnonzero(exact <= reach))
    searched = ~np.isnan(fast.distance)
    np.testing.assert_array_equal(fast.distance[searched], slow.distance[searched])
    assert 0 < searched.sum() < 0.5 * len(fast.rows)
    # exact within 0.5 nm only: on the closed box the shell (0.5, 1.5] nm gets its side, proved, and nothing else
    signed = _box_sdf(positions.astype(np.float64), half)
    kind, side = ReachGrid.of(SurfaceDistance(_box(half), reach=reach), reach, inner=0.5).classify(positions)
    shell = kind == WITHIN
    assert np.all((exact[shell] > 0.5) & (exact[shell] <= reach)) and np.all(side[shell] == np.sign(signed[shell]))
    assert np.all(exact[kind == FAR] > reach) and shell.sum() > 0.3 * (exact <= reach).sum()
    part = select_near(positions, _box(half), reach, chunk=7_001, distances=0.5)
    assert np.array_equal(part.rows, slow.rows)
    finite = np.isfinite(part.distance)
    np.testing.assert_array_equal(part.distance[finite], slow.distance[finite])
    assert np.all(np.abs(slow.distance[~finite]) > 0.5)
    assert np.array_equal(np.sign(part.distance[~finite]), np.sign(slow.distance[~finite]))


def test_closest_points_and_nearest_on_a_plane():
    from apt_filters.core.distance import SurfaceDistance

    # the unit square z = 0 in 2 x 8 x 8 triangles: the closest point of (x, y, z) is (clamped x, clamped y, 0)
    g = np.linspace(0.0, 1.0, 9)
    x, y = np.meshgrid(g, g, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(81)])
    i = (np.arange(8)[:, None] * 9 + np.arange(8)[None, :]).ravel()
    faces = np.concatenate([np.column_stack([i, i + 9, i + 10]), np.column_stack([i, i + 10, i + 1])])
    mesh = TriMesh(vertices, faces)
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 1.5, 5000), rng.uniform(-0.5, 1.5, 5000), rng.uniform(-2, 2, 5000)])
    engine = SurfaceDistance(mesh)
    near, face, weights = engine.closest(points, near=0.2)  # most points farther than 0.2: found without bound
    truth = np.column_stack([np.clip(points[:, :2], 0, 1), np.zeros(len(points))])
    assert np.allclose(near, truth, atol=1e-9)
    assert np.allclose(weights.sum(axis=1), 1.0) and (weights >= -1e-12).all()
    assert np.allclose(np.einsum("nk,nkj->nj", weights, vertices[faces[face]]), near)
    far = engine.nearest(points, 0.2)
    assert np.array_equal(far.distance, engine.query(points).distance) and np.array_equal(far.face, engine.query(points).face)


def test_edge_pairs_of_an_open_tetrahedron():
    # a tetrahedron without its face (1, 2, 3): three faces, three inner edges, three rim edges
    faces = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 3]])
    top = TriMesh(np.eye(4, 3), faces).topology
    pairs = top.edge_pairs()
    inner = top.edge_faces == 2
    assert inner.sum() == 3 and np.array_equal(np.sort(pairs[inner], axis=1), np.sort(top.face_pairs, axis=1))
    assert (pairs[~inner, 1] == -1).all()
    for e in np.flatnonzero(~inner):  # a rim edge's one face holds both its vertices
        assert set(top.edge_vertices[e]) <= set(faces[pairs[e, 0]])


def test_serial_blas_runs_blas_on_one_thread_and_restores_it():
    from threadpoolctl import threadpool_info

    from apt_filters.core.threads import serial_blas

    before = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    inside = serial_blas(lambda: [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"])()
    assert inside and all(n == 1 for n in inside)
    assert [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"] == before


def test_points_beyond_the_rings_get_the_nearest_of_every_triangle():
    from apt_filters.core.distance import SurfaceDistance, _MAX_RING
    from apt_filters.core.triangle import closest_on_triangle
    from tests.proxigram_specimens import icosphere

    # a 2 nm sphere of 1,280 faces (0.6 nm cells) and points 12-40 nm away: beyond the 16 cells the lists reach,
    # so each is finished by the pass over every triangle that the run boxes and disk bounds prune
    mesh = icosphere(2.0, 3)
    engine = SurfaceDistance(mesh)
    rng = np.random.default_rng(3)
    direction = rng.normal(size=(150, 3))
    points = direction / np.linalg.norm(direction, axis=1, keepdims=True) * rng.uniform(12, 40, (150, 1))
    assert (np.linalg.norm(points, axis=1) - 2.0 > _MAX_RING * engine.grid.cell).all()
    sd = engine.query(points)
    corners = mesh.vertices[mesh.faces]
    for p, d, f in zip(points, sd.distance, sd.face):
        every = np.array([closest_on_triangle(*p, *c.ravel())[0] for c in corners])
        # the face found is a nearest one, bit for bit, and the distance is its
        assert every[f] == every.min() and d == np.float32(np.sqrt(every.min()))


def test_the_closest_face_is_the_rules_whatever_the_order_of_the_search():
    """Where several faces are exactly as near (the closest point on a corner or an edge they share), the face
    returned is the one of lowest centroid (x, then y, then z), as a naive pass over every face finds it, whatever
    order the ions, the faces, the grid's cells or its homes make the search take; float32 and float64 points
    take one compiled kernel."""
    from apt_filters.core.distance import SurfaceDistance, _signed_in_cells
    from apt_filters.core.triangle import closest_on_triangle
    from tests.proxigram_specimens import icosphere

    mesh = icosphere(3.0, 2)  # 320 faces, 162 corners
    rng = np.random.default_rng(11)
    # points straight out from the corners (their closest point: the corner, on 5-6 faces at once), points just
    # off the edges' midpoints (on 2), and points anywhere near the surface
    edges = mesh.vertices[mesh.faces[:, [0, 1]]].mean(axis=1)
    points = np.vstack([mesh.vertices * rng.uniform(1.02, 1.6, (len(mesh.vertices), 1)),
                        edges * rng.uniform(1.02, 1.3, (len(edges), 1)),
                        rng.normal(size=(600, 3)) * 2.0])
    corners = mesh.vertices[mesh.faces]
    centre = (mesh.vertices[mesh.faces[:, 0]] + mesh.vertices[mesh.faces[:, 1]] + mesh.vertices[mesh.faces[:, 2]]) / 3
    expected = np.empty(len(points), np.int64)
    ties = 0
    for i, p in enumerate(points):
        every = np.array([closest_on_triangle(*p, *c.ravel())[0] for c in corners])
        tied = np.flatnonzero(every == every.min())
        ties += len(tied) > 1
        expected[i] = tied[np.lexsort(centre[tied].T[::-1])[0]]
    assert ties > 150
    first = SurfaceDistance(mesh).query(points)
    assert np.array_equal(first.face, expected)
    shuffle = rng.permutation(len(points))
    faces = rng.permutation(mesh.n_faces)
    same = np.arange(mesh.n_faces)
    for engine, order, back in [(SurfaceDistance(mesh, cell=0.4, home=1), shuffle, same),
                                (SurfaceDistance(mesh, cell=1.7, home=3), np.arange(len(points)), same),
                                (SurfaceDistance(TriMesh(mesh.vertices, mesh.faces[faces])), shuffle, faces)]:
        for dtype in (np.float64, np.float32):
            sd = engine.query(points[order].astype(dtype))
            assert np.array_equal(back[sd.face], SurfaceDistance(mesh).query(points[order].astype(dtype)).face)
        sd = engine.query(points[order])
        assert np.array_equal(back[sd.face], first.face[order])
        assert np.array_equal(sd.distance, first.distance[order]) and np.array_equal(sd.feature, first.feature[order])
    assert len(_signed_in_cells.signatures) == 1


def test_an_engine_built_for_a_reach_has_coarser_cells_and_finds_the_same_distances():
    """With ``reach`` the grid's cells are at least half of it and each home one cell (a quarter less CPU for the
    ions within 3-4 nm of a remeshed surface); every selected row, distance, face and rim flag is the one the
    engine of the default grid (twice the median edge, homes of two cells) finds, bit for bit."""
    from apt_filters.core.distance import _REACH_CELL, SurfaceDistance
    from apt_filters.core.nearby import select_near
    from tests.proxigram_specimens import icosphere

    mesh = icosphere(4.0, 4)  # edges about 0.3 nm: the default cell is far below the reach's
    reach = 3.0
    engine, plain = SurfaceDistance(mesh, reach=reach), SurfaceDistance(mesh)
    assert engine.grid.cell >= reach * _REACH_CELL > 2 * plain.grid.cell and (engine.home, plain.home) == (1, 2)
    rng = np.random.default_rng(5)
    positions = rng.uniform(-8, 8, size=(40_000, 3)).astype(np.float32)
    for distances in (True, 2.0):
        a = select_near(positions, engine, reach, distances=distances)
        b = select_near(positions, plain, reach, distances=distances)
        assert len(a.rows) > 10_000 and np.array_equal(a.rows, b.rows)
        assert np.array_equal(a.distance, b.distance, equal_nan=True) and np.array_equal(a.face, b.face)
        assert np.array_equal(a.on_boundary, b.on_boundary)


def test_reach_grid_leaves_the_cells_within_the_inner_distance_unmeasured():
    """A shell (3, 4] nm as the segregant search asks: coarse cells proved nearer than 3 nm are :data:`CORE` (their
    fine centres not measured, every ion of them searched, as each is nearer than 3 nm); the selection keeps the
    rows and exact distances the grid-free search gives."""
    from apt_filters.core.distance import SurfaceDistance
    from apt_filters.core.nearby import CORE, FAR, SEARCH, WITHIN, ReachGrid, select_near

    half, reach, inner = np.array([2.0, 3.0, 4.0]), 4.0, 3.0
    positions = np.random.default_rng(5).uniform(-9, 9, size=(80_000, 3)).astype(np.float32)
    signed = _box_sdf(positions.astype(np.float64), half)
    grid = ReachGrid.of(SurfaceDistance(_box(half), reach=reach), reach, inner=inner)
    core = grid.state == CORE
    assert core.sum() > 20
    assert not np.any(np.repeat(np.repeat(np.repeat(core, 2, 0), 2, 1), 2, 2) & ~np.isnan(grid.fine))
    kind, side = grid.classify(positions)
    cell = np.floor((positions - grid.origin) / (2 * grid.cell)).astype(int)
    in_core = core[tuple(np.clip(cell, 0, np.array(core.shape) - 1).T)] & np.all(cell >= 0, axis=1) & np.all(
        cell < core.shape, axis=1)
    assert in_core.sum() > 1_000 and np.all(kind[in_core] == SEARCH) and np.all(np.abs(signed[in_core]) < inner)
    assert np.all(np.abs(signed[kind == FAR]) > reach) and np.all(side[kind == WITHIN] == np.sign(signed[kind == WITHIN]))
    part = select_near(positions, _box(half), reach, chunk=9_001, distances=inner)
    whole = select_near(positions, _box(half), reach, chunk=9_001)
    assert np.array_equal(part.rows, whole.rows) and np.array_equal(part.rows, np.flatnonzero(np.abs(signed) <= reach))
    exact = np.isfinite(part.distance)
    assert np.all(exact[np.abs(whole.distance) <= inner])
    np.testing.assert_array_equal(part.distance[exact], whole.distance[exact])


def test_tabulated_erfc_is_within_its_stated_error_everywhere():
    from scipy.special import erfc as exact

    from apt_filters.core.special import ERROR, erfc, erfc_scalar

    # dense over the table (every interval's worst point included) and beyond it on both sides
    x = np.r_[np.linspace(-8.0, 8.0, 2_000_001), np.random.default_rng(0).uniform(-7.0, 7.0, 1_000_000)]
    error = np.abs(erfc(x) - exact(x))
    assert error.max() <= ERROR, error.max()
    assert error.max() > 0.5 * ERROR  # the bound is the interpolation's, not a loose one
    assert erfc_scalar(-30.0) == 2.0 and erfc_scalar(30.0) == 0.0 and erfc_scalar(0.0) == 1.0
    assert np.isnan(erfc(np.array([np.nan])))[0] and erfc(np.array([-np.inf, np.inf])).tolist() == [2.0, 0.0]


def test_touching_pairs_are_exactly_the_overlapping_balls_and_one_sliver_pairs_only_its_neighbours():
    from apt_filters.core.checks import touching_pairs

    rng = np.random.default_rng(7)
    # sizes over four orders of magnitude, so that every size class meets every other
    centre = rng.uniform(0, 10, (600, 3))
    radius = 0.05 * 10 ** rng.uniform(0, 4, 600) ** 0.5 * rng.uniform(0.5, 1, 600)
    gap = np.linalg.norm(centre[:, None] - centre[None], axis=2)
    i, j = np.triu_indices(len(centre), 1)
    oracle = {(a, b) for a, b in zip(i, j) if gap[a, b] <= radius[a] + radius[b]}
    got = touching_pairs(centre, radius)
    assert (got[:, 0] < got[:, 1]).all() and len(got) == len(oracle) == len({tuple(p) for p in got.tolist()})
    assert {tuple(p) for p in got.tolist()} == oracle
    # 5,000 small faces 1 apart along a line and one sliver 5,000 long beside them: every small face touches the
    # sliver and none another, so 5,000 pairs (one search radius for all, twice the sliver's, paired all 12.5 M)
    small = np.column_stack([np.arange(5000.0), np.zeros(5000), np.zeros(5000)])
    centre = np.vstack([small, [[2500.0, 0.1, 0.0]]])
    radius = np.append(np.full(5000, 0.2), 2500.0)
    got = touching_pairs(centre, radius)
    assert len(got) == 5000 and (got[:, 1] == 5000).all()


def test_triangles_intersect_tests_axes_only_for_pairs_whose_boxes_meet(monkeypatch):
    from apt_filters.core import checks

    # analytic pairs, far from the origin (rounding of 1e3 nm coordinates): a triangle through another, two
    # meeting at one corner only, two coplanar ones overlapping, and copies of the first triangle pulled apart
    # along x by 1 nm, 1e-3 nm and 1e-5 nm (boxes apart; the 1e-9 share of a 1e3 coordinate is 1e-6)
    base = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    through = np.array([[0.5, 0.5, -1.0], [0.5, 0.5, 1.0], [1.5, 0.2, 0.0]])
    corner = np.array([[2.0, 0.0, 0.0], [3.0, 0.0, 1.0], [3.0, 1.0, 1.0]])
    flat = base + [0.5, 0.5, 0.0]
    pulled = [base - [gap + 2.0, 0.0, 0.0] for gap in (1.0, 1e-3, 1e-5)]
    a = np.stack([base, base, base] + [base] * 3) + 1e3
    b = np.stack([through, corner, flat] + pulled) + 1e3
    truth = np.array([True, True, True, False, False, False])
    seen = []
    full = checks._separated
    monkeypatch.setattr(checks, "_separated", lambda a, b: seen.append(len(a)) or full(a, b))
    assert (checks.triangles_intersect(a, b) == truth).all()
    assert seen == [3]  # the three pairs whose boxes are apart are not tested axis by axis
    # every pair the separating axes see gives the answer they give on their own
    assert (~full(a, b) == truth).all()


def test_self_intersections_of_a_crumpled_sheet_equal_the_all_pairs_oracle():
    from apt_filters.core.checks import self_intersecting_faces, triangles_intersect

    rng = np.random.default_rng(3)
    # a grid sheet whose vertices are thrown about: many faces cross, some of them long slivers
    n = 14
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)]) + rng.normal(0, 0.9, (n * n, 3))
    vertices[rng.choice(n * n, 4, replace=False)] += rng.normal(0, 8, (4, 3))
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel(), k[:-1, 1:].ravel()
    faces = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    got = self_intersecting_faces(vertices, faces)
    tri = vertices[faces]
    centre = tri.mean(axis=1)
    tri = centre[:, None] + (1 - 1e-6) * (tri - centre[:, None])
    i, j = np.triu_indices(len(faces), 1)
    keep = (faces[i, :, None] == faces[j, None, :]).sum(axis=(1, 2)) < 2
    i, j = i[keep], j[keep]
    hit = triangles_intersect(tri[i], tri[j])
    oracle = np.zeros(len(faces), dtype=bool)
    oracle[i[hit]] = oracle[j[hit]] = True
    # pymeshlab's flags are the candidates: every face they confirm is the oracle's, and it misses none of them
    assert got.sum() > 20
    assert not (got & ~oracle).any() and (oracle & ~got).sum() == 0
