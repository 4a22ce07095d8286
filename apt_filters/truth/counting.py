"""What the ions of a synthetic specimen allow: the counting floor and the counted truth.

:func:`counting_floor` gives what no method can beat on a given set of ions: the Cramér-Rao bound of
an object's size, i.e. the standard deviation of the best unbiased estimate of a uniform offset of its
true surface from its ions, and the volume and area errors that offset alone implies.
:func:`counted_truth` gives the same for composition: the excess and plateaus an object's own ions hold
in its true frame, whose scatter about the specimen's model values every method inherits.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from apt_filters.analysis.width import inside_windows
from apt_filters.core.mesh import TriMesh
from apt_filters.refine.blur import vertex_areas
from apt_filters.refine.crossval import LENGTHS, open_low_pass
from apt_filters.refine.levels import PLATEAU_WINDOW
from apt_filters.refine.marker import combined_offset_errors
from apt_filters.refine.peak import fit_peak


@dataclass
class CountingFloor:
    """Counting-statistics floor of one object (standard deviations).

    Attributes
    ----------
    offset : float, nm
        Of a uniform offset of the whole true surface along its normals, estimated from the object's ions.
    volume, area : float
        Relative standard deviations of the volume (``A offset / V``) and area (``|dA/dd| offset / A``).
    ions : int
        Ions within ``reach`` of the object's surface.
    """

    offset: float
    volume: float
    area: float
    ions: int


def counting_floor(sdfs: Sequence[Callable[[np.ndarray], np.ndarray]],
                   level_areas: Sequence[Callable[[np.ndarray], np.ndarray]], volumes: Sequence[float],
                   positions: np.ndarray, atoms: np.ndarray, reach: float = 2.0,
                   bin_width: float = 0.05, marker: np.ndarray | None = None) -> list[CountingFloor]:
    """Cramér-Rao floor of each object's offset, volume and area from its ions and the true profile.

    The profile of each basis element's fraction against the true signed distance ``d``, pooled over
    all the objects given (all alike, e.g. the precipitates of one phase), is fitted by error-function
    steps ``f_k(d) = out_k + (in_k - out_k) Phi(-(d - c) / s)`` (plateaus from ``|d| > 1`` nm, inside
    from half the objects' depth where that is nearer; a common centre and width; a fit, since the noise
    of a binned profile's slope would add information that is not there). Each atom within ``reach`` nm
    of an object carries the Fisher information ``sum_k f_k'(d)^2 / f_k(d)`` about a shift of the object's
    surface, and the bound is one over the square root of their sum (NaN where the ions hold no step).

    With a ``marker`` (a segregant left out of the basis, whose layer marks the interface:
    :mod:`apt_filters.refine.marker`), its peak against the true distance, pooled likewise, is fitted by a
    Gaussian over a background (:func:`~apt_filters.refine.peak.fit_peak`), and each ion adds
    ``m'(d)^2 / (m (1 - m))`` per atom (``m`` the marker's fraction of all the atoms: whether an atom is the
    marker, then which basis element it is if not, so the two informations are independent). The layer's
    offset from the midpoint is one unknown shared by the objects given, as the refinement fits it, so the
    bound is :func:`~apt_filters.refine.marker.combined_offset_errors` of the two (a single object gains
    nothing from its marker).

    Parameters
    ----------
    sdfs : callables
        Each object's exact SDF (nm, negative inside).
    level_areas : callables
        Each object's ``A(d)``, the area (nm²) of its level set ``sdf = d``.
    volumes : floats, nm³
    positions : (N, 3) float
        Ion positions (nm).
    atoms : (N, k) float
        Atoms of each basis element per ion (:func:`~apt_filters.refine.composition.ion_atoms`).
    reach, bin_width : float, nm
    marker : (N,) float, optional
        Atoms of the marker per ion (none of them in ``atoms``).
    """
    from scipy.optimize import least_squares
    from scipy.special import erfc

    positions = np.asarray(positions, dtype=np.float64)
    edges = np.arange(-reach, reach + 1e-9, bin_width)
    n_bins = len(edges) - 1
    centre = 0.5 * (edges[1:] + edges[:-1])
    marker = np.zeros(len(positions)) if marker is None else np.asarray(marker, dtype=np.float64)
    near = []
    counts, totals = np.zeros((n_bins, atoms.shape[1])), np.zeros(n_bins)
    for sdf in sdfs:
        d = sdf(positions)
        rows = np.flatnonzero((np.abs(d) < reach) & (atoms.sum(axis=1) + marker > 0))
        a = np.asarray(atoms[rows], dtype=np.float64)
        b = np.minimum(((d[rows] + reach) / bin_width).astype(np.int64), n_bins - 1)
        np.add.at(counts, b, a)
        np.add.at(totals, b, a.sum(axis=1))
        near.append((d[rows], a, marker[rows]))
    fraction = counts / np.maximum(totals, 1.0)[:, None]
    # the inside plateau from 1 nm deep, or from half the objects' depth where they are thinner (the report's
    # window, :func:`~apt_filters.analysis.width.inside_windows`): discs and rods whose ions all lie within
    # 1 nm of their surface left it empty, and the fit then read no step at all (floors of 1e49)
    deep = centre < -inside_windows(depth=-centre, atoms=totals, inner=1.0)[0]
    inside = counts[deep].sum(axis=0) / max(totals[deep].sum(), 1.0)
    outside = counts[centre > 1.0].sum(axis=0) / max(totals[centre > 1.0].sum(), 1.0)
    weight = np.sqrt(totals)[:, None]

    def model(p, d):
        return outside + (inside - outside) * 0.5 * erfc((d[:, None] - p[0]) / (np.sqrt(2) * abs(p[1])))

    fit = least_squares(lambda p: ((model(p, centre) - fraction) * weight).ravel(), [0.0, 0.3])
    c, s = fit.x[0], abs(fit.x[1])
    pooled = [np.concatenate(x) for x in zip(*near)] if near else None
    peak = fit_peak(pooled[0], pooled[2], pooled[1].sum(axis=1) + pooled[2], reach) if near and marker.any() else None
    step, mark = np.zeros(len(near)), np.zeros(len(near))
    for k, (d, a, m) in enumerate(near):
        f = model(fit.x, d)
        slope = -(inside - outside) * np.exp(-0.5 * ((d[:, None] - c) / s) ** 2) / (np.sqrt(2 * np.pi) * s)
        step[k] = np.sum(a.sum(axis=1) * np.sum(np.divide(slope ** 2, f, out=np.zeros_like(f), where=f > 0), axis=1))
        if peak is not None:
            bump = peak.amplitude * np.exp(-0.5 * ((d - peak.centre) / peak.width) ** 2)
            mf = peak.background + bump
            mark[k] = np.sum((a.sum(axis=1) + m) * (bump * (d - peak.centre) / peak.width ** 2) ** 2 / (mf * (1 - mf)))
    # no information (no step in the ions): no floor, rather than one so wide that any error passes within it
    offsets = 1.0 / np.sqrt(np.where(step > 0, step, np.nan))
    if len(near) > 1 and mark.all():
        offsets = combined_offset_errors(offsets, 1.0 / np.sqrt(mark))
    out = []
    for (d, _, _), offset, level_area, volume in zip(near, offsets, level_areas, volumes):
        area = float(level_area(np.zeros(1))[0])
        growth = float(np.diff(level_area(np.array([-bin_width, bin_width])))[0] / (2 * bin_width))
        out.append(CountingFloor(offset, area * offset / volume, abs(growth) * offset / area, len(d)))
    return out


@dataclass
class CountedTruth:
    """What one object's own ions hold in its true frame (the figures of a method that knew the true
    surface and the true plateaus).

    Attributes
    ----------
    excess_ions : (k,) float
        Per basis element: ions within ``half_width`` nm of the true surface minus the true plateau
        fractions times the atoms on each side of it (the count :func:`~apt_filters.refine.excess.object_excess`
        estimates).
    inside, outside : (k,) float
        Fractions of each basis element between ``window`` nm inside / outside the true surface (the
        plateaus :func:`~apt_filters.refine.levels.object_levels` estimates).
    n_inside, n_outside : float
        Basis atoms in the two windows.
    """

    excess_ions: np.ndarray
    inside: np.ndarray
    outside: np.ndarray
    n_inside: float
    n_outside: float


def counted_truth(sdf: Callable[[np.ndarray], np.ndarray], positions: np.ndarray, atoms: np.ndarray,
                  inside: np.ndarray, outside: np.ndarray, half_width: float = 1.5,
                  window: tuple[float, float] = PLATEAU_WINDOW) -> CountedTruth:
    """Excess and plateaus of one object counted from its ions against its true surface and plateaus.

    A synthetic specimen's model gives expected values; its ions are one draw, so even this count
    misses them by the counting noise (a 3 nm sphere's ~240 excess ions: 6-7 %). A method's error
    against the model is this count's error plus its own.

    Parameters
    ----------
    sdf : callable
        The object's exact SDF (nm, negative inside).
    positions : (N, 3) float
        Ion positions (nm).
    atoms : (N, k) float
        Atoms of each basis element per ion (:func:`~apt_filters.refine.composition.ion_atoms`).
    inside, outside : (k,) float
        The true plateau fractions of the basis elements.
    half_width : float, nm
        Band of the excess count, each side of the surface.
    window : (float, float), nm
        Distances between which the plateaus are counted, each side.
    """
    d = sdf(np.asarray(positions, dtype=np.float64))
    atoms = np.asarray(atoms, dtype=np.float64)
    band = np.abs(d) <= half_width
    totals = atoms.sum(axis=1)
    expected = (np.asarray(inside) * totals[band & (d < 0)].sum()
                + np.asarray(outside) * totals[band & (d >= 0)].sum())
    win_in = (d <= -window[0]) & (d >= -window[1])
    win_out = (d >= window[0]) & (d <= window[1])
    n_in, n_out = totals[win_in].sum(), totals[win_out].sum()
    return CountedTruth(atoms[band].sum(axis=0) - expected, atoms[win_in].sum(axis=0) / max(n_in, 1.0),
                        atoms[win_out].sum(axis=0) / max(n_out, 1.0), float(n_in), float(n_out))


SMOOTHED_NOISE = 13.0 / 128.0
"""``l^2`` times the variance that :func:`~apt_filters.refine.spectral.rim_held_low_pass` at length ``l`` leaves of
a white offset noise of unit variance per nm²: ``int H(k)^2 d^2k / (2 pi)^2`` with the twiced Tikhonov damping
``H = (1 + 2a) / (1 + a)^2``, ``a = (l k)^4``, is ``(1 / (4 pi l^2)) int_0^inf ((1 + 2v^2) / (1 + v^2)^2)^2 dv`` and
the integral is ``13 pi / 32`` (an effective area of ``9.8 l^2``: 19 nm² at ``l`` = 1.4 nm)."""


@dataclass
class DistanceFloor:
    """Counting floor of an open surface's mean distance to its truth at the best smoothing length.

    Attributes
    ----------
    mean : float, nm
        Expected mean ``|d|`` of the ideal estimate low-passed at ``length``: over the true surface, ``E|b + s Z|``
        (``b`` the filter's bias there, ``s`` the noise it leaves, ``Z`` standard normal).
    length : float, nm
        The smoothing length (of those given) at which ``mean`` is smallest.
    noise : float, nm
        ``s`` at ``length``.
    bias : float, nm
        Mean ``|b|`` at ``length``.
    """

    mean: float
    length: float
    noise: float
    bias: float


def distance_floor(*, true_mesh: TriMesh, sdf: Callable[[np.ndarray], np.ndarray], offset: float, area: float,
                   region: Callable[[np.ndarray], np.ndarray] | None = None,
                   lengths: Sequence[float] = LENGTHS) -> DistanceFloor:
    """Counting floor of the mean distance of an open surface (an interface leaving the specimen) low-passed as
    the refinement low-passes it (:func:`~apt_filters.refine.crossval.open_low_pass`, rim held), from its ions.

    The ideal estimate of the surface places each area element at the unbiased offset its ions support: an
    offset noise, white along the surface, of variance ``offset^2 area`` per nm² (``offset`` the Cramér-Rao floor
    of one uniform offset of ``area`` nm² of the surface, :func:`counting_floor`, which assumes the ions' density
    and the step uniform along the surface). The low-pass at length ``l`` leaves ``s^2 = SMOOTHED_NOISE offset^2
    area / l^2`` of it (:data:`SMOOTHED_NOISE`) and moves the true surface by ``b`` (the filter applied to
    ``true_mesh``; ``b`` its vertices' SDF): its expected mean distance is the area-weighted mean over
    the true surface of ``E|b + s Z| = s sqrt(2/pi) exp(-b^2 / 2 s^2) + b (1 - 2 Phi(-b / s))``. The floor is
    that at the best of ``lengths`` (the refinement's candidates, :data:`~apt_filters.refine.crossval.LENGTHS`;
    tried from the shortest until it rises):
    what the refinement could reach with the held-out ions' choice made by the truth and a placement as efficient
    as the counts allow; a mean distance near it is the counts' and one well above it the estimator's.

    Parameters
    ----------
    true_mesh : TriMesh
        The true surface (one or more open components, each with its rim at the specimen's edge).
    sdf : callable
        Its exact SDF (nm).
    offset : float, nm
        Cramér-Rao floor of a uniform offset of ``area`` of the surface (``CountingFloor.offset`` of the ions
        there).
    area : float, nm²
        The area those ions cover.
    region : callable, optional
        Where the surface is compared (``region(points) < 0``); everywhere if None.
    lengths : floats, nm
    """
    from scipy.special import erfc

    faces = true_mesh.faces
    labels = true_mesh.face_components()
    components = np.full(true_mesh.n_vertices, -1, dtype=np.int64)
    components[faces.ravel()] = np.repeat(labels, 3)
    weight = vertex_areas(true_mesh.vertices, faces)
    if region is not None:
        weight = weight * (region(true_mesh.vertices) < 0)
    best = None
    # rough to smooth: the noise falls and the bias grows with the length, so the first rise is past the floor
    for length in sorted(lengths):
        moved = open_low_pass(true_mesh.vertices, faces, components, dict.fromkeys(range(int(labels.max()) + 1),
                                                                                  float(length)))
        b = np.abs(sdf(moved))
        s = offset * np.sqrt(SMOOTHED_NOISE * area) / length
        expected = s * np.sqrt(2 / np.pi) * np.exp(-0.5 * (b / s) ** 2) + b * (1 - erfc(b / (np.sqrt(2) * s)))
        floor = DistanceFloor(float(np.average(expected, weights=weight)), float(length), float(s),
                              float(np.average(b, weights=weight)))
        if best is not None and floor.mean >= best.mean:
            break
        best = floor
    return best
