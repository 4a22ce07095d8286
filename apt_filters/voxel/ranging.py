"""Fast ranging for the scatter: m/z -> ion row through a uniform bin table, exact at range bounds.

``RangeTable.ion_index`` does a binary search per ion in numpy (several passes over the
chunk); here one pass looks the m/z up in a table of uniform bins that gives the
sorted range at or below the bin's start, then steps forward with the same comparisons as
``searchsorted(lowers, mz, side="right")`` and ``mz <= upper``, so the result is identical to
``ion_index(mz) + 1`` for every value, bounds included.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from apt_filters.io.ranges import RangeTable
from apt_filters.core.threads import on_threads, shares

N_BINS = 1 << 14
"""Bins of the lookup table (64 kB of int32: stays in cache)."""


@dataclass(frozen=True)
class MzLookup:
    """Sorted ranges and a uniform bin table over their m/z span.

    Attributes
    ----------
    lowers, uppers : (n_ranges,) float64
        Range bounds (Da), sorted by lower bound.
    rows : (n_ranges,) int32
        Ion row of each sorted range: ion species index + 1 (row 0 = unranged).
    base, inv_width : float
        The table's first bin starts at ``base`` Da; bins are ``1 / inv_width`` Da wide.
    first : (N_BINS,) int32
        Index of the last sorted range whose lower bound lies below the bin before this one
        (-1 if none): a safe start for the forward step, whatever the rounding of the bin index.
    """

    lowers: np.ndarray
    uppers: np.ndarray
    rows: np.ndarray
    base: float
    inv_width: float
    first: np.ndarray

    @classmethod
    def from_ranges(cls, ranges: RangeTable) -> "MzLookup":
        order = np.argsort([r.lower for r in ranges.ranges], kind="stable")
        lowers = np.array([ranges.ranges[i].lower for i in order], dtype=np.float64)
        uppers = np.array([ranges.ranges[i].upper for i in order], dtype=np.float64)
        ions = ranges.ions
        rows = np.array([ions.index(ranges.ranges[i].ion) + 1 for i in order], dtype=np.int32)
        if len(lowers):
            base, span = lowers[0], max(uppers.max() - lowers[0], 1e-9)
        else:
            base, span = 0.0, 1.0
        width = span / N_BINS
        starts = base + (np.arange(N_BINS) - 1) * width  # one bin early: bin-index rounding cannot skip a range
        first = (np.searchsorted(lowers, starts, side="right") - 1).astype(np.int32)
        return cls(lowers, uppers, rows, float(base), float(1.0 / width), first)

    def rows_of(self, mz: np.ndarray, threads: int = 1) -> np.ndarray:
        """(N,) int32 ion row (ion species index + 1, 0 = unranged) of each m/z (Da), ``threads``
        contiguous shares at once."""
        mz = np.ascontiguousarray(mz)
        out = np.empty(len(mz), dtype=np.int32)
        on_threads(lambda a, b: _rows_of(mz[a:b], self.lowers, self.uppers, self.rows, self.base, self.inv_width,
                                         self.first, out[a:b]),
                   shares(len(mz), max(1, int(threads))))
        return out


@njit(nogil=True, cache=True)
def _rows_of(mz, lowers, uppers, rows, base, inv_width, first, out):
    n_ranges, n_bins = lowers.shape[0], first.shape[0]
    for i in range(mz.shape[0]):
        m = np.float64(mz[i])
        out[i] = 0
        if not (n_ranges > 0 and m >= base):  # below every range, or NaN
            continue
        f = (m - base) * inv_width
        k = first[n_bins - 1] if f >= n_bins - 1 else first[np.int64(f)]  # compared first: inf m/z
        while k + 1 < n_ranges and lowers[k + 1] <= m:
            k += 1
        if k >= 0 and m <= uppers[k]:
            out[i] = rows[k]
