"""Synthetic mass spectra: isotope peaks of each species in its charge states, noise, and ranges.

Isotope masses and natural abundances come from ``periodictable``. Every peak is a Gaussian in
m/z with sigma = m/z / (2.3548 * mass_resolution) (``mass_resolution`` is m/dm at FWHM); each
peak gets a range of +- ``range_sigmas`` sigma, so that (for 5 sigma) fewer than 1e-6 of an
element's ions fall outside its ranges. Unranged background ions are uniform in m/z.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.io.ranges import Range, RangeTable

DEFAULT_CHARGE_STATES: dict[str, dict[int, float]] = {
    "Ni": {2: 0.85, 1: 0.15},
    "Al": {2: 0.8, 3: 0.2},
    "Cr": {2: 1.0},
    "B": {1: 0.7, 2: 0.3},
    "Co": {2: 1.0},
    "Si": {2: 0.7, 1: 0.3},
    "Ti": {2: 0.8, 3: 0.2},
    "Mo": {3: 0.6, 2: 0.4},
    "Cu": {1: 0.6, 2: 0.4},
    "Mg": {2: 0.8, 1: 0.2},
}
"""Charge-state fractions per element (chosen so that no two elements' peaks overlap among them;
e.g. Al+ at 27 Da would coincide with 54Cr2+); other elements default to 2+ only."""

_COLORS = ["33A02C", "E31A1C", "1F78B4", "FF7F00", "6A3D9A", "B15928", "A6CEE3", "FB9A99", "B2DF8A", "FDBF6F"]


@dataclass(frozen=True)
class Peak:
    """One isotope of one species in one charge state."""

    species: str
    isotope: int
    charge: int
    mz: float  # Da
    probability: float  # of an ion of this species landing in this peak
    sigma: float  # Da


@dataclass(frozen=True)
class SpectrumModel:
    """How species become m/z values.

    Attributes
    ----------
    charge_states : dict element -> {charge: fraction}
        Overrides of :data:`DEFAULT_CHARGE_STATES`.
    mass_resolution : float
        m/dm at FWHM of every peak.
    range_sigmas : float
        Half-width of each range in peak sigmas.
    noise_fraction : float
        Fraction of all ions that are background noise, uniform in m/z over ``noise_mz`` (Da;
        None: from 1 Da to 10% beyond the heaviest peak) and uniform in space.
    """

    charge_states: dict[str, dict[int, float]] = field(default_factory=dict)
    mass_resolution: float = 1000.0
    range_sigmas: float = 5.0
    noise_fraction: float = 0.01
    noise_mz: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.noise_fraction < 1:
            raise AptFiltersError(f"noise fraction must be in [0, 1), got {self.noise_fraction}")
        if not self.mass_resolution > 0 or not self.range_sigmas > 0:
            raise AptFiltersError("mass resolution and range width must be positive")


def _element(symbol: str):
    import periodictable

    try:
        return periodictable.elements.symbol(symbol)
    except ValueError as exc:
        raise AptFiltersError(f"species {symbol!r} is not an element symbol") from exc


def peaks(species: list[str], model: SpectrumModel) -> list[Peak]:
    """Every peak of every species, probabilities within a species summing to 1."""
    out = []
    for sp in species:
        el = _element(sp)
        charges = model.charge_states.get(sp, DEFAULT_CHARGE_STATES.get(sp, {2: 1.0}))
        total_charge = sum(charges.values())
        isotopes = [(iso, el[iso].mass, el[iso].abundance) for iso in el.isotopes if el[iso].abundance > 0]
        if not isotopes or total_charge <= 0:
            raise AptFiltersError(f"species {sp!r} has no natural isotopes or no charge states")
        total_abundance = sum(a for _, _, a in isotopes)
        for q, frac in sorted(charges.items()):
            for iso, mass, abundance in isotopes:
                mz = mass / q
                out.append(Peak(sp, iso, q, mz, frac / total_charge * abundance / total_abundance,
                                mz / (2.3548 * model.mass_resolution)))
    return out


def noise_window(peak_list: list[Peak], model: SpectrumModel) -> tuple[float, float]:
    """(low, high) Da of the uniform background."""
    if model.noise_mz is not None:
        return float(model.noise_mz[0]), float(model.noise_mz[1])
    return 1.0, float(math.ceil(1.1 * max(p.mz for p in peak_list)))


def range_table(peak_list: list[Peak], model: SpectrumModel, atomic_volume: float | None = None) -> RangeTable:
    """Ranges of +- range_sigmas around every peak; overlapping windows of one species are merged.

    Raises
    ------
    AptFiltersError
        If windows of two different species overlap (the truth would be ambiguous); choose other
        charge states for one of them.
    """
    windows = sorted((p.mz - model.range_sigmas * p.sigma, p.mz + model.range_sigmas * p.sigma, p)
                     for p in peak_list)
    merged: list[list] = []
    for lo, hi, p in windows:
        if merged and lo <= merged[-1][1]:
            prev = merged[-1][2]
            if prev.species != p.species:
                raise AptFiltersError(
                    f"peaks overlap: {prev.isotope}{prev.species}{prev.charge}+ at {prev.mz:.3f} Da and "
                    f"{p.isotope}{p.species}{p.charge}+ at {p.mz:.3f} Da; choose other charge states")
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi, p])
    species = list(dict.fromkeys(p.species for p in peak_list))
    colors = {sp: _COLORS[i % len(_COLORS)] for i, sp in enumerate(species)}
    ranges = [Range(round(lo, 4), round(hi, 4), ((p.species, 1),), colors[p.species], atomic_volume)
              for lo, hi, p in merged]
    return RangeTable(ranges, source="synthetic")


def ranged_noise_fraction(ranges: RangeTable, window: tuple[float, float]) -> float:
    """Fraction of uniform background ions in ``window`` that fall inside some range."""
    lo, hi = window
    covered = sum(max(0.0, min(r.upper, hi) - max(r.lower, lo)) for r in ranges.ranges)
    return covered / (hi - lo)


class MzSampler:
    """Draws m/z for ions of given species (vectorised), and for noise ions."""

    def __init__(self, species: list[str], peak_list: list[Peak], window: tuple[float, float]):
        self.window = window
        order = sorted(range(len(peak_list)), key=lambda i: species.index(peak_list[i].species))
        ordered = [peak_list[i] for i in order]
        owner = np.array([species.index(p.species) for p in ordered])
        # species s owns the edges s + (cumulative probability of its peaks), all in one sorted array
        within = np.array([p.probability for p in ordered])
        cum = [within[owner == s].cumsum() for s in range(len(species))]
        self.edges = np.concatenate([s + c for s, c in enumerate(cum)]).astype(np.float64)
        self.last = np.cumsum([len(c) for c in cum]) - 1
        self.mz = np.array([p.mz for p in ordered])
        self.sigma = np.array([p.sigma for p in ordered])

    def sample(self, species_index: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(N,) float64 m/z; species_index -1 marks noise ions (uniform over the window)."""
        n = len(species_index)
        u, g = rng.random(n), rng.standard_normal(n)
        noise = species_index < 0
        s = np.where(noise, 0, species_index)
        k = np.minimum(np.searchsorted(self.edges, s + u, side="right"), self.last[s])
        lo, hi = self.window
        return np.where(noise, lo + (hi - lo) * u, self.mz[k] + self.sigma[k] * g)
