"""Range audit on the real Si dataset (945,211 ions): the known faults of Si.RRNG are found.

The range 57.8-61.2 Da is labelled Cr2O but holds Ni+ (58/60/61/62/64 Da); the ranges labelled Si at
28.8-29.3 and 29.8-30.3 Da hold mostly Ni++ (58Ni++ at 28.97, 60Ni++ at 29.97).
"""

import pytest

from apt_filters.audit import audit_ranges
from apt_filters.io import read_ions, read_ranges


@pytest.fixture(scope="module")
def si_audit(real_si):
    ranges = read_ranges(real_si / "Si.RRNG")
    return ranges, audit_ranges(read_ions(real_si / "Si.pos"), ranges)


def _index(ranges, lower):
    return next(i for i, r in enumerate(ranges.ranges) if abs(r.lower - lower) < 1e-3)


def test_cr2o_range_is_ni_plus(si_audit):
    ranges, result = si_audit
    index = _index(ranges, 57.819)
    (finding,) = [f for f in result.flagged if f.range == index]
    assert finding.severity == "error" and finding.kind == "mislabelled"
    assert finding.figures["best_fit_composition"] == (("Ni", 1),) and finding.figures["best_fit_charge"] == 1
    assert finding.figures["foreign_fraction"] > 0.95
    assert finding.figures["label_p_value"] < 1e-10 and finding.figures["label_residual"] > 0.5
    ni = next(s for s in result.species if s.name == "Ni+")
    assert not ni.labelled and ni.residual < 0.05  # Ni+ fits the five peaks to within 5 % of their ions


@pytest.mark.parametrize("lower", [28.826, 29.783])
def test_si_ranges_hold_ni_plus_plus(si_audit, lower):
    ranges, result = si_audit
    (finding,) = [f for f in result.flagged if f.range == _index(ranges, lower)]
    assert finding.severity == "error"
    assert finding.figures["foreign_species"] == "Ni++" and finding.figures["foreign_fraction"] > 0.9


def test_correct_si_ranges_are_not_flagged(si_audit):
    """28Si+ and the three Si++ ranges hold what their label says."""
    ranges, result = si_audit
    for lower in (27.856, 13.8745, 14.407, 14.912):
        assert _index(ranges, lower) not in result.flagged_ranges(), str(result)


def test_unranged_ni_peaks_are_reported(si_audit):
    _, result = si_audit
    uncovered = {round(f.figures["mz"], 1): f.figures.get("likely_species") for f in result.flagged
                 if f.kind == "uncovered_peak"}
    assert uncovered[61.9] == "Ni+" and uncovered[63.9] == "Ni+" and uncovered[31.0] == "Ni++"
    assert 1.0 in uncovered  # H+
