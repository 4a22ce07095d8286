"""Isotope patterns, candidate table and spectrum background of the range audit, against ground truth."""

import itertools

import numpy as np
import periodictable
import pytest

from apt_filters.audit.candidates import candidate_compositions
from apt_filters.audit.isotopes import canonical, element_isotopes, isotope_pattern, species_name
from apt_filters.audit.spectrum import build_spectrum, find_peaks
from apt_filters.core.errors import AptFiltersError


def test_atomic_pattern_is_the_natural_abundance_table():
    mz, ab = isotope_pattern((("Ni", 1),), 1, resolution=1e6)
    table = [(iso.mass, iso.abundance / 100) for iso in periodictable.Ni if iso.abundance > 0]
    np.testing.assert_allclose(mz, [m for m, _ in table], atol=1e-9)
    np.testing.assert_allclose(ab, [a for _, a in table], rtol=1e-6)
    mz2, ab2 = isotope_pattern((("Ni", 1),), 2, resolution=1e6)
    np.testing.assert_allclose(mz2, mz / 2)
    np.testing.assert_allclose(ab2, ab)


def test_molecular_pattern_equals_brute_force_enumeration():
    """Cr2O: every isotopologue enumerated by hand, grouped by nominal mass."""
    cr_m, cr_a = element_isotopes("Cr")
    o_m, o_a = element_isotopes("O")
    expected: dict[int, list[float]] = {}
    for (i, j, k) in itertools.product(range(len(cr_m)), range(len(cr_m)), range(len(o_m))):
        m = cr_m[i] + cr_m[j] + o_m[k]
        a = cr_a[i] * cr_a[j] * o_a[k]
        e = expected.setdefault(int(round(m)), [0.0, 0.0])
        e[0] += m * a
        e[1] += a
    mz, ab = isotope_pattern((("Cr", 2), ("O", 1)), 2, resolution=2000, min_abundance=1e-6)
    for nominal, (ma, a) in expected.items():
        if a < 1e-6:
            continue
        k = np.argmin(np.abs(mz - nominal / 2))
        assert mz[k] == pytest.approx(ma / a / 2, abs=2e-4)
        assert ab[k] == pytest.approx(a, rel=1e-4)
    # the numbers: Cr2O++ peaks at 59.94 (52Cr2 16O) and 60.44, hardly at 57.94 (50Cr2 16O)
    main = np.argsort(ab)[::-1]
    assert mz[main[0]] == pytest.approx(59.94, abs=0.005) and ab[main[0]] > 0.70
    assert mz[main[1]] == pytest.approx(60.44, abs=0.005)
    assert ab[np.argmin(np.abs(mz - 57.94))] < 0.003


def test_peaks_closer_than_resolution_merge_and_keep_abundance():
    fine_mz, fine_ab = isotope_pattern((("Cr", 1), ("H", 1)), 1, resolution=1e6, min_abundance=0)
    coarse_mz, coarse_ab = isotope_pattern((("Cr", 1), ("H", 1)), 1, resolution=200, min_abundance=0)
    assert len(coarse_mz) < len(fine_mz)
    assert coarse_ab.sum() == pytest.approx(fine_ab.sum(), rel=1e-9)
    assert np.sum(coarse_mz * coarse_ab) == pytest.approx(np.sum(fine_mz * fine_ab), rel=1e-9)
    assert np.all(np.diff(coarse_mz) >= coarse_mz[1:] / 200)
    assert np.any(np.diff(fine_mz) < fine_mz[1:] / 200)  # 53Cr1H and 54Cr1H: merged at 200, not at 1e6


def test_names_and_canonical_order():
    assert canonical((("O", 1), ("Cr", 2), ("O", 1))) == (("Cr", 2), ("O", 2))
    assert species_name((("Ni", 1),), 2) == "Ni++"
    assert species_name((("Ni", 2),), 1) == "Ni2+"


def test_unknown_or_isotope_free_elements_are_user_errors():
    with pytest.raises(AptFiltersError, match="unknown element 'Xq'"):
        element_isotopes("Xq")
    with pytest.raises(AptFiltersError, match="Tc has no natural isotopes"):
        element_isotopes("Tc")


def test_candidate_table_holds_oxides_hydrides_dimers_without_repeats():
    table = candidate_compositions()
    assert len(table) == len(set(table))
    for formula in [(("Ni", 1),), (("Cr", 2), ("O", 1)), (("H", 2), ("O", 1)), (("Ni", 2),), (("C", 1), ("Ti", 1))]:
        assert canonical(formula) in table


def test_background_estimate_is_unbiased_beside_and_under_peaks():
    rng = np.random.default_rng(3)
    level = 200.0  # ions per Da
    mz = np.concatenate([rng.uniform(0, 100, int(level * 100)),
                         rng.normal(27.0, 0.01, 50_000), rng.normal(28.0, 0.01, 5_000), rng.normal(60.0, 0.03, 20_000)])
    spectrum = build_spectrum(mz)
    for lo, hi in [(10, 20), (26.5, 28.5), (59, 61), (80, 95)]:
        assert spectrum.expected_background(lo, hi) == pytest.approx(level * (hi - lo), rel=0.06)
    assert spectrum.count(26.9, 27.1) == pytest.approx(50_000 + 0.2 * level, abs=5 * np.sqrt(50_000))
    apex, _ = find_peaks(spectrum)
    np.testing.assert_allclose(np.sort(apex), [27.0, 28.0, 60.0], atol=0.015)
