"""Test helpers for the range audit: real data without the io readers, and small synthetic spectra.

The POS is read with a numpy memory-map and the RRNG with a minimal parser here, because the io
readers are written in parallel; the audit itself only takes arrays and RangeTables.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apt_filters.audit.isotopes import isotope_pattern
from apt_filters.io.ranges import Range


@dataclass
class SynthSpecies:
    """A species of a synthetic spectrum: composition, charge and number of ions."""

    composition: tuple[tuple[str, int], ...]
    charge: int
    ions: int


# Chosen so that no two species share an isotope peak within the resolution.
SPECIMEN = (
    SynthSpecies((("Al", 1),), 1, 30_000),
    SynthSpecies((("Al", 1),), 2, 10_000),
    SynthSpecies((("Cr", 1),), 1, 40_000),
    SynthSpecies((("Ni", 1),), 1, 20_000),
    SynthSpecies((("Cu", 1),), 1, 8_000),
    SynthSpecies((("Cr", 1), ("O", 1)), 1, 6_000),
    SynthSpecies((("Mo", 1),), 3, 10_000),
    SynthSpecies((("Mo", 1),), 1, 5_000),
)
RESOLUTION = 900.0  # FWHM resolving power of the synthetic peaks
BACKGROUND_PER_DA = 150.0
MAX_MZ = 120.0


def synth_mz(seed: int, specimen=SPECIMEN) -> np.ndarray:
    """(N,) float32 m/z: Gaussian isotope peaks (natural abundances) on a uniform background."""
    rng = np.random.default_rng(seed)
    parts = []
    for sp in specimen:
        mz, abundance = isotope_pattern(sp.composition, sp.charge, resolution=1e6)
        which = rng.choice(len(mz), size=sp.ions, p=abundance / abundance.sum())
        centre = mz[which]
        parts.append(centre + rng.normal(size=sp.ions) * centre / (2.355 * RESOLUTION))
    parts.append(rng.uniform(0.0, MAX_MZ, size=int(BACKGROUND_PER_DA * MAX_MZ)))
    return rng.permutation(np.concatenate(parts)).astype(np.float32)


def synth_ranges(specimen=SPECIMEN, min_ions: float = 60.0) -> list[Range]:
    """A correct range file: every isotope peak with at least ``min_ions`` expected ions, +-3.5 sigma.

    Peaks below ``min_ions`` stay unranged, as a careful analyst would leave them; the check
    below makes sure the largest of them is far below the audit's 20-ion, 5-sigma detection.
    Where peaks of two species coincide (54Fe/54Cr), one range takes the label of the species
    with more ions there.
    """
    peaks = []  # (lower, upper, expected ions, composition)
    for sp in specimen:
        mz, abundance = isotope_pattern(sp.composition, sp.charge, resolution=RESOLUTION)
        expected = sp.ions * abundance
        half = 3.5 * mz / (2.355 * RESOLUTION)
        for m, e, h in zip(mz, expected, half):
            if e >= min_ions:
                peaks.append((round(m - h, 3), round(m + h, 3), e, sp.composition))
            else:
                assert e < 10, f"synthetic design: unranged peak of {e:.0f} ions at {m:.2f} Da is detectable"
    peaks.sort()
    merged = []
    for lo, hi, e, comp in peaks:
        if merged and lo < merged[-1][1]:
            plo, phi, pe, pcomp = merged[-1]
            merged[-1] = (plo, max(hi, phi), max(e, pe), comp if e > pe else pcomp)
        else:
            merged.append((lo, hi, e, comp))
    return [Range(lo, hi, comp) for lo, hi, _, comp in merged]


def relabel(ranges: list[Range], near_mz: float, composition) -> tuple[list[Range], int]:
    """The ranges with the one containing ``near_mz`` given another label; returns (ranges, its index)."""
    index = next(i for i, r in enumerate(ranges) if r.lower <= near_mz <= r.upper)
    out = list(ranges)
    r = out[index]
    out[index] = Range(r.lower, r.upper, tuple(composition), r.color, r.volume)
    return out, index
