"""Range tables and ranging: m/z windows -> ion species -> element counts.

A range maps the closed window ``[lower, upper]`` Da to an ion species such as ``CrO2``
whose decomposition into elements (``Cr: 1, O: 2``) is kept, so that element fields count
molecular ions by their atoms.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.errors import AptFiltersError

UNRANGED = -1
"""Ion index given to ions outside every range (they are kept, and flagged by this value)."""

MAX_ATOMS = 1000
"""Most atoms of one element in one ion: far beyond any field-evaporated ion, and small enough that
atom counts times ion counts stay exact in int64."""


@dataclass(frozen=True)
class ReadNote:
    """A quirk met while reading a range file, and what the reader did about it.

    Attributes
    ----------
    kind : str
        ``encoding``, ``layout``, ``header_line``, ``decimal_comma``, ``colour``, ``duplicate_index``,
        ``duplicate_range``, ``merged_overlap``, ``unknown_species``, ``extra_ranges`` or ``relabel``
        (see docs/io.md, "Reading policy").
    line : int or None
        1-based line of the range file (None for the whole file or the command line).
    message : str
        One line for people: what was found and what was done.
    """

    kind: str
    line: int | None
    message: str


def ion_name(composition: tuple[tuple[str, int], ...]) -> str:
    """Canonical ion name from its elements, in the given order: (("Cr", 1), ("O", 2)) -> "CrO2"."""
    return "".join(el if n == 1 else f"{el}{n}" for el, n in composition)


@dataclass(frozen=True)
class Range:
    """One m/z window.

    Attributes
    ----------
    lower, upper : float
        Window bounds in Da, ``lower < upper``; both inclusive.
    composition : tuple of (element, count)
        Atoms of the ion, e.g. ``(("Cr", 1), ("O", 2))``.
    color : str or None
        ``"RRGGBB"`` hex colour from the range file.
    volume : float or None
        Atomic volume (nm³) from the range file, if given.
    """

    lower: float
    upper: float
    composition: tuple[tuple[str, int], ...]
    color: str | None = None
    volume: float | None = None

    @property
    def ion(self) -> str:
        return ion_name(self.composition)

    def describe(self) -> str:
        return f"{self.ion} [{self.lower:g}, {self.upper:g}] Da"


@dataclass
class RangeTable:
    """An ordered list of ranges, checked for overlaps.

    ``ions`` lists the distinct ion species in order of first appearance; ``elements`` the
    distinct elements. Several ranges may share one ion (isotopes, charge states).
    """

    ranges: list[Range]
    source: str | None = None
    notes: list[ReadNote] = field(default_factory=list)
    """What the reader met and did (decimal commas read, duplicates merged, unknown species kept...)."""
    _order: np.ndarray = field(init=False, repr=False)
    _ions: list[str] = field(init=False, repr=False)
    _ion_of_range: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        for r in self.ranges:
            if not (np.isfinite(r.lower) and np.isfinite(r.upper) and r.lower < r.upper):
                raise AptFiltersError(f"range {r.describe()} has lower bound not below upper bound", self.source)
            if not r.composition or any(n < 1 for _, n in r.composition):
                raise AptFiltersError(f"range {r.describe()} has no atoms", self.source)
            if any(n > MAX_ATOMS for _, n in r.composition):
                raise AptFiltersError(f"range {r.describe()} has more than {MAX_ATOMS} atoms of one element",
                                      self.source)
        # ion list and each range's ion, once: per-range list lookups made 10^4 ranges take a minute
        position: dict[str, int] = {}
        self._ion_of_range = np.array([position.setdefault(r.ion, len(position)) for r in self.ranges],
                                      dtype=np.int32)
        self._ions = list(position)
        self._order = np.argsort([r.lower for r in self.ranges], kind="stable")
        sorted_ranges = [self.ranges[i] for i in self._order]
        for a, b in zip(sorted_ranges, sorted_ranges[1:]):
            if b.lower < a.upper:
                raise AptFiltersError(f"ranges overlap: {a.describe()} and {b.describe()}", self.source)

    def __len__(self) -> int:
        return len(self.ranges)

    @property
    def ions(self) -> list[str]:
        return list(self._ions)

    def ion_of_range(self) -> np.ndarray:
        """(n_ranges,) int32 index into ``ions`` of each range's species."""
        return self._ion_of_range.copy()

    @property
    def elements(self) -> list[str]:
        return list(dict.fromkeys(el for r in self.ranges for el, _ in r.composition))

    def ion_compositions(self) -> dict[str, tuple[tuple[str, int], ...]]:
        """Ion name -> its composition."""
        return {r.ion: r.composition for r in self.ranges}

    def ion_colors(self) -> dict[str, str | None]:
        """Ion name -> ``"RRGGBB"`` colour of its first range (None where the file gives none)."""
        colors: dict[str, str | None] = {}
        for r in self.ranges:
            colors.setdefault(r.ion, r.color)
        return colors

    def element_matrix(self) -> np.ndarray:
        """(n_ions, n_elements) int64: atoms of each element per ion, rows in ``ions`` order."""
        column = {el: k for k, el in enumerate(self.elements)}
        m = np.zeros((len(self._ions), len(column)), dtype=np.int64)
        for row, comp in enumerate(self.ion_compositions().values()):  # dict in ``ions`` order
            for el, n in comp:
                m[row, column[el]] = n
        return m

    def range_index(self, mz: np.ndarray) -> np.ndarray:
        """(N,) int32 index into ``ranges`` for each m/z, ``UNRANGED`` (-1) outside every range.

        Vectorised: one ``searchsorted`` over the sorted lower bounds.
        """
        mz = np.asarray(mz)
        lowers = np.array([self.ranges[i].lower for i in self._order], dtype=np.float64)
        uppers = np.array([self.ranges[i].upper for i in self._order], dtype=np.float64)
        pos = np.searchsorted(lowers, mz, side="right") - 1
        inside = (pos >= 0) & (mz <= uppers[np.clip(pos, 0, None)]) if len(lowers) else np.zeros(mz.shape, bool)
        out = np.full(mz.shape, UNRANGED, dtype=np.int32)
        out[inside] = self._order[pos[inside]]
        return out

    def ion_index(self, mz: np.ndarray) -> np.ndarray:
        """(N,) int32 index into ``ions`` for each m/z, ``UNRANGED`` (-1) outside every range."""
        lookup = np.append(self._ion_of_range, np.int32(UNRANGED))
        return lookup[self.range_index(mz)]  # index -1 picks the trailing UNRANGED entry
