"""Interfacial excess against constructed specimens with a known segregated shell."""

import json

import numpy as np
import pytest

from apt_filters.analysis.excess import (INSTRUMENT_EFFICIENCY, excess_of_profile, interfacial_excess,
                                         write_excess_json)
from apt_filters.analysis.proxigram import POOLED, compute_proxigram
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from tests.proxigram_specimens import (MATRIX, PRECIPITATE, RANGES, element_fractions, icosphere, specimen,
                                       sphere_distance, with_sphere_shell)

# detected B ions per nm² of the true sphere; large enough that the standard error (~3 %, from the
# 1 % B background) leaves the 10 % target at > 3 sigma
RADIUS, GAMMA = 6.0, 3.0


@pytest.fixture(scope="module")
def segregated():
    rng = np.random.default_rng(21)
    ions, _ = specimen(rng, [-9.5, -9.5, -9.5], [9.5, 9.5, 9.5], 40.0, lambda p: sphere_distance(p, RADIUS))
    ions, n_shell = with_sphere_shell(rng, ions, RADIUS, GAMMA)
    return ions, n_shell


def test_excess_of_segregated_sphere(segregated):
    ions, n_shell = segregated
    prox = compute_proxigram(ions, RANGES, icosphere(RADIUS, 4))
    (res,) = interfacial_excess(prox, "B", efficiency=0.5)
    assert res.object_id == 0 and res.area == pytest.approx(prox.areas[0])
    truth = n_shell / (4 * np.pi * RADIUS ** 2)
    for est in (res.integration, res.cumulative):
        assert est.gamma_detected == pytest.approx(truth, rel=0.10)
        assert est.gamma_atoms == pytest.approx(truth / 0.5, rel=0.10)
        assert 0 < est.gamma_detected_error < 0.1 * truth  # a real, small uncertainty
        assert abs(est.count - n_shell) < 4 * est.count_error + 0.05 * n_shell
    # plateau levels of B (a 1 % background on both sides)
    assert res.matrix.value == pytest.approx(element_fractions(MATRIX)["B"], abs=0.01)
    assert res.precipitate.value == pytest.approx(element_fractions(PRECIPITATE)["B"], abs=0.01)
    # Al is not segregated, but the added B dilutes it: half the shell lies on each side, so its
    # excess is -n_shell times the mean of its two plateau fractions
    (al,) = interfacial_excess(prox, "Al", efficiency=0.5)
    al_truth = -n_shell * 0.5 * (element_fractions(MATRIX)["Al"] + element_fractions(PRECIPITATE)["Al"])
    assert abs(al.integration.count - al_truth) < 4 * al.integration.count_error
    assert al.integration.count < 0


def test_two_objects_own_area_and_pooled():
    rng = np.random.default_rng(22)
    # Γ large enough that the standard error (3-4 % over 8 seeds) leaves the 10 % target at > 2.5 sigma
    centers, radii, gammas = [(-6.0, 0, 0), (6.0, 0, 0)], [4.0, 3.0], [5.0, 6.0]
    truth = lambda p: np.maximum(*(sphere_distance(p, r, c) for r, c in zip(radii, centers)))  # noqa: E731
    ions, _ = specimen(rng, [-13, -7, -7], [13, 7, 7], 40.0, truth)
    placed = []
    for r, c, g in zip(radii, centers, gammas):
        shell, n = with_sphere_shell(rng, type(ions)(np.zeros((0, 3), np.float32), np.zeros(0, np.float32)), r, g)
        ions = type(ions)(np.concatenate([ions.positions, shell.positions + np.float32(c)]),
                          np.concatenate([ions.mz, shell.mz]))
        placed.append(n)
    meshes = [icosphere(r, 4, c) for r, c in zip(radii, centers)]
    mesh = TriMesh(np.concatenate([m.vertices for m in meshes]),
                   np.concatenate([meshes[0].faces, meshes[1].faces + meshes[0].n_vertices]))
    prox = compute_proxigram(ions, RANGES, mesh, max_distance=2.5)
    results = interfacial_excess(prox, "B", efficiency=INSTRUMENT_EFFICIENCY["LEAP 5000S"])
    assert [r.object_id for r in results] == [0, 1, POOLED]
    for res, n, r in zip(results, placed, radii):
        assert res.area == pytest.approx(meshes[results.index(res)].area())
        assert res.integration.gamma_detected == pytest.approx(n / (4 * np.pi * r ** 2), rel=0.10)
        assert res.integration.gamma_atoms == pytest.approx(res.integration.gamma_detected / 0.80)
    pooled = results[-1]
    assert pooled.area == pytest.approx(sum(m.area() for m in meshes))
    true_pooled = sum(placed) / sum(4 * np.pi * r ** 2 for r in radii)
    assert pooled.integration.gamma_detected == pytest.approx(true_pooled, rel=0.10)
    assert pooled.cumulative.gamma_detected == pytest.approx(true_pooled, rel=0.10)


def test_flat_profile_methods_agree_exactly_without_noise():
    """Noise-free step with a delta of excess: both estimates return the planted count."""
    s = np.linspace(-2.95, 2.95, 60)
    total = np.full(60, 1000)
    n = np.where(s > 0, 300, 100)
    n[30] += 250  # the bin just inside the interface
    m, p, integ, cum = excess_of_profile(s, n, total, area=50.0, efficiency=0.5, inner=1.0, outer=3.0)
    assert m.value == pytest.approx(0.1) and p.value == pytest.approx(0.3)
    assert integ.count == pytest.approx(250) and cum.count == pytest.approx(250)
    assert integ.gamma_detected == pytest.approx(5.0) and integ.gamma_atoms == pytest.approx(10.0)


def test_json_and_errors(segregated, tmp_path):
    ions, _ = segregated
    prox = compute_proxigram(ions.subset(slice(0, 60000)), RANGES, icosphere(RADIUS, 2), max_distance=2.0)
    results = interfacial_excess(prox, "CrO2", efficiency=0.52)
    path = write_excess_json(tmp_path / "excess.json", results)
    doc = json.loads(path.read_text())
    assert doc["results"][0]["solute"] == "CrO2"
    assert set(doc["results"][0]["integration"]) >= {"gamma_detected", "gamma_atoms", "count_error"}
    with pytest.raises(AptFiltersError, match="neither an element"):
        interfacial_excess(prox, "Xe", efficiency=0.5)
    with pytest.raises(AptFiltersError, match="efficiency"):
        interfacial_excess(prox, "B", efficiency=1.5)
    with pytest.raises(AptFiltersError, match="windows"):
        interfacial_excess(prox, "B", efficiency=0.5, inner=2.5, outer=2.0)


def test_unmeasurable_objects_are_an_error_or_skipped():
    """An object with no ions in its inner plateau window has no excess to measure."""
    from apt_filters.analysis.proxigram import Proxigram

    centers = np.arange(-2.95, 3.0, 0.1)
    edges = np.append(centers - 0.05, centers[-1] + 0.05)
    counts = np.zeros((2, len(centers), 2), dtype=np.int64)
    counts[:, :, 1] = 100
    counts[:, :, 0] = 5
    counts[1, centers > 0.5, :] = 0  # object 1 is thin: nothing deeper than 0.5 nm inside
    prox = Proxigram(edges=edges, ions=["B", "Ni"], elements=["B", "Ni"], element_matrix=np.eye(2, dtype=np.int64),
                     colors={}, object_ids=np.array([0, 1]), counts=counts,
                     unranged=np.zeros((2, len(centers)), np.int64), areas=np.array([10.0, 10.0]),
                     shell_volumes=np.ones((2, len(centers))))
    with pytest.raises(AptFiltersError, match="no ions in a plateau window"):
        interfacial_excess(prox, "B", 0.5)
    kept = interfacial_excess(prox, "B", 0.5, skip_unmeasurable=True)
    assert [e.object_id for e in kept] == [0, -1]
    assert kept[0].cumulative.count == pytest.approx(0.0, abs=1e-6)
