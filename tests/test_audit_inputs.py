"""Range audit on degenerate or bad input: empty data, corrupt m/z values, unknown species."""

import numpy as np

from apt_filters.audit import audit_ranges
from apt_filters.io.ranges import Range, RangeTable


def test_empty_ions_and_ranges():
    result = audit_ranges(np.zeros(0, np.float32), [])
    assert result.findings == [] and result.n_ions == 0


def test_corrupt_mz_values_are_left_out_and_input_untouched():
    mz = np.array([np.nan, np.inf, -3.0, 1e30] + [27.0] * 500, np.float32)
    before = mz.copy()
    result = audit_ranges(mz, [Range(26.9, 27.1, (("Al", 1),))])
    assert result.flagged == [], str(result)
    np.testing.assert_array_equal(mz, before)


def test_range_on_empty_spectrum_is_background_only():
    rng = np.random.default_rng(0)
    result = audit_ranges(rng.uniform(0, 50, 5000).astype(np.float32), [Range(10, 11, (("Fe", 1),))])
    assert [(f.kind, f.range) for f in result.flagged] == [("background_only", 0)]


def test_unknown_species_is_reported_not_fitted():
    # a name that is not a formula (an unidentified peak) has no isotope pattern to check
    mz = np.random.default_rng(0).normal(10.5, 0.01, 500).astype(np.float32)
    result = audit_ranges(mz, RangeTable([Range(10, 11, (("Xx", 1),))], source="a.rrng"))
    [finding] = [f for f in result.findings if f.range == 0]
    assert finding.kind == "unknown_label" and finding.severity == "warning"
    assert "Xx [10, 11] Da: Xx is not a chemical formula" in finding.message
