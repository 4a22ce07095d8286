"""Proxigrams of constructed specimens: plateaus, interface position, rim exclusion, outputs."""

import csv

import numpy as np
import pytest

from apt_filters.analysis.excess import fit_level, interface_position
from apt_filters.analysis.proxigram import POOLED, compute_proxigram
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from tests.proxigram_specimens import (MATRIX, PRECIPITATE, RANGES, box_distance, cube, element_fractions,
                                       icosphere, plane, specimen, sphere_distance)

RADIUS = 6.0


@pytest.fixture(scope="module")
def sphere_ions():
    rng = np.random.default_rng(11)
    ions, _ = specimen(rng, [-9.5, -9.5, -9.5], [9.5, 9.5, 9.5], 40.0, lambda p: sphere_distance(p, RADIUS))
    return ions


def window_fraction(prox, element, lo, hi, k=0):
    counts = prox.species_counts("element")[k]
    sel = (prox.centers > lo) & (prox.centers < hi)
    return counts[sel, prox.elements.index(element)].sum() / counts[sel].sum()


def test_sphere_plateaus_and_interface(sphere_ions):
    prox = compute_proxigram(sphere_ions, RANGES, icosphere(RADIUS, 4))
    assert prox.counts.shape == (1, 60, 4) and prox.object_ids.tolist() == [0]
    inside, outside = element_fractions(PRECIPITATE), element_fractions(MATRIX)
    for el in ("Fe", "Al", "Cr", "O"):
        assert window_fraction(prox, el, 1.0, 3.0) == pytest.approx(inside[el], abs=0.01)
        assert window_fraction(prox, el, -3.0, -1.0) == pytest.approx(outside[el], abs=0.01)
    c, err = prox.concentration("element")
    al = prox.elements.index("Al")
    pos = interface_position(prox.centers, c[0, :, al], outside["Al"], inside["Al"])
    assert abs(pos) < 0.2
    # errors are binomial
    n = prox.species_counts("element")[0].sum(axis=1)
    np.testing.assert_allclose(err[0, :, al], np.sqrt(c[0, :, al] * (1 - c[0, :, al]) / n))
    # all ions within 3 nm are counted once, in the right bin
    d = sphere_distance(sphere_ions.positions.astype(np.float64), RADIUS)
    ranged = RANGES.ion_index(sphere_ions.mz) >= 0
    assert prox.counts.sum() == pytest.approx(np.count_nonzero(ranged & (np.abs(d) < 3.0)), rel=2e-3)
    assert prox.unranged.sum() > 0
    # shell density: the specimen has 40 ions/nm³, 2 % unranged, CrO2 = 3 atoms (7 % of ions)
    atoms_per_nm3 = 40.0 * (1 + 2 * 0.07 - 0.02)
    dens = prox.atom_density()[0]
    assert np.nanmean(dens[np.abs(prox.centers) < 2.5]) == pytest.approx(atoms_per_nm3, rel=0.03)


def test_interface_shift_has_the_right_sign(sphere_ions):
    """A mesh 0.5 nm outside the true interface puts the interface at +0.5 nm (inside is positive)."""
    prox = compute_proxigram(sphere_ions, RANGES, icosphere(RADIUS + 0.5, 4))
    c, _ = prox.concentration("element")
    al = prox.elements.index("Al")
    pos = interface_position(prox.centers, c[0, :, al], element_fractions(MATRIX)["Al"],
                             element_fractions(PRECIPITATE)["Al"])
    assert pos == pytest.approx(0.5, abs=0.2)


def test_cube_and_sphere_objects_separately_and_pooled():
    rng = np.random.default_rng(12)
    half, c_cube, c_sph = (3.0, 3.5, 4.0), (-6.0, 0.0, 0.0), (7.0, 1.0, 0.5)
    truth = lambda p: np.maximum(box_distance(p, half, c_cube), sphere_distance(p, 4.0, c_sph))  # noqa: E731
    ions, d = specimen(rng, [-13, -7, -7.5], [14, 8, 7.5], 30.0, truth)
    a, b = cube(half, 3, c_cube), icosphere(4.0, 4, c_sph)
    mesh = TriMesh(np.concatenate([a.vertices, b.vertices]), np.concatenate([a.faces, b.faces + a.n_vertices]))
    prox = compute_proxigram(ions, RANGES, mesh, max_distance=2.5)
    assert prox.object_ids.tolist() == [0, 1]
    np.testing.assert_allclose(prox.areas, [a.area(), b.area()])
    # Steiner shell volumes sum to the volume between the offsets outside the convex cube
    outer = np.sum(prox.shell_volumes[0][prox.centers < 0])
    h, (x, y, z) = 2.5, 2 * np.array(half)
    exact = 2 * h * (x * y + y * z + z * x) + np.pi * h ** 2 * (x + y + z) + 4 / 3 * np.pi * h ** 3
    assert outer == pytest.approx(exact, rel=1e-6)
    inside, outside = element_fractions(PRECIPITATE), element_fractions(MATRIX)
    for k in (0, 1):
        assert window_fraction(prox, "Al", 0.8, 2.5, k) == pytest.approx(inside["Al"], abs=0.01)
        assert window_fraction(prox, "Al", -2.5, -0.8, k) == pytest.approx(outside["Al"], abs=0.01)
    pooled = prox.pooled()
    assert pooled.object_ids.tolist() == [POOLED]
    np.testing.assert_array_equal(pooled.counts[0], prox.counts.sum(axis=0))
    assert pooled.areas[0] == pytest.approx(a.area() + b.area())


def test_object_id_face_scalar_is_used():
    rng = np.random.default_rng(13)
    ions, _ = specimen(rng, [-6, -6, -6], [6, 6, 6], 10.0, lambda p: sphere_distance(p, 3.0))
    mesh = icosphere(3.0, 3)
    mesh.face_scalars["object_id"] = np.where(mesh.face_normals()[:, 0] > 0, 7, 3)
    prox = compute_proxigram(ions, RANGES, mesh)
    assert prox.object_ids.tolist() == [3, 7]
    assert prox.areas.sum() == pytest.approx(mesh.area())


@pytest.fixture(scope="module")
def plane_ions():
    """Precipitate below z = 0, ions also beyond the 10 x 10 nm surface's rim."""
    rng = np.random.default_rng(14)
    ions, _ = specimen(rng, [-14, -14, -4], [14, 14, 4], 20.0, lambda p: -p[:, 2])
    return ions


def test_open_surface_rim_excluded_by_default(plane_ions):
    mesh = plane(10.0, n=20)
    prox = compute_proxigram(plane_ions, RANGES, mesh)
    kept = compute_proxigram(plane_ions, RANGES, mesh, keep_edge=True)
    p = plane_ions.positions
    ranged = RANGES.ion_index(plane_ions.mz) >= 0
    within = np.abs(p[:, 2]) < 3.0
    over = np.all(np.abs(p[:, :2]) <= 10.0, axis=1)
    assert prox.counts.sum() == np.count_nonzero(ranged & within & over)
    assert prox.n_rim == np.count_nonzero(within & ~over & (np.linalg.norm(np.maximum(np.abs(p[:, :2]) - 10, 0), axis=1) ** 2 + p[:, 2] ** 2 < 9.0))
    assert kept.counts.sum() > prox.counts.sum() + 1000
    # flat surface: shell volume = area x width, exactly
    np.testing.assert_allclose(prox.shell_volumes[0], 400.0 * 0.1)
    inside, outside = element_fractions(PRECIPITATE), element_fractions(MATRIX)
    assert window_fraction(prox, "Fe", 0.5, 3.0) == pytest.approx(inside["Fe"], abs=0.01)
    assert window_fraction(prox, "Fe", -3.0, -0.5) == pytest.approx(outside["Fe"], abs=0.01)
    # the rim ions, kept, pull the inside plateau toward the matrix near s = 0 only a little, but they
    # are counted: bins near |s| = 3 hold the rim's matrix ions beyond the edge
    assert kept.counts[0, -1].sum() > prox.counts[0, -1].sum()


def test_level_fit_recovers_a_linear_profile():
    rng = np.random.default_rng(15)
    s = np.linspace(1.05, 2.95, 20)
    total = np.full(20, 20000)
    n = rng.binomial(total, 0.2 + 0.01 * s)
    level, cov = fit_level(s, n, total)
    assert level.value == pytest.approx(0.2, abs=3 * level.error)
    assert level.slope == pytest.approx(0.01, abs=3 * np.sqrt(cov[1, 1]))


def test_outputs_csv_and_png(sphere_ions, tmp_path):
    prox = compute_proxigram(sphere_ions, RANGES, icosphere(RADIUS, 3), bin_width=0.25, max_distance=2.0,
                             iso_value=0.2)
    csv_path = prox.write_csv(tmp_path / "p.csv")
    rows = list(csv.DictReader(open(csv_path)))
    assert len(rows) == 16
    assert float(rows[0]["distance_nm"]) == pytest.approx(-1.875)
    assert sum(int(r["n_Al"]) for r in rows) == prox.counts[0, :, prox.ions.index("Al")].sum()
    assert int(rows[3]["atoms_O"]) == 2 * int(rows[3]["n_CrO2"])
    assert abs(float(rows[-1]["c_Al"]) - element_fractions(PRECIPITATE)["Al"]) < 0.05
    with pytest.raises(AptFiltersError, match="exists"):
        prox.write_csv(csv_path)
    png = prox.plot(tmp_path / "p.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*tmp*"))


def test_bad_parameters():
    rng = np.random.default_rng(16)
    ions, _ = specimen(rng, [-2, -2, -2], [2, 2, 2], 5.0, lambda p: sphere_distance(p, 1.0))
    with pytest.raises(AptFiltersError, match="positive"):
        compute_proxigram(ions, RANGES, icosphere(1.0, 1), bin_width=0)
    with pytest.raises(AptFiltersError, match="no triangles"):
        compute_proxigram(ions, RANGES, TriMesh(np.zeros((0, 3)), np.zeros((0, 3))))
