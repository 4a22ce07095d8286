"""How smooth each object is, chosen from ions it was not fitted to: two-fold cross-validation.

How many manifold harmonics (:mod:`apt_filters.refine.spectral`) a refined object's shape deserves
depends on how many ions describe it and on the shape: a 3 nm sphere's ions support its centre, its
radius and perhaps an ellipsoid (4-9 modes); an elongated object needs more (an ellipsoid of axes 2:3:4
about 36 to keep its extents to 1 %); a cube's edges need many more, unless the facets rebuild them after
the low-pass. No fixed smoothing suits all, and a prior on the shape is what the truth-first rule
forbids, so each object's cut-off is chosen by how well the surface predicts ions that did not place it.

Method
------
The ions are split in two (even and odd rows, as the cross-fitted plateaus of
:func:`~apt_filters.refine.surface.refine_surface` are); each half has placed its own surface. For each
candidate number of modes ``k`` and for the refined shape as it is (``k = 0``), every eligible object of
each half's surface is low-passed to ``k`` modes and finished as the final surface is (blur correction,
facets); the OTHER half's ions within 2 nm of it are then scored: each ion's score fraction against the
object's error-function step (its plateaus, its measured profile width) at the ion's signed distance to
that candidate, squared and weighted by the ion's atoms. The ``k`` whose two held-out sums are smallest
is the object's, or rather the fewest modes whose loss is within one standard error of the smallest
(the one-standard-error rule of cross-validation: two candidates the ions cannot tell apart go to the
smoother, since the loss is itself noisy). Since the held-out ions are independent of the surface they
score, the expected loss is a constant plus ``sum_i m'(d_i)^2 delta_i^2``, ``delta`` the candidate's distance to the true
interface where ion ``i`` is: an information-weighted mean squared error of the shape, minimised
without knowing the truth.

Eligible objects are closed (an open interface meets the specimen edge, where its rim must stay) with
both plateaus measured. On the gamma-prime specimen (seeds 1-8) the 3 nm spheres chose 4 modes (13 of 16)
or 9, the cubes 4 (9 of 16) to 36, their edges and corners then rebuilt by the facets; the spheres' mean
distance to the truth is 0.08-0.13 nm with the selection (0.15-0.20 without) and their area errors within
their volume's (+2-8 % without; benchmarks/results_refine.md).

Cost: per half, one eigensolve per eligible object, one finish and band per candidate (with and without
facets) and, for the facets' test at fitted sizes, two more finishes, bands and size fits (each faceted object's
best candidates with and without facets); memory: the held-out ions within 3 nm of the surface (as
:class:`~apt_filters.refine.band.NearIons`), the scored ones of both halves kept for the second pass, and
``n x 47`` float64 of harmonics per object and half.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from numba import njit
from scipy.special import erfc

from apt_filters.core.mesh import TriMesh, vertex_normals
from apt_filters.refine.band import NearIons
from apt_filters.refine.composition import ObjectScores
from apt_filters.refine.facets import unclosed_margin
from apt_filters.refine.spectral import Harmonics, harmonics, low_pass, rim_held_low_pass

CANDIDATES = (4, 9, 16, 25, 36)
"""Numbers of modes tried: complete spherical-harmonic degrees 1-5 on a sphere. 64 modes would be chosen for
none of 32 gamma-prime precipitates (seeds 1-8) and their 82-mode eigensolves cost a sixth of the
refinement of the 10M-ion ``many`` specimen (47 objects)."""
ONE_SE = 1.0
"""Standard errors within which the smoothest candidate is preferred to the best (the one-standard-error rule)."""
SCORED = 2.0
"""nm from the unsmoothed half surface within which held-out ions are scored (the profile's reach)."""


@dataclass
class ModeSelection:
    """The modes chosen per object and the held-out losses behind the choice.

    Attributes
    ----------
    modes : dict[int, int]
        Component -> modes kept (0: the refined shape as it is). Ineligible objects are absent.
    candidates : tuple of int
        The ``k`` tried, in the order of ``losses``' columns (then 0).
    losses : (c, len(candidates) + 1) float64
        Held-out loss of each candidate minus that of the shape as it is (atoms; negative: better),
        summed over both folds; NaN for ineligible objects or candidates with more modes than vertices.
    facets : dict[int, bool]
        Component -> whether its facets are kept: every object with facets on either half's surface, tried
        with and without them; dropped where its best candidate without them has a held-out loss lower by more
        than one standard error than its best with them, either as the candidates stand or with these two first
        moved by the offset that fits each to the placing half's ions (:meth:`HeldOutLoss.fitted_shift`: the
        facets' planes are fitted so; this second test judges their shape, not the smooth surface's size).
        Facets that do not close their object (``unclosed``) are kept only where both tests prefer them by a margin
        that grows with their planes (:func:`~apt_filters.refine.facets.unclosed_margin`).
    lengths : dict[int, float]
        Open object -> its smoothing length, nm (:func:`cross_validated_lengths`; 0: as it is).
    """

    modes: dict[int, int]
    candidates: tuple[int, ...]
    losses: np.ndarray
    facets: dict[int, bool] = field(default_factory=dict)
    lengths: dict[int, float] = field(default_factory=dict)


def object_harmonics(vertices: np.ndarray, faces: np.ndarray, components: np.ndarray, objects,
                     k: int | dict[int, int]) -> dict[int, tuple[np.ndarray, Harmonics]]:
    """Component -> (its vertex indices, its ``k`` lowest harmonics) for each of ``objects`` (``k`` one number
    for all, or per object)."""
    out = {}
    for c in objects:
        idx = np.flatnonzero(components == c)
        local = np.full(len(vertices), -1, dtype=np.int64)
        local[idx] = np.arange(len(idx))
        mine = faces[components[faces[:, 0]] == c]
        out[c] = (idx, harmonics(vertices[idx], local[mine], k[c] if isinstance(k, dict) else k))
    return out


def mode_limit(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The modes an object's shape holds down to its thickness: ``A^3 / (pi V^2)`` = ``A / (pi tau^2)``, ``tau = V
    / A`` (nm; a sphere's radius / 3, a disc's half-thickness), for one closed object's ``vertices`` (n, 3) nm and
    ``faces`` (m, 3).

    Weyl's law puts the number of Laplace-Beltrami modes of wavelength above ``l`` on a surface of area ``A`` at
    ``~ pi A / l^2``: the count that resolves the object's thinnest extent grows as ``A / tau^2``. Scaled so that a
    sphere's is the largest of :data:`CANDIDATES` (``4 pi R^2 / (pi R^2 / 9)`` = 36, its complete degrees up to 5):
    a cube 69, a lath 3 x 6.5 x 11.5 nm 108, a disc 1.9 nm thick of radius 6.4 nm 199, whose rim the 36 modes of
    a sphere round off.
    """
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    volume = abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0
    return float(area ** 3 / (np.pi * volume ** 2)) if volume > 0 else 0.0


def finer_candidates(candidates: tuple[int, ...], limit: float) -> tuple[int, ...]:
    """``candidates`` continued past the last, ``(d + 1)^2`` modes of degree ``d``, in steps of two degrees (64, 100,
    144, ...), as far as ``limit`` (:func:`mode_limit`) reaches."""
    out, degree = list(candidates), int(round(np.sqrt(candidates[-1]))) + 1
    while (degree + 1) ** 2 <= limit:
        out.append((degree + 1) ** 2)
        degree += 2
    return tuple(out)


def apply_modes(vertices: np.ndarray, bases: dict[int, tuple[np.ndarray, Harmonics]], modes: dict[int, int]
                ) -> np.ndarray:
    """(n, 3) ``vertices`` with each object ``c`` of ``modes`` low-passed to about ``modes[c]`` modes (0: as it
    is), cut at the nearest gap of its spectrum (:meth:`~apt_filters.refine.spectral.Harmonics.cut`)."""
    out = vertices.copy()
    for c, k in modes.items():
        if k:
            idx, basis = bases[c]
            out[idx] = low_pass(vertices[idx], basis, basis.cut(k))
    return out


def basis_size(k: int) -> int:
    """Harmonics to compute for a cut near ``k`` modes (the gap search looks a quarter beyond it)."""
    return int(1.25 * k) + 2


def cross_validated_modes(fits: list[np.ndarray], faces: np.ndarray, components: np.ndarray, objects: list[int],
                          held_out: list[NearIons], scores: ObjectScores, widths: np.ndarray, finisher: Callable[[int], Callable],
                          candidates: tuple[int, ...] = CANDIDATES, faceted_objects=(),
                          unclosed: dict[int, int] | None = None) -> ModeSelection:
    """Each object's number of modes by two-fold cross-validation (module docstring).

    Parameters
    ----------
    fits : two (n, 3) float64 arrays
        The surfaces each half of the ions placed (same ``faces``), before finishing.
    faces : (m, 3) int
    components : (n,) int
        Object of each vertex.
    objects : list of int
        Eligible objects.
    held_out : two NearIons
        The ions of each half (in the order of ``fits``) near the OTHER half's surface (at least ``SCORED + 1``
        nm from it), in the basis of the profiles.
    scores : ObjectScores
        Each object's score weights and plateau levels.
    widths : (c,) float64, nm
        Each object's profile width (error-function sigma).
    finisher : callable
        ``finisher(k, facets)(vertices)[0]``: the vertices after what follows the low-pass on the final surface
        (blur, and the facets if ``facets``), for the surface half ``k`` placed (``fits[k]`` before the
        low-pass).
    candidates : tuple of int
    faceted_objects : iterable of int
        Objects with facets on either half's surface: tried without them too.
    unclosed : dict[int, int]
        Of those, the objects whose facets on the whole surface (those the finish will apply) do not close them
        (:func:`~apt_filters.refine.facets.closes`), with the number of those facets: they keep their facets only
        where the held-out ions prefer them by :func:`~apt_filters.refine.facets.unclosed_margin` of that number
        (below), not merely where they do not reject them.
    """
    n_comp = len(scores.usable)
    # each object's candidates go as far as its shape's detail (mode_limit, the less of the two halves' surfaces)
    own = {c: finer_candidates(candidates, min(mode_limit(fit, mine) for fit in fits))
           for c in objects for mine in [faces[components[faces[:, 0]] == c]]}
    candidates = max(own.values(), key=len, default=tuple(candidates))
    plain = list(candidates) + [0]
    half = len(plain)
    # each candidate finished with the facets, then without them (the second set only where there are facets)
    columns = [(k, True) for k in plain] + [(k, False) for k in plain]
    m = len(columns)
    faceted = np.zeros(n_comp, dtype=bool)
    faceted[list(faceted_objects)] = True
    # per object: sums and the Gram matrix of the per-ion losses, for the losses and their differences' errors
    sums, gram, count = np.zeros((n_comp, m)), np.zeros((n_comp, m, m)), np.zeros(n_comp)
    missing = np.zeros((n_comp, m), dtype=bool)
    folds = []
    for k, fit in enumerate(fits):
        bases = object_harmonics(fit, faces, components, objects, {c: basis_size(max(own[c])) for c in objects})
        finish = {True: finisher(k, True), False: finisher(k, False)}
        comp, loss = held_out_loss(fit, faces, components, objects, held_out[1 - k], scores, widths)
        # the candidates without facets are read for the faceted objects alone (the others' ions score 0 there)
        faceted_ions = np.flatnonzero(faceted[comp])
        per_ion = np.empty((len(comp), m))
        for j, (modes, with_facets) in enumerate(columns):
            trial = {c: modes for c in objects if modes in own[c] and basis_size(modes) <= bases[c][1].size}
            missing[np.ix_([c for c in objects if c not in trial and modes], [j])] = True
            if not with_facets and not faceted.any():
                missing[:, j] = True
                continue
            candidate = finish[with_facets](apply_modes(fit, bases, trial))[0]
            per_ion[:, j] = loss(candidate) if with_facets else loss(candidate, faceted_ions)
        _accumulate(per_ion, comp, objects, sums, gram, count)
        folds.append((fit, bases, finish, comp, loss, faceted_ions))
    missing[~faceted, half:] = True
    loss_of = np.where(missing, np.inf, sums)
    # the facets' second test, at fitted sizes: each faceted object's best candidate with its facets and its best
    # without them (as they stand, over both folds), each first moved by the offset that fits it to the ions of the
    # half that placed it; columns 0 and 1 of ``sized`` (the objects' other candidates are never compared)
    best = {c: (int(np.argmin(loss_of[c, :half])), half + int(np.argmin(loss_of[c, half:]))) for c in objects}
    sized_sums, sized_gram = np.zeros((n_comp, 2)), np.zeros((n_comp, 2, 2))
    for k, (fit, bases, finish, comp, loss, faceted_ions) in enumerate(folds if faceted.any() else []):
        own_comp, own = held_out_loss(fit, faces, components, objects, held_out[k], scores, widths)
        own_ions = np.flatnonzero(faceted[own_comp])
        per_ion = np.zeros((len(comp), 2))
        for side, with_facets in enumerate((True, False)):
            trial = {c: plain[best[c][side] % half] for c in objects if faceted[c]}
            candidate = finish[with_facets](apply_modes(fit, bases, trial))[0]
            shift = own.fitted_shift(own.distances(candidate, own_ions), own_ions, n_comp)
            per_ion[:, side] = loss.at(loss.distances(candidate, faceted_ions), faceted_ions, shift)
        _accumulate(per_ion, comp, objects, sized_sums, sized_gram)
    losses = np.full((n_comp, half), np.nan)
    chosen, keep_facets = {}, {}
    for c in objects:
        loss = loss_of[c]
        # facets are a prior on the shape, found by a rule: dropped where the held-out ions prefer the best
        # candidate without them to the best with them by more than one standard error of the difference, as
        # the candidates stand (the surfaces the whole would have) or with each sized to the placing half's ions
        # (the facets' planes are, by fit_to_ions: a smooth surface left at its own size lost to a polyhedron
        # around a 1.45 nm rod, held-out thin 10005: the smooth one 10 % small in volume, the polyhedron's 7 %
        # large and 13 % in area, preferred by 2.5 SE for its size, rejected by 1.04 SE at fitted sizes). Facets
        # must pass both: sized alone, dev rod 3's 1.5 nm rod, rejected by 1.45 SE as it stood, kept its facets
        # at -0.39 SE (area -2.8 -> +5.3 %). Where neither rejects them they stay: at fitted sizes the ions could
        # not tell a 4.5 nm cube at 10 points of contrast from its 0.8 nm rounding (+0.7 SE; a 6 % volume).
        # Facets that do not close their object are no polyhedron: nothing refits their planes to the ions (those of
        # the placement's vertices), and they have no edge or corner to rebuild; only their cores move onto the
        # planes, and what lies between them stays where the low-pass left it, so on a curved low-passed face the
        # flattened core breaks off from its surroundings (held-out plate 10010's second plate, 4.2 points of
        # contrast: two parallel faces on its 9-mode lens, their cores up to 1.6 nm off the planes, area 262 ->
        # 318 nm² against a true 261, at +0.06 and -0.36 SE). They are a weaker prior, so they must win in both
        # tests, by a margin that grows with their planes: a search that cuts a smooth object into more strips has
        # more chances to fit its noise (unclosed_margin: a capsule's eight strips won by 1.85 and 1.21 SE)
        with_facets = True
        if faceted[c]:
            gains = [_difference(gram[c], sums[c], count[c], *best[c]),
                     _difference(sized_gram[c], sized_sums[c], count[c], 0, 1)]
            with_facets = bool(np.isfinite(loss[:half]).any()) and (
                all(diff > unclosed_margin(unclosed[c], ONE_SE) * se for diff, se in gains) if c in (unclosed or {})
                else not any(diff < -ONE_SE * se for diff, se in gains))
            keep_facets[c] = with_facets
        side = slice(0, half) if with_facets else slice(half, 2 * half)
        loss, g, s_c = loss[side], gram[c][side, side], sums[c][side]
        chosen[c] = plain[smoothest_within_one_se(loss, g, s_c, count[c])]
        losses[c] = np.where(np.isinf(loss), np.nan, s_c - s_c[-1])
    return ModeSelection(chosen, tuple(candidates), losses, keep_facets)


def _difference(gram: np.ndarray, sums: np.ndarray, count: float, jw: int, jn: int) -> tuple[float, float]:
    """How much lower (atoms; negative: higher) the held-out loss of candidate ``jw`` (the best with facets) is than
    that of ``jn`` (the best without them), and the standard error of that difference (arguments as
    :func:`smoothest_within_one_se`'s)."""
    diff = sums[jn] - sums[jw]
    se = np.sqrt(max(gram[jw, jw] + gram[jn, jn] - 2 * gram[jw, jn] - diff ** 2 / max(count, 1.0), 0.0))
    return float(diff), float(se)


def held_out_loss(fit: np.ndarray, faces: np.ndarray, components: np.ndarray, objects, held: NearIons,
                  scores: ObjectScores, widths: np.ndarray) -> tuple[np.ndarray, "HeldOutLoss"]:
    """The held-out ions a half surface is scored on, and their loss against a candidate surface.

    Parameters
    ----------
    fit : (n, 3) float64
        The surface one half of the ions placed (its candidates are the same mesh, moved).
    faces : (m, 3) int
    components : (n,) int
    objects : list of int
        The objects scored.
    held : NearIons
        The OTHER half's ions near ``fit`` (at least ``SCORED + 1`` nm from it).
    scores : ObjectScores
    widths : (c,) float64, nm

    Returns
    -------
    comp : (h,) int
        Object of each scored ion (those within ``SCORED`` of ``fit`` on an object of ``objects``).
    loss : HeldOutLoss
        ``loss(vertices, only=None, shift=None)`` (h,): each ion's atoms times the squared difference of its score
        fraction from its object's error-function step at its signed distance to ``vertices``.
    """
    held = held.subset(np.arange(len(held.rows)), fit, SCORED + 1.0)
    start = held.band(fit, vertex_normals(fit, faces), SCORED + 1.0)
    keep = np.abs(start.distance) < SCORED
    rows, comp = start.index[keep], components[start.vertex[keep]]
    score, total = scores.fraction(held.atoms.atoms[rows], comp)
    ok = (total > 0) & np.isin(comp, objects)
    rows, comp, fraction, total = rows[ok], comp[ok], score[ok] / total[ok], total[ok]
    # only the scored ions are measured against each candidate (their nearest vertices of ``fit`` kept)
    return comp, HeldOutLoss(held.subset(rows, fit, SCORED + 1.0), faces, comp, fraction, total,
                             scores.outside[comp], scores.inside[comp], np.sqrt(2) * widths[comp])


class HeldOutLoss:
    """The scored ions of :func:`held_out_loss` and their losses against candidate surfaces.

    ``only`` (indices into the scored ions, the same in every call that gives it, after every call without it):
    the other ions' losses are 0 and not measured. ``shift`` (c,) nm: each object's candidate taken as moved out
    along its normals by ``shift[c]`` (its ions' signed distances less the shift: exact for an offset surface).
    """

    def __init__(self, held: NearIons, faces: np.ndarray, comp: np.ndarray, fraction: np.ndarray, total: np.ndarray,
                 lo: np.ndarray, hi: np.ndarray, sigma: np.ndarray):
        self.held, self.faces, self.comp, self.fraction, self.total = held, faces, comp, fraction, total
        self.lo, self.hi, self.sigma = lo, hi, sigma
        self._some = None  # the ions of ``only``, taken once: their nearest vertices followed from there on

    def distances(self, vertices: np.ndarray, only: np.ndarray | None = None) -> np.ndarray:
        """(h,) or (len(only),) nm: the scored ions' signed distances to ``vertices`` (``SCORED + 1`` beyond it)."""
        if only is not None and self._some is None:
            self._some = self.held.take(only)
        ions = self.held if only is None else self._some
        band = ions.band(vertices, vertex_normals(vertices, self.faces), SCORED + 1.0)
        distance = np.full(len(ions.positions), SCORED + 1.0)
        distance[band.index] = band.distance
        return distance

    def at(self, distance: np.ndarray, only: np.ndarray | None = None, shift: np.ndarray | None = None
           ) -> np.ndarray:
        """(h,) the losses of the ions at ``distance`` (from :meth:`distances` with the same ``only``)."""
        pick = slice(None) if only is None else only
        if shift is not None:
            distance = distance - shift[self.comp[pick]]
        out = np.zeros(len(self.comp))
        model = self.lo[pick] + (self.hi[pick] - self.lo[pick]) * 0.5 * erfc(distance / self.sigma[pick])
        out[pick] = self.total[pick] * (self.fraction[pick] - model) ** 2
        return out

    def __call__(self, vertices: np.ndarray, only: np.ndarray | None = None, shift: np.ndarray | None = None
                 ) -> np.ndarray:
        return self.at(self.distances(vertices, only), only, shift)

    def fitted_shift(self, distance: np.ndarray, only: np.ndarray, n_comp: int, iterations: int = 20
                     ) -> np.ndarray:
        """(n_comp,) nm: each object's outward move of the candidate (``distance``: the ions of ``only``, from
        :meth:`distances`) that minimises these ions' loss, by Gauss-Newton on the one offset per object, each step
        at most the object's profile width; 0 for objects without ions here or with a profile of zero width (a
        sharp step has no slope to follow: their candidates are compared as they stand)."""
        spread = self.sigma[only] > 0
        only, distance = only[spread], distance[spread]
        comp, f, a = self.comp[only], self.fraction[only], self.total[only]
        lo, hi, sigma = self.lo[only], self.hi[only], self.sigma[only]
        # what the steps do not change, taken once (the same numbers as in every step)
        above, contrast, half_contrast = f - lo, hi - lo, (hi - lo) * 0.5
        density = np.sqrt(np.pi) * sigma
        # at most one width (sigma / sqrt 2) a step
        width = np.bincount(comp, sigma, minlength=n_comp) / np.maximum(np.bincount(comp, minlength=n_comp), 1)
        largest, settled = width / np.sqrt(2), 1e-6 * np.maximum(width, 1e-12)
        shift = np.zeros(n_comp)
        for _ in range(iterations):
            # the error function and the exponential stay scipy's and numpy's (the same numbers); the rest of the
            # step is two compiled passes
            x, square = _scaled(distance, shift, comp, sigma)
            num, den = _normal_sums(comp, a, above, half_contrast, erfc(x), contrast, np.exp(square), density,
                                    n_comp)
            step = np.clip(np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0), -largest, largest)
            shift += step
            if np.all(np.abs(step) <= settled):
                break
        return shift


@njit(cache=True, nogil=True)
def _scaled(distance, shift, comp, sigma):
    """(h,) ``x = (distance - shift[comp]) / sigma`` and (h,) ``-x x`` (:meth:`HeldOutLoss.fitted_shift`)."""
    x, square = np.empty(len(distance)), np.empty(len(distance))
    for i in range(len(distance)):
        x[i] = (distance[i] - shift[comp[i]]) / sigma[i]
        square[i] = -x[i] * x[i]
    return x, square


@njit(cache=True, nogil=True)
def _normal_sums(comp, a, above, half_contrast, erfc_x, contrast, exp_x, density, n_comp):
    """(n_comp,) each object's Gauss-Newton numerator and denominator of :meth:`HeldOutLoss.fitted_shift`: the sums
    of ``a r s`` and ``a s^2`` over its ions, the residual ``r = above - half_contrast erfc_x`` and the slope ``s =
    contrast exp_x / density`` (all (h,)), added in the ions' order as ``np.bincount`` adds them (the same numbers,
    without the five temporary arrays a pass)."""
    num, den = np.zeros(n_comp), np.zeros(n_comp)
    for i in range(len(comp)):
        residual = above[i] - half_contrast[i] * erfc_x[i]
        slope = contrast[i] * exp_x[i] / density[i]
        num[comp[i]] += a[i] * residual * slope
        den[comp[i]] += a[i] * slope * slope
    return num, den


def _accumulate(per_ion: np.ndarray, comp: np.ndarray, objects, sums: np.ndarray, gram: np.ndarray,
                count: np.ndarray | None = None) -> None:
    """Adds each object's per-ion losses (ions x candidates) to its sums, Gram matrix and ion count (``count``;
    None where the ions were counted already, as for a second pass over the same ions)."""
    for c in objects:
        mine = per_ion[comp == c]
        sums[c] += mine.sum(axis=0)
        gram[c] += mine.T @ mine
        if count is not None:
            count[c] += len(mine)


def smoothest_within_one_se(loss: np.ndarray, gram: np.ndarray, sums: np.ndarray, count: float) -> int:
    """Index of the smoothest candidate (columns run smooth to rough) whose held-out loss is within
    :data:`ONE_SE` standard errors of the smallest; the error of each candidate's loss minus the best one's is
    that of a sum over ions of their differences (``gram``: the candidates' per-ion Gram matrix, ``sums`` their
    sums, ``count`` ions; ``loss`` is ``sums`` with inf where a candidate is missing)."""
    best = int(np.argmin(loss))
    diff_sq = np.diag(gram) + gram[best, best] - 2 * gram[:, best]
    se = np.sqrt(np.maximum(diff_sq - (sums - sums[best]) ** 2 / max(count, 1.0), 0.0))
    return int(np.flatnonzero(loss <= loss[best] + ONE_SE * se)[0])


LENGTHS = (8.0, 5.6, 4.0, 2.8, 2.0, 1.4, 1.0)
"""Smoothing lengths (nm) tried for open surfaces, smooth to rough
(:func:`~apt_filters.refine.spectral.rim_held_low_pass`: cut-off wavelengths 6-50 nm); the surface as it is is
tried last."""


def open_low_pass(vertices: np.ndarray, faces: np.ndarray, components: np.ndarray, lengths: dict[int, float]
                  ) -> np.ndarray:
    """(n, 3) ``vertices`` with each open object ``c`` of ``lengths`` low-passed at ``lengths[c]`` nm, its rim
    held (:func:`~apt_filters.refine.spectral.rim_held_low_pass`)."""
    out = vertices.copy()
    for c, length in lengths.items():
        if length > 0:
            idx = np.flatnonzero(components == c)
            local = np.full(len(vertices), -1, dtype=np.int64)
            local[idx] = np.arange(len(idx))
            out[idx] = rim_held_low_pass(vertices[idx], local[faces[components[faces[:, 0]] == c]], length)
    return out


def cross_validated_lengths(fits: list[np.ndarray], faces: np.ndarray, components: np.ndarray, objects: list[int],
                            held_out: list[NearIons], scores: ObjectScores, widths: np.ndarray,
                            candidates: tuple[float, ...] = LENGTHS) -> dict[int, float]:
    """Each open object's smoothing length by two-fold cross-validation, as :func:`cross_validated_modes`
    chooses a closed object's modes: each half's surface low-passed at each candidate length (rim held) is
    scored on the other half's ions; the object keeps the smoothest candidate within one standard error of the
    best (0: the surface as it is), among those whose cut-off wavelength ``2 pi l`` is within the object's
    extent (the square root of its area): longer ones flatten the object's shape, not its noise, and with few
    ions the standard errors are wide enough to let the flattest candidate through (a 40 nm cap across a
    14 nm box came out 0.26 nm flat). Arguments as :func:`cross_validated_modes`'s.

    The halves' surfaces must not share noise the held-out ions hold: a start contoured from all the ions does,
    and where the placement cannot undo it (shorter than its own smoothing of the moves) the held-out ions
    agree with it and the selection keeps it; :func:`refine_surface` smooths an open start first
    (:func:`open_start`).
    """
    plain = np.array(list(candidates) + [0.0])
    n_comp = len(scores.usable)
    sums, gram, count = np.zeros((n_comp, len(plain))), np.zeros((n_comp, len(plain), len(plain))), np.zeros(n_comp)
    # no cut-off wavelength (2 pi l) beyond the object's own extent (the square root of its area): there the
    # filter would flatten the object's shape, not its noise
    extent = np.sqrt(np.bincount(components[faces[:, 0]], TriMesh(fits[0], faces).face_areas(), minlength=n_comp))
    for k, fit in enumerate(fits):
        comp, loss = held_out_loss(fit, faces, components, objects, held_out[1 - k], scores, widths)
        per_ion = np.column_stack([loss(open_low_pass(fit, faces, components,
                                                      {c: length for c in objects if 2 * np.pi * length <= extent[c]}))
                                   for length in plain])
        _accumulate(per_ion, comp, objects, sums, gram, count)
    return {c: float(plain[smoothest_within_one_se(np.where(2 * np.pi * plain <= extent[c], sums[c], np.inf), gram[c],
                                                   sums[c], count[c])]) for c in objects}


def open_start(vertices: np.ndarray, faces: np.ndarray, components: np.ndarray, objects, smoothing: int
               ) -> np.ndarray:
    """(n, 3) the start of the refinement with its open ``objects`` low-passed below the length the placement
    smooths its own moves over: ``smoothing`` umbrella passes spread a move over ``sqrt(smoothing / 2)`` edges
    (a random walk of one edge per pass in two dimensions). Shorter than that the placement cannot correct the
    start, so the noise of a start contoured from all the ions would stay in both halves' surfaces and in the
    held-out ions alike (on a low-contrast curved interface the selection then kept a 0.3 nm roughness it
    would otherwise have removed)."""
    if not len(objects):
        return vertices
    edges = np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1)
    length = float(np.sqrt(smoothing / 2.0) * np.median(edges))
    return open_low_pass(vertices, faces, components, {c: length for c in objects})
