"""Sort-based set operations on integer arrays.

numpy 2.4's hash-based ``np.unique`` (without ``return_inverse``), ``np.isin`` and
``np.unique(axis=0)`` were measured 10-50x slower than sorting on the index arrays used
here (2.3 s against 0.05 s for 600k int64), so the remesher uses these instead.
"""

from __future__ import annotations

import numpy as np


def unique(a: np.ndarray) -> np.ndarray:
    """Sorted distinct values of a 1-D array."""
    s = np.sort(np.asarray(a).ravel())
    return s[np.r_[True, s[1:] != s[:-1]]] if len(s) else s


def isin(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Boolean mask: which elements of ``a`` occur in ``b``."""
    b = unique(b)
    a = np.asarray(a)
    if len(b) == 0:
        return np.zeros(a.shape, bool)
    pos = np.minimum(np.searchsorted(b, a), len(b) - 1)
    return b[pos] == a


def unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Distinct rows of a non-negative int (k, d) array, d <= 3.

    Returns ``(uniq, index, inverse, counts)`` as ``np.unique(axis=0, return_index=True,
    return_inverse=True, return_counts=True)`` would, with ``index`` the first occurrence.
    """
    rows = np.ascontiguousarray(rows, np.int64)
    n = int(rows.max()) + 1 if rows.size else 1
    key = rows[:, 0].copy()
    for col in range(1, rows.shape[1]):
        key = key * n + rows[:, col]
    order = np.argsort(key, kind="stable")
    k = key[order]
    first = np.r_[True, k[1:] != k[:-1]] if len(k) else np.zeros(0, bool)
    inverse = np.empty(len(key), np.int64)
    inverse[order] = np.cumsum(first) - 1
    index = order[first]
    counts = np.diff(np.r_[np.flatnonzero(first), len(k)])
    return rows[index], index, inverse, counts
