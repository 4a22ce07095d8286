"""Gibbsian interfacial excess of a solute from a proxigram.

Two estimates from the same counts:

- integration of the proxigram: ``sum_i (n_i - c_ref(s_i) N_i)`` over the bins between the two
  plateau windows, where ``c_ref`` is the matrix level on the negative side and the precipitate
  level on the positive side (the Gibbs dividing surface is the iso-surface, s = 0);
- Krakauer & Seidman's cumulative method (1993): cumulative solute against cumulative total
  ions; straight lines fitted over the windows are extrapolated to the interface, and the
  excess is their vertical offset there (a parabola where the window's level has a significant
  gradient, which bends the cumulative curve).

Plateau levels come from straight-line fits ``c(s) = a + b s`` over windows away from the
interface (``inner <= |s| <= outer``), weighted by the ions per bin, with binomial errors; a
slope that is not significant (below 2 standard errors) falls back to the window's mean, because
extrapolating a noise slope to the interface only adds noise (on a 4 nm sphere it moved Γ by 15%).

The excess is divided by the object's own surface area: Γ in detected ions (or decomposed atoms)
per nm², and in atoms per nm² after dividing by the detection efficiency. The pooled figure
divides the summed excess of all objects by their summed area (so it is the area-weighted mean
of the per-object Γ). AP Suite's interfacial-excess extension divides by the *mean* object area
instead: applied to the excess count of a pooled (summed) proxigram that gives n_objects times
our figure; applied to the mean count per object it gives mean excess / mean area, which equals
ours. Ours states the summed area it used, so the two can always be told apart.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from apt_filters.analysis.proxigram import POOLED, Proxigram
from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_write_text
from apt_filters.core.errors import AptFiltersError

INSTRUMENT_EFFICIENCY = {
    "LEAP 5000S": 0.80,
    "LEAP 5000R": 0.52,
    "LEAP 6000": 0.52,
    "Invizio": 0.624,
    "EIKOS": 0.3575,
}
"""Detection efficiency of common atom probes (fraction of evaporated atoms detected)."""


@dataclass
class Level:
    """A plateau level at the interface (fit extrapolated to s = 0) with its standard error."""

    value: float
    error: float
    slope: float
    n_ions: int


@dataclass
class ExcessEstimate:
    """One excess estimate: solute count in excess and Γ, each with its standard error."""

    count: float
    count_error: float
    gamma_detected: float
    gamma_detected_error: float
    gamma_atoms: float
    gamma_atoms_error: float


@dataclass
class Excess:
    """Interfacial excess of one solute across one object (or pooled over all).

    Attributes
    ----------
    solute : str
        Element (decomposed atoms over all atoms) or ion species (ions over ranged ions).
    object_id : int
        Object, or ``POOLED`` (-1).
    area : float
        Surface area divided by, nm² (the summed area when pooled).
    efficiency : float
        Detection efficiency used for ``gamma_atoms``.
    matrix, precipitate : Level
        Plateau fractions on the negative (outside) and positive (inside) side.
    integration, cumulative : ExcessEstimate
        Proxigram integration and Krakauer–Seidman estimates. ``gamma_detected`` is per nm² in
        detected ions (atoms for an element), ``gamma_atoms`` that divided by the efficiency.
    window_nm : (float, float)
        ``(inner, outer)`` |distance| of the plateau windows.
    """

    solute: str
    object_id: int
    area: float
    efficiency: float
    matrix: Level
    precipitate: Level
    integration: ExcessEstimate
    cumulative: ExcessEstimate
    window_nm: tuple[float, float]


def levels_from_moments(w0, w1, w2, m0, m1, slope_sigmas=2.0, fraction=None) -> tuple[np.ndarray, ...]:
    """Weighted straight-line fits ``c(s) = a + b s`` from the moments of binned counts, vectorised.

    Parameters
    ----------
    w0, w1, w2 : array_like (...)
        Sums over the window's bins of ``N``, ``N s`` and ``N s²`` (N: ions (atoms) per bin,
        s: bin centre, nm).
    m0, m1 : array_like (...)
        Sums of ``n`` and ``n s`` (n: the species' counts per bin).
    slope_sigmas : float or array_like (...)
        A slope below this many standard errors is not significant and the level is the
        window's mean fraction instead (0: always keep the line; inf: never).
    fraction : array_like (...), optional
        The fraction whose binomial variance the covariance uses (default: the window's own
        mean fraction). A small window's own count of a trace element makes its error small
        exactly where its count fluctuated low (none: an error of 0); a fraction known from
        more ions (e.g. the whole interface's plateau) does not.

    Returns
    -------
    value, slope, cov00, cov01, cov11 : (...) float64
        Level at s = 0, slope (0 where not significant) and the covariance of (a, b) under
        binomial counting (variance c (1 - c) / N per bin, c ``fraction`` or the window's mean
        fraction); NaN where the window holds no ions. One bin (or a singular design) gives a
        constant level.
    """
    w0, w1, w2, m0, m1 = (np.asarray(x, dtype=np.float64) for x in (w0, w1, w2, m0, m1))
    with np.errstate(invalid="ignore", divide="ignore"):
        c = m0 / w0
        var = c * (1 - c) if fraction is None else np.asarray(fraction) * (1 - np.asarray(fraction))
        det = w0 * w2 - w1 ** 2
        # the design's condition number, from the eigenvalues of the 2 x 2 normal matrix
        half_trace = 0.5 * (w0 + w2)
        root = np.sqrt(np.maximum(half_trace ** 2 - det, 0.0))
        line = (half_trace - root) * 1e12 > half_trace + root
        a = (w2 * m0 - w1 * m1) / det
        b = (w0 * m1 - w1 * m0) / det
        cov00, cov01, cov11 = var * w2 / det, -var * w1 / det, var * w0 / det
        # no significant gradient: extrapolating a noise slope to s = 0 would only add noise
        line &= np.abs(b) >= slope_sigmas * np.sqrt(cov11)
        return (np.where(line, a, c), np.where(line, b, 0.0), np.where(line, cov00, var / w0),
                np.where(line, cov01, 0.0), np.where(line, cov11, 0.0))


def fit_level(s: np.ndarray, n: np.ndarray, total: np.ndarray,
              slope_sigmas: float = 2.0) -> tuple[Level, np.ndarray]:
    """Weighted straight-line fit of the fraction ``n / total`` against distance ``s`` (bins).

    Weights are the ions per bin (binomial variance c(1 - c)/N with c nearly constant over a
    plateau). A slope smaller than ``slope_sigmas`` standard errors is not significant and the
    level is the window's mean fraction instead (set 0 to always keep the line); see
    :func:`levels_from_moments`. Returns the level at s = 0 and the (2, 2) covariance of (a, b).
    """
    used = total > 0
    s, n, total = s[used], n[used].astype(np.float64), total[used].astype(np.float64)
    if total.sum() == 0:
        raise AptFiltersError("no ions in a plateau window: widen the range or the windows")
    value, slope, c00, c01, c11 = levels_from_moments(total.sum(), (total * s).sum(), (total * s * s).sum(),
                                                      n.sum(), (n * s).sum(), slope_sigmas)
    cov = np.array([[c00, c01], [c01, c11]])
    return Level(float(value), float(np.sqrt(c00)), float(slope), int(total.sum())), cov


def reference_counts(total, total_s, value, slope, cov00, cov01, cov11) -> tuple[np.ndarray, np.ndarray]:
    """Solute counts a fitted level predicts for ``total`` ions (with ``total_s`` = sum of N s) on
    its side of the interface, and the variance of that prediction from the level's covariance."""
    ref = total * value + total_s * slope
    return ref, total ** 2 * cov00 + 2 * total * total_s * cov01 + total_s ** 2 * cov11


def own_levels(s: np.ndarray, n: np.ndarray, total: np.ndarray, fit) -> tuple[np.ndarray, np.ndarray]:
    """One object's two plateaus fitted on its own profile with the shapes of the surface's pooled fit.

    ``c(s) = c_out (1 - F(s)) + c_in F(s) + A g(s)``: F the pooled profile's fitted step, g its solute's
    Gaussian peak (centre and width as fitted, significant or not, as the pooled fit's plateaus had it; none
    where the profile was fitted with a step only), the levels and the
    peak's amplitude the object's own (linear in them: weighted least squares, reweighted twice by the
    binomial variance ``c (1 - c) / N`` of the model's fractions). The covariance adds the pooled fit's error
    of the peak's centre and width, carried by the levels' numerical gradient (for a profile that is the
    pooled one, the fit's own errors of its plateaus). A thin object's deeper ions lie in the peak's tail and
    short of its step's plateau: their mean is not the inside level (a 2.4 nm slab with a B shell, sigma
    0.3 nm: its deeper half's B fraction 0.017 for a plateau of 0.002, the excess 16 % low), and the pooled
    fit's plateau is the pooled objects', undetermined where all of them are thin.

    Parameters
    ----------
    s : (b,) float
        Bin centres, nm (positive inside).
    n, total : (b,) int
        Solute and total counts per bin.
    fit : apt_filters.analysis.width.ProfileFit
        The solute's fit on the pooled profile (:meth:`apt_filters.analysis.width.Windows.fit_of`).

    Returns
    -------
    levels : (2,) float
        ``(c_out, c_in)``.
    cov : (2, 2) float
        Their covariance (the amplitude's marginalised); NaN where the profile cannot tell them apart.
    """
    s = np.asarray(s, dtype=np.float64)
    n, total = np.asarray(n, dtype=np.float64), np.asarray(total, dtype=np.float64)
    step = fit.step_share(s)
    # a fraction is known to one ion of the profile at best: a model fraction of 0 would weigh its bins without end
    floor = 1.0 / max(total.sum(), 1.0)

    def solve(centre: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        peak = [np.exp(-0.5 * ((s - centre) / sigma) ** 2)] if np.isfinite(sigma) else []
        columns = [1 - step, step] + peak
        design = np.stack(columns, axis=1) * total[:, None]
        c = np.full(len(s), n.sum() * floor)
        for _ in range(3):
            weight = 1.0 / np.maximum(total * c * (1 - c), floor)
            try:
                cov = np.linalg.inv(design.T @ (design * weight[:, None]))
            except np.linalg.LinAlgError:
                return np.full(2, np.nan), np.full((2, 2), np.nan)
            p = cov @ (design.T @ (weight * n))
            c = np.clip(design @ p / np.maximum(total, 1.0), floor, 1 - floor)
        return p[:2], cov[:2, :2]

    values, cov = solve(fit.peak_centre, fit.peak_sigma)
    if np.isfinite(fit.peak_sigma):
        h = 1e-4  # nm
        grad = np.stack([(solve(fit.peak_centre + dc, fit.peak_sigma + ds)[0]
                          - solve(fit.peak_centre - dc, fit.peak_sigma - ds)[0]) / (2 * h)
                         for dc, ds in ((h, 0.0), (0.0, h))], axis=1)  # (2 levels, 2 shape parameters)
        cov = cov + grad @ np.asarray(fit.peak_shape_cov) @ grad.T
    return values, cov


def _windows(centers: np.ndarray, inner: float, outer: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    matrix = (centers <= -inner) & (centers >= -outer)
    precipitate = (centers >= inner) & (centers <= outer)
    between = np.abs(centers) < inner
    if not matrix.any() or not precipitate.any():
        raise AptFiltersError(f"plateau windows {inner:g}..{outer:g} nm hold no bins of the proxigram "
                              f"({centers[0]:g}..{centers[-1]:g} nm)")
    return matrix, precipitate, between


def _estimate(count: float, var: float, area: float, efficiency: float) -> ExcessEstimate:
    err = float(np.sqrt(max(var, 0.0)))
    return ExcessEstimate(float(count), err, count / area, err / area, count / area / efficiency,
                          err / area / efficiency)


def excess_of_profile(s: np.ndarray, n: np.ndarray, total: np.ndarray, area: float, efficiency: float,
                      inner: float = 1.0, outer: float = 3.0, fit=None, thin: bool = False
                      ) -> tuple[Level, Level, ExcessEstimate, ExcessEstimate]:
    """Levels and both excess estimates from one profile.

    Parameters
    ----------
    s : (b,) float
        Bin centres, nm (positive inside); bins of equal width, in increasing order.
    n, total : (b,) int
        Solute and total counts per bin.
    area : float
        Interface area, nm².
    efficiency : float
        Detection efficiency (0, 1].
    inner, outer : float
        Plateau windows ``inner <= |s| <= outer`` nm.
    fit : apt_filters.analysis.width.ProfileFit, optional
        The solute's fit on the surface's pooled profile (:meth:`apt_filters.analysis.width.Windows.fit_of`),
        for a side with no plateau window of its own: a window that holds no ions (the matrix side cut away
        by the edge exclusion, an object with no ion inside), or the inside of a ``thin`` object. That side's
        level is then :func:`own_levels`' (the object's own ions under the pooled fit's shapes), the
        integration runs over all of the object's bins on that side, and the cumulative estimate, which needs
        both windows' data, equals the integration. Without it such an object raises.
    thin : bool
        The object is shallower than ``inner``: its depth by the rule of its reported inside plateau
        (:func:`apt_filters.analysis.width.inside_windows`) is short of ``inner``, so that the window holds at
        most the few ions that rule takes for strays; its deeper ions are short of the step's plateau and in
        the tail of a segregation peak.
    """
    matrix_w, precip_w, between = _windows(s, inner, outer)
    own = [total[matrix_w].sum() == 0, thin or total[precip_w].sum() == 0]
    if fit is not None and any(own):
        values, cov = own_levels(s[np.abs(s) <= outer], n[np.abs(s) <= outer], total[np.abs(s) <= outer], fit)
        if not np.all(np.isfinite(cov)):
            raise AptFiltersError("the object's profile cannot tell its plateaus from the pooled fit's shapes")
    fitted = []
    for k, window in enumerate((matrix_w, precip_w)):
        if fit is None or not own[k]:
            fitted.append(fit_level(s[window], n[window], total[window]))
        else:  # no plateau window of its own on this side: its own level under the pooled shapes
            between |= window
            fitted.append((Level(float(values[k]), float(np.sqrt(cov[k, k])), 0.0, 0),
                           np.array([[cov[k, k], 0.0], [0.0, 0.0]])))
    (matrix, cov_m), (precip, cov_p) = fitted
    thin = fit is not None and any(own)
    n = n.astype(np.float64)
    total = total.astype(np.float64)
    # counting noise of the solute in the interface region, binomial given the totals
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(total > 0, n / total, 0.0)
    var_counts = float(np.sum(total[between] * frac[between] * (1 - frac[between])))

    # integration against the fitted lines, each on its own side of s = 0
    ref, var_sides = 0.0, []
    for side, level, cov in ((between & (s < 0), matrix, cov_m), (between & (s >= 0), precip, cov_p)):
        r, v = reference_counts(total[side].sum(), (total[side] * s[side]).sum(), level.value, level.slope,
                                cov[0, 0], cov[0, 1], cov[1, 1])
        ref += r
        var_sides.append(v)
    integration = _estimate(n[between].sum() - ref, var_counts + sum(var_sides), area, efficiency)
    if thin:
        return matrix, precip, integration, integration

    # Krakauer–Seidman: cumulative counts at the upper edge of each bin, from the matrix side
    cum_total, cum_n = np.cumsum(total), np.cumsum(n)
    x0 = cum_total[s < 0][-1] if np.any(s < 0) else 0.0
    lines = []
    var_ks = var_counts
    for window, level, var_side in zip((matrix_w, precip_w), (matrix, precip), var_sides):
        x, y = cum_total[window], cum_n[window]
        # where the level has a significant gradient the cumulative curve bends: a parabola follows it,
        # a straight line extrapolated over the lever arm would not (O across the Si cap: -5.2 against
        # -0.6 detected atoms/nm² by integration; with the parabola -0.7)
        degree = 2 if level.slope != 0 and len(x) > 3 else 1
        coef = np.polyfit(x, y, degree) if np.ptp(x) > 0 else np.array([float(y.mean())])
        lines.append(float(np.polyval(coef, x0)))
        c = min(max(float(coef[-2]) if len(coef) > 1 else 0.0, 0.0), 1.0)
        # slope error from counting over the window, with the lever arm to the interface; at least
        # the fitted level's extrapolation variance
        var_ks += max((x0 - x.mean()) ** 2 * c * (1 - c) / max(total[window].sum(), 1.0), var_side)
    cumulative = _estimate(lines[1] - lines[0], var_ks, area, efficiency)
    return matrix, precip, integration, cumulative


def interfacial_excess(proxigram: Proxigram, solute: str, efficiency: float, inner: float = 1.0,
                       outer: float | None = None, skip_unmeasurable: bool = False, fit=None) -> list[Excess]:
    """Excess of ``solute`` per object (own area) and, when there are several objects, pooled
    (summed counts over the summed area, last in the list, ``object_id`` = ``POOLED``).

    ``outer`` defaults to the proxigram's range. An object shallower than ``inner`` (its depth by the rule
    of its reported inside plateau, :func:`apt_filters.analysis.width.inside_starts`: its inside window
    starts nearer than ``inner / 2``) or with no ions in a plateau window (cut away by the edge exclusion)
    takes that side's level from its own profile under the shapes of ``fit``, the solute's fit on the pooled
    profile (see
    :func:`excess_of_profile`); without one it has no measurable excess: an error, or left out of the list
    with ``skip_unmeasurable``.
    """
    from apt_filters.analysis.width import inside_starts  # width builds on this module's levels

    if not 0 < efficiency <= 1:
        raise AptFiltersError(f"detection efficiency must be in (0, 1], got {efficiency}")
    outer = float(proxigram.edges[-1]) if outer is None else outer
    if not 0 <= inner < outer:
        raise AptFiltersError(f"plateau windows need 0 <= inner < outer, got {inner} and {outer}")
    profiles = proxigram if len(proxigram.object_ids) == 1 else _with_pooled(proxigram)
    n, total = profiles.counts_of(solute)
    # thin: its depth (twice where its inside window starts) short of inner, so that the window from inner
    # holds only the ions the depth rule takes for strays; deeper, that window is clear of the step and the
    # peak by the windows' construction (a spinodal's ligaments, 1.95 nm deep for inner 1.2 nm, were taken
    # as thin at depth < 2 inner: its Si excess -1.2 -> -3.2 %, -2.6 sigma)
    thin = inside_starts(proxigram=profiles, inner=inner, outer=outer) < 0.5 * inner
    out = []
    for k, obj in enumerate(profiles.object_ids):
        area = float(profiles.areas[k])
        if area <= 0:
            raise AptFiltersError(f"object {obj} has no area")
        try:
            levels = excess_of_profile(profiles.centers, n[k], total[k], area, efficiency, inner, outer, fit,
                                       bool(thin[k]))
        except AptFiltersError:
            if skip_unmeasurable:
                continue
            raise
        out.append(Excess(solute, int(obj), area, efficiency, *levels, (inner, outer)))
    return out


def _with_pooled(proxigram: Proxigram) -> Proxigram:
    pooled = proxigram.pooled()
    fields = ("object_ids", "counts", "unranged", "areas", "shell_volumes")
    return replace(proxigram, **{f: np.concatenate([getattr(proxigram, f), getattr(pooled, f)]) for f in fields})


def interface_position(centers: np.ndarray, c: np.ndarray, matrix: float, precipitate: float) -> float:
    """Distance (nm) where the profile ``c`` crosses the midpoint of two levels, nearest to 0.

    Linear interpolation between bin centres; NaN if it never crosses.
    """
    diff = c - 0.5 * (matrix + precipitate)
    ok = np.isfinite(diff)
    s, d = centers[ok], diff[ok]
    cross = np.flatnonzero(np.sign(d[:-1]) * np.sign(d[1:]) < 0)
    if len(cross) == 0:
        return float("nan")
    pos = s[cross] - d[cross] * (s[cross + 1] - s[cross]) / (d[cross + 1] - d[cross])
    return float(pos[np.argmin(np.abs(pos))])


def write_excess_json(path: str | os.PathLike, results: list[Excess], overwrite: bool = False) -> Path:
    """Write the results as JSON (one object per entry; object_id -1 = pooled), atomically."""
    doc = {"pooled_area": "pooled Γ = summed excess / summed area of the objects (object_id -1)",
           "gamma_detected": "excess per nm² in detected ions (decomposed atoms for an element)",
           "gamma_atoms": "gamma_detected / detection efficiency",
           "results": [asdict(r) for r in results]}
    return atomic_write_text(path, jsontext.dumps(doc, indent=2) + "\n", overwrite)


__all__ = ["Excess", "ExcessEstimate", "Level", "INSTRUMENT_EFFICIENCY", "POOLED", "interfacial_excess",
           "excess_of_profile", "fit_level", "interface_position", "levels_from_moments", "own_levels",
           "reference_counts", "write_excess_json"]
