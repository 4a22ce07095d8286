"""Per-object statistics against analytic shapes and a constructed specimen with known ions."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from apt_filters.analysis.objects import SpecimenHull, SpecimenMask, cap_boundaries, object_table
from apt_filters.core.distance import mesh_distance
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.meshlab.chains import apply_chain
from apt_filters.truth.precipitates import winding_number
from tests.meshlab_shapes import box, cut_below, merge, sphere, torus

SPECIMEN = np.array([40.0, 30.0, 60.0])  # x, y, z extents of the constructed specimen (nm)
BALL = (np.array([10.0, 10.0, 15.0]), 5.0)
RING = (np.array([25.0, 15.0, 40.0]), 5.0, 1.5)  # centre, major, minor radius; axis z
SPECK = np.array([30.0, 5.0, 5.0])
CAP = (np.array([20.0, 15.0, 0.0]), 4.0)  # cut by the specimen's z = 0 face
RANGES = RangeTable([Range(15.5, 16.5, (("O", 1),), "ff0000"), Range(55.5, 56.5, (("Fe", 1),), "0000ff"),
                     Range(83.5, 84.5, (("Cr", 1), ("O", 2)), "00ff00")])
MZ = {"O": 16.0, "Fe": 56.0, "CrO2": 84.0}


def test_sphere_cube_box_torus_against_analytic_values():
    shapes = merge(sphere(5.0, (1, 2, 3)), box((1, 1, 1), (20, 0, 0)), box((2, 4, 8), (40, -5, 7)),
                   torus(3.0, 1.0, (0, 30, 0)))
    ball, cube, brick, ring = object_table(shapes).objects
    assert ball.volume == pytest.approx(4 / 3 * math.pi * 125, rel=0.02)
    assert ball.area == pytest.approx(4 * math.pi * 25, rel=0.02)
    assert ball.equivalent_radius == pytest.approx(5.0, rel=0.01)
    assert ball.sphericity >= 0.98
    assert ball.centroid == pytest.approx((1, 2, 3), abs=1e-9)
    assert (ball.euler_characteristic, ball.genus, ball.status) == (2, 0, "closed")
    assert cube.sphericity == pytest.approx(math.pi ** (1 / 3) * 6 ** (2 / 3) / 6, rel=1e-12)  # 0.806
    assert cube.sphericity == pytest.approx(0.806, abs=1e-3)
    assert (brick.volume, brick.area) == pytest.approx((64.0, 112.0), rel=1e-12)
    assert brick.obb_extents == pytest.approx((8, 4, 2), rel=1e-9)
    assert brick.aspect_ratios == pytest.approx((0.5, 0.25), rel=1e-9)
    assert brick.centroid == pytest.approx((40, -5, 7), abs=1e-9)  # x, y, z order kept
    assert (ring.euler_characteristic, ring.genus) == (0, 1)
    assert ring.volume == pytest.approx(2 * math.pi ** 2 * 3, rel=0.02)
    assert ring.area == pytest.approx(4 * math.pi ** 2 * 3, rel=0.02)


def test_inverted_orientation_gives_negative_volume():
    s = sphere(2.0)
    o = object_table(TriMesh(s.vertices, s.faces[:, ::-1])).objects[0]
    assert o.volume == pytest.approx(-s.signed_volume()) and o.volume < 0
    assert math.isnan(o.sphericity) and math.isnan(o.equivalent_radius)


def test_open_object_is_proxy_when_capped_and_open_otherwise():
    s = sphere(5.0, subdiv=4)
    half = cut_below(s, 0.0)
    proxy = object_table(half).objects[0]
    assert (proxy.status, proxy.boundary_loops, proxy.euler_characteristic, proxy.genus) == ("proxy", 1, 1, 0)
    rim_z = half.vertices[np.unique(half.boundary_edges()), 2].mean()
    h = 5.0 - rim_z  # height of the kept cap
    assert proxy.volume == pytest.approx(math.pi * h ** 2 * (15.0 - h) / 3, rel=0.02)
    assert proxy.area == pytest.approx(half.area())  # the surface only, not the cap
    opened = object_table(half, cap_open=False).objects[0]
    assert opened.status == "open" and math.isnan(opened.volume)
    meshlab_closed, _ = apply_chain(half, "close")  # MeshLab's caps, flagged in face scalar "cap"
    by_meshlab = object_table(meshlab_closed, cap_open=False).objects[0]
    assert by_meshlab.status == "proxy" and by_meshlab.area == pytest.approx(half.area(), rel=1e-12)
    # caps lie in the slab of the jagged rim, so the volume lies between the two planar caps
    rim = half.vertices[np.unique(half.boundary_edges()), 2]
    lower, upper = (math.pi * (5 - z) ** 2 * (10 + z) / 3 for z in (rim.max(), rim.min()))
    assert lower <= proxy.volume <= upper and lower <= by_meshlab.volume <= upper
    assert (by_meshlab.boundary_loops, by_meshlab.genus) == (1, 0)
    capped, loop = cap_boundaries(half)
    assert len(capped.boundary_edges()) == 0 and capped.non_manifold_edge_count() == 0
    assert set(loop) == {0}


def test_a_wavy_sheet_whose_cap_crosses_it_stays_open():
    """An interface across the specimen, capped by the plane of its rim, encloses no region (the cap cuts
    through the waves, the sides alternate): it stays open, without volume or ions. A sheet with a flat rim
    that bulges to one side only is a proxy."""
    n = 41
    x, y = np.meshgrid(np.linspace(0, 20, n), np.linspace(0, 20, n), indexing="ij")
    quads = np.array([[i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1]
                      for i in range(n - 1) for j in range(n - 1)])
    faces = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    rng = np.random.default_rng(4)
    ions = IonTable(rng.uniform([0, 0, -3], [20, 20, 3], (20_000, 3)).astype(np.float32),
                    np.full(20_000, MZ["Fe"], dtype=np.float32))
    for z, status in ((np.sin(x / 2) * np.sin(y / 2), "open"), (np.sin(np.pi * x / 20) * np.sin(np.pi * y / 20),
                                                                   "proxy")):
        sheet = TriMesh(np.column_stack([x.ravel(), y.ravel(), z.ravel()]), faces)
        o = object_table(sheet, ions, RANGES, specimen=SpecimenHull.from_points(ions.positions)).objects
        assert len(o) == 1 and o[0].status == status
        if status == "open":
            assert math.isnan(o[0].volume) and o[0].n_ions == -1
        else:  # the dome under a sin x sin bump: 4 A / pi^2 of the 20 x 20 square
            assert abs(o[0].volume) == pytest.approx(4 * 400 / np.pi ** 2, rel=0.01) and o[0].n_ions > 0


def _specimen_ions(seed: int = 5) -> tuple[IonTable, dict[str, np.ndarray]]:
    """Uniform ions in the specimen box: CrO2 or Fe (1:1) inside the ball and the ring,
    O elsewhere; none near the speck. Ions within 0.05 nm of an analytic surface are left
    out, so that inside/outside does not depend on the facets."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, SPECIMEN, (250_000, 3))
    d_ball = np.linalg.norm(p - BALL[0], axis=1) - BALL[1]
    c, big, small = RING
    q = p - c
    d_ring = np.hypot(np.hypot(q[:, 0], q[:, 1]) - big, q[:, 2]) - small
    d_speck = np.linalg.norm(p - SPECK, axis=1)
    keep = (np.abs(d_ball) > 0.05) & (np.abs(d_ring) > 0.05) & (d_speck > 0.5)
    p, d_ball, d_ring = p[keep], d_ball[keep], d_ring[keep]
    inside = (d_ball < 0) | (d_ring < 0)
    names = np.where(inside, np.where(rng.random(len(p)) < 0.5, "CrO2", "Fe"), "O")
    mz = np.array([MZ[n] for n in names], dtype=np.float32)
    return IonTable(p.astype(np.float32), mz), {"ball": (d_ball < 0), "ring": (d_ring < 0), "names": names}


def _scene() -> TriMesh:
    return merge(sphere(BALL[1], BALL[0]), torus(RING[1], RING[2], RING[0]), sphere(0.05, SPECK, subdiv=1),
                 cut_below(sphere(CAP[1], CAP[0]), 0.0))


def test_ions_inside_by_species_composition_edge_distance_and_density():
    ions, truth = _specimen_ions()
    table = object_table(_scene(), ions, RANGES)
    assert table.n_dropped == 1  # the speck encloses no ion
    ball, ring, cap = table.objects
    assert [o.object_id for o in table.objects] == [0, 1, 3]  # numbered by first face, as TriMesh.face_components
    names = truth["names"]
    for obj, inside in ((ball, truth["ball"]), (ring, truth["ring"])):
        expected = {n: int(np.sum(inside & (names == n))) for n in ("O", "Fe", "CrO2")}
        assert obj.ion_counts == {**expected, "unranged": 0}
        n_cr, n_fe = expected["CrO2"], expected["Fe"]
        atoms = n_cr * 3 + n_fe
        assert obj.composition == pytest.approx({"O": 2 * n_cr / atoms, "Fe": n_fe / atoms, "Cr": n_cr / atoms},
                                                rel=1e-12)
    assert ball.edge_distance == pytest.approx(5.0, abs=0.05)  # 5 nm from the x = 0 and y = 0 faces
    assert cap.status == "proxy" and cap.edge_distance < 0.3 and cap.ion_counts["O"] > 0
    assert table.analysed_volume == pytest.approx(np.prod(SPECIMEN), rel=0.002)
    assert table.number_density == pytest.approx(3 / np.prod(SPECIMEN), rel=0.002)


def test_specimen_mask_and_hull_distances_keep_xyz_order():
    mask = SpecimenMask(np.ones(tuple(SPECIMEN.astype(int)), bool), origin=(0.5, 0.5, 0.5), spacing=1.0)
    hull = SpecimenHull.from_points(np.array(np.meshgrid(*[[0, s] for s in SPECIMEN], indexing="ij")).reshape(3, -1).T)
    pts = np.array([[5.0, 15.0, 30.0], [20.0, 2.0, 30.0], [20.0, 15.0, 57.0]])
    for specimen in (mask, hull):
        np.testing.assert_allclose(specimen.distance(pts), [5.0, 2.0, 3.0], atol=1e-9)
        assert specimen.volume == pytest.approx(np.prod(SPECIMEN))


def test_table_written_as_csv_and_json(tmp_path):
    ions, _ = _specimen_ions()
    table = object_table(_scene(), ions, RANGES)
    table.write_csv(tmp_path / "objects.csv")
    table.write_json(tmp_path / "objects.json")
    lines = (tmp_path / "objects.csv").read_text().splitlines()
    assert lines[0].startswith("# objects 3;") and "dropped (no ion inside) 1" in lines[0]
    rows = list(csv.DictReader(lines[1:]))
    assert len(rows) == 3 and {"volume", "sphericity", "centroid_x", "n_CrO2", "frac_Cr", "edge_distance"} <= set(rows[0])
    assert float(rows[0]["centroid_z"]) == pytest.approx(BALL[0][2], abs=1e-6)
    data = json.loads((tmp_path / "objects.json").read_text())
    assert len(data["objects"]) == 3 and data["objects"][1]["genus"] == 1
    with pytest.raises(AptFiltersError, match="exists"):
        table.write_csv(tmp_path / "objects.csv")
    with pytest.raises(AptFiltersError, match="both"):
        object_table(_scene(), ions)


def test_json_writes_undefined_values_as_null(tmp_path):
    table = object_table(cut_below(sphere(5.0), 0.0), cap_open=False)
    table.write_json(tmp_path / "o.json")
    data = json.loads((tmp_path / "o.json").read_text())
    assert data["objects"][0]["status"] == "open" and data["objects"][0]["volume"] is None
    assert data["number_density_per_nm3"] is None  # no specimen given


def test_hull_built_in_chunks_equals_the_hull_of_all_points():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(20_000, 3)) * [3.0, 1.0, 2.0]
    whole = SpecimenHull.from_points(pts, chunk=len(pts))
    chunked = SpecimenHull.from_points(pts, chunk=3_000)
    assert chunked.volume == pytest.approx(whole.volume, rel=1e-12)
    probe = rng.normal(size=(100, 3))
    np.testing.assert_allclose(chunked.distance(probe), whole.distance(probe), atol=1e-9)


def test_hull_equals_qhull_of_every_point_for_float32_ions():
    rng = np.random.default_rng(3)
    p = rng.uniform(-1, 1, (60_000, 3)) * [20.0, 15.0, 40.0]
    p = p[np.hypot(p[:, 0] / 20.0, p[:, 1] / 15.0) < 1.0 - 0.4 * (p[:, 2] + 40.0) / 80.0].astype(np.float32)  # a cone
    hull = SpecimenHull.from_points(p, chunk=7_000)
    reference = ConvexHull(p.astype(np.float64))
    assert hull.volume == pytest.approx(reference.volume, rel=1e-12)
    probe = rng.uniform(-25, 25, (200, 3))
    expected = -(probe @ reference.equations[:, :3].T + reference.equations[:, 3]).max(axis=1)
    np.testing.assert_allclose(hull.distance(probe), expected, atol=1e-9)


def test_ion_counts_equal_the_winding_number_of_every_ion_also_near_surfaces_and_in_nested_objects():
    """The label grid decides most ions without a distance query: compare with the winding number of every
    ion (an independent inside test: solid angles, no closest point), with ions crowded within 0.02 nm of the
    surfaces and a cavity inside a ball (its ions count for both the ball and the cavity's inverted
    surface)."""
    outer, cavity = sphere(6.0, (20.0, 15.0, 30.0), subdiv=3), sphere(2.5, (21.0, 15.0, 30.0), subdiv=2)
    scene = merge(outer, TriMesh(cavity.vertices, cavity.faces[:, ::-1]), box((4, 6, 3), (8.0, 8.0, 50.0)))
    rng = np.random.default_rng(9)
    on_surface = scene.vertices[rng.integers(0, scene.n_vertices, 40_000)] + rng.normal(0, 0.02, (40_000, 3))
    p = np.vstack([rng.uniform(0, SPECIMEN, (150_000, 3)), on_surface]).astype(np.float32)
    names = rng.choice(["O", "Fe", "CrO2"], len(p))
    ions = IonTable(p, np.array([MZ[n] for n in names], dtype=np.float32))
    table = object_table(scene, ions, RANGES)
    scene_components = scene.face_components()
    assert len(table.objects) == 3
    for o in table.objects:
        part = TriMesh(scene.vertices, scene.faces[scene_components == o.object_id])
        corners = part.vertices[np.unique(part.faces)]
        box_in = np.flatnonzero(np.all((p >= corners.min(axis=0)) & (p <= corners.max(axis=0)), axis=1))
        inside = np.zeros(len(p), dtype=bool)  # outside its box, a point is outside a closed surface
        inside[box_in] = np.abs(winding_number(part, p[box_in])) > 0.5
        # no ion so close to a surface that rounding could decide it (the nearest lies ~1e-5 nm away)
        assert mesh_distance(part, p[box_in]).min() > 1e-7
        expected = {n: int(np.sum(inside & (names == n))) for n in ("O", "Fe", "CrO2")}
        assert o.ion_counts == {**expected, "unranged": 0}
    assert table.objects[1].ion_counts["O"] > 0 and table.objects[0].n_ions > table.objects[1].n_ions
