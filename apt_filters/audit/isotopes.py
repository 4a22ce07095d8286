"""Natural isotope patterns of atomic and molecular ions, from the ``periodictable`` package.

A molecular ion's pattern is the convolution of its atoms' isotope distributions; peaks
closer than the instrument's resolving width ``m / resolution`` are merged into one peak at
their abundance-weighted mean. Masses are atomic masses divided by the charge (the electron
mass, 0.00055 Da per charge, is far below any APT resolution and is ignored).
"""

from __future__ import annotations

from collections import Counter
from functools import lru_cache

import numpy as np
import periodictable

from apt_filters.core.errors import AptFiltersError

Composition = tuple[tuple[str, int], ...]

_CONVOLUTION_TOLERANCE = 0.005  # Da: isotopologues closer than this are one peak for any atom probe
_PRUNE = 1e-7  # isotopologues rarer than this never matter against APT backgrounds


@lru_cache(maxsize=65536)
def canonical(composition: Composition) -> Composition:
    """Merge repeated elements and sort by symbol: (("O", 1), ("Cr", 2)) -> (("Cr", 2), ("O", 1))."""
    total: Counter[str] = Counter()
    for el, n in composition:
        total[el] += int(n)
    return tuple(sorted(total.items()))


def species_name(composition: Composition, charge: int) -> str:
    """``"Ni+"``, ``"Ni++"``, ``"Cr2O++"``: the ion followed by one ``+`` per charge (no clash with dimers)."""
    return "".join(el if n == 1 else f"{el}{n}" for el, n in composition) + "+" * charge


@lru_cache(maxsize=None)
def element_isotopes(symbol: str) -> tuple[np.ndarray, np.ndarray]:
    """Stable isotopes of one element.

    Returns
    -------
    mass : (k,) float64
        Isotope masses in Da, ascending.
    abundance : (k,) float64
        Natural abundances as fractions summing to 1.

    Raises
    ------
    AptFiltersError
        Unknown symbol, or an element without natural isotopes (e.g. Tc).
    """
    try:
        element = periodictable.elements.symbol(symbol)
    except ValueError:
        raise AptFiltersError(f"unknown element {symbol!r} in a range label") from None
    if isinstance(element, periodictable.core.Isotope):  # "D" and "T" name single isotopes
        return np.array([element.mass]), np.array([1.0])
    pairs = [(iso.mass, iso.abundance) for iso in element if iso.abundance > 0]
    if not pairs:
        raise AptFiltersError(f"element {symbol} has no natural isotopes: its isotope pattern is undefined")
    mass, abundance = np.array(pairs, dtype=np.float64).T
    return mass, abundance / abundance.sum()


def merge_peaks(mass: np.ndarray, abundance: np.ndarray, width) -> tuple[np.ndarray, np.ndarray]:
    """Merge peaks whose gap to the previous peak is below ``width`` (scalar or per-peak array, Da).

    Merged peaks sit at their abundance-weighted mean mass. Input need not be sorted.
    """
    order = np.argsort(mass, kind="stable")
    mass, abundance = mass[order], abundance[order]
    width = np.broadcast_to(width, mass.shape)[order] if np.ndim(width) else width
    new_group = np.ones(len(mass), dtype=bool)
    new_group[1:] = np.diff(mass) >= (width[1:] if np.ndim(width) else width)
    group = np.cumsum(new_group) - 1
    total = np.bincount(group, abundance)
    return np.bincount(group, mass * abundance) / total, total


@lru_cache(maxsize=8192)
def _mass_pattern(composition: Composition, relative_width: float) -> tuple[np.ndarray, np.ndarray]:
    mass, abundance = np.zeros(1), np.ones(1)
    for el, n in composition:
        iso_mass, iso_abundance = element_isotopes(el)
        for _ in range(n):
            mass = (mass[:, None] + iso_mass[None, :]).ravel()
            abundance = (abundance[:, None] * iso_abundance[None, :]).ravel()
            keep = abundance > _PRUNE
            mass, abundance = merge_peaks(mass[keep], abundance[keep], _CONVOLUTION_TOLERANCE)
    mass, abundance = merge_peaks(mass, abundance, mass * relative_width)
    mass.setflags(write=False)
    abundance.setflags(write=False)
    return mass, abundance


def isotope_pattern(composition: Composition, charge: int, resolution: float = 500.0,
                    min_abundance: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """Expected isotope peaks of an ion species at one charge state.

    Parameters
    ----------
    composition : tuple of (element, count)
        Atoms of the ion, e.g. ``(("Cr", 2), ("O", 1))``.
    charge : int
        Charge state, >= 1.
    resolution : float
        Mass resolving power m/Δm; peaks closer than ``m / resolution`` are merged.
    min_abundance : float
        Peaks below this fraction of all ions of the species are dropped.

    Returns
    -------
    mz : (k,) float64
        Peak positions in Da (mass-to-charge), ascending.
    abundance : (k,) float64
        Fraction of the species' ions in each peak (sums to <= 1 after dropping).
    """
    if charge < 1:
        raise ValueError(f"charge must be >= 1, got {charge}")
    mass, abundance = _mass_pattern(canonical(composition), 1.0 / resolution)
    keep = abundance >= min_abundance
    return mass[keep] / charge, abundance[keep]
