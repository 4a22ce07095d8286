"""Streaming summary of ions: count, bounds, m/z span and, with a range table, the ranged
fraction and the composition by element (molecular ions decomposed into their atoms).

Used by ``apt-filters info`` (on a file) and by ``apt-filters run`` (on the ions it read):
one pass over chunks, so a 10^9-ion file needs one chunk of memory.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np
from numba import njit

from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.io.readers import iter_ion_chunks

CHUNK = 1 << 22
"""Ions per chunk (4M: 64 MB of POS records)."""


@dataclass
class IonSummary:
    """Summary of a set of ions.

    Attributes
    ----------
    ions : int
        Number of ions.
    lower, upper : (3,) float64
        Bounding box corners in nm (x, y, z).
    mz_min, mz_max : float
        m/z span in Da.
    ion_counts : dict[str, int]
        Ions per ranged species (empty without a range table).
    atoms : dict[str, int]
        Atoms per element, molecular ions counted by their atoms.
    """

    ions: int = 0
    lower: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    upper: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    mz_min: float = np.inf
    mz_max: float = -np.inf
    ion_counts: dict[str, int] = field(default_factory=dict)
    atoms: dict[str, int] = field(default_factory=dict)

    @property
    def ranged(self) -> int:
        return sum(self.ion_counts.values())

    @property
    def ranged_fraction(self) -> float:
        return self.ranged / self.ions if self.ions else 0.0

    def composition(self) -> dict[str, float]:
        """Atomic fraction per element (sums to 1), largest first; empty without ranged ions."""
        total = sum(self.atoms.values())
        fractions = {el: n / total for el, n in self.atoms.items()} if total else {}
        return dict(sorted(fractions.items(), key=lambda kv: -kv[1]))


def summarize(source: str | os.PathLike | IonTable, ranges: RangeTable | None = None,
              chunk_size: int = CHUNK) -> IonSummary:
    """Count, bounds, m/z span and (with ``ranges``) species and element counts of ions.

    Parameters
    ----------
    source : path or IonTable
        An ion file (streamed with :func:`~apt_filters.io.iter_ion_chunks`) or ions already
        read (walked in slices, no copy; a memory-mapped table stays mapped).
    ranges : RangeTable, optional
    chunk_size : int
        Ions per chunk.

    Peak memory: one chunk of ``chunk_size`` ions (16 B/ion from a file; nothing for ions
    already read in native byte order). One compiled pass per chunk finds the bounds, the m/z
    span and the ions per range (a binary search over the sorted range bounds, giving the
    same ranging as :meth:`RangeTable.ion_index`, bounds included).
    """
    chunks: Iterable[IonTable] = (
        (IonTable(source.positions[i:i + chunk_size], source.mz[i:i + chunk_size])
         for i in range(0, len(source), chunk_size))
        if isinstance(source, IonTable) else iter_ion_chunks(source, chunk_size))
    s = IonSummary()
    edges, range_of_bin = range_edges(ranges) if ranges else (np.zeros(0), np.zeros(1, dtype=np.int64))
    bins = np.zeros(len(edges) + 1, dtype=np.int64)
    span = np.array([np.inf, -np.inf])
    for chunk in chunks:
        s.ions += len(chunk)
        _scan(_native(chunk.positions), _native(chunk.mz), edges, s.lower, s.upper, span, bins)
    s.mz_min, s.mz_max = float(span[0]), float(span[1])
    if ranges:
        per_ion = np.bincount(range_of_bin, weights=bins, minlength=len(ranges.ions) + 1).astype(np.int64)[1:]
        s.ion_counts = dict(zip(ranges.ions, per_ion.tolist()))
        atoms = per_ion @ ranges.element_matrix()
        s.atoms = dict(zip(ranges.elements, atoms.tolist()))
    return s


def _native(a: np.ndarray) -> np.ndarray:
    """Native byte order (POS/EPOS memory maps are big-endian), converted only if needed."""
    return np.asarray(a, dtype=a.dtype.newbyteorder("="))


def range_edges(ranges: RangeTable) -> tuple[np.ndarray, np.ndarray]:
    """Sorted bin edges ``lower_0, upper_0+, lower_1, upper_1+, ...`` of the ranges and, for each
    bin of ``searchsorted(edges, mz, side="right")``, its ion species + 1 (0: unranged).

    ``upper+`` is the next float64 above the upper bound (ranges include both bounds, as
    :meth:`RangeTable.range_index`), or the next range's lower bound where the two touch.
    """
    order = np.argsort([r.lower for r in ranges.ranges], kind="stable")
    lower = np.array([ranges.ranges[k].lower for k in order], dtype=np.float64)
    upper = np.array([ranges.ranges[k].upper for k in order], dtype=np.float64)
    edges = np.column_stack([lower, np.minimum(np.nextafter(upper, np.inf), np.r_[lower[1:], np.inf])]).ravel()
    range_of_bin = np.zeros(len(edges) + 1, dtype=np.int64)
    range_of_bin[1::2] = ranges.ion_of_range()[order] + 1  # odd bins lie inside a range
    return edges, range_of_bin


@njit(cache=True, nogil=True)
def _scan(positions, mz, edges, lower, upper, span, bins):  # pragma: no cover - compiled
    """One pass over a chunk: bounds, m/z span, and counts per bin of ``edges``."""
    for i in range(mz.shape[0]):
        for a in range(3):
            v = positions[i, a]
            if v < lower[a]:
                lower[a] = v
            if v > upper[a]:
                upper[a] = v
        m = mz[i]
        if m < span[0]:
            span[0] = m
        if m > span[1]:
            span[1] = m
        bins[np.searchsorted(edges, m, side="right")] += 1
