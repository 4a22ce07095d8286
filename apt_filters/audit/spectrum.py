"""The mass spectrum as a fine histogram, with a local background estimate and a peak finder.

Only the histogram is kept: building it reads the m/z column once in chunks, so a spectrum of
10^9 ions costs one pass and ``n_bins`` int64 counts (about 4 MB per 100 Da at the default
0.005 Da bins), whatever the number of ions.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, signal

_CHUNK = 1 << 22  # ions per histogram pass: 16 MB of float32 m/z, 32 MB as float64


@dataclass
class Spectrum:
    """Counts per m/z bin from 0 Da and the expected background per bin.

    Attributes
    ----------
    counts : (n,) int64
        Ions per bin; bin ``i`` covers ``[i * bin_width, (i + 1) * bin_width)`` Da.
    background : (n,) float64
        Local background estimate, ions per bin (smooth, peaks excluded).
    bin_width : float
        Da.
    """

    counts: np.ndarray
    background: np.ndarray
    bin_width: float
    _cum: np.ndarray = field(init=False, repr=False)
    _bcum: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._cum = np.concatenate([[0], np.cumsum(self.counts)])
        self._bcum = np.concatenate([[0.0], np.cumsum(self.background)])

    @property
    def max_mz(self) -> float:
        return len(self.counts) * self.bin_width

    def _edges(self, lo, hi) -> tuple[np.ndarray, np.ndarray]:
        n = len(self.counts)
        i = np.clip(np.rint(np.asarray(lo, dtype=np.float64) / self.bin_width), 0, n).astype(np.int64)
        j = np.clip(np.rint(np.asarray(hi, dtype=np.float64) / self.bin_width), 0, n).astype(np.int64)
        return i, np.maximum(i, j)

    def count(self, lo, hi) -> np.ndarray:
        """Ions in ``[lo, hi]`` Da (scalars or arrays, rounded to bin edges)."""
        i, j = self._edges(lo, hi)
        return (self._cum[j] - self._cum[i]).astype(np.float64)

    def expected_background(self, lo, hi) -> np.ndarray:
        """Background ions expected in ``[lo, hi]`` Da."""
        i, j = self._edges(lo, hi)
        return self._bcum[j] - self._bcum[i]


def histogram(mz: np.ndarray, bin_width: float, max_mz: float) -> np.ndarray:
    """(ceil(max_mz / bin_width),) int64 counts of ``mz`` in bins from 0 Da; values outside are dropped.

    Reads ``mz`` (any array, memory-map included) in chunks of 4M ions.
    """
    n_bins = int(np.ceil(max_mz / bin_width))
    counts = np.zeros(n_bins, dtype=np.int64)
    for start in range(0, len(mz), _CHUNK):
        idx = np.floor(np.asarray(mz[start:start + _CHUNK], dtype=np.float64) / bin_width)
        idx = idx[(idx >= 0) & (idx < n_bins)].astype(np.int64)
        counts += np.bincount(idx, minlength=n_bins)
    return counts


def estimate_background(counts: np.ndarray, bin_width: float, coarse_width: float = 0.05,
                        span: float = 3.0, iterations: int = 3) -> np.ndarray:
    """Local background per fine bin: a sigma-clipped running mean over ``span`` Da.

    The spectrum is summed into ``coarse_width`` bins; a running median gives a first level;
    bins more than 3 sigma (Poisson) above it are peaks and are excluded from a running mean,
    repeated ``iterations`` times. Isotope peaks occupy a small part of any 3 Da span, so they
    do not lift the estimate, while slow trends (the 1/sqrt(m) decay, thermal tails of big
    peaks) are followed.

    Returns
    -------
    (len(counts),) float64
        Expected background ions per fine bin.
    """
    factor = max(1, int(round(coarse_width / bin_width)))
    n_coarse = -(-len(counts) // factor)
    padded = np.zeros(n_coarse * factor)
    padded[:len(counts)] = counts
    coarse = padded.reshape(n_coarse, factor).sum(axis=1)
    size = max(3, int(round(span / (factor * bin_width))) | 1)
    level = ndimage.median_filter(coarse, size=size, mode="nearest")
    for _ in range(iterations):
        keep = (coarse <= level + 3.0 * np.sqrt(level) + 1.0).astype(np.float64)
        weight = ndimage.uniform_filter1d(keep, size, mode="nearest")
        level = ndimage.uniform_filter1d(coarse * keep, size, mode="nearest") / np.maximum(weight, 1e-12)
    return np.repeat(level / factor, factor)[:len(counts)]


def build_spectrum(mz: np.ndarray, bin_width: float = 0.005, max_mz: float = 1000.0) -> Spectrum:
    """Histogram and background of an m/z array (Da).

    The spectrum ends 1 Da above the largest finite m/z, or at ``max_mz`` (ions above it are
    left out, so that a corrupt value cannot blow up the histogram). Peak memory: the histogram
    and a few arrays of its length (8 bytes x max_mz / bin_width at most), plus one 4M-ion chunk.
    """
    top = 0.0
    for start in range(0, len(mz), _CHUNK):
        chunk = np.asarray(mz[start:start + _CHUNK], dtype=np.float64)
        finite = chunk[np.isfinite(chunk) & (chunk <= max_mz)]
        top = max(top, float(finite.max()) if len(finite) else 0.0)
    counts = histogram(mz, bin_width, min(max_mz, np.ceil(top) + 1.0))
    return Spectrum(counts, estimate_background(counts, bin_width), bin_width)


def find_peaks(spectrum: Spectrum, z: float = 5.0, smooth: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Peak apexes standing out of the spectrum by ``z`` Poisson sigma (prominence on ``smooth`` Da sums).

    Returns
    -------
    mz : (p,) float64
        Apex positions in Da.
    height : (p,) float64
        Smoothed counts at the apex (ions per ``smooth`` Da).
    """
    k = max(1, int(round(smooth / spectrum.bin_width)))
    summed = np.convolve(spectrum.counts.astype(np.float64), np.ones(k), mode="same")
    apex, _ = signal.find_peaks(summed, prominence=z * np.sqrt(summed + 1.0))
    return (apex + 0.5) * spectrum.bin_width, summed[apex]
