"""The interface's width fitted from its proxigram, and the plateau windows and proxigram range it sets.

The iso species' profile across the surface is fitted with an error-function step (a sharp interface
blurred by a Gaussian: the reconstruction's blur, the surface's own roughness and the interface's
chemical width together), allowed a different width on each side because real interfaces are often
steeper on one (the step is the cumulative F of a split normal: half-Gaussians of widths σ_out and
σ_in joined at its mode),

    c(s) = c_out + (c_in - c_out) F(s),

by maximum likelihood with binomial counts per bin (least squares on deviance residuals; s: signed
distance, positive inside). Reported: the 10–90 % width F⁻¹(0.9) - F⁻¹(0.1) (2.563 σ for a symmetric
step) and the plateaus, with errors from the fit's covariance, scaled by the reduced chi-square where
it exceeds 1 (a real interface varies along itself beyond counting noise); and the interface position,
the 50 %-of-the-way point between the fitted plateaus, where a monotone fit of the profile crosses the
midpoint level (:func:`midpoint`: a model-free crossing, because a real step is not exactly a split
normal and a misfit model would move its 50 % point), with its error over Poisson redraws. Each solute's
profile is then fitted with the same step plus a Gaussian peak (a segregation shell), centre s1 and
width τ, kept where its amplitude stands 3 standard errors above zero.

From the fits, the windows (:func:`plateau_windows`):

- ``inner``: the distance from the surface beyond which every profile is on its plateau, i.e. less than
  ``tail`` (0.5 %) of the step and of each significant peak lies further out: ``-F⁻¹(tail)``,
  ``F⁻¹(1 - tail)`` and ``|s1| + z τ`` with z = Φ⁻¹(1 - t) (for a symmetric step about one 10–90 % width
  beyond its centre), t = tail (2.58) or, for a peak holding N ions, :data:`TAIL_SIGMAS` / sqrt(N) where
  smaller (a rich shell's tail left in the windows would bias its excess by more than its counting error).
  Nearer, the plateau windows count the interface as plateau and the excess comes out low (the real Si Cr/Si
  interface, 10–90 % 4.3 nm, against fixed 1–3 nm windows: C excess 0.35 detected atoms/nm², half of what a 1D
  profile through a central cylinder gives);
  further, the integration collects counting noise from plateau ions for nothing.
- ``outer = 3 inner``: the plateau windows are twice as long as the integrated half-width, so the
  fitted levels' error adds at most half the counting variance of the integrated ions (flat plateaus:
  variance ratio inner / (outer - inner)).

The proxigram's range is ``outer``. :func:`fitted_proxigram` computes a first proxigram over
``FIRST_RANGE`` nm, fits, and widens it until it covers the windows the fits ask for.

References: Hellman et al., Microsc. Microanal. 6 (2000) 437, doi:10.1007/s100050010051 (proxigram);
Krakauer & Seidman, Phys. Rev. B 48 (1993) 6724, doi:10.1103/PhysRevB.48.6724 (excess); Ayer et al.,
Ann. Math. Statist. 26 (1955) 641, doi:10.1214/aoms/1177728423 (pool adjacent violators, the monotone fit
of :func:`midpoint`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from apt_filters.analysis.proxigram import Proxigram, compute_proxigram
from apt_filters.core.errors import AptFiltersError

TAIL = 0.005
"""Fraction of a step's or a peak's integral allowed beyond the inner edge of the plateau windows."""

OUTER_FACTOR = 3.0
"""outer / inner edge of the plateau windows (see the module doc)."""

FIRST_RANGE = 3.0
"""Half range (nm) of the first proxigram the width is fitted on; widened as the fits ask."""

MAX_RANGE = 50.0
"""Half range (nm) the proxigram is never widened beyond (no APT interface is wider than ~15 nm)."""

PEAK_SIGMAS = 3.0
"""A solute's peak is kept when its amplitude stands this many standard errors above zero."""

DEPTH_QUANTILE = 0.9
"""An object's depth (:func:`inside_windows`) is the distance from its surface within which this fraction of its
inside atoms lie: its deepest ions but for the few a bump of the surface or the reconstruction's blur put
deeper than the object reaches (which would make a thin object look thick from one stray ion)."""

TAIL_SIGMAS = 0.1
"""A peak's expected count beyond the inner edge of the plateau windows, each side, is at most this many of
its counting sigma (the square root of its count), where that is less than ``tail`` of it: the excess such
a tail leaves in the plateau windows (a loss, about doubled where the fitted levels extrapolate its slope
to the surface) stays a small part of the excess's counting sigma however many ions the peak holds."""


@dataclass
class ProfileFit:
    """A profile's fitted step (and peak) across the surface.

    Attributes
    ----------
    species : str
        Element or ion species of the profile.
    centre, centre_error : float
        Distance (nm, positive inside) from the surface of the step's 50 %-of-the-way point, and its error.
    width, width_error : float
        10–90 % width of the step, nm.
    mode : float
        Where the step is steepest, nm.
    sigma_outside, sigma_inside : float
        Gaussian widths of the step's two halves, nm (outside / inside its mode).
    outside, inside, outside_error, inside_error : float
        Fitted plateau fractions far outside / inside, and their errors.
    peak, peak_error, peak_centre, peak_sigma : float
        Amplitude (fraction), position and width (nm) of a Gaussian peak on the step (NaN when the
        profile was fitted with a step only, 0 amplitude when no peak was significant).
    peak_shape_cov : ((float, float), (float, float))
        Covariance of ``(peak_centre, peak_sigma)``, nm² (empty when fitted with a step only).
    chi2_dof : float
        Reduced chi-square of the fit (errors are scaled by its root where above 1).
    reach : float
        Distance (nm) from the surface beyond which less than ``tail`` of the step (and of a
        significant peak, less than ``tail`` and than :data:`TAIL_SIGMAS` / sqrt(its count)) lies,
        on either side.
    """

    species: str
    centre: float
    centre_error: float
    width: float
    width_error: float
    mode: float
    sigma_outside: float
    sigma_inside: float
    outside: float
    inside: float
    outside_error: float
    inside_error: float
    peak: float = math.nan
    peak_error: float = math.nan
    peak_centre: float = math.nan
    peak_sigma: float = math.nan
    chi2_dof: float = math.nan
    reach: float = math.nan
    peak_shape_cov: tuple = ()

    def reached(self, s: float) -> float:
        """Share (0-1) of the step from the outside plateau to the inside one reached at ``s`` nm from the
        surface (positive inside), by the fitted split-normal shape."""
        return float(_split_cdf(s, self.mode, self.sigma_outside, self.sigma_inside))

    def step_share(self, s: np.ndarray) -> np.ndarray:
        """:meth:`reached` at each of the distances ``s`` (nm, positive inside)."""
        return _split_cdf(np.asarray(s, dtype=np.float64), self.mode, self.sigma_outside, self.sigma_inside)

    def as_dict(self) -> dict:
        return asdict(self)


def _split_cdf(s, mode, sigma_out, sigma_in):
    """Cumulative of the split normal (two half-Gaussians of widths ``sigma_out`` below and ``sigma_in``
    above ``mode``, joined continuously): the shape of an asymmetric blurred step."""
    w_out = 2 * sigma_out / (sigma_out + sigma_in)
    return np.where(s < mode, w_out * _phi((s - mode) / sigma_out),
                    1 - (2 - w_out) * (1 - _phi((s - mode) / sigma_in)))


def _split_quantile(q, mode, sigma_out, sigma_in):
    """Where :func:`_split_cdf` reaches ``q`` (0 < q < 1)."""
    from scipy.special import ndtri

    w_out = 2 * sigma_out / (sigma_out + sigma_in)
    below = q < 0.5 * w_out
    return np.where(below, mode + sigma_out * ndtri(np.minimum(q / w_out, 1 - 1e-16)),
                    mode + sigma_in * ndtri(np.maximum(1 - (1 - q) / (2 - w_out), 1e-16)))


@dataclass
class Windows:
    """Plateau windows ``inner <= |s| <= outer`` nm (also the proxigram's range) and where they came from.

    Attributes
    ----------
    inner, outer : float
        nm from the surface, each side.
    source : str
        ``"fitted"`` (both from the fits), ``"given"`` (both set by the user), ``"inner given"``,
        ``"outer given"``, or ``"fallback"`` (no step could be fitted: 1 and 3 nm).
    step : ProfileFit or None
        Fit of the iso species' step (the interface width and position).
    peaks : list of ProfileFit
        Fits of the solutes' profiles (step + peak).
    note : str
        Why a fallback was taken, or empty.
    """

    inner: float
    outer: float
    source: str
    step: ProfileFit | None = None
    peaks: list[ProfileFit] = field(default_factory=list)
    note: str = ""

    def fit_of(self, solute: str) -> ProfileFit | None:
        """The solute's fit on the surface's pooled profile, whose shapes give the levels of objects too thin for
        their own windows (:func:`apt_filters.analysis.excess.own_levels`); None if not fitted."""
        return next((p for p in self.peaks if p.species == solute), None)

    def describe(self) -> str:
        """One line: the windows, and the width and position they came from."""
        words = f"plateau windows {self.inner:.3g}-{self.outer:.3g} nm ({self.source}"
        if self.step is not None:
            s = self.step
            words += (f"; {s.species} 10-90 % width {s.width:.3g} ± {s.width_error:.2g} nm, "
                      f"centre {s.centre:+.3g} ± {s.centre_error:.2g} nm")
        return words + (f"; {self.note})" if self.note else ")")

    def as_dict(self) -> dict:
        return {"inner_nm": self.inner, "outer_nm": self.outer, "source": self.source, "note": self.note,
                "step": self.step.as_dict() if self.step else None, "peaks": [p.as_dict() for p in self.peaks]}


def _phi(x):
    from scipy.special import ndtr

    return ndtr(x)


def _isotonic(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least-squares non-decreasing fit of ``y`` (pool adjacent violators)."""
    values, weights, sizes = [], [], []
    for yi, wi in zip(y, w):
        values.append(yi)
        weights.append(wi)
        sizes.append(1)
        while len(values) > 1 and values[-2] > values[-1]:
            wsum = weights[-2] + weights[-1]
            values[-2] = (values[-2] * weights[-2] + values[-1] * weights[-1]) / wsum
            weights[-2], sizes[-2] = wsum, sizes[-2] + sizes[-1]
            del values[-1], weights[-1], sizes[-1]
    return np.repeat(values, sizes)


def midpoint(*, s: np.ndarray, n: np.ndarray, total: np.ndarray, outside: float, inside: float,
             draws: int = 100, seed: int = 0) -> tuple[float, float]:
    """Where a step profile is 50 % of the way from ``outside`` to ``inside``, and its counting error.

    The profile's fractions are fitted with a monotone step function (weighted isotonic regression,
    decreasing when ``inside < outside``), which follows any shape of step; its crossing of the midpoint
    level is interpolated between bin centres. The error is the spread of that crossing over ``draws``
    Poisson redraws of the counts.

    Parameters
    ----------
    s : (b,) float
        Bin centres, nm.
    n, total : (b,) int
        Counts of the species and of all ions (atoms) per bin.
    outside, inside : float
        Plateau fractions on the negative and positive side.

    Returns
    -------
    position, error : float
        nm; NaN when the profile never crosses the midpoint.
    """
    used = np.asarray(total) > 0
    s, n, total = (np.asarray(x, dtype=np.float64)[used] for x in (s, n, total))
    sign = 1.0 if inside >= outside else -1.0
    mid = 0.5 * (inside + outside)

    def crossing(n_, total_):
        ok = total_ > 0
        f = _isotonic(sign * n_[ok] / total_[ok], total_[ok]) - sign * mid  # rising through 0
        x = s[ok]
        k = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0))
        if len(k) == 0:
            return np.nan
        k = k[np.argmin(np.abs(x[k]))]
        return x[k] - f[k] * (x[k + 1] - x[k]) / (f[k + 1] - f[k]) if f[k + 1] != f[k] else x[k]

    position = crossing(n, total)
    rng = np.random.default_rng(seed)
    redrawn = []
    for _ in range(draws):
        m = rng.poisson(n)
        redrawn.append(crossing(m, m + rng.poisson(total - n)))
    return float(position), float(np.nanstd(redrawn, ddof=1))


def fit_profile(*, s: np.ndarray, n: np.ndarray, total: np.ndarray, species: str = "",
                step: ProfileFit | None = None, tail: float = TAIL) -> ProfileFit:
    """Fit a fraction profile with an asymmetric error-function step, or with ``step``'s step plus a peak.

    The step is the cumulative of a split normal: ``c(s) = c_out + (c_in - c_out) F(s)``, F rising with
    width ``sigma_outside`` below its mode and ``sigma_inside`` above it (real interfaces are often
    steeper on one side; a symmetric fit would put the 50 % point off the profile's own crossing).

    Parameters
    ----------
    s : (b,) float
        Bin centres, nm (positive inside).
    n, total : (b,) int
        Counts of the species and of all ions (atoms) per bin.
    species : str
        Name recorded in the result.
    step : ProfileFit, optional
        A fitted step (the iso species'): its shape is kept and the plateaus and a Gaussian peak's
        amplitude, centre and width are fitted (a solute's profile). Without it, the step's plateaus,
        mode and two widths are fitted.
    tail : float
        Fraction of the step's (peak's) integral beyond the returned ``reach``; a peak's at most
        :data:`TAIL_SIGMAS` / sqrt(its expected count).

    Returns
    -------
    ProfileFit
        Maximum-likelihood fit (binomial counts per bin); errors from its covariance (scaled by the
        reduced chi-square where above 1), carried to the 10–90 % width by its numerical gradient; the
        50 % point from :func:`midpoint`.

    Raises
    ------
    AptFiltersError
        Fewer than 8 bins hold ions, or the fit does not converge.
    """
    from scipy.optimize import least_squares
    from scipy.special import ndtri, xlogy

    used = np.asarray(total) > 0
    s, n, total = (np.asarray(x, dtype=np.float64)[used] for x in (s, n, total))
    if len(s) < 8:
        raise AptFiltersError(f"{species or 'the'} profile has ions in {len(s)} bins: too few for a width")
    frac = n / total
    edge = max(2, len(s) // 6)
    lo, hi = frac[:edge].mean(), frac[-edge:].mean()
    span = float(s[-1] - s[0])

    def solve(model, starts, bounds):  # the maximum-likelihood parameters, their covariance and chi-square/dof
        def deviance(p):  # binomial deviance residuals: their sum of squares is -2 log-likelihood + const
            m = np.clip(model(p), 1e-12, 1 - 1e-12)
            d = 2 * (xlogy(n, frac / m) + xlogy(total - n, (1 - frac) / (1 - m)))
            return np.sign(frac - m) * np.sqrt(np.maximum(d, 0.0))

        fits = [least_squares(deviance, p0, bounds=bounds, x_scale="jac", max_nfev=5000) for p0 in starts]
        fit = min(fits, key=lambda f: (not f.success, f.cost))  # the maximum likelihood of those that converged
        if not fit.success:
            raise AptFiltersError(f"the {species} profile's step fit did not converge ({fit.message})")
        chi2 = float(np.sum(fit.fun ** 2) / max(len(s) - len(fit.x), 1))
        try:
            return fit.x, np.linalg.inv(fit.jac.T @ fit.jac) * max(chi2, 1.0), chi2
        except np.linalg.LinAlgError:
            return fit.x, np.full((len(fit.x), len(fit.x)), np.nan), chi2

    if step is None:
        p, cov, chi2 = solve(lambda p: p[0] + (p[1] - p[0]) * _split_cdf(s, p[2], p[3], p[4]),
                             [[lo, hi, 0.0, max(0.1 * span, 0.2), max(0.1 * span, 0.2)]],
                             ([-1, -1, s[0], 1e-3, 1e-3], [2, 2, s[-1], 2 * span, 2 * span]))
    else:
        shape = _split_cdf(s, step.mode, step.sigma_outside, step.sigma_inside)
        # two starts: the deeper bins' mean as the inside plateau, the peak at the bin of the largest fraction
        # above it; and no step, the peak at the bin of the most ions above the outside plateau. Where every
        # object is thin its deeper bins lie in the peak's tail and hold few ions: from the first start alone
        # the fit ended in a step to 0.56 with no peak (thin 10131's B: deviance 196 against 66 from the second)
        near = np.abs(s - step.centre) < step.width + 1.0
        residual0 = frac - (lo + (hi - lo) * shape)
        k = int(np.argmax(residual0 * near))
        m = int(np.argmax((frac - lo) * total * near))
        p, cov, chi2 = solve(lambda p: p[0] + (p[1] - p[0]) * shape + p[2] * np.exp(-0.5 * ((s - p[3]) / p[4]) ** 2),
                             [[lo, hi, max(residual0[k], 1e-6), s[k], max(0.25 * step.width, 0.1)],
                              [lo, lo, max(frac[m] - lo, 1e-6), s[m], max(0.25 * step.width, 0.1)]],
                             ([-1, -1, -1, s[0], 0.02], [2, 2, 2, s[-1], span]))
    if step is not None:
        err = np.sqrt(np.maximum(np.diag(cov), 0.0))
        significant = p[2] > PEAK_SIGMAS * err[2]
        held = p[2] * float(np.sum(total * np.exp(-0.5 * ((s - p[3]) / p[4]) ** 2)))  # the peak's expected count
        z = float(ndtri(1.0 - min(tail, TAIL_SIGMAS / np.sqrt(max(held, 1.0)))))
        reach = max(step.reach, float(abs(p[3]) + z * p[4])) if significant else step.reach
        return replace(step, species=species, outside=float(p[0]), inside=float(p[1]), outside_error=float(err[0]),
                       inside_error=float(err[1]),
                       peak=float(p[2]) if significant else 0.0, peak_error=float(err[2]), peak_centre=float(p[3]),
                       peak_sigma=float(p[4]), chi2_dof=chi2, reach=reach,
                       peak_shape_cov=tuple(map(tuple, cov[3:, 3:].tolist())))

    def figures(q):  # 10-90 % width and reach from (mode, sigma_out, sigma_in)
        at = _split_quantile(np.array([0.1, 0.9, tail, 1 - tail]), *q)
        return np.array([at[1] - at[0], max(-at[2], at[3], 0.0)])

    def width_of(p, cov):  # the figures and their variances
        grad = np.stack([(figures(p[2:] + h) - figures(p[2:] - h)) / (2 * 1e-6)
                         for h in 1e-6 * np.eye(3)], axis=1)  # (2 figures, 3 shape parameters)
        return figures(p[2:]), np.einsum("ij,jk,ik->i", grad, cov[2:, 2:], grad)

    value, var = width_of(p, cov)
    if not np.sqrt(var[0]) < value[0]:
        # the profile does not tell the two widths apart (a cut object's cap, less than a step deep inside: one
        # side's width ran to 6.6 nm and its plateau to 2, the width 10.6 ± 2700 nm, for the same likelihood as
        # one width's 2.1 ± 0.6 nm): one width for both sides
        q, c4, chi2 = solve(lambda q: q[0] + (q[1] - q[0]) * _split_cdf(s, q[2], q[3], q[3]),
                            [[lo, hi, 0.0, max(0.1 * span, 0.2)]], ([-1, -1, s[0], 1e-3], [2, 2, s[-1], 2 * span]))
        tie = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0, 0, 1]], dtype=np.float64)
        p, cov = tie @ q, tie @ c4 @ tie.T
        value, var = width_of(p, cov)
    centre, centre_error = midpoint(s=s, n=n, total=total, outside=float(p[0]), inside=float(p[1]))
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return ProfileFit(species, centre, centre_error, float(value[0]), float(np.sqrt(max(var[0], 0.0))),
                      float(p[2]), float(p[3]), float(p[4]), float(p[0]), float(p[1]), float(err[0]),
                      float(err[1]), chi2_dof=chi2, reach=float(value[1]))


def plateau_windows(*, proxigram: Proxigram, species: str, solutes: list[str] = (), tail: float = TAIL,
                    inner: float | None = None, outer: float | None = None) -> Windows:
    """Plateau windows from the interface width fitted on ``proxigram``'s pooled profile.

    Parameters
    ----------
    proxigram : Proxigram
        Profiles across the surface (pooled over its objects for the fits).
    species : str
        The iso species (element or ion) whose step gives the interface width and position; empty (an
        iso-density surface, or a proxigram of a mesh alone) falls back to 1 and 3 nm, said in ``note``.
    solutes : list of str
        Species whose peaks (segregation shells) must lie inside the inner edge as well.
    tail : float
        See :data:`TAIL`.
    inner, outer : float, optional
        Given edges (nm) kept as they are; a missing one follows from the fits (``outer`` =
        :data:`OUTER_FACTOR` × ``inner``, ``inner`` = ``outer`` / :data:`OUTER_FACTOR` when only
        ``outer`` is given and no step can be fitted).

    Returns
    -------
    Windows
        ``inner`` and ``outer`` rounded up to whole bins of the proxigram.
    """
    pooled = proxigram if len(proxigram.object_ids) == 1 else proxigram.pooled()
    s = pooled.centers
    step, peaks, note = None, [], ""
    if species:
        try:
            n, total = pooled.counts_of(species)
            step = fit_profile(s=s, n=n[0], total=total[0], species=species, tail=tail)
            for solute in solutes:
                n, total = pooled.counts_of(solute)
                try:
                    peaks.append(fit_profile(s=s, n=n[0], total=total[0], species=solute, step=step, tail=tail))
                except AptFiltersError:
                    continue  # a solute too rare for a profile fit sets no window
        except AptFiltersError as exc:
            note = str(exc)
    else:
        note = "no species named whose step could be fitted"
    bin_width = float(proxigram.edges[1] - proxigram.edges[0])

    def whole_bins(x):
        return round(bin_width * math.ceil(x / bin_width - 1e-9), 9)

    if inner is not None and outer is not None:
        return Windows(inner, outer, "given", step, peaks, note)
    if step is None or not np.isfinite(step.reach) or step.reach <= 0:
        fitted, source = None, "fallback"
        note = note or "no step fitted"
    else:
        fitted, source = max([step.reach] + [p.reach for p in peaks if np.isfinite(p.reach)]), "fitted"
    if inner is not None:
        return Windows(inner, whole_bins(OUTER_FACTOR * inner), "inner given", step, peaks, note)
    if fitted is None:
        fitted = 1.0 if outer is None else outer / OUTER_FACTOR
    fitted = whole_bins(max(fitted, bin_width))
    if outer is not None:
        if fitted >= outer:  # the user's range is kept; the windows are cut, and say so
            note = (f"the fitted width asks for windows from {fitted:g} nm, beyond the given range {outer:g} nm: "
                    f"from {outer / OUTER_FACTOR:.3g} nm, the excess may come out low")
            fitted = whole_bins(outer / OUTER_FACTOR)
        return Windows(fitted, outer, "outer given", step, peaks, note)
    return Windows(fitted, whole_bins(OUTER_FACTOR * fitted), source, step, peaks, note)


def inside_windows(*, depth: np.ndarray, atoms: np.ndarray, inner: float,
                   quantile: float = DEPTH_QUANTILE) -> np.ndarray:
    """Where each object's inside plateau window starts: ``inner``, or half the object's own depth where that is
    nearer.

    The plateau windows' ``inner`` comes from the interface width fitted on all objects pooled. An object whose
    half-thickness is not twice that (a plate 2 nm thick, a rod of 1.5 nm radius, a small sphere under a wide
    interface) holds few or none of its own ions ``inner`` deep: its window would be empty, or hold only the
    ions a bump of the surface put deeper, and say nothing of the object. Its depth ``D`` is read off its own
    inside ions (the ``quantile`` of their distances from its surface, :data:`DEPTH_QUANTILE`: the
    distribution of depths is what the object's local thickness leaves, whatever its shape) and its window
    starts at ``min(inner, D / 2)``, its deeper half, the part least mixed with its interface (the principle
    of :func:`apt_filters.refine.levels.inside_inner`). The rule reads depths only, never a shape: an object
    whose ions reach ``2 inner`` deep keeps ``inner``; that includes an open interface or a bicontinuous
    phase, whose inside ions fill the range on that side wherever its ligaments are thick, and a fragment
    of one with few ions moves the pooled figure by as little as it holds. For a uniform slab of half-thickness
    ``h`` the window starts at ``0.45 h`` and holds 55 % of its atoms; a rod of radius ``R``: ``0.34 R``, 44 %;
    a sphere: ``0.27 R``, 39 %. The plateau may not be reached there: the report gives the share of the fitted
    step reached where each such window starts (:meth:`ProfileFit.reached`) and names the objects whose
    unreached share may bias the window beyond its counting error; it is what the object's own ions hold at
    its centre.

    Parameters
    ----------
    depth : (b,) float
        Distance from the surface, nm, positive inside (a proxigram's bin centres, or each ion's distance).
    atoms : (k, b) or (b,) float
        Atoms of each of ``k`` objects at each ``depth`` (a proxigram's per-object atom counts summed over
        species, cropped at ``outer``: depths beyond the window's outer edge are not the object's to count).
    inner : float
        The plateau windows' inner edge, nm.
    quantile : float
        See :data:`DEPTH_QUANTILE`.

    Returns
    -------
    (k,) float
        nm per object; a window holds the depths at or beyond it. An object with no atom inside gets 0.
    """
    depth = np.asarray(depth, dtype=np.float64)
    atoms = np.atleast_2d(np.asarray(atoms, dtype=np.float64))
    inside = depth > 0
    order = np.argsort(depth[inside], kind="stable")
    d = depth[inside][order]
    held = np.cumsum(atoms[:, inside][:, order], axis=1)  # (k, inside depths), rising
    starts = np.zeros(len(atoms))
    for k, c in enumerate(held):
        if len(c) and c[-1] > 0:
            starts[k] = min(inner, 0.5 * d[np.searchsorted(c, quantile * c[-1])])
    return starts


def inside_starts(*, proxigram: Proxigram, inner: float, outer: float) -> np.ndarray:
    """(k,) nm: where each of ``proxigram``'s objects' inside window starts, :func:`inside_windows` of its atoms
    (all elements) within ``outer``: the one window both its inside plateau and its excess's inside level are
    counted in."""
    s = proxigram.centers
    atoms = proxigram.species_counts("element").sum(axis=2) * (s <= outer)
    return inside_windows(depth=s, atoms=atoms, inner=inner)


def first_range(*, inner: float | None = None, outer: float | None = None) -> float:
    """Half range (nm) of the first proxigram :func:`fitted_proxigram` computes: the given ``outer``, else
    :data:`OUTER_FACTOR` × a given ``inner``, else :data:`FIRST_RANGE`."""
    return outer if outer is not None else (OUTER_FACTOR * inner if inner is not None else FIRST_RANGE)


def fitted_proxigram(*, ions, ranges, mesh, species: str, solutes: list[str] = (), bin_width: float = 0.1,
                     inner: float | None = None, outer: float | None = None, keep_edge: bool = False,
                     iso_value: float | None = None, tail: float = TAIL, covered: float = math.inf,
                     select=None, measured=None) -> tuple[Proxigram, Windows]:
    """The proxigram over the range the interface's fitted width asks for, and its plateau windows.

    A first proxigram over ``outer`` (if given) or :data:`FIRST_RANGE` nm is fitted
    (:func:`plateau_windows`); while the windows reach beyond it, it is computed again over the
    windows' outer edge (at most :data:`MAX_RANGE` nm, four passes), then cut to that edge. Windows
    still beyond the last range are cut to it (``inner`` a third of it) and say so in ``note``.

    Parameters
    ----------
    ions, ranges, mesh, bin_width, keep_edge, iso_value
        As :func:`apt_filters.analysis.proxigram.compute_proxigram`.
    species, solutes, tail, inner, outer
        As :func:`plateau_windows`.
    covered : float
        ``ions`` hold every ion within this distance (nm) of ``mesh`` (a selection such as
        :func:`apt_filters.pipeline.surface.analysis_ions` makes; infinite: the whole table).
    select : callable, optional
        ``select(reach) -> (ions, measured)`` within ``reach`` nm, called when a wider proxigram than ``covered``
        is needed (the caller keeps what it returns for its later analyses).
    measured : core.nearby.NearSurface, optional
        The signed distances of ``ions`` to ``mesh``, exact within ``covered`` (``select``'s ``measured`` the
        same; None: measured here), as :func:`~apt_filters.analysis.proxigram.compute_proxigram` takes them.

    Returns
    -------
    proxigram : Proxigram
        Over ``[-windows.outer, windows.outer)``.
    windows : Windows
    """
    extent = round(bin_width * math.ceil(first_range(inner=inner, outer=outer) / bin_width - 1e-9), 9)
    for _ in range(4):
        if extent > covered:
            if select is None:
                raise AptFiltersError(f"the ions cover {covered:g} nm of the surface; the proxigram needs {extent:g}")
            (ions, measured), covered = select(extent), extent
        prox = compute_proxigram(ions, ranges, mesh, bin_width=bin_width, max_distance=extent, keep_edge=keep_edge,
                                 iso_value=iso_value, measured=measured)
        windows = plateau_windows(proxigram=prox, species=species, solutes=solutes, tail=tail, inner=inner,
                                  outer=outer)
        if windows.outer <= extent + 1e-9:
            return prox.crop(windows.outer), windows
        if extent >= MAX_RANGE:
            break
        extent = min(windows.outer, MAX_RANGE)
    windows.note = (f"the fits ask for windows to {windows.outer:g} nm, beyond the {extent:g} nm computed: "
                    f"cut to it, the excess may come out low")
    windows.outer = extent
    windows.inner = min(windows.inner, round(extent / OUTER_FACTOR, 9))
    return prox, windows


__all__ = ["DEPTH_QUANTILE", "FIRST_RANGE", "MAX_RANGE", "OUTER_FACTOR", "ProfileFit", "TAIL", "TAIL_SIGMAS", "Windows",
           "first_range", "fit_profile", "fitted_proxigram", "inside_starts", "inside_windows", "midpoint",
           "plateau_windows"]
