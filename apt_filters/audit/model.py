"""A spectrum model: background plus species isotope patterns, fitted in windows around their peaks.

Each species (a composition at one charge state) contributes ``amplitude * abundance`` ions
to the window of each of its isotope peaks. Windows that overlap are merged into one
*cluster*, so that overlapping isotopes of different species (54Cr/54Fe, 29Si+/58Ni++)
share their counts. Amplitudes are fitted by non-negative least squares with Poisson weights
and refined by Poisson maximum likelihood (EM), and the fit is judged by the Poisson deviance
(the G statistic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from apt_filters.audit.isotopes import Composition, canonical, isotope_pattern, species_name
from apt_filters.audit.spectrum import Spectrum

_WINDOW_PEAK = 1e-3  # isotopes below this abundance get no window of their own (they may still share one)
_EM_ITERATIONS = 60


@dataclass(frozen=True)
class Species:
    """One ion species at one charge state and its isotope peaks inside the spectrum.

    Attributes
    ----------
    composition : canonical composition, e.g. ``(("Cr", 2), ("O", 1))``
    charge : int
    mz, abundance : (k,) float64
        Peak positions (Da) and fractions of the species' ions.
    """

    composition: Composition
    charge: int
    mz: np.ndarray
    abundance: np.ndarray

    @property
    def name(self) -> str:
        return species_name(self.composition, self.charge)

    @property
    def key(self) -> tuple[Composition, int]:
        return self.composition, self.charge


def make_species(composition: Composition, charge: int, resolution: float, max_mz: float) -> Species | None:
    """The species with its peaks below ``max_mz``; None when no window-worthy peak is in the spectrum."""
    mz, abundance = isotope_pattern(canonical(composition), charge, resolution)
    inside = mz < max_mz
    if not np.any(abundance[inside] >= _WINDOW_PEAK):
        return None
    return Species(canonical(composition), charge, mz[inside], abundance[inside])


@dataclass(frozen=True)
class Windows:
    """Peak window widths: ``[p - lower(p), p + upper(p)]`` around a peak at ``p`` Da.

    The upper side is wider because atom probe peaks have thermal tails toward high m/z.
    """

    resolution: float = 500.0
    min_halfwidth: float = 0.05

    def bounds(self, mz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fwhm = np.asarray(mz) / self.resolution
        return mz - np.maximum(self.min_halfwidth, 1.2 * fwhm), mz + np.maximum(2 * self.min_halfwidth, 2.5 * fwhm)


@dataclass
class Fit:
    """A fitted model.

    Attributes
    ----------
    species : list of Species
    lo, hi : (n_clusters,) float64
        Cluster bounds in Da.
    design : (n_clusters, n_species) float64
        Abundance of each species in each cluster.
    observed, background : (n_clusters,) float64
        Ions counted and background ions expected in each cluster.
    amplitude : (n_species,) float64
        Fitted ions of each species (all its isotopes).
    """

    species: list[Species]
    lo: np.ndarray
    hi: np.ndarray
    design: np.ndarray
    observed: np.ndarray
    background: np.ndarray
    amplitude: np.ndarray

    @property
    def expected(self) -> np.ndarray:
        """(n_clusters,) model ions per cluster: background plus species."""
        return self.background + self.design @ self.amplitude

    def deviance(self, columns: np.ndarray | None = None) -> float:
        """Poisson deviance (G statistic) over all clusters or over the clusters where ``columns`` species peak."""
        rows = slice(None) if columns is None else np.any(self.design[:, columns] > 0, axis=1)
        return poisson_deviance(self.observed[rows], self.expected[rows])


def poisson_deviance(observed: np.ndarray, expected: np.ndarray) -> float:
    """``2 * sum(N log(N / mu) - (N - mu))``, with ``0 log 0 = 0``."""
    mu = np.maximum(expected, 1e-9)
    n = observed
    ratio = np.where(n > 0, n / mu, 1.0)
    return float(2.0 * np.sum(n * np.log(ratio) - (n - mu)))


def clusters(species: list[Species], windows: Windows, spectrum: Spectrum,
             probes: np.ndarray = np.zeros(0)) -> tuple[np.ndarray, ...]:
    """Merged windows of all species' peaks (and of ``probes``, observed peaks no species need explain).

    Returns
    -------
    lo, hi : (c,) float64
        Cluster bounds, ascending, disjoint.
    design : (c, s) float64
        Abundance of species ``s`` in cluster ``c``.
    """
    peaks = [(sp.mz[sp.abundance >= _WINDOW_PEAK]) for sp in species]
    centres = np.concatenate(peaks + [probes])
    lo, hi = windows.bounds(np.sort(centres))
    hi = np.maximum.accumulate(hi)
    start = np.ones(len(lo), dtype=bool)
    start[1:] = lo[1:] > hi[:-1]
    group = np.cumsum(start) - 1
    c_lo = lo[start]
    c_hi = np.zeros(len(c_lo))
    np.maximum.at(c_hi, group, hi)
    c_hi = np.minimum(c_hi, spectrum.max_mz)
    design = np.zeros((len(c_lo), len(species)))
    for s, sp in enumerate(species):
        idx = np.searchsorted(c_lo, sp.mz, side="right") - 1
        inside = (idx >= 0) & (sp.mz <= c_hi[np.clip(idx, 0, None)])
        np.add.at(design[:, s], idx[inside], sp.abundance[inside])
    return c_lo, c_hi, design


def fit(species: list[Species], windows: Windows, spectrum: Spectrum, probes: np.ndarray = np.zeros(0)) -> Fit:
    """Fit non-negative amplitudes of ``species`` to the spectrum in their clusters.

    ``probes`` (Da) add windows around observed peaks, so that counts there that no species
    explains show up as excess.
    """
    lo, hi, design = clusters(species, windows, spectrum, probes)
    observed = spectrum.count(lo, hi)
    background = spectrum.expected_background(lo, hi)
    return Fit(list(species), lo, hi, design, observed, background, _amplitudes(design, observed, background))


def refit_without(result: Fit, exclude: np.ndarray) -> Fit:
    """The same model with amplitudes fitted on all clusters but the ``exclude`` ones.

    Used once no candidate explains the excess left in some clusters: fitted without them, the
    species' amplitudes are no longer pulled up by counts they cannot explain, so the excess
    there is measured against what the clean isotopes predict.
    """
    keep = ~exclude
    amplitude = _amplitudes(result.design[keep], result.observed[keep], result.background[keep])
    return Fit(result.species, result.lo, result.hi, result.design, result.observed, result.background, amplitude)


def _amplitudes(design: np.ndarray, observed: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Non-negative species amplitudes: Poisson-weighted NNLS, refined by Poisson EM."""
    if design.size == 0:  # scipy's nnls corrupts memory on an empty matrix
        return np.zeros(design.shape[1])
    weight = 1.0 / np.sqrt(np.maximum(observed, 1.0))
    amplitude, _ = nnls(design * weight[:, None], (observed - background) * weight)
    usable = design.sum(axis=0)
    for _ in range(_EM_ITERATIONS):  # Poisson EM: keeps zeros at zero, fixes the NNLS low-count bias
        mu = np.maximum(background + design @ amplitude, 1e-9)
        amplitude = amplitude * (design.T @ (observed / mu)) / np.maximum(usable, 1e-12)
    return amplitude


def excess_clusters(result: Fit, z: float, min_counts: float, min_fraction: float) -> np.ndarray:
    """(c,) bool: clusters holding significantly more ions than the model explains."""
    excess = result.observed - result.expected
    net = np.maximum(result.observed - result.background, 0.0)
    return (excess > z * np.sqrt(np.maximum(result.expected, 1.0))) & (excess >= min_counts) & (excess >= min_fraction * net)


@dataclass
class CandidatePool:
    """Candidate species with their peaks padded into (n, k) arrays and the counts in their windows.

    Observed and background counts in every candidate peak window are fixed by the spectrum, so
    they are taken once; screening a candidate is then a one-parameter Poisson fit on arrays.
    """

    species: list[Species]
    abundance: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    observed: np.ndarray
    background: np.ndarray
    major: np.ndarray

    @classmethod
    def build(cls, species: list[Species], windows: Windows, spectrum: Spectrum) -> "CandidatePool":
        k = max((len(sp.mz) for sp in species), default=1)
        mz = np.zeros((len(species), k))
        abundance = np.zeros((len(species), k))
        for i, sp in enumerate(species):
            mz[i, :len(sp.mz)], abundance[i, :len(sp.mz)] = sp.mz, sp.abundance
        lo, hi = windows.bounds(mz)
        major = abundance >= 0.1 * abundance.max(axis=1, keepdims=True)
        return cls(species, abundance, lo, hi, spectrum.count(lo, hi), spectrum.expected_background(lo, hi), major)

    def screen(self, current: Fit, hot: np.ndarray, skip: set, min_counts: float) -> np.ndarray:
        """(n,) approximate deviance gain of adding each candidate to ``current`` (-inf: not eligible).

        A candidate is eligible when a major peak (>= 10 % of its strongest) lies in a ``hot`` cluster
        and it is not in ``skip``. Its amplitude is fitted by Newton steps on the Poisson likelihood
        with the current model's expectation in its windows held fixed.
        """
        idx = np.searchsorted(current.lo[hot], self.lo + (self.hi - self.lo) / 2, side="right") - 1
        centre = (self.lo + self.hi) / 2
        in_hot = (idx >= 0) & (centre <= current.hi[hot][np.clip(idx, 0, None)])
        eligible = np.any(in_hot & self.major, axis=1)
        eligible &= np.array([sp.key not in skip for sp in self.species])
        mu0 = self.background + _species_expectation(current, self.lo, self.hi)
        a, n = self.abundance, self.observed
        amp = np.maximum(((n - mu0) * a).sum(axis=1) / np.maximum((a * a).sum(axis=1), 1e-12), 0.0)
        for _ in range(25):
            mu = np.maximum(mu0 + amp[:, None] * a, 1e-9)
            grad = (n * a / mu).sum(axis=1) - a.sum(axis=1)
            curv = (n * a * a / (mu * mu)).sum(axis=1)
            amp = np.maximum(amp + grad / np.maximum(curv, 1e-12), 0.0)
        gain = _deviance_rows(n, mu0) - _deviance_rows(n, mu0 + amp[:, None] * a)
        eligible &= amp * a.sum(axis=1) >= min_counts
        return np.where(eligible, gain, -np.inf)


def _species_expectation(result: Fit, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Ions the fitted species put into each window ``[lo, hi]`` (any shape)."""
    peak_mz = np.concatenate([sp.mz for sp in result.species]) if result.species else np.zeros(0)
    peak_n = np.concatenate([a * sp.abundance for a, sp in zip(result.amplitude, result.species)]) \
        if result.species else np.zeros(0)
    order = np.argsort(peak_mz)
    cum = np.concatenate([[0.0], np.cumsum(peak_n[order])])
    sorted_mz = peak_mz[order]
    return cum[np.searchsorted(sorted_mz, hi, side="right")] - cum[np.searchsorted(sorted_mz, lo, side="left")]


def _deviance_rows(n: np.ndarray, mu: np.ndarray) -> np.ndarray:
    mu = np.maximum(mu, 1e-9)
    return 2.0 * (n * np.log(np.where(n > 0, n / mu, 1.0)) - (n - mu)).sum(axis=1)


COMMON_IMPURITIES = frozenset({"H", "C", "N", "O"})
"""Elements present in nearly every atom probe spectrum (residual gas, surface contamination)."""


def prior_cost(species: Species, known: set[str], per_atom: float, per_element: float) -> float:
    """Deviance charged to a candidate so that, of equal fits, the plausible one wins.

    ``per_atom`` for each atom beyond the first and each charge beyond the first (simpler ions
    first), ``per_element`` for each element that is neither in ``known`` nor a common impurity
    (so H2O+ wins over Be2+ at 18 Da in a specimen without beryllium).
    """
    atoms = sum(n for _, n in species.composition) - 1 + species.charge - 1
    novel = sum(el not in known and el not in COMMON_IMPURITIES for el, _ in species.composition)
    return per_atom * atoms + per_element * novel


def explain_excess(base: list[Species], pool: CandidatePool, windows: Windows, spectrum: Spectrum,
                   probes: np.ndarray, *,
                   z: float, min_counts: float, min_fraction: float, min_gain: float, max_added: int,
                   shortlist: int = 32, per_atom_cost: float = 10.0,
                   per_element_cost: float = 20.0) -> tuple[Fit, list[Species]]:
    """Greedy forward selection: add the pool species that best explains the remaining excess.

    At each step, the pool is screened (:meth:`CandidatePool.screen`) and the ``shortlist`` best
    candidates are refitted with the whole model, on the cluster set with their own windows added
    (so their other isotopes must fit too). The one with the largest deviance drop, less its
    :func:`prior_cost` (elements of the model so far are known), is kept if that is at least ``min_gain`` and it
    takes at least ``min_counts`` ions. Stops when no cluster holds significant excess, or after
    ``max_added`` species.

    Returns
    -------
    fit : Fit of ``base`` plus the added species (with the ``probes`` windows)
    added : list of Species added, in order
    """
    current = fit(base, windows, spectrum, probes)
    added: list[Species] = []
    skip = {sp.key for sp in base}
    known = {el for sp in base for el, _ in sp.composition}
    for _ in range(max_added):
        hot = excess_clusters(current, z, min_counts, min_fraction)
        if not np.any(hot):
            break
        approx = pool.screen(current, hot, skip, min_counts)
        best: tuple[float, Fit, Species] | None = None
        for i in np.argsort(-approx)[:shortlist]:
            if not np.isfinite(approx[i]):
                break
            cand = pool.species[i]
            trial = fit(current.species + [cand], windows, spectrum, probes)
            before = Fit(current.species, trial.lo, trial.hi, trial.design[:, :-1], trial.observed,
                         trial.background, current.amplitude)
            score = before.deviance() - trial.deviance() - prior_cost(cand, known, per_atom_cost, per_element_cost)
            if trial.amplitude[-1] * cand.abundance.sum() >= min_counts and (best is None or score > best[0]):
                best = (score, trial, cand)
        if best is None or best[0] < min_gain:
            break
        _, current, chosen = best
        added.append(chosen)
        skip.add(chosen.key)
        known |= {el for el, _ in chosen.composition}
    return current, added
