"""Property-based fuzzing of generated range files of every dialect (RRNG, RNG, ENV, GPM ENV):
a table comes back, or the project's one-line error naming the file; nothing else escapes.

The one-off campaign over thousands of files is benchmarks/fuzz_ranges.py; linear-time reading is
checked in tests/test_io_range_quirks.py and measured in benchmarks/bench_ranges.py.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings

from apt_filters.core.errors import AptFiltersError
from apt_filters.io import RangeTable, read_ranges
from apt_filters.io.formula import CLIP
from rangefile_gen import range_files

FUZZ = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                         HealthCheck.function_scoped_fixture])


def check_range_file(path) -> RangeTable | None:
    """Read ``path``: a valid table, or one short line naming the file (anything else fails)."""
    try:
        table = read_ranges(path)
    except AptFiltersError as exc:
        msg = str(exc)
        assert msg.startswith(f"{path}: ") and "\n" not in msg, msg
        assert len(msg) < len(str(path)) + 6 * CLIP + 200, f"{len(msg)} characters"
        return None
    lowers = np.array([r.lower for r in table.ranges])
    uppers = np.array([r.upper for r in table.ranges])
    order = np.argsort(lowers)
    assert np.all(lowers < uppers) and np.all(lowers[order][1:] >= uppers[order][:-1]), "ranges disjoint"
    table.element_matrix()  # counts fit int64
    return table


@FUZZ
@given(case=range_files())
def test_generated_range_files(tmp_path, case):
    suffix, data = case
    path = tmp_path / f"g{suffix}"
    path.write_bytes(data)
    check_range_file(path)
