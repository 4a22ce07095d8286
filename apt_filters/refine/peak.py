"""A segregant's peak across a surface: a Poisson fit of a Gaussian over a flat background.

A species held in a thin layer at an interface shows, against the ions' signed distance ``d`` to the
surface, a peak in its fraction of the atoms. Its width tells the blur (:func:`~apt_filters.refine.blur.peak_blur`)
and its centre where the interface lies (:mod:`apt_filters.refine.marker`). Both come from one fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class PeakFit:
    """A marker's fraction ``background + amplitude exp(-(d - centre)^2 / 2 width^2)`` against ``d``.

    Attributes
    ----------
    background, amplitude : float
        Fractions of the atoms.
    centre, width : float, nm
    se : (4,) float64
        Standard errors of (background, amplitude, centre, width), from the fit's Fisher information.
    """

    background: float
    amplitude: float
    centre: float
    width: float
    se: np.ndarray

    def significant(self, significance: float, half_width: float) -> bool:
        """Whether the peak stands ``significance`` standard errors above its background, centred within
        half the profile's range (a peak fitted at the range's edge is a background fluctuation)."""
        return bool(self.amplitude > significance * self.se[1] and abs(self.centre) <= 0.5 * half_width)


def fit_peak(distance: np.ndarray, marker: np.ndarray, total: np.ndarray, half_width: float = 1.5,
             bin_width: float = 0.1) -> PeakFit | None:
    """Fit the peak of the marker's fraction in bins of ``bin_width`` over [-half_width, half_width] nm.

    The marker's atoms per bin are Poisson with mean ``n (b + a exp(-(d - mu)^2 / 2 w^2))`` (``n`` the bin's
    atoms); the fit minimises the deviance.

    Parameters
    ----------
    distance : (b,) float64, nm
        Ions' signed distances to the surface (positive outside).
    marker : (b,) float64
        Atoms of the marker per ion.
    total : (b,) float64
        Atoms per ion, the marker's included.
    half_width, bin_width : float, nm
        Profile range (ions farther out are left out) and bin size.

    Returns
    -------
    PeakFit or None
        None where no ion carries the marker.
    """
    from scipy.optimize import least_squares

    edges = np.arange(-half_width, half_width + 1e-9, bin_width)
    idx = np.digitize(distance, edges) - 1
    ok = (idx >= 0) & (idx < len(edges) - 1)
    n = np.bincount(idx[ok], weights=total[ok], minlength=len(edges) - 1)
    k = np.bincount(idx[ok], weights=marker[ok], minlength=len(edges) - 1)
    centre = 0.5 * (edges[1:] + edges[:-1])
    if k.sum() <= 0:
        return None

    def mean(p):
        return n * (abs(p[0]) + abs(p[1]) * np.exp(-0.5 * ((centre - p[2]) / p[3]) ** 2)) + 1e-12

    def deviance(p):
        lam = mean(p)
        return np.sign(k - lam) * np.sqrt(2 * np.maximum(lam - k + k * np.log(np.maximum(k, 1e-12) / lam), 0.0))

    fraction = k / np.maximum(n, 1e-12)
    background = float(np.median(np.concatenate([fraction[:3], fraction[-3:]])))
    fit = least_squares(deviance, [background, max(float(fraction.max()) - background, 1e-6), 0.0, 0.3])
    cov = np.linalg.pinv(fit.jac.T @ fit.jac)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return PeakFit(abs(float(fit.x[0])), abs(float(fit.x[1])), float(fit.x[2]), abs(float(fit.x[3])), se)
