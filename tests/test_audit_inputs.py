"""Range audit on degenerate or bad input: empty data, corrupt m/z values, unknown elements."""

import numpy as np
import pytest

from apt_filters.audit import audit_ranges
from apt_filters.core.errors import AptFiltersError
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


def test_unknown_element_names_the_range_file():
    with pytest.raises(AptFiltersError, match=r"^a\.rrng: unknown element 'Xx'"):
        audit_ranges(np.ones(10, np.float32), RangeTable([Range(10, 11, (("Xx", 1),))], source="a.rrng"))
