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

from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.io.readers import iter_ion_chunks

CHUNK = 1 << 22
"""Ions per chunk (4M: 64 MB of POS records, 16 MB of ranging)."""


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

    Peak memory: one chunk of ``chunk_size`` ions (16 B/ion from a file) plus its ranging
    (4 B/ion).
    """
    chunks: Iterable[IonTable] = (
        (IonTable(source.positions[i:i + chunk_size], source.mz[i:i + chunk_size])
         for i in range(0, len(source), chunk_size))
        if isinstance(source, IonTable) else iter_ion_chunks(source, chunk_size))
    s = IonSummary()
    per_ion = np.zeros(len(ranges.ions) + 1 if ranges else 1, dtype=np.int64)  # slot 0: unranged
    for chunk in chunks:
        if not len(chunk):
            continue
        s.ions += len(chunk)
        s.lower = np.minimum(s.lower, chunk.positions.min(axis=0))
        s.upper = np.maximum(s.upper, chunk.positions.max(axis=0))
        s.mz_min = min(s.mz_min, float(chunk.mz.min()))
        s.mz_max = max(s.mz_max, float(chunk.mz.max()))
        if ranges:
            per_ion += np.bincount(ranges.ion_index(chunk.mz) + 1, minlength=len(per_ion))
    if ranges:
        s.ion_counts = dict(zip(ranges.ions, per_ion[1:].tolist()))
        atoms = per_ion[1:] @ ranges.element_matrix()
        s.atoms = dict(zip(ranges.elements, atoms.tolist()))
    return s
