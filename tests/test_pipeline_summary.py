"""The streaming ion summary that `apt-filters info` and `apt-filters run` share, against numpy."""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.io.summary import summarize
from apt_filters.io.writers import write_pos

# touching ranges (27.0 is the upper bound of one and the lower of the next), a molecular ion,
# and two ranges of one ion
RANGES = RangeTable([Range(26.5, 27.0, (("Al", 1),), "00ff00"), Range(27.0, 27.5, (("Si", 1),), "0000ff"),
                     Range(13.4, 13.6, (("Al", 1),), "00ff00"), Range(41.5, 42.5, (("Cr", 1), ("O", 2)), "ff0000"),
                     Range(58.0, 58.0 + 2 ** -10, (("Ni", 1),), "aaaaaa")])


def _ions(n: int = 50_000, seed: int = 4) -> IonTable:
    rng = np.random.default_rng(seed)
    bounds = np.array([v for r in RANGES.ranges for v in (r.lower, r.upper)], dtype=np.float32)
    mz = np.concatenate([rng.uniform(10, 60, n), np.repeat(bounds, 7), np.nextafter(bounds, 0), np.nextafter(bounds, 99)])
    mz = rng.permutation(mz).astype(np.float32)
    positions = rng.normal(size=(len(mz), 3)).astype(np.float32) * [10, 20, 40]
    return IonTable(positions.astype(np.float32), mz)


@pytest.mark.parametrize("chunk", [1 << 22, 997])
def test_summary_equals_ion_index_counts_bounds_included(chunk):
    ions = _ions()
    s = summarize(ions, RANGES, chunk_size=chunk)
    expected = np.bincount(RANGES.ion_index(ions.mz) + 1, minlength=len(RANGES.ions) + 1)
    assert s.ion_counts == dict(zip(RANGES.ions, expected[1:].tolist()))
    assert s.ranged == int(np.sum(RANGES.ion_index(ions.mz) >= 0)) and s.ions == len(ions)
    assert s.ion_counts["Si"] > 0 and s.ion_counts["Ni"] > 0
    np.testing.assert_array_equal(s.lower, ions.positions.min(axis=0))
    np.testing.assert_array_equal(s.upper, ions.positions.max(axis=0))
    assert (s.mz_min, s.mz_max) == (float(ions.mz.min()), float(ions.mz.max()))
    atoms = expected[1:] @ RANGES.element_matrix()
    assert s.composition() == pytest.approx(dict(zip(RANGES.elements, atoms / atoms.sum())), rel=1e-12)
    assert list(s.composition().values()) == sorted(s.composition().values(), reverse=True)


def test_summary_of_a_file_equals_that_of_its_ions(tmp_path):
    ions = _ions(seed=7)
    write_pos(tmp_path / "a.pos", ions)
    from_file, in_memory = summarize(tmp_path / "a.pos", RANGES, chunk_size=10_000), summarize(ions, RANGES)
    assert from_file.ion_counts == in_memory.ion_counts and from_file.atoms == in_memory.atoms
    np.testing.assert_array_equal(from_file.lower, in_memory.lower)
    assert summarize(ions).composition() == {} and summarize(ions).ion_counts == {}
