"""The reconstruction blur's curvature bias: where a blurred interface's midpoint lies on a curved surface.

Blurring the ion positions by a Gaussian of covariance ``Sigma`` changes a composition field ``c`` by
``(1/2) sum_ij Sigma_ij d_i d_j c`` to first order. Across an interface ``c = f(d)`` (``d`` the signed
distance, ``f`` any profile symmetric about its midpoint, so ``f'' = 0`` there) only the tangential
part survives: ``(1/2) f' tr(Sigma S)``, with ``S`` the shape operator (the tangential gradient of the
outward normal; ``I / R`` on a sphere of radius ``R``). The blurred midpoint therefore lies

    shift = (1/2) tr(Sigma S)  nm inside a convex surface (outside a concave one),

``sigma^2 / R`` on a sphere blurred isotropically. Any estimator that puts the surface at the ions'
profile crossing (equal-area or matched filter, :mod:`apt_filters.refine.surface`) inherits it: a
3 nm sphere under the gamma-prime specimen's blur (0.3 nm lateral, 0.1 nm in depth) comes out ~0.02 nm
small, 2 % of its volume. The correction moves each vertex outward by ``shift`` afterwards.

The normal profile alone cannot give ``Sigma``: its width mixes the blur with the interface's own width
(no curvature bias) and with the surface's noise. Its orientation dependence can, in part: APT blurs
laterally (x, y) more than in depth (z), so an interface seen edge-on (normal in the x-y plane) looks
wider than one seen face-on. With ``s(n)`` the error-function width of the profile at normal ``n``,

    s(n)^2 = a + (sigma_lat^2 - sigma_depth^2) (1 - n_z^2),

``a`` holding the interface's own width, the surface noise and ``sigma_depth^2``. :func:`lateral_blur`
fits the slope from the ions of all objects pooled by ``n_z^2``; with ``sigma_depth`` taken as 0 (APT's
depth resolution, ~0.05-0.1 nm, is several times its lateral one) it gives ``sigma_lat``, and the
correction uses ``Sigma = diag(s, s, 0)``: on the gamma-prime specimen (0.3 / 0.1 nm) that is 89 % of
the lateral variance and leaves out the depth part (0.003 nm on a 3 nm sphere). A flat interface (all
normals alike) gives no estimate and no correction; ``RefineParams(blur=(lateral, depth))`` sets a
known blur instead.

A segregant in a thin layer at the interface is a sharper marker of the same slope: its fraction's peak
has ``s(n)^2 = t^2 + noise^2 + sigma_n^2`` (``t`` the layer's own width), and a peak's width is read far
more precisely than a step's at a 10-point contrast. On gamma-prime seeds 1-8 (B in a 0.25 nm shell)
the slope from the B peak scattered 0.056-0.104 nm² (sd 0.015), the step's -0.075-0.143 nm² (sd 0.065),
truth 0.08. :func:`peak_blur` fits it (:func:`~apt_filters.refine.peak.fit_peak`: Poisson likelihood of
the marker's counts per bin); it assumes the layer's own width does not depend on the interface's
orientation, as the step's estimate assumes of the interface's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apt_filters.core.mesh import TriMesh, vertex_normals
from apt_filters.refine.band import adjacency
from apt_filters.refine.peak import fit_peak


def vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) barycentric vertex areas in nm² (a third of each adjacent face's area)."""
    v = vertices[faces]
    a = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    out = np.zeros(len(vertices))
    for k in range(3):
        np.add.at(out, faces[:, k], a / 3)
    return out


def smoothed_normals(vertices: np.ndarray, faces: np.ndarray, passes: int) -> np.ndarray:
    """(n, 3) unit vertex normals averaged over ``passes`` umbrella passes (noise of single faces out)."""
    adj = adjacency(faces, len(vertices))
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    normals = vertex_normals(vertices, faces)
    for _ in range(passes):
        normals = (adj @ normals) / deg[:, None]
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    return normals


def shape_operator(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(n, 3, 3) symmetric shape operator per vertex: the tangential gradient of the normal field.

    Per face, the linear interpolation of the vertex ``normals`` has gradient ``D`` (``dn = D dp`` in the
    face's plane); vertices take the area-weighted mean of their faces' symmetrised ``D``, projected on
    their tangent plane. Its trace is the sum of the principal curvatures (``2 / R`` on a sphere, 1/nm),
    positive where the surface is convex (normals pointing out).
    """
    p = vertices[faces]
    e = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=2)  # (m, 3, 2) edge vectors
    dn = np.stack([normals[faces[:, 1]] - normals[faces[:, 0]], normals[faces[:, 2]] - normals[faces[:, 0]]], axis=2)
    gram = np.einsum("mki,mkj->mij", e, e)
    det = gram[:, 0, 0] * gram[:, 1, 1] - gram[:, 0, 1] ** 2
    ok = det > 1e-10 * gram[:, 0, 0] * gram[:, 1, 1]  # slivers (marching cubes makes some) carry no gradient
    inv = np.zeros_like(gram)
    inv[ok, 0, 0], inv[ok, 1, 1] = gram[ok, 1, 1] / det[ok], gram[ok, 0, 0] / det[ok]
    inv[ok, 0, 1] = inv[ok, 1, 0] = -gram[ok, 0, 1] / det[ok]
    grad = np.einsum("mia,mab,mjb->mij", dn, inv, e)
    grad = 0.5 * (grad + grad.transpose(0, 2, 1))
    area = np.where(ok, 0.5 * np.sqrt(np.maximum(det, 0.0)), 0.0)
    total = np.zeros((len(vertices), 3, 3))
    weight = np.zeros(len(vertices))
    for k in range(3):
        np.add.at(total, faces[:, k], grad * area[:, None, None])
        np.add.at(weight, faces[:, k], area)
    total /= np.maximum(weight, 1e-300)[:, None, None]
    tangent = np.eye(3)[None] - normals[:, :, None] * normals[:, None, :]
    return tangent @ total @ tangent


def face_covariance(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3, 3) nm² per vertex: the area-weighted mean over its faces of ``(1/12) sum_e e e^T`` (``e`` a face's
    three edge vectors).

    A flat face through three points of a smooth surface lies inside it (convex) by
    ``(1/2) sum_{i<j} l_i l_j e_ij^T S e_ij`` at barycentric ``l`` (the linear interpolant's error on a quadratic
    surface), ``(1/24) sum_e e^T S e = (1/2) tr(C S)`` on the face's mean with this ``C``: ``e^2 / 8R`` for an
    equilateral face of edge ``e`` on a sphere of radius ``R``. It is the blur's form (module docstring) with the
    faces' own second moment in place of ``Sigma``.
    """
    p = vertices[faces]
    e = p[:, [1, 2, 0]] - p  # (m, 3 edges, 3)
    area = 0.5 * np.linalg.norm(np.cross(e[:, 0], -e[:, 2]), axis=1)
    weighted = (np.einsum("mki,mkj->mij", e, e) / 12 * area[:, None, None]).reshape(-1, 9)
    n = len(vertices)
    at = faces.T.ravel()  # each face once per corner
    total = np.stack([np.bincount(at, np.tile(weighted[:, j], 3), n) for j in range(9)], axis=1)
    weight = np.bincount(at, np.tile(area, 3), n)
    return (total / np.maximum(weight, 1e-300)[:, None]).reshape(n, 3, 3)


def blur_shift(mesh: TriMesh, blur: tuple[float, float], normal_smoothing: int = 2, *,
               sag: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex outward shift (nm) that undoes the blur's curvature bias (and, with ``sag``, the flat faces'
    sag), and the normals to move along.

    Parameters
    ----------
    mesh : TriMesh
        Surface placed at the ions' profile crossing (normals out of the region above iso).
    blur : (lateral, depth) float, nm
        Gaussian sigmas of the reconstruction blur in x and y (lateral) and z (depth).
    normal_smoothing : int
        Umbrella passes over the normals before their gradient is taken (the curvature of single
        faces is noise).
    sag : bool
        Add ``(1/2) tr(C S)`` (:func:`face_covariance`): the vertices lie on the interface, the flat faces
        between them inside it by that much on average, so a convex object's volume comes out short by its area
        times it (thin zoo rods and discs, edges ~0.6 nm at R ~1.3 nm: 0.035 nm, 4-6 % of their volume; the
        placement stretches a thin object's start, whose radius grows ~1.6-fold). Moving the vertices out by
        it puts the faces' mean on the interface. At most a quarter of ``sqrt(tr C)`` (an eighth of the edge):
        the expansion holds where an edge is shorter than the radius of curvature.

    Returns
    -------
    shift : (n,) float64, nm
        ``(1/2) tr(Sigma S)`` (plus the sag), positive outward where the surface is convex.
    normals : (n, 3) float64
        The smoothed unit normals the shift is taken along.
    """
    lateral, depth = blur
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    normals = smoothed_normals(vertices, mesh.faces, normal_smoothing)
    sigma = np.diag([lateral ** 2, lateral ** 2, depth ** 2])
    shape = shape_operator(vertices, mesh.faces, normals)
    shift = 0.5 * np.einsum("ij,nji->n", sigma, shape)
    # the expansion is first order in the blur over the radius of curvature: it holds where the radius exceeds
    # the blur, i.e. for shifts up to the largest sigma; beyond it the shape operator reads the mesh's own
    # crumples (a low-passed rough surface's collapsed faces), not the interface's curvature
    reach = max(lateral, depth)
    shift = np.clip(shift, -reach, reach)
    if sag:
        cov = face_covariance(vertices, mesh.faces)
        bound = 0.25 * np.sqrt(np.trace(cov, axis1=1, axis2=2))  # e / 8 = e^2 / 8R at R = e
        shift += np.clip(0.5 * np.einsum("nij,nji->n", cov, shape), -bound, bound)
    return shift, normals


SLOPE_PRIOR = (0.093, 0.070)
"""nm²: mean and sd of the Gaussian prior on ``sigma_lat^2 - sigma_depth^2`` that a fitted slope is weighed against
(:func:`shrunk_slope`): a lateral sigma anywhere in 0.1-0.5 nm (uniform; APT's lateral resolution, the zoo's 0.2-0.4
nm within it) less a depth sigma of ~0.1 nm. The correction is linear in the slope, so its least-squares reading is
the posterior mean. ``max(slope, 0)`` instead took an uninformative reading at face value: across a wide interface
(tanh w 0.75-0.9 nm) on two small objects the step's width is mostly the interface's own and the slope's standard
error is 0.1-0.4 nm², as large as the slope itself (dev sphere 34213: 0.68 +- 0.42 for a true 0.08, the two R
1.75-1.95 spheres +26 / +36 points of volume from it; seen rod 10137: -0.28 +- 0.22 for 0.07, read 0). A slope read
to 0.02 nm² keeps 92 % of its own weight, one read to 0.07 nm² half."""


@dataclass
class BlurEstimate:
    """The lateral blur read off the orientation dependence of the profile width (module docstring).

    Attributes
    ----------
    lateral : float, nm
        ``sqrt(max(slope, 0))``: the lateral sigma with the depth sigma taken as 0, the fit's own reading (what the
        cross-fit's ball model takes, :attr:`shrunk_lateral` what the correction takes).
    slope : float, nm²
        Fitted ``sigma_lat^2 - sigma_depth^2``.
    slope_se : float, nm²
        Its standard error (from the widths' fit errors).
    widths : (classes,) float64, nm
        Width of the pooled profile per class of ``1 - n_z^2``: the error-function width of the step, or
        the Gaussian sigma of the marker's peak.
    tilt : (classes,) float64
        Mean ``1 - n_z^2`` of each class.
    source : str
        What was read: ``"step"`` (the score's profile) or ``"peak of X"`` (a segregant's, :func:`peak_blur`).
    """

    lateral: float
    slope: float
    slope_se: float
    widths: np.ndarray
    tilt: np.ndarray
    source: str = "step"

    @property
    def shrunk_lateral(self) -> float:
        """nm: ``sqrt(max(shrunk_slope(slope=slope, se=slope_se), 0))``, the lateral sigma the curvature correction
        takes (:data:`SLOPE_PRIOR`; the correction is linear in the slope, so the posterior mean is its
        least-squares reading)."""
        return float(np.sqrt(max(shrunk_slope(slope=self.slope, se=self.slope_se), 0.0)))


def _step_width(distance: np.ndarray, u: np.ndarray, weight: np.ndarray, half_width: float,
                bin_width: float) -> tuple[float, float]:
    """Error-function width (nm) and its standard error fitted to binned normalised profile values."""
    from scipy.optimize import least_squares
    from scipy.special import erfc

    edges = np.arange(-half_width, half_width + 1e-9, bin_width)
    idx = np.digitize(distance, edges) - 1
    ok = (idx >= 0) & (idx < len(edges) - 1)
    n = np.bincount(idx[ok], weights=weight[ok], minlength=len(edges) - 1)
    mean = np.divide(np.bincount(idx[ok], weights=(weight * u)[ok], minlength=len(edges) - 1), n,
                     out=np.zeros(len(n)), where=n > 0)
    centre, use = 0.5 * (edges[1:] + edges[:-1]), n > 0
    # every bin weighed by its atoms (the bound u (1 - u) <= 1/4 of a fraction's variance): plateau bins,
    # whose variance is smaller, would otherwise outweigh the step
    se = np.sqrt(0.25 / np.maximum(n, 1.0))
    fit = least_squares(lambda p: ((0.5 * erfc((centre - p[0]) / (np.sqrt(2) * abs(p[1]) + 1e-9)) - mean) / se)[use],
                        [0.0, 0.3])
    jac = fit.jac
    cov = np.linalg.pinv(jac.T @ jac) * max(float(np.mean(fit.fun ** 2)), 1.0)
    return abs(float(fit.x[1])), float(np.sqrt(cov[1, 1]))


def lateral_blur(distance: np.ndarray, u: np.ndarray, weight: np.ndarray, nz2: np.ndarray, classes: int = 4,
                 half_width: float = 1.5, bin_width: float = 0.1, min_ions: int = 2000) -> BlurEstimate | None:
    """Lateral blur sigma from the profile width's dependence on the surface orientation.

    Parameters
    ----------
    distance : (b,) float64, nm
        Ions' signed distances to the surface.
    u : (b,) float64
        Their normalised score (0 on the outside plateau, 1 inside; a fraction per ion).
    weight : (b,) float64
        Atoms per ion.
    nz2 : (b,) float64
        Squared z component of the unit normal where each ion is.
    classes : int
        Classes of ``1 - n_z^2`` (equal width on [0, 1]).
    min_ions : int
        Fewest ions in a class for it to count; fewer than two such classes at least half the range apart
        give None (no estimate: e.g. one flat interface).

    Returns
    -------
    BlurEstimate or None
    """
    def width(sel):
        return _step_width(distance[sel], u[sel], weight[sel], half_width, bin_width)

    return _by_tilt(distance, nz2, width, classes, half_width, min_ions, "step")


def peak_blur(distance: np.ndarray, marker: np.ndarray, total: np.ndarray, nz2: np.ndarray, name: str = "marker",
              classes: int = 4, half_width: float = 1.5, bin_width: float = 0.1, min_ions: int = 2000,
              significance: float = 5.0) -> BlurEstimate | None:
    """Lateral blur sigma from the width of a segregant's peak against the surface orientation (module docstring).

    Parameters
    ----------
    distance : (b,) float64, nm
        Ions' signed distances to the surface.
    marker : (b,) float64
        Atoms of the segregant per ion.
    total : (b,) float64
        Atoms per ion (the segregant's included: its fraction is ``marker / total``).
    nz2 : (b,) float64
        Squared z component of the unit normal where each ion is.
    name : str
        The segregant, for :attr:`BlurEstimate.source`.
    significance : float
        Standard errors by which a class's peak must stand above its background to count.
    classes, half_width, bin_width, min_ions
        As in :func:`lateral_blur`.

    Returns
    -------
    BlurEstimate or None
        None where fewer than two classes, at least half the tilt range apart, hold a significant peak.
    """
    def width(sel):
        peak = fit_peak(distance[sel], marker[sel], total[sel], half_width, bin_width)
        if peak is None or not peak.significant(significance, half_width):
            return None
        return peak.width, float(peak.se[3])

    return _by_tilt(distance, nz2, width, classes, half_width, min_ions, f"peak of {name}")


def _by_tilt(distance: np.ndarray, nz2: np.ndarray, width, classes: int, half_width: float, min_ions: int,
             source: str) -> BlurEstimate | None:
    """The slope of ``width(sel)^2`` against ``1 - n_z^2`` over classes of the tilt (``width`` -> (w, se) or None)."""
    tilt = 1 - np.clip(nz2, 0.0, 1.0)
    label = np.minimum((tilt * classes).astype(np.int64), classes - 1)
    near = np.abs(distance) <= half_width
    widths, errors, means = [], [], []
    for k in range(classes):
        sel = near & (label == k)
        if sel.sum() < min_ions:
            continue
        found = width(sel)
        if found is None:
            continue
        widths.append(found[0])
        errors.append(found[1])
        means.append(float(tilt[sel].mean()))
    if len(widths) < 2 or max(means) - min(means) < 0.5:
        return None
    widths, errors, means = map(np.asarray, (widths, errors, means))
    y, sy = widths ** 2, np.maximum(2 * widths * errors, 1e-6)
    design = np.column_stack([np.ones_like(means), means]) / sy[:, None]
    coef, *_ = np.linalg.lstsq(design, y / sy, rcond=None)
    cov = np.linalg.pinv(design.T @ design)
    slope = float(coef[1])
    return BlurEstimate(float(np.sqrt(max(slope, 0.0))), slope, float(np.sqrt(cov[1, 1])), widths, means, source)


def shrunk_slope(*, slope: float, se: float) -> float:
    """Posterior mean (nm²) of ``sigma_lat^2 - sigma_depth^2`` given a fitted ``slope`` with standard error ``se``
    (nm²) under the Gaussian :data:`SLOPE_PRIOR`: the fit and the prior weighed by their inverse variances."""
    mean, sd = SLOPE_PRIOR
    fit = 1.0 / max(se, 1e-12) ** 2
    return (fit * slope + mean / sd ** 2) / (fit + 1.0 / sd ** 2)
