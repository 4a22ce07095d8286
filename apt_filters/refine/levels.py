"""Plateau compositions of each object, and the per-object iso-value (midpoint of its plateaus)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.special import ndtri

from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh, topology, vertex_normals
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.band import Band, NearIons
from apt_filters.refine.composition import IonAtoms
from apt_filters.refine.specks import ALPHA
from apt_filters.voxel import ConcentrationBasis

PLATEAU_WINDOW = (0.75, 3.0)
"""Default distances (nm) from the surface between which the plateaus are measured, each side.

Against a refined surface the inside plateau from 0.75 nm is biased by the surface's own noise (+0.6 at.%
Al with the refinement's own ions, +0.0 with an independent specimen's, gamma-prime seeds 1-5), but from
1.0 nm (the refinement's :data:`~apt_filters.refine.surface.REFINE_WINDOW`) a 3 nm sphere keeps ~30 % fewer
atoms inside and the reported plateau came out worse (seeds 1-3, worst / mean abs: 1.72 / 1.04 ->
2.33 / 1.40 at.%; on the TRUE surfaces 1.55 / 0.75 -> 2.73 / 1.09 at.%), so reporting keeps 0.75 nm."""

PLATEAU_PRIOR = 3000.0
"""Default weight (atoms) of the pooled plateaus of all objects in each object's own (shrinkage)."""


@dataclass
class ObjectLevels:
    """The two plateaus of one connected surface (one object), in the concentration basis.

    Attributes
    ----------
    component : int
        Component id (``face_scalars["component"]`` numbering of :meth:`TriMesh.face_components`).
    elements : list of str
        Basis elements.
    inside, outside : (k,) float64
        Fractions of each basis element between ``window`` nm inside / outside the surface
        (shrunk toward the pooled levels of the objects that agree with it by ``prior`` atoms, :func:`agreeing_pools`).
    n_inside, n_outside : float
        Basis atoms of this object counted in each plateau window.
    iso : float
        Midpoint of the iso species' two plateaus: where this object's surface belongs.
    worth_inside, worth_outside : float
        Atoms whose binomial count would be as certain as each shrunk plateau (:func:`shrunk_worth`): the window's
        own atoms and the prior's, the prior no more certain than the pool it is drawn from. NaN where not known.
    """

    component: int
    elements: list[str]
    inside: np.ndarray
    outside: np.ndarray
    n_inside: float
    n_outside: float
    iso: float
    worth_inside: float = math.nan
    worth_outside: float = math.nan

    def as_dict(self) -> dict:
        return {"component": self.component, "iso": self.iso, "n_inside": self.n_inside, "n_outside": self.n_outside,
                "inside": dict(zip(self.elements, self.inside.tolist())),
                "outside": dict(zip(self.elements, self.outside.tolist()))}


def within_rim(band: Band, near: NearIons, mesh: TriMesh, reach: float) -> Band:
    """The ions of ``band`` whose closest point on ``mesh`` is not on its rim.

    An open surface (an interface that leaves the specimen, an object cut by its edge) has ions beyond its
    rim: their nearest vertex is a rim vertex and their offset along its normal says nothing about which
    side of the interface they are on, yet counted they enter a plateau window or the excess band as if
    across the surface (a spinodal's Si excess +14 % and its inside plateau 14 sigma low on the whole box).
    They are the ions whose exact closest surface point lies on a boundary edge or vertex
    (:attr:`~apt_filters.core.distance.SignedDistance.on_boundary`, as the proxigram leaves them out); a
    closed mesh keeps every ion.

    Parameters
    ----------
    band : Band
        Ions of ``near`` within ``reach`` of their nearest vertex of ``mesh``.
    near : NearIons
    mesh : TriMesh
        The surface ``band`` was measured against.
    reach : float, nm
    """
    if not len(mesh.boundary_edges()) or not len(band.index):
        return band
    rim = SurfaceDistance(mesh, reach=reach).query(near.positions[band.index], max_distance=reach).on_boundary
    return Band(band.index[~rim], band.vertex[~rim], band.distance[~rim])


def plateau_sums(band: Band, atoms: IonAtoms, components: np.ndarray, n_components: int,
                 window=PLATEAU_WINDOW, weight: np.ndarray | None = None) -> np.ndarray:
    """(n_components, 2, k) atoms of each basis element in each object's inside (0) and outside (1) window.

    Sums, so that the windows of separate ion sets (e.g. the two halves of :func:`refine_surface`'s
    cross-fit) add up before :func:`levels_from_sums`. Each window's sum runs over its ions in the band's order, in
    float64, as ``np.bincount`` sums it.

    An object with no ion ``window[0]`` deep (a rod or plate thinner than the delocalization, or a first contour
    that is a sliver of one) is measured from halfway to its deepest ion instead (:func:`inside_inner`).
    ``weight``: (b,) what each ion of ``band`` counts for (:func:`lobe_weights`); 1 each where not given.
    """
    comp = components[band.vertex]
    out = np.zeros((n_components, 2, atoms.atoms.shape[1]))
    _window_sums(np.ascontiguousarray(comp, dtype=np.int64), window_labels(band, comp, n_components, window),
                 np.ascontiguousarray(band.index, dtype=np.int64), atoms.atoms,
                 np.zeros(0) if weight is None else np.ascontiguousarray(weight, dtype=np.float64), out)
    return out


@njit(cache=True, nogil=True)
def _window_sums(comp, window_of, index, atoms, weight, out):
    """:func:`plateau_sums`' one pass over the band (``atoms`` (N, k) of every ion, ``weight`` (b,) or empty)."""
    for i in range(comp.shape[0]):
        side = window_of[i]
        if side < 0:
            continue
        for e in range(atoms.shape[1]):
            a = np.float64(atoms[index[i], e])
            out[comp[i], side, e] += a * weight[i] if weight.shape[0] else a


def window_labels(band: Band, comp: np.ndarray, n_components: int, window=PLATEAU_WINDOW) -> np.ndarray:
    """(b,) int64 each ion's plateau window: 0 inside, 1 outside, -1 neither or of no object (``comp``: each ion's
    object, -1 none). ``window``: (inner, outer) nm, ``outer`` one edge for every object or (n_components,) each
    object's own (:func:`open_window_edges`)."""
    inner, outer = window
    comp = np.ascontiguousarray(comp, dtype=np.int64)
    window_of = np.empty(len(comp), dtype=np.int64)
    _window_labels(np.ascontiguousarray(band.distance, dtype=np.float64), comp,
                   inside_inner(band, comp, n_components, inner), float(inner),
                   np.ascontiguousarray(np.broadcast_to(np.asarray(outer, dtype=np.float64), (n_components,))),
                   window_of)
    return window_of


@njit(cache=True, nogil=True)
def _window_labels(distance, comp, starts, inner, outer, out):
    """:func:`window_labels`' one pass, without branches on the distances (they fall at random): outside where both
    windows hold."""
    for i in range(distance.shape[0]):
        d, c = distance[i], comp[i]
        if c < 0:
            out[i] = -1
            continue
        beyond = (inner <= d) & (d <= outer[c])
        under = (-outer[c] <= d) & (d <= -starts[c])
        out[i] = np.int64(beyond | under) + np.int64(beyond) - 1


def inside_inner(band: Band, comp: np.ndarray, n_components: int, inner: float) -> np.ndarray:
    """(n_components,) nm: where each object's inside plateau window starts: ``inner``, or half its ``depth`` where
    no ion of it lies ``inner`` deep (``depth``: the largest distance inside its surface of the band's ions
    assigned to it; ``comp``: each ion's object, -1 none).

    An object whose half-thickness is under ``inner`` (a rod or plate thinner than the delocalization, or a first
    contour that is a sliver of one) would have no inside plateau at all, and its surface could not be moved.
    Its deeper half is the part of it least mixed with its interface; once it is grown to where the ions put
    its interface, its ions reach ``inner`` again where it is that thick.
    """
    depth = np.zeros(n_components)
    _deepest(np.ascontiguousarray(band.distance, dtype=np.float64), np.ascontiguousarray(comp, dtype=np.int64), depth)
    return np.where(depth > inner, inner, 0.5 * depth)


@njit(cache=True, nogil=True)
def _deepest(distance, comp, depth):
    """:func:`inside_inner`'s depths: ``depth`` (n_components, zeros) raised to each object's ions' ``-distance``
    (only an ion inside, ``distance`` < 0, can exceed a depth that starts at 0)."""
    for i in range(distance.shape[0]):
        c = comp[i]
        if c >= 0 and -distance[i] > depth[c]:
            depth[c] = -distance[i]


OPEN_REACH = 9.0
"""nm: the farthest an open object's plateau windows may reach (:func:`open_window_edges`). It bounds the ions the
refinement selects around a surface with an open object (all within ``OPEN_REACH + 2.5`` nm: a 20 nm box's sheet
holds most of its specimen there); where the windows stop is set by the ions (:data:`FLAT_SE`)."""

FLAT_SE = 2.0
"""Standard errors by which a shell's midpoint may differ from its window's and still widen it
(:func:`open_window_edges`): a two-sided two-sigma test. A shell wrongly refused (~5 % of them) only keeps the
narrower window that the refinement used before; one with a real gradient or another phase is refused."""


def open_window_edges(band: Band, atoms: IonAtoms, components: np.ndarray, objects: np.ndarray, k: int,
                      window=PLATEAU_WINDOW, reach: float = OPEN_REACH, z: float = FLAT_SE) -> np.ndarray:
    """(n_components,) nm: the outer edge of each object's two plateau windows (the ``outer`` of
    :func:`window_labels`): ``window[1]`` for every object but ``objects`` ((n_components,) bool, the open ones:
    interfaces leaving the specimen, bicontinuous structures, objects cut by its edge); each of those widened by
    shells as wide as the window (``window[1] - window[0]`` nm, up to ``reach``) while each shell's midpoint of
    species ``k`` (its inside and outside fractions averaged) agrees with that of its windows so far within ``z``
    standard errors (binomial, on the atoms counted). A side whose shell holds no atoms (the specimen, or another
    object's nearer ions, ends its windows) is left out of the test and adds nothing; the widening stops where
    neither side holds any. ``band``: the ions within ``reach`` (nm) of the surface, those beyond an open object's
    rim left out (:func:`within_rim`); ``components``: each vertex's object.

    Why the midpoint: the placement crosses it, and a flat interface's tails, which bias its two windows' fractions
    toward each other by the same amount, leave it unbiased: the windows may widen across a wide interface's tails
    (where a test of each side's flatness would stop them), but not into a gradient or a neighbour on one side. An
    open object's 1-3 nm windows hold a few tens of thousands of atoms a side, whose counting error moved its
    midpoint by the equivalent of 0.02-0.06 nm at the zoo's low contrasts (session 37, windows of 1-9 nm halved it),
    and each cross-fit half, which reads its own levels from half of them, by more."""
    inner, outer = float(window[0]), float(window[1])
    width = outer - inner
    n_comp = len(objects)
    edges = np.full(n_comp, outer)
    n_shells = int(np.floor((reach - outer) / width + 1e-9))
    comp = components[band.vertex]
    depth = np.abs(band.distance)
    sel = (comp >= 0) & (depth >= inner) & (depth <= outer + n_shells * width)
    sel[sel] = objects[comp[sel]]
    if n_shells < 1 or not sel.any():
        return edges
    shell = np.maximum(np.ceil((depth[sel] - outer) / width), 0).astype(np.int64)  # 0: the window itself
    key = (comp[sel] * 2 + (band.distance[sel] > 0)) * (n_shells + 1) + shell
    held = atoms.atoms[band.index[sel]]
    size = n_comp * 2 * (n_shells + 1)
    total = np.bincount(key, held.sum(axis=1), size).reshape(n_comp, 2, n_shells + 1)
    part = np.bincount(key, held[:, k], size).reshape(n_comp, 2, n_shells + 1)
    for c in np.flatnonzero(objects):
        n_win, k_win = total[c, :, 0].copy(), part[c, :, 0].copy()
        for j in range(1, n_shells + 1):
            n_shell, k_shell = total[c, :, j], part[c, :, j]
            both = (n_shell > 0) & (n_win > 0)
            if not both.any():
                break
            f_shell, f_win = k_shell[both] / n_shell[both], k_win[both] / n_win[both]
            f = (k_shell[both] + k_win[both]) / (n_shell[both] + n_win[both])
            # twice the midpoints' difference and its standard error: the factor cancels
            diff = float(np.sum(f_shell - f_win))
            se = float(np.sqrt(np.sum(f * (1 - f) * (1 / n_shell[both] + 1 / n_win[both]))))
            if abs(diff) > z * se:
                break
            n_win, k_win = n_win + n_shell, k_win + k_shell
            edges[c] = outer + j * width
    return edges


def lobe_weights(*, positions: np.ndarray, atoms: np.ndarray, objects: np.ndarray, outside: np.ndarray, k: int,
                 cell: float, alpha: float = ALPHA) -> np.ndarray:
    """(m,) what each ion of the objects' inside windows counts for: the posterior that its place is inside the
    object rather than in matrix the surface holds (a noise lobe of the start, kept by the placement), 1 in every
    object whose window the ions do not show to hold matrix.

    At low contrast the counting noise of the matrix crosses the iso-value beside an object and the first contour
    takes it in (:func:`~apt_filters.refine.specks.trim_lobes` removes the lobes the field shows; a lobe the field
    does not separate stays). The placement cannot find the interface there (matrix on both sides), so the lobe is
    kept, and an inside window 1-3 nm under it holds matrix: dev cuboid 33181's second cube (Ni 70.9 -> 79.0 at.%)
    had its window 70 % truly outside, read 73.6 at.%, pulled the other cube's pooled level down with it, and the
    cubes came out V +52 % and +149 %. No test on the two cross-fit halves sees it, since both are placed from the
    same lobed start.

    The ions' own evidence: each object's window is cut into cubes of ``cell`` nm and the cubes' counts of basis
    element ``k`` are fitted by a two-level binomial mixture, a cube either inside (its fraction the object's
    inside level, unknown) or matrix (the object's ``outside`` level, measured on many more atoms), by EM
    (Dempster, Laird & Rubin 1977). The mixture replaces the single level where its likelihood ratio against one
    level exceeds the chi-square quantile of ``alpha`` (1 d.f., at the speck test's family-wise level,
    Bonferroni over the objects tested): a window that is all inside, or whose cubes cannot be told apart, keeps
    every ion at weight 1, bit for bit. Where it is replaced each ion counts for its cube's posterior of being
    inside, so the weighted window's level is the mixture's maximum-likelihood inside level (consistent; a hard
    cut at 0.5 would take the inside cubes that read low by chance out and bias it up).

    Parameters
    ----------
    positions : (m, 3) float64, nm
        The inside window ions (both cross-fit halves may be pooled: their ions are independent).
    atoms : (m, kk) float
        Their atoms per basis element.
    objects : (m,) int
        The object of each ion's window.
    outside : (n_objects,) float
        Each object's outside level of element ``k`` (fraction).
    k : int
        The measured species' index in ``atoms``.
    cell : float, nm
        The cubes' side: the window's outer depth (a lobe the window holds is at least that deep where it holds it;
        dev cuboid 33181's lobed cube, window 70 % matrix: 1.5-2 nm cubes of 31-50 atoms put the mixture's
        likelihood ratio at 10.5, under the 12.1 of two objects, 3 nm cubes of 117 at 22.2).
    alpha : float
    """
    weight = np.ones(len(positions))
    tested = [c for c in np.unique(objects) if 0.0 < outside[c] < 1.0]
    if not tested:
        return weight
    limit = float(ndtri(1.0 - alpha / (2.0 * len(tested)))) ** 2  # chi-square, 1 d.f.
    for c in tested:
        mine = np.flatnonzero(objects == c)
        _, cube = np.unique(np.floor(positions[mine] / cell).astype(np.int64), axis=0, return_inverse=True)
        cube = cube.ravel()
        n = np.bincount(cube, atoms[mine].sum(axis=1))
        part = np.bincount(cube, atoms[mine, k])
        inside = _two_level_mixture(n, part, float(outside[c]), limit)
        if inside is not None:
            weight[mine] = inside[cube]
    return weight


def _two_level_mixture(n: np.ndarray, part: np.ndarray, outside: float, limit: float,
                       iterations: int = 500) -> np.ndarray | None:
    """Each cube's posterior of being at the inside level, under the binomial mixture of :func:`lobe_weights`
    (``n``, ``part``: the cubes' atoms and those of the measured element; ``outside``: the matrix's fraction), or
    None where the mixture's log-likelihood ratio against one level (twice it) is under ``limit`` or its inside
    level is not above the matrix's (the inside of a depleted object is below it; the cubes are then mixed
    the other way, and no lobe of this kind is told apart)."""
    total = n.sum()
    if len(n) < 2 or total <= 0:
        return None
    one = part.sum() / total

    def loglik(f):
        return part * np.log(f) + (n - part) * np.log1p(-f)

    if not 0.0 < one < 1.0:
        return None
    single = float(loglik(one).sum())
    # from the cubes that read above the window's level: the inside level's start, so that EM does not take the
    # lobe for the object
    high = part > one * n
    level, share = min(part[high].sum() / n[high].sum() if high.any() else one, 1.0 - 1e-9), 0.5
    for _ in range(iterations):
        a = math.log(share) + loglik(level)
        b = math.log1p(-share) + loglik(outside)
        post = np.exp(a - np.logaddexp(a, b))
        new = float(np.clip((post * part).sum() / max((post * n).sum(), 1e-12), 1e-9, 1.0 - 1e-9))
        share = float(np.clip(post.mean(), 1e-9, 1.0 - 1e-9))
        if abs(new - level) < 1e-9:
            level = new
            break
        level = new
    mixed = float(np.logaddexp(math.log(share) + loglik(level), math.log1p(-share) + loglik(outside)).sum())
    if not (level > outside and 2.0 * (mixed - single) > limit):
        return None
    return post


def levels_from_sums(sums: np.ndarray, elements: list[str], species: str, prior: float = PLATEAU_PRIOR,
                     pooled: np.ndarray | None = None) -> list[ObjectLevels]:
    """Each object's plateaus from its window sums (:func:`plateau_sums`), shrunk toward the pooled ones
    (``pooled``: (n_components, 2, k) the sums each object is shrunk toward; None: every object's summed)."""
    k = elements.index(species)
    out = []
    if pooled is None:
        pooled = np.broadcast_to(sums.sum(axis=0), sums.shape)
    for c in range(len(sums)):
        inside, outside = sums[c, 0], sums[c, 1]
        n_in, n_out = inside.sum(), outside.sum()
        if prior > 0:
            # shrink toward the pooled levels: a small object's own plateau is mostly noise
            inside = inside + prior * pooled[c, 0] / max(pooled[c, 0].sum(), 1e-300)
            outside = outside + prior * pooled[c, 1] / max(pooled[c, 1].sum(), 1e-300)
        c_in = inside / inside.sum() if inside.sum() > 0 else np.full(len(inside), np.nan)
        c_out = outside / outside.sum() if outside.sum() > 0 else np.full(len(outside), np.nan)
        out.append(ObjectLevels(c, list(elements), c_in, c_out, float(n_in), float(n_out),
                                float(0.5 * (c_in[k] + c_out[k])), shrunk_worth(n_in, prior, pooled[c, 0].sum()),
                                shrunk_worth(n_out, prior, pooled[c, 1].sum())))
    return out


def shrunk_worth(n: float, prior: float, n_pool: float) -> float:
    """Atoms whose binomial count would be as certain as a window of ``n`` atoms shrunk toward a pool of ``n_pool``
    atoms that holds it, by ``prior`` atoms (:func:`levels_from_sums`).

    The shrunk fraction ``(x + prior (x + y) / N) / (n + prior)`` (``x`` of the window's ``n`` atoms, ``y`` of the
    pool's other ``N - n``; ``N`` = ``n_pool``) has the variance ``f (1 - f) (n + 2 n prior / N + prior^2 / N) /
    (n + prior)^2``: a prior of 3000 atoms drawn from a pool of 2000 is no more certain than those 2000, and an object
    pooled with itself alone is worth its own atoms. Its worth is ``f (1 - f)`` over it.
    """
    if prior <= 0 or n_pool <= 0:
        return float(n)
    return float((n + prior) ** 2 / (n + (2 * n * prior + prior ** 2) / n_pool)) if n + prior > 0 else 0.0


def agreeing_pools(sums: np.ndarray, k: int, prior: float) -> np.ndarray:
    """(n_components, 2, kk) what each object's windows are shrunk toward (``pooled`` of :func:`levels_from_sums`):
    on each side, the summed windows of every object whose level of basis element ``k`` agrees with its own.

    The shrinkage is the posterior mean of a model in which the objects' true levels spread about a common one by
    ``tau^2 = f (1 - f) / m`` (``m`` = ``prior`` atoms is that spread's worth): objects of one phase. Two windows of
    ``n_i`` and ``n_j`` atoms then differ by ``f (1 - f) (1 / n_i + 1 / n_j + 2 / m)`` in variance (``f`` their
    pooled fraction). Where they differ significantly at the speck test's family-wise rate
    (:data:`~apt_filters.refine.specks.ALPHA`, two-sided, Bonferroni over every pair and both sides; a pair of large
    windows must differ by more than the prior's spread, a pair of small ones by more than their counting), the data
    refute the model for that pair and neither is shrunk toward the other: objects of two phases keep their own
    levels instead of each being pulled to the mean of both (two phases at 15 and 25 at.%, windows of 8000 and 800
    atoms: the small object's level off by 7.2 at.% RMS pooled, by 1.5 apart, its own window's counting error).
    Where the data do not refute it the pool is every agreeing window's atoms, as for identical objects (held-out
    plate 10010: its two plates' windows, 2004 atoms at 17.1 at.% (lobe-diluted) and 797 at 20.2, differ by 1.6
    standard errors and stay pooled; the truth is 19.0 for both). ``prior`` 0 (no shrinkage): every object's
    windows.

    Parameters
    ----------
    sums : (n_components, 2, kk) float64
        Atoms per basis element in each object's inside (0) and outside (1) window (:func:`plateau_sums`).
    k : int
        Index of the measured species.
    prior : float
        The shrinkage's atoms (``plateau_prior``).
    """
    pooled = np.broadcast_to(sums.sum(axis=0), sums.shape).copy()
    n, part = sums.sum(axis=2), sums[:, :, k]
    has = n > 0
    pairs = sum(int(has[:, s].sum()) * (int(has[:, s].sum()) - 1) // 2 for s in (0, 1))
    if prior <= 0 or not pairs:
        return pooled
    # a stricter level than the targets' 2 sigma: a pair of one phase split by chance takes the small window's own
    # noisy level (at 2 sigma, one phase in 7700- and 800-atom windows: the small one's RMS error 0.51 -> 0.62 at.%)
    z = float(ndtri(1.0 - ALPHA / (2.0 * pairs)))
    for s in (0, 1):
        for i, j in zip(*np.triu_indices(len(sums), 1)):
            if not (has[i, s] and has[j, s]):
                continue
            f = (part[i, s] + part[j, s]) / (n[i, s] + n[j, s])
            var = f * (1 - f) * (1 / n[i, s] + 1 / n[j, s] + 2 / prior)
            if (part[i, s] / n[i, s] - part[j, s] / n[j, s]) ** 2 > z * z * var:
                pooled[i, s] -= sums[j, s]
                pooled[j, s] -= sums[i, s]
    return pooled


def chosen_pools(windows: np.ndarray, best: np.ndarray, chosen: np.ndarray, unmixed: np.ndarray,
                 profiles: np.ndarray, k: int, prior: float) -> np.ndarray:
    """(n_components, 2, k) what each object's levels are shrunk toward (``pooled`` of :func:`levels_from_sums`)
    where some objects' levels are read off the model (``RefineParams.curved_levels``).

    An object that keeps its windows: every object's windows that agree with its own (:func:`agreeing_pools`), as
    without the model. An object whose levels the model reads (``chosen``): every object's levels as chosen that
    agree with its own (``best``; its own windows, which the held-out ions
    found biased, left out). An unmixed one's inside level (``unmixed``): the pool of every object's profile level
    (``profiles``, :func:`profile_levels`, :func:`pooled_profiles`), where there is one. Its unmixed counts are worth
    ``(g_in - g_out)^2`` of its window atoms (:func:`unmixed_sums`), a few hundred on a small object against the
    prior's 3000, and the others' windows, which do not reach their plateaus either where the interface is as wide,
    would pull its level back to theirs (held-out rod 10011's first rod: inside 67.6 at.% toward its neighbour's
    windows, 70.9 toward the profiles', truth 71.8).

    Parameters
    ----------
    windows : (n_components, 2, k) float64
        What each object's window sums (:func:`plateau_sums`) are shrunk toward: :func:`agreeing_pools` of them.
    best : (n_components, 2, k) float64
        Each object's sums as chosen (its windows, unmixed, or its profile's level).
    chosen, unmixed : (n_components,) bool
    profiles : (k,) float64
        Every closed object's profile level pooled, times the pool's worth in atoms (:func:`pooled_profiles`).
    k : int
        Index of the measured species.
    prior : float
        The shrinkage's atoms (``plateau_prior``): windows pool with those that agree (:func:`agreeing_pools`).
    """
    pooled = np.where(chosen[:, None, None], agreeing_pools(best, k, prior), windows)
    if profiles.sum() > 0:
        pooled[unmixed, 0] = profiles
    return pooled


def plateaus(band: Band, atoms: IonAtoms, components: np.ndarray, n_components: int, species: str,
             window=PLATEAU_WINDOW, prior: float = PLATEAU_PRIOR, agreeing: bool = True) -> list[ObjectLevels]:
    """Plateaus of every component from ions already in a band (see :func:`object_levels`), each shrunk toward the
    objects whose windows agree with its own (:func:`agreeing_pools`), as the cross-fit's levels are: pooled with
    every object, an object's level moved with whatever another object's windows read (a 4 nm sphere at 30 at.%
    beside a 3.5 nm one at 60: 0.358, seven of its errors; tests/test_agreeing_pools.py), and with it its excess
    (:func:`~apt_filters.refine.excess.object_excess`). ``agreeing`` False: toward every object's windows, for
    windows measured against a provisional surface (:func:`~apt_filters.refine.surface._place`)."""
    sums = plateau_sums(band, atoms, components, n_components, window)
    return levels_from_sums(sums, atoms.elements, species, prior,
                            agreeing_pools(sums, atoms.elements.index(species), prior) if agreeing else None)


def object_levels(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str,
                  basis: ConcentrationBasis = ConcentrationBasis(), window=PLATEAU_WINDOW,
                  prior: float = PLATEAU_PRIOR) -> list[ObjectLevels]:
    """Inside and outside plateaus of every connected surface of ``mesh``, and its midpoint iso-value.

    Ions are assigned to their nearest vertex and measured along its normal; the inside plateau
    is every ion between ``window[0]`` and ``window[1]`` nm inside, the outside one likewise. Ions beyond
    the rim of an open surface are not counted (:func:`within_rim`).
    An object with no ion ``window[0]`` deep is measured from halfway to its deepest ion (:func:`inside_inner`).

    Parameters
    ----------
    mesh : TriMesh
        Iso-surface (normals out of the region above iso).
    ions : IonTable
    ranges : RangeTable
    species : str
        The iso-surface element.
    basis : ConcentrationBasis
        Denominator of the fractions (e.g. ``exclude=("B",)`` for a segregant).
    window : (inner, outer) nm
    prior : float
        Atoms' worth of the pooled plateaus of the objects that agree with it (:func:`agreeing_pools`) added to
        each object's own counts
        (shrinkage, empirical-Bayes style). A 3 nm sphere has ~1000 atoms in its inside window:
        its own plateau is uncertain by ~1.3 at.%, which moves its midpoint and its surface; a
        large object (many more atoms than ``prior``) keeps its own plateau, so objects of
        different phases stay apart once they are big enough to tell. 0: objects' own values.

    Returns
    -------
    list of ObjectLevels, one per component.
    """
    components = topology(mesh.faces, mesh.n_vertices).vertex_components
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    near = NearIons.select(ions, ranges, basis, vertices, mesh.faces, window[1] + 1.0)
    band = within_rim(near.band(vertices, vertex_normals(vertices, mesh.faces), window[1] + 1.0), near, mesh,
                      window[1] + 1.0)
    return plateaus(band, near.atoms, components, int(components.max()) + 1, species, window, prior)


def per_object_iso(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str,
                   basis: ConcentrationBasis = ConcentrationBasis(), window=PLATEAU_WINDOW,
                   prior: float = PLATEAU_PRIOR) -> np.ndarray:
    """(n_components,) iso-value of each object: the midpoint of its own inside and outside plateaus.

    Contour each object again at its value (e.g. with :func:`apt_filters.refine.recontour`) so that
    objects of different compositions are cut at the same relative height of their interfaces.
    """
    return np.array([lv.iso for lv in object_levels(mesh, ions, ranges, species, basis, window, prior)])


_WIDTH_NODES = np.linspace(-6.0, 6.0, 161)
"""Standard normal nodes over which :func:`ball_profile` averages the interface's own width (0.075 apart: with the
blur floored at a tenth of the width, the average of the nodes' blurred steps is smooth in the offset and width).
Against 1921 nodes the profile is off by at most 1e-5 on the quick preset's 76 calls (241 nodes: 9e-7), and by at
most 3.6e-4 where the fits may call it (blur at least a fifth of the width, radius at least the width; 241 nodes
2.0e-4): at a slab whose radius is about its width (its nodes' shrunk radius reaches 0 inside the Gaussian's bulk,
a kink the equally spaced nodes straddle) under a sharp blur, an order below the counting error of such a thin
object's windows. 0.78 of the CPU of 241 nodes (the node sums are most of it)."""


def ball_profile(d: np.ndarray, *, radius: float, dims: float, width: float, blur: float) -> np.ndarray:
    """Expected inside fraction at signed distance ``d`` (nm, negative inside) from a ball's interface.

    The ball (``dims`` 3: a sphere, 2: a cylinder's cross-section, 1: a slab of half-thickness ``radius``;
    fractional values in between) has an error-function interface of Gaussian width ``width`` in the
    distance to its surface, ``Phi((radius - r) / width)`` at distance ``r`` from its centre, and the ions'
    positions are blurred by an isotropic Gaussian of sigma ``blur``. The blurred fraction is

        g(r) = E_Z[ P(|x + blur N| < radius + width Z) ],  r = |x| = radius + d,

    where ``P`` is the noncentral chi-square distribution function with ``dims`` degrees of freedom
    (the blurred indicator of a ball), averaged over ``Z`` on :data:`_WIDTH_NODES`. As
    ``radius / width`` and ``radius / blur`` grow it tends to the planar step
    ``Phi(-d / sqrt(width^2 + blur^2))``; on a curved object the blur moves the midpoint inside by about
    ``(dims - 1) blur^2 / (2 radius)`` near the interface but not deep inside, and the interface's tails
    reach deeper than a plane's (more of a small ball's volume lies near its surface).

    Within 30 blurs of the centre the distribution function is its Poisson mixture of central ones,
    ``P = sum_i Pois(i; r^2 / 2 s^2) P_gamma(dims / 2 + i, e^2 / 2 s^2)`` (``s`` the blur, ``e`` a node's edge,
    ``P_gamma`` the regularized lower incomplete gamma function; Johnson, Kotz & Balakrishnan, *Continuous
    Univariate Distributions* 2, ch. 29), so the average over the width's nodes is taken inside the sum once per
    call, ``c_i = sum_Z h(Z) P_gamma(dims / 2 + i, e(Z)^2 / 2 s^2)``, and each distance needs only its Poisson
    weights, ``g(r) = sum_i Pois(i; r^2 / 2 s^2) c_i`` (:func:`_poisson_mixture`): O((n + q) terms) instead of
    n q noncentral distribution functions (scipy's ``chndtr``, ~1 us each). The Poisson weights left out are
    below 1e-20 in all, and the result agrees with the node-by-node ``chndtr`` average within 1e-12
    (tests/test_ball_profile.py keeps that average as the oracle).

    Parameters
    ----------
    d : (n,) float64, nm
    radius, width, blur : float, nm
    dims : float, [1, 3]

    Returns
    -------
    (n,) float64 in [0, 1]
    """
    from scipy.special import gammainc

    d = np.asarray(d, dtype=np.float64)
    if d.size <= 256:
        r = np.maximum(radius + d, 0.0)
    else:  # many ions: on a 0.01 nm grid (the profile varies over tenths of a nm), interpolated
        r = np.arange(max(radius + d.min(), 0.0), max(radius + d.max(), 0.0) + 0.02, 0.01)
    z = _WIDTH_NODES
    h = np.exp(-0.5 * z ** 2)
    h /= h.sum()
    edge = np.maximum(radius + width * z, 0.0)  # (q,) the ball's radius at each node of its own width
    s = max(blur, 0.1 * max(width, 1e-3), 1e-3)  # a vanishing blur: a tenth of the width, ~0.5 % of its variance
    nc = (r / s) ** 2
    g = np.empty(len(r))
    # far from the centre in blur units (the mixture needs ~r^2 / s^2 terms there): the planar step shifted by the
    # curvature, P(|x + blur N| < edge) ~ Phi((edge - r - (dims - 1) s^2 / 2r) / s) to O((s / r)^2)
    far = nc > 900.0
    if far.any():
        g[far] = _shifted_steps(r[far], edge, h, s, dims)
    if not far.all():
        mu = 0.5 * nc[~far]
        top = int(np.ceil(mu.max() + 15.0 * np.sqrt(mu.max()) + 60.0))  # past every Poisson weight above e^-50
        y = 0.5 * (edge / s) ** 2
        a = 0.5 * dims
        # each node's P_gamma at the top of the sums, from where the mixture's terms are added downward
        g[~far] = _poisson_mixture(mu, y, h, a, gammainc(a + top, y), top)
    return np.clip(g, 0.0, 1.0) if d.size <= 256 else _on_grid(np.maximum(radius + d, 0.0), r, np.clip(g, 0.0, 1.0))


@njit(cache=True, nogil=True)
def _on_grid(x, xp, fp):
    """``np.interp(x, xp, fp)``, the same numbers, for ``xp`` (q >= 2,) equally spaced and increasing: each point's
    interval from its offset on the grid (checked against its ends), not by bisection (:func:`ball_profile` reads
    its 0.01 nm grid at every ion of an object, ~10 bisection steps each). The same cases and arithmetic as numpy's
    ``arr_interp``: ``fp[0]`` left of the grid, ``fp[-1]`` right of it and at its end, ``fp[j]`` at a node, else
    ``slope * (x - xp[j]) + fp[j]`` with ``slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])`` (from the other
    end where that is NaN); NaN for NaN."""
    out = np.empty(x.shape[0])
    q = xp.shape[0]
    step = (xp[q - 1] - xp[0]) / (q - 1)
    for i in range(x.shape[0]):
        v = x[i]
        if v != v:
            out[i] = v
            continue
        if v < xp[0]:
            out[i] = fp[0]
            continue
        if v >= xp[q - 1]:
            out[i] = fp[q - 1]
            continue
        j = min(max(int((v - xp[0]) / step), 0), q - 2)
        while xp[j] > v:
            j -= 1
        while xp[j + 1] <= v:
            j += 1
        if xp[j] == v:
            out[i] = fp[j]
            continue
        slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
        value = slope * (v - xp[j]) + fp[j]
        if value != value:
            value = slope * (v - xp[j + 1]) + fp[j + 1]
            if value != value and fp[j] == fp[j + 1]:
                value = fp[j]
        out[i] = value
    return out


@njit(cache=True, nogil=True)
def _shifted_steps(r, edge, h, s, dims):
    """``sum_j h_j Phi((edge_j - r - (dims - 1) s^2 / 2r) / s)`` for each ``r`` (n,), nm: :func:`ball_profile` far
    from the centre. ``Phi(x) = erfc(-x / sqrt 2) / 2``; beyond x > 8.3 it is 1 and below -38.5 it is 0 in float64."""
    out = np.empty(r.shape[0])
    for k in range(r.shape[0]):
        shift = r[k] + (dims - 1.0) * s * s / (2.0 * r[k])
        total = 0.0
        for j in range(edge.shape[0]):
            x = (edge[j] - shift) / s
            if x > 8.3:
                total += h[j]
            elif x > -38.5:
                total += h[j] * 0.5 * math.erfc(-x / math.sqrt(2.0))
        out[k] = total
    return out


@njit(cache=True, nogil=True)
def _poisson_mixture(mu, y, h, a, p_top, top):
    """``sum_i Pois(i; mu) sum_j h_j P_gamma(a + i, y_j)`` for each ``mu`` (:func:`ball_profile`).

    ``mu`` (n,) Poisson means; ``y`` (q,) the gamma functions' arguments (0: a node holding nothing), ``h`` (q,)
    their weights; ``p_top`` (q,) ``P_gamma(a + top, y)``; ``top``: terms, past every Poisson weight above e^-50.
    ``P_gamma(a + i, y) = P_gamma(a + i + 1, y) + y^(a+i) e^-y / Gamma(a + i + 1)`` is summed downward from ``top``
    (positive terms, no cancellation). The Poisson weights are taken outward from the mode by their ratios and
    stop below e^-50 (a tail beyond it is at most ~3 times its first term: the ratios are below 0.7 there).
    Returns (n,) float64.
    """
    log_gamma = np.empty(top)
    for i in range(top):
        log_gamma[i] = math.lgamma(a + i + 1.0)
    c = np.zeros(top)
    for j in range(y.shape[0]):
        if y[j] <= 0.0:
            continue
        ly, yj, hj = math.log(y[j]), y[j], h[j]
        p = p_top[j]
        term = 0.0
        for i in range(top - 1, -1, -1):
            # the term y^(a+i) e^-y / Gamma(a+i+1) from its logarithm every 16 steps (and while it would be
            # subnormal), between by its ratio to the one above, (a+i+1) / y: ~2e-15 relative error at most. The
            # step told by a mask, not ``i % 16``: Python's modulo of a signed integer adds a sign fix to every step
            # of this loop (0.88 of its CPU over 2,000 calls of a 10M-ion refinement, the same numbers)
            if (i & 15) == 0 or term < 1e-290:
                log_term = (a + i) * ly - yj - log_gamma[i]
                term = math.exp(log_term) if log_term > -745.2 else 0.0  # below, exp is 0
            else:
                term *= (a + i + 1.0) / yj
            p += term
            c[i] += hj * p
    out = np.empty(mu.shape[0])
    floor = math.exp(-50.0)
    for k in range(mu.shape[0]):
        m = mu[k]
        if m <= 0.0:
            out[k] = c[0]
            continue
        mode = min(int(m), top - 1)
        w0 = math.exp(-m + mode * math.log(m) - math.lgamma(mode + 1.0))
        total = w0 * c[mode]
        w = w0
        for i in range(mode + 1, top):
            w *= m / i
            total += w * c[i]
            if w < floor:
                break
        w = w0
        for i in range(mode - 1, -1, -1):
            w *= (i + 1) / m
            total += w * c[i]
            if w < floor:
                break
        out[k] = total
    return out


class _ShiftedProfiles:
    """Each of several objects' fitted ball profiles at its own distances, remembered per (offset, width).

    Object ``i``'s profile with its interface ``offset`` nm out and its own ``width``: :func:`ball_profile` at
    ``distances[i] - offset`` of the ball of radius ``radius[i] + offset``. The joint fits (:func:`fit_balls`,
    :func:`profile_levels`) take their derivatives by finite differences, one object's offset or width at a time:
    the other objects' profiles are then those of the last call, kept here, and each difference costs one object's
    profile instead of every object's (the same values bit for bit: :func:`ball_profile` is a function of its
    arguments alone).

    Parameters
    ----------
    distances : list of (b_i,) float64, nm
    radius, dims : (m,) float
        The objects' balls (:func:`object_shapes`).
    blur : float, nm
    """

    KEPT = 5
    """(offset, width) pairs kept per object: the point derivatives are taken at and its four central steps."""

    def __init__(self, distances, radius, dims, blur: float):
        self.distances, self.radius, self.dims, self.blur = distances, radius, dims, blur
        self.kept = [{} for _ in distances]

    def __call__(self, i: int, offset: float, width: float) -> np.ndarray:
        kept, key = self.kept[i], (float(offset), float(width))
        if key not in kept:
            if len(kept) >= self.KEPT:
                del kept[next(iter(kept))]  # the oldest
            kept[key] = ball_profile(self.distances[i] - offset, radius=max(self.radius[i] + offset, 0.0),
                                     dims=self.dims[i], width=width, blur=self.blur)
        return kept[key]


def object_shapes(vertices: np.ndarray, faces: np.ndarray, components: np.ndarray,
                  n_components: int) -> tuple[np.ndarray, np.ndarray]:
    """(radius, dims) of the ball (:func:`ball_profile`) with each closed object's volume, area and total mean curvature.

    A ball of radius ``R`` in ``D`` dimensions (``D - 1`` curved directions) has ``V / A = R / D`` and
    ``kappa_1 + kappa_2 = (D - 1) / R`` everywhere, so ``M V / A^2 = (D - 1) / D`` with
    ``M = integral (kappa_1 + kappa_2) dA``, measured on the mesh as ``sum |e| theta_e`` over its edges
    (``theta_e`` the signed angle between the edge's face normals, positive where convex). A sphere gives
    ``D = 3``, ``R = 3 V / A``; a long rod ``D = 2``, ``R`` its radius; a plate ``D -> 1``, ``R`` its
    half-thickness; a cube of side ``a`` ``D = 2.1``, ``R = 0.35 a``. ``D`` is clipped to [1, 3].

    Parameters
    ----------
    vertices : (n, 3) float64, nm
    faces : (m, 3) int
    components : (n,) int
        Each vertex's object.
    n_components : int

    Returns
    -------
    radius : (n_components,) float64, nm
    dims : (n_components,) float64
    """
    p = vertices[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    comp = components[faces[:, 0]]
    volume = object_volumes(vertices, faces, components, n_components)
    area = np.bincount(comp, weights=0.5 * area2, minlength=n_components)
    normal = cross / np.maximum(area2, 1e-300)[:, None]
    topo = topology(faces, len(vertices))
    pairs, shared = topo.face_pairs, topo.edge_vertices[topo.edge_faces == 2]  # both in edge order
    f, g = pairs[:, 0], pairs[:, 1]
    edge = vertices[shared[:, 1]] - vertices[shared[:, 0]]
    length = np.linalg.norm(edge, axis=1)
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", normal[f], normal[g]), -1.0, 1.0))
    angle[(area2[f] <= 0) | (area2[g] <= 0)] = 0.0  # a degenerate face has no normal to bend
    # convex where the other face's centroid lies behind this face's plane
    behind = np.einsum("ij,ij->i", p[g].mean(axis=1) - p[f].mean(axis=1), normal[f]) < 0
    curvature = np.bincount(comp[f], weights=length * np.where(behind, angle, -angle), minlength=n_components)
    ratio = np.divide(curvature * volume, area ** 2, out=np.zeros(n_components), where=area > 0)
    dims = np.clip(1.0 / np.maximum(1.0 - ratio, 1e-9), 1.0, 3.0)
    return dims * np.divide(volume, area, out=np.zeros(n_components), where=area > 0), dims


def object_volumes(vertices: np.ndarray, faces: np.ndarray, components: np.ndarray, n_components: int) -> np.ndarray:
    """(n_components,) nm³ each closed object's signed volume (divergence theorem; negative where it is inside out;
    ``components``: each vertex's object)."""
    p = vertices[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return np.bincount(components[faces[:, 0]], weights=np.einsum("ij,ij->i", p[:, 0], cross) / 6,
                       minlength=n_components)


@dataclass
class BallFit:
    """The interface of one object fitted with :func:`ball_profile` (:func:`fit_ball`).

    Attributes
    ----------
    offset : float, nm
        Where the fitted interface lies from the surface the distances were measured to (positive: outside).
    width : float, nm
        The interface's own Gaussian width (the blur given apart).
    inside, outside : float
        The fitted fraction's asymptotes deep inside and far outside.
    cov : (2, 2) float64, nm²
        Covariance of (offset, width) (Gauss-Newton, the levels profiled out; the residuals' variance the
        binomial one or, if larger, their own).
    """

    offset: float
    width: float
    inside: float
    outside: float
    cov: np.ndarray

    @property
    def offset_se(self) -> float:
        """nm: the offset's standard error."""
        return float(np.sqrt(self.cov[0, 0]))


def fit_ball(distance: np.ndarray, part: np.ndarray, total: np.ndarray, *, radius: float, dims: float, blur: float,
             half_width: float = 3.0, bin_width: float = 0.1) -> BallFit | None:
    """The interface's offset and own width, and the two levels, of one object's binned profile (least squares).

    The fraction ``part / total`` of the ions at ``distance`` is modelled as
    ``outside + (inside - outside) g(distance - offset)`` with ``g`` the blurred ball profile
    (:func:`ball_profile`) of radius ``radius + offset``; each bin of ``bin_width`` nm within ``half_width`` weighs
    its atoms, the two levels are solved for in closed form at each (offset, width) (variable projection).

    Parameters
    ----------
    distance : (b,) float64, nm
        Signed distances of the object's ions (negative inside).
    part, total : (b,) float64
        Atoms of the measured species, and basis atoms, per ion.
    radius, dims : float
        The object's ball (:func:`object_shapes`).
    blur : float, nm
        Isotropic sigma of the reconstruction blur.

    Returns
    -------
    BallFit, or None where fewer than 10 bins hold atoms.
    """
    binned = _binned_profile(distance, part, total, half_width, bin_width)
    if binned is None:
        return None
    return _fit_shared_levels([binned], [radius], [dims], blur)[0][0]


def _binned_profile(distance: np.ndarray, part: np.ndarray, total: np.ndarray, half_width: float,
                    bin_width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(centres nm, atoms, fractions) of one object's bins of ``bin_width`` within ``half_width`` that hold atoms;
    None where fewer than 10 do."""
    edges = np.arange(-half_width, half_width + 1e-9, bin_width)
    idx = np.digitize(distance, edges) - 1
    ok = (idx >= 0) & (idx < len(edges) - 1)
    n = np.bincount(idx[ok], weights=total[ok], minlength=len(edges) - 1)
    k = np.bincount(idx[ok], weights=part[ok], minlength=len(edges) - 1)
    use = n > 0
    if use.sum() < 10:
        return None
    return (0.5 * (edges[1:] + edges[:-1]))[use], n[use], k[use] / n[use]


def _fit_shared_levels(binned: list, radius, dims, blur: float) -> tuple[list[BallFit], np.ndarray]:
    """The m objects' binned profiles (:func:`_binned_profile`) fitted with one inside and one outside level
    shared by all, each its own offset and width (:func:`fit_ball` is the case m = 1): each object's
    :class:`BallFit` (its block of the covariance) and the (2 m, 2 m) joint covariance of the offsets and widths."""
    from scipy.optimize import least_squares

    n, y = np.concatenate([b[1] for b in binned]), np.concatenate([b[2] for b in binned])
    root = np.sqrt(n)
    profile = _ShiftedProfiles([b[0] for b in binned], radius, dims, blur)
    m = len(binned)

    def levels(q):
        g = np.concatenate([profile(i, q[2 * i], q[2 * i + 1]) for i in range(m)])
        design = np.column_stack([1 - g, g]) * root[:, None]
        coef = np.linalg.lstsq(design, y * root, rcond=None)[0]
        return coef, design @ coef - y * root

    fit = least_squares(lambda q: levels(q)[1], np.tile([0.0, 0.5], m),
                        bounds=(np.tile([-1.0, 0.02], m), np.tile([1.0, 3.0], m)))
    (outside, inside), _ = levels(fit.x)
    # residuals in units of sqrt(atoms): their variance is the binomial c (1 - c), or the fit's own scatter if larger
    scale = max(float(np.sum(fit.fun ** 2)) / max(len(y) - 2 * m - 2, 1), float(np.average(y * (1 - y), weights=n)))
    cov = np.linalg.pinv(fit.jac.T @ fit.jac) * scale
    return [BallFit(float(fit.x[2 * i]), float(fit.x[2 * i + 1]), float(inside), float(outside),
                    cov[2 * i:2 * i + 2, 2 * i:2 * i + 2].copy()) for i in range(m)], cov


def fit_balls(distance: np.ndarray, part: np.ndarray, total: np.ndarray, group: np.ndarray, *, radius: np.ndarray,
              dims: np.ndarray, blur: float, half_width: float = 3.0,
              bin_width: float = 0.1) -> tuple[dict[int, BallFit], np.ndarray]:
    """The closed objects of one phase fitted together (:func:`fit_ball`): one inside and one outside level shared by
    all, each object its own interface offset and width.

    A small or thin object's own fit trades its levels off against its offset and width (its profile never reaches
    its plateau), so its levels, and the shares of the inside phase its windows hold under them, are noisier than
    its atoms; objects of one phase share their plateaus, and fitted together each object's interface is fixed by
    every object's levels (held-out rod 10011: two rods, inside 76.6 and 68.5 at.% fitted apart, truth 71.8).
    Whether the objects are of one phase is not assumed here: :func:`held_out_gain` judges the joint fit on the ions
    it was not fitted to.

    Parameters
    ----------
    distance, part, total : (b,) float64
        As :func:`fit_ball`, the ions of every object.
    group : (b,) int
        Each ion's object.
    radius, dims : (n_components,) float64
        The objects' balls (:func:`object_shapes`).
    blur : float, nm

    Returns
    -------
    fits : {object: BallFit}
        Each fitted object's offset, width and their covariance (its block of the joint one), and the shared levels;
        empty where fewer than two objects have 10 bins holding atoms.
    cov : (2 m, 2 m) float64
        The joint covariance of the m objects' (offset, width), in the order of ``fits`` (the shared levels tie
        them: one level too high moves every object's interface).
    """
    objects, binned = [], []
    for c in np.unique(group):
        mine = group == c
        one = _binned_profile(distance[mine], part[mine], total[mine], half_width, bin_width)
        if one is not None and radius[c] > 0:
            objects.append(int(c))
            binned.append(one)
    if len(objects) < 2:
        return {}, np.zeros((0, 0))
    fits, cov = _fit_shared_levels(binned, radius[objects], dims[objects], blur)
    return dict(zip(objects, fits)), cov


def unmixed_sums(sums: np.ndarray, mixed: np.ndarray, weight: np.ndarray, worth: np.ndarray) -> np.ndarray:
    """(n_components, 2, k) plateau window sums (:func:`plateau_sums`) with part of the interface's share taken out.

    A window whose ions hold, on the mean, a share ``mixed[c, s]`` of the inside phase (1 for an inside window deep
    enough, 0 for an outside one) reads ``(1 - mixed) c_out + mixed c_in``; the two windows' compositions are
    solved for ``c_in`` and ``c_out``, and each window's level is moved that far by ``weight[c]``
    (:func:`unmixing_weight`: 0 keeps the window, 1 unmixes it whole). Each is returned as a sum of ``worth[c, s]``
    atoms, what the moved level is worth (its variance grows with the unmixing's amplified counts, the shares' own
    error and the weight's), so that the shrinkage toward the pooled levels (:func:`levels_from_sums`) weighs them
    as much as they are worth. An object of ``weight`` 0, or whose windows cannot tell the phases apart
    (``mixed_in - mixed_out`` at most 0.1), keeps its sums.

    Parameters
    ----------
    sums : (n_components, 2, k) float64
        Atoms per basis element in each object's inside (0) and outside (1) window.
    mixed : (n_components, 2) float64
        The inside phase's mean share in each window (e.g. :func:`ball_profile` over its ions).
    weight : (n_components,) float64
        How far each object's windows are moved toward their unmixed levels, in [0, 1].
    worth : (n_components, 2) float64
        Atoms whose binomial count would be as certain as each moved level (:attr:`Unmixing.worth`).
    """
    out = sums.astype(np.float64).copy()
    for c in range(len(sums)):
        (g_in, g_out), spread = mixed[c], mixed[c, 0] - mixed[c, 1]
        n = sums[c].sum(axis=1)
        if weight[c] <= 0 or spread <= 0.1 or (n <= 0).any():  # windows kept, or that cannot tell the phases apart
            continue
        w_in, w_out = sums[c, 0] / n[0], sums[c, 1] / n[1]
        c_in = np.clip(((1 - g_out) * w_in - (1 - g_in) * w_out) / spread, 0.0, None)
        c_out = np.clip((g_in * w_out - g_out * w_in) / spread, 0.0, None)
        for s, (own, solved) in enumerate(((w_in, c_in / max(c_in.sum(), 1e-300)),
                                           (w_out, c_out / max(c_out.sum(), 1e-300)))):
            moved = own + weight[c] * (solved - own)
            out[c, s] = moved / max(moved.sum(), 1e-300) * worth[c, s]
    return out


@dataclass
class Unmixing:
    """What unmixing one object's windows by its fitted ball does to its levels (:func:`unmixing_weight`).

    Attributes
    ----------
    mixed : (2,) float64
        The inside phase's mean share in the inside and outside windows.
    shift : float
        ``B - W``: the unmixed midpoint less the windows', fraction.
    var : float
        ``var B``, fraction².
    gain : float
        ``MSE(W) - MSE(B)`` as estimated, fraction²; positive exactly where ``weight`` is.
    weight : float
        How far the levels are moved from the windows' toward the unmixed ones, in [0, 1].
    worth : (2,) float64
        Atoms whose binomial count would be as certain as each moved level (inside, outside).
    """

    mixed: np.ndarray
    shift: float
    var: float
    gain: float
    weight: float
    worth: np.ndarray


def unmixing_weight(*, w: np.ndarray, n: np.ndarray, mixed: np.ndarray, mixed_cov: np.ndarray) -> Unmixing:
    """How far one object's windows are moved toward their unmixed levels, and what the moved levels are worth.

    The windows' midpoint ``W = (w_in + w_out) / 2`` is biased by ``b`` where the windows still hold the interface;
    the unmixed one (:func:`unmixed_sums`) ``B = ((1 - 2 g_out) w_in + (2 g_in - 1) w_out) / (2 (g_in - g_out))`` is
    not if the ball holds, but is noisier (its counts amplified by ``1 / (g_in - g_out)``, the shares ``g`` carrying
    their own error). ``B`` has the smaller mean squared error where the estimated gain ``G = D^2 - var D - var B +
    var W`` (``D = B - W``; ``D^2 - var D`` estimates ``b^2`` without bias) is positive; taken whole there and not
    at all elsewhere (a hard choice), the choice selects the draws whose shift is large by chance, and over
    redrawn ions its level lies off by more than the error it states (a winner's curse; a small sphere unmixed 3 of
    its standard errors above the truth). Here the windows are moved by ``lambda = G / D^2`` clipped to [0, 1]:
    the share of the shift's square that is estimated bias less the noise the unmixing adds (with ``var B = var W``
    it is the empirical-Bayes posterior mean of the bias, ``lambda D = D (b^2 / (b^2 + var D))`` with ``b^2``
    estimated). It is 0 exactly where the hard choice kept the windows, tends to 1 for a shift far beyond its
    noise, and moves with ``D`` instead of jumping; the level's variance carries that move (delta method:
    ``d lambda / d D = 2 (1 - lambda) / D`` inside (0, 1)) beside the counts' and the shares': each window's moved
    level is worth ``f (1 - f) / var`` atoms (``f`` its fraction). The MSE-optimal weight with ``b^2`` plugged in,
    ``1 - (var D + var B - var W) / (2 D^2)``, is positive where the hard choice kept the windows, and on dev rod
    10039 it unmixed a rod the hard choice keeps (weight 0.44, volume +2.3 -> -20.2 %).

    Parameters
    ----------
    w : (2,) float64
        The measured species' fraction in the inside and outside windows.
    n : (2,) float64
        Basis atoms in each window.
    mixed : (2,) float64
        The inside phase's mean share in each window (``g_in``, ``g_out``).
    mixed_cov : (2, 2) float64
        Covariance of the shares (e.g. the ball fit's (offset, width) covariance carried by their Jacobian).

    Returns
    -------
    Unmixing
    """
    (g_in, g_out), spread = mixed, mixed[0] - mixed[1]
    counts = w * (1 - w) / np.maximum(n, 1e-300)
    # every level below is a function of (w_in, w_out, g_in, g_out), whose errors are independent but for the shares'
    noise = np.zeros((4, 4))
    noise[[0, 1], [0, 1]] = counts
    noise[2:, 2:] = mixed_cov
    # gradients over (w_in, w_out, g_in, g_out): the windows' midpoint, the unmixed one, each window and its unmixing
    mid = np.array([0.5, 0.5, 0.0, 0.0])
    gap = w[1] - w[0]
    unmixed = np.array([1 - 2 * g_out, 2 * g_in - 1, (1 - 2 * g_out) * gap, (2 * g_in - 1) * gap]) / (2 * spread)
    unmixed[2:] /= spread
    windows = np.eye(4)[:2]
    solved = np.array([[1 - g_out, g_in - 1, (1 - g_out) * gap, (g_in - 1) * gap],
                       [-g_out, g_in, -g_out * gap, g_in * gap]]) / spread
    solved[:, 2:] /= spread
    level = np.array([((1 - g_out) * w[0] - (1 - g_in) * w[1]), (g_in * w[1] - g_out * w[0])]) / spread
    shift = float(unmixed[:2] @ w - 0.5 * w.sum())
    delta = unmixed - mid
    var_b, var_w, var_shift = (float(v @ noise @ v) for v in (unmixed, mid, delta))
    gain = shift ** 2 - var_shift - var_b + var_w
    lam = float(np.clip(gain / shift ** 2, 0.0, 1.0)) if shift else 0.0
    slope = 2 * (1 - lam) / shift if 0 < lam < 1 else 0.0  # d lambda / d D
    worth = np.zeros(2)
    for s in (0, 1):
        grad = windows[s] + lam * (solved[s] - windows[s]) + (level[s] - w[s]) * slope * delta
        f = float(np.clip(w[s] + lam * (level[s] - w[s]), 1e-6, 1 - 1e-6))
        worth[s] = f * (1 - f) / max(float(grad @ noise @ grad), 1e-300)
    return Unmixing(np.asarray(mixed, dtype=np.float64), shift, var_b, gain, lam, worth)


def unmixing_shift(distance: np.ndarray, part: np.ndarray, total: np.ndarray, window: np.ndarray, fit: BallFit, *,
                   radius: float, dims: float, blur: float) -> Unmixing:
    """Each window's share of the inside phase under one object's fitted ball, and how far unmixing the windows by
    them moves its levels (:func:`unmixing_weight`).

    The shares ``g`` are each window's mean of :func:`ball_profile` over its ions; their covariance is the fit's
    (offset, width) covariance carried by their Jacobian (delta method, central differences). An interface the
    ions do not fix (a thin, low-contrast object whose fitted offset and width trade off over nanometres) gives
    shares, and an unmixed level, far less certain than any shift: weight 0.

    Parameters
    ----------
    distance, part, total, window : (b,)
        The object's ions (:func:`held_out_gain`).
    fit : BallFit
        Its ball fitted to them (:func:`fit_ball`).
    radius, dims, blur : float
        The ball (:func:`object_shapes`) and the isotropic blur sigma, nm.

    Returns
    -------
    Unmixing
    """
    sides = [window == side for side in (0, 1)]
    n = np.array([total[s].sum() for s in sides])
    w = np.array([part[s].sum() for s in sides]) / np.maximum(n, 1e-300)

    def shares(offset: float, width: float) -> np.ndarray:
        return np.array([np.average(ball_profile(distance[s] - offset, radius=max(radius + offset, 0.0), dims=dims,
                                                 width=width, blur=blur), weights=total[s]) for s in sides])

    q = np.array([fit.offset, max(fit.width, 0.02)])
    step = 1e-3
    jac = np.column_stack([(shares(*(q + h)) - shares(*(q - h))) / (2 * step) for h in np.eye(2) * step])
    return unmixing_weight(w=w, n=n, mixed=shares(*q), mixed_cov=jac @ fit.cov @ jac.T)


def profile_levels(distance: np.ndarray, atoms: np.ndarray, species: int, fit: BallFit | dict[int, BallFit], *,
                   radius, dims, blur: float, half_width: float = 3.0,
                   group: np.ndarray | None = None, cov: np.ndarray | None = None) -> tuple[np.ndarray, float] | None:
    """One object's inside composition from all its ions under its fitted ball profile, and what it is worth in atoms.

    Each basis element's fraction is regressed on the fitted profile (:func:`fit_ball`),
    ``fraction_e(d) = out_e + (in_e - out_e) g(d - offset)``, by least squares weighted by each ion's atoms over
    ``half_width`` each side: the levels deep inside that the whole two-sided profile implies, which move with the
    fitted interface, not with the surface the distances are measured to. An object thinner than its plateau windows
    has few or none of its ions in its inside window, and those it has lie in its interface (a window that starts
    halfway to its deepest ion samples more of its core the smaller its surface); the profile's level uses every
    ion. Its worth is the measured species' binomial variance over the level's variance: the count's (the weighted
    regression's) plus the fit's (offset, width) covariance carried by central differences (delta method), so that an
    interface the ions do not fix (offset and width trading off) makes it worth little.

    Parameters
    ----------
    distance : (b,) float64, nm
        Signed distances of the object's ions (negative inside).
    atoms : (b, k) float64
        Basis atoms of each element per ion.
    species : int
        Index of the measured species in the basis.
    fit : BallFit, or {object: BallFit}
        The object's ball fitted to these ions; or, with ``group``, the balls of the objects of one phase fitted
        together (:func:`fit_balls`): one inside composition regressed on all their ions, each under its own ball.
    radius, dims : float, or (n_components,) float64 with ``group``
        The ball (:func:`object_shapes`).
    blur : float, nm
        The isotropic blur sigma.
    half_width : float, nm
    group : (b,) int, optional
        Each ion's object (ions of objects not in ``fit`` left out).
    cov : (2 m, 2 m) float64, optional
        With ``group``: the joint covariance of the objects' (offset, width) (:func:`fit_balls`), carried whole (the
        shared levels correlate the objects' interfaces; their blocks alone would overstate the level's worth).

    Returns
    -------
    inside : (k,) float64
        Fractions, clipped at 0 and normalised.
    worth : float
        Atoms whose binomial count would be as certain as the measured species' level; None where the profile does
        not separate the two levels (no ion the model puts inside).
    """
    if group is None:
        fits, group, radius, dims = {0: fit}, np.zeros(len(distance), dtype=int), {0: radius}, {0: dims}
    else:
        fits = fit
    use = (np.abs(distance) <= half_width) & np.isin(group, list(fits))
    d, a, grp = distance[use], atoms[use], group[use]
    weight = a.sum(axis=1)
    objects = list(fits)
    mine = [np.flatnonzero(grp == c) for c in objects]  # indices: each solve writes every object's ions, not m masks
    profile = _ShiftedProfiles([d[sel] for sel in mine], [radius[c] for c in objects], [dims[c] for c in objects],
                               blur)

    def solve(q: np.ndarray):  # q: (m, 2) each object's offset and width
        g = np.empty(len(d))
        for i, (sel, (offset, width)) in enumerate(zip(mine, q)):
            g[sel] = profile(i, offset, max(width, 0.02))
        design = np.column_stack([1 - g, g])
        normal = design.T @ (design * weight[:, None])
        if np.linalg.cond(normal) > 1e12:
            return None, None
        return np.linalg.solve(normal, design.T @ a), normal

    q = np.array([[fits[c].offset, fits[c].width] for c in objects])
    coef, normal = solve(q)
    if coef is None:
        return None
    level = coef[1, species]
    step = 1e-3
    grad = []
    for h in np.eye(q.size) * step:
        up, down = solve(q + h.reshape(q.shape))[0], solve(q - h.reshape(q.shape))[0]
        if up is None or down is None:
            return None
        grad.append((up[1, species] - down[1, species]) / (2 * step))
    grad = np.array(grad)
    if cov is None:
        cov = fits[objects[0]].cov if len(objects) == 1 else np.zeros((q.size, q.size))
    f = float(np.clip(level, 1e-6, 1 - 1e-6))
    var = f * (1 - f) * np.linalg.inv(normal)[1, 1] + float(grad @ cov @ grad)
    inside = np.clip(coef[1], 0.0, None)
    return inside / max(inside.sum(), 1e-300), f * (1 - f) / max(var, 1e-300)


def split_worth(level: tuple[np.ndarray, float], halves: list, species: int) -> tuple[np.ndarray, float]:
    """An object's profile level (:func:`profile_levels`) with its worth checked against its two cross-fit halves.

    The two halves' ions are independent, so the information they hold about the level adds up: a level read from
    all the ions can be worth no more than the two halves' levels, each read on its half's ions alone under its own
    fit, are worth together. A stated worth beyond that sum is the delta method failing where the level moves
    non-linearly with a poorly fixed interface (low contrast: offset and width trade off), the curse
    :func:`pooled_profiles` measures, a fit that comes out narrow by chance reading the level low and stating it
    certain (dev cuboid 31113's first cube, Ti 6.8 points of contrast: fitted 0.12 nm wide, ``P`` 15.6 at.% stated
    worth 6015 atoms against a true 17.65 and a window's 17.1; its halves, 0.02 and 0.91 nm wide, worth 3369 and
    23). There the level's variance is taken as the larger of the stated one and ``(P_A - P_B)^2 / 4``, the
    halves' spread (the whole's level is to first order their mean), which owes nothing to the delta method (16.6
    and 19.0 at.%: worth 906); a worth within the sum is kept as stated.

    Parameters
    ----------
    level : ((k,) float64, float)
        The profile's fractions and their worth in atoms.
    halves : [level or None, level or None]
        The same profile level read on each half's ions alone (None where a half has no fit: the worth as stated).
    species : int
        Index of the measured species.

    Returns
    -------
    ((k,) float64, float)
        ``level`` with its worth checked.
    """
    inside, worth = level
    if any(h is None for h in halves) or worth <= halves[0][1] + halves[1][1]:
        return level
    f = float(np.clip(inside[species], 1e-6, 1 - 1e-6))
    spread = 0.25 * (halves[0][0][species] - halves[1][0][species]) ** 2
    return inside, min(worth, f * (1 - f) / max(spread, 1e-300))


def pooled_profiles(*, levels: list[tuple[np.ndarray, float]], species: int) -> np.ndarray:
    """(k,) several objects' profile levels (:func:`profile_levels`) pooled, as a sum of atoms whose binomial count
    would be as certain as the pool: what an unmixed object's inside level is shrunk toward (:func:`chosen_pools`).

    A profile level's worth moves with its own error: a fitted interface that comes out narrow by chance reads the
    inside level low (the profile reaches its plateau sooner) and, its inside less extrapolated, states it more
    certain (spheres of 2.0 and 2.6 nm under a 1.0 nm interface at 55 / 5 at.%, redrawn ions: correlation of the
    error with the worth -0.7 and -0.9, RMS error over the stated one 1.29 and 1.21). Pooled by those worths alone the
    pool states itself too certain, and leans toward the draws that read low. The objects then scatter about their
    pool by more than their worths allow, and that excess is measured: the levels are pooled as a random-effects mean
    (DerSimonian & Laird, *Controlled Clinical Trials* 7, 177, 1986), each weighed by ``1 / (var_i + tau^2)``
    (``var_i = f (1 - f) / worth_i`` at the pooled fraction ``f``), ``tau^2`` the between-object variance beyond the
    stated ones, ``(Q - (m - 1)) / (sum w - sum w^2 / sum w)`` from Cochran's ``Q = sum w_i (f_i - f)^2`` about the
    worths' mean ``f`` (``w_i = 1 / var_i``; 0 where ``Q <= m - 1``), and the pool is worth
    ``f (1 - f) sum_i 1 / (var_i + tau^2)`` atoms. A single object, or objects that agree within their errors, pool
    as before (the worths' sum). The two spheres at 41 / 2.7 at.%, 180 redraws: the pool's error over its stated
    error, RMS, 1.28 pooled by the worths, 1.06 so (tests/test_curved_levels.py).

    Parameters
    ----------
    levels : list of ((k,) float64, float)
        Each object's profile fractions and their worth in atoms (> 0), at least one.
    species : int
        Index of the measured species.

    Returns
    -------
    (k,) float64
        The pooled fractions times the pool's worth in atoms.
    """
    f, worth = np.array([lv[species] for lv, _ in levels]), np.array([worth for _, worth in levels])
    # each level's variance at the pooled fraction: without excess scatter the pool is the worths' (atoms) mean
    mean = float(worth @ f) / worth.sum()
    var = max(mean * (1 - mean), 1e-12) / worth
    w = 1.0 / var
    tau2 = max(float(w @ (f - mean) ** 2) - (len(f) - 1), 0.0) / (w.sum() - float(w @ w) / w.sum()) \
        if len(f) > 1 else 0.0
    weight = 1.0 / (var + tau2)
    inside = sum(wi * lv for wi, (lv, _) in zip(weight, levels)) / weight.sum()
    return inside * max(mean * (1 - mean), 1e-12) * weight.sum()


PROFILE_SE = 1.0
"""Standard errors of the profile level's own by which it may lie off while its mean squared error stays below the
window's, and of the window's own by which its reading may lie off while its misfit still vetoes the profile
(:func:`profile_better`; the one-standard-error rule of the mode selection)."""


def profile_better(level: tuple[np.ndarray, float], fit: BallFit, window: np.ndarray, pool: np.ndarray, g_in: float,
                   k: int, prior: float) -> bool:
    """Whether an object's profile level ``P`` (:func:`profile_levels`) is expected nearer its inside phase than the
    level ``S`` its inside window gives it: the window's atoms shrunk toward the pooled windows by ``prior`` atoms
    (:func:`levels_from_sums`).

    Mean squared errors, as the unmixing's weight (:func:`unmixing_weight`). Under the fitted ball the window reads
    ``O + (P - O) g_in`` (``O`` the fitted outside level, ``g_in`` the window's mean share of the inside phase),
    so ``S`` is biased by ``b = E[S] - P``: its window's share of the weight by the interface the window holds, the
    prior's by the pool's distance from ``P``. ``b^2`` is estimated by the positive part of ``b^2 - var b``.
    ``var S`` counts the atoms behind ``S``: the window's own and the pool's (a prior of ``prior`` atoms drawn from
    a pool of fewer is no more certain than the pool). ``P`` has a bias of its own where the ball does not hold
    (its misfit); the window, unmixed by the fitted shares, ``(W - O (1 - g_in)) / g_in``, reads the inside phase
    without it, so ``P`` less that reading, ``m``, estimates it: ``m^2 - var m``, its positive part. ``P`` is taken where the
    estimated mean squared error of ``S``, ``b^2 - var b + var S``, exceeds that of ``P``,
    ``m^2 - var m + var P``, with ``P`` moved by :data:`PROFILE_SE` of its own standard error either way (the
    delta method; both biases are read off ``P``, so ``P`` lying off by chance makes ``S`` look biased and would
    choose ``P`` where it is wrong: held-out artefact 10004, a 2 nm cube whose profile of 34 atoms' worth read 45
    at.% against its window's 33 and a true 34). Each positive part moves along its slope but not below zero: the
    estimate of a squared bias cannot fall further, so where ``S``'s variance alone exceeds ``P``'s the choice is
    ``P`` however little of the bias is real (held-out thin 10019's third rod: 7 window atoms, a level that is the
    pool's of 72 window atoms, variance 2.4 times that of its profile worth 180; with the slope of ``b^2`` taken
    whole at a bias just above its error, a fall of 0.0054 against a positive part of 0.0005 and a gain of 0.0024,
    the pool's level 6.5 points below the truth was kept). The misfit is the window's evidence against ``P``, and
    counts only as far as it holds with the window's reading moved toward ``P`` by :data:`PROFILE_SE` of its own
    counting error (the positive part of ``m^2 - var m`` moved by ``2 |m| sd W / g_in``, not below zero), its variance
    taken at the reading ``P`` predicts for it, ``O + (P - O) g_in``, the misfit's null (at its own reading a window of
    a few atoms reads 0 or 1 and counts as certain: held-out thin 10005's fourth rod, 0 of 3 atoms, vetoed its
    profile level 27.73 at.% worth 478 atoms, 0.4 of its errors from the truth 28.61, and kept the pool's 29.30 of
    450; 0 of 20 still vetoes it): a small
    window reading high by chance does not veto a profile worth many more atoms (unseen thin 10033's second rod: a
    76-atom window 1.6 of its errors above the truth's reading vetoed ``P`` 17.39 at.% worth 964, truth 17.1, and
    kept the pool's 20.0); the same reading from four times the atoms still does. A window deep enough (``g_in``
    1) with many atoms keeps its level where the profile disagrees with it (a large sphere's); a thin object's few
    window atoms, whose level is the pool's, give way to the profile where the pool is the less certain or lies off
    it by more than their errors.

    Parameters
    ----------
    level : ((k,) float64, float)
        The profile's fractions and their worth in atoms (:func:`profile_levels`).
    fit : BallFit
        The object's fitted ball.
    window : (k,) float64
        Atoms per basis element in the object's inside window.
    pool : (k,) float64
        Atoms per basis element in every object's inside windows (what ``S`` is shrunk toward).
    g_in : float
        The inside window's mean share of the inside phase under ``fit`` (:func:`ball_profile`).
    k : int
        Index of the measured species.
    prior : float
        Atoms' worth of the pool in ``S`` (``plateau_prior``).

    Returns
    -------
    bool
    """
    read = window_bias(level, fit, window, pool, g_in, k, prior)
    if read is None:
        return False
    bias, var_bias, var_s, w = read
    inside, worth = level
    p_in, n_in = inside[k], window.sum()
    var_p = p_in * (1 - p_in) / worth
    misfit = var_misfit = var_own = 0.0
    if n_in > 0 and g_in > 0:  # the window unmixed by the model is a reading of the inside phase P must agree with
        own = window[k] / n_in
        misfit = p_in - (own - fit.outside * (1 - g_in)) / g_in
        # the window's counting variance at the reading P predicts for it (the misfit's null), not at its own
        # reading: a window of a few atoms reads 0 or 1 and would count as certain (held-out thin 10005's fourth
        # rod: 0 of 3 atoms vetoed a profile level worth 478 atoms)
        expected = min(max(fit.outside + (p_in - fit.outside) * g_in, 0.0), 1.0)
        var_own = expected * (1 - expected) / n_in / g_in ** 2
        var_misfit = var_p + var_own
    # squared biases estimated by their positive parts (a squared bias is not negative; the part below zero is
    # noise that would choose at random between estimators of equal error)
    biased, misfitted = max(bias ** 2 - var_bias, 0.0), max(misfit ** 2 - var_misfit, 0.0)
    # both biases are read off P (d bias / dP = -(1 - w g_in), d misfit / dP = 1), and P lying off by chance would
    # make it look better: P is taken where the gain stays positive with P moved by PROFILE_SE of its own error
    # either way, each positive part moved along its slope but not below zero (it cannot fall further: where S's
    # variance alone exceeds P's, S gives way however little of its bias is real)
    step = PROFILE_SE * np.sqrt(var_p)
    d_biased = -2 * bias * (1 - w * g_in) * (biased > 0) * step
    d_misfitted = 2 * misfit * (misfitted > 0) * step
    # the misfit is the window's evidence against P: it vetoes P only as far as it holds with the window's reading
    # moved toward P by PROFILE_SE of the window's own counting error (d misfit / d window = -1 / g_in), as P's
    # evidence for itself is taken only as far as it holds with P moved by its own
    own_fall = 2 * abs(misfit) * (misfitted > 0) * PROFILE_SE * np.sqrt(var_own)
    return min(max(biased + sign * d_biased, 0.0) + var_s - max(misfitted + sign * d_misfitted - own_fall, 0.0)
               - var_p for sign in (-1.0, 1.0)) > 0


def window_bias(level: tuple[np.ndarray, float], fit: BallFit, window: np.ndarray, pool: np.ndarray, g_in: float,
                k: int, prior: float) -> tuple[float, float, float, float] | None:
    """How far the level ``S`` an object's inside window gives it (its atoms shrunk toward the pooled windows by
    ``prior`` atoms, :func:`levels_from_sums`) is expected to lie from its profile level ``P`` (:func:`profile_levels`)
    under the fitted ball (:func:`profile_better`, which the arguments are those of).

    Returns
    -------
    (bias, var_bias, var_s, w) or None
        ``b = E[S] - P`` (fraction; the window reads ``O + (P - O) g_in``, the pool its own level), its variance
        (``P``'s count carried by ``1 - w g_in``, the pool's by ``1 - w``), ``var S`` (the window's atoms and the
        pool's: a prior of ``prior`` atoms drawn from a pool of fewer is no more certain than the pool) and ``w``, the
        window's own share of ``S``. None for an empty pool.
    """
    inside, worth = level
    p_in, n_in, n_pool = inside[k], window.sum(), pool.sum()
    if n_pool <= 0:
        return None
    w = n_in / (n_in + prior)
    s = (window[k] + prior * pool[k] / n_pool) / (n_in + prior)
    var_s = s * (1 - s) * (n_in + prior ** 2 / n_pool) / (n_in + prior) ** 2
    var_p = p_in * (1 - p_in) / worth
    bias = w * (fit.outside + (p_in - fit.outside) * g_in) + (1 - w) * pool[k] / n_pool - p_in
    var_bias = var_p * (1 - w * g_in) ** 2 + (1 - w) ** 2 * s * (1 - s) / n_pool
    return float(bias), float(var_bias), float(var_s), float(w)


def short_of_plateau(window: np.ndarray, fit: BallFit, g_in: float, k: int) -> bool:
    """Whether an object's inside window falls short of its inside plateau by more than its own counting error.

    Under the fitted ball the window reads ``O + (I - O) g_in`` (``g_in`` its mean share of the inside phase), short
    of the inside level ``I`` by ``(1 - g_in) (I - O)``. Where that shortfall is within one standard error of the
    window's fraction, ``sqrt(f (1 - f) / n)`` with ``f`` the reading the ball expects (not the window's own, which
    is 0 or 1 on a few atoms), the window reads its plateau as well as its atoms can tell (its squared bias below
    its variance); a level pooled from other objects (:func:`fit_balls`) could only trade the
    window's own atoms for the others', and the shrinkage toward the pooled windows already does that within the
    windows' model (:func:`levels_from_sums`). Where it falls short by more, the window's level is biased beyond its
    counting, and only a profile model can read the plateau it does not reach (held-out rod 10011's second rod:
    window 1.0 nm into a 1 nm rod; dev rod 3's thick rods, ``g_in`` 1, keep their windows).

    Parameters
    ----------
    window : (k,) float64
        Atoms per basis element in the object's inside window.
    fit : BallFit
        The ball whose levels and ``g_in`` are offered.
    g_in : float
        The inside window's mean share of the inside phase under ``fit`` (:func:`ball_profile`).
    k : int
        Index of the measured species.

    Returns
    -------
    bool
        True also for an empty window (its level is wholly the pool's).
    """
    n = window.sum()
    if n <= 0:
        return True
    short = (1.0 - g_in) * (fit.inside - fit.outside)
    f = fit.inside - short
    return short ** 2 > f * (1.0 - f) / n


def held_out_gain(distance: np.ndarray, part: np.ndarray, total: np.ndarray, window: np.ndarray, half: np.ndarray, *,
                  radius: float, dims: float, blur: float, half_width: float = 3.0,
                  fits: tuple[BallFit, BallFit] | None = None) -> tuple[float, float] | None:
    """Nats by which one object's blurred ball profile predicts its held-out window ions better than its windows do,
    and that gain's standard error.

    Two-fold cross-validation on the halves of the cross-fit: on each half the ball profile is fitted
    (:func:`fit_ball`) and the two windows' own fractions are counted; the other half's window ions are scored
    under each, the binomial log-likelihood of each ion's ``part`` atoms of its ``total``. The windows' model
    says the plateaus are reached at the windows (the fraction flat across each); the ball's says how much of
    each window the interface still holds. Positive: the ball's model predicts the ions it was not fitted to
    better. The standard error is that of a sum over the held-out ions of their log-likelihood differences, as
    the mode selection's (:func:`~apt_filters.refine.crossval.smoothest_within_one_se`).

    Parameters
    ----------
    distance : (b,) float64, nm
        Signed distances of the object's ions (negative inside), each to the other half's surface.
    part, total : (b,) float64
        Atoms of the measured species, and basis atoms, per ion.
    window : (b,) int
        Each ion's plateau window (:func:`window_labels`: 0 inside, 1 outside, -1 neither).
    half : (b,) int
        Each ion's half (0 or 1).
    radius, dims : float
        The object's ball (:func:`object_shapes`).
    blur : float, nm
        Isotropic sigma of the reconstruction blur.
    half_width : float, nm
        Reach of the profile fit each side.
    fits : (BallFit, BallFit), optional
        The ball fitted on each half (e.g. with the other objects of its phase, :func:`fit_balls`, or its own
        :func:`fit_ball` of that half's ions, None where it has none); None: fitted here on this object's ions.

    Returns
    -------
    gain, se : float, nats; or None where a half has too few ions to fit or an empty window.
    """
    diff = []
    for fold in (0, 1):
        train, test = half == fold, (half != fold) & (window >= 0)
        fit = fits[fold] if fits is not None else fit_ball(distance[train], part[train], total[train], radius=radius,
                                                           dims=dims, blur=blur, half_width=half_width)
        n = [total[train & (window == side)].sum() for side in (0, 1)]
        if fit is None or min(n) <= 0:
            return None
        flat = [part[train & (window == side)].sum() / n[side] for side in (0, 1)]
        g = ball_profile(distance[test] - fit.offset, radius=max(radius + fit.offset, 0.0), dims=dims,
                         width=fit.width, blur=blur)
        ball = fit.outside + (fit.inside - fit.outside) * g
        diff.append(_log_likelihood(part[test], total[test], ball)
                    - _log_likelihood(part[test], total[test], np.where(window[test] == 0, flat[0], flat[1])))
    diff = np.concatenate(diff)
    gain = float(diff.sum())
    return gain, float(np.sqrt(max(np.sum(diff ** 2) - gain ** 2 / max(len(diff), 1), 0.0)))


def _log_likelihood(part: np.ndarray, total: np.ndarray, fraction: np.ndarray) -> np.ndarray:
    """Per ion: binomial log-likelihood (nats, less its combinatorial term) of ``part`` of ``total`` atoms at
    ``fraction``; the fraction kept within 1e-6 of 0 and 1 (a fitted level may reach past them)."""
    f = np.clip(fraction, 1e-6, 1 - 1e-6)
    return part * np.log(f) + (total - part) * np.log1p(-f)


def crossing_share(distance: np.ndarray, total: np.ndarray, fit: BallFit, *, radius: float, dims: float, blur: float,
                   lift: float, half_width: float, bin_width: float) -> float:
    """The share of its inside level at which an object's placement must take the crossing so that it stops at the
    interface of its fitted ball profile.

    The placement fits an error-function step between the two levels to each vertex's profile
    (:func:`~apt_filters.refine.surface.matched_offset`: each bin weighs its atoms times the step's slope) and the
    blur stage then moves the surface out by the blur's curvature bias ``lift``. A thick object's profile is that
    step; a thin one's is not: its two sides' blurred interfaces overlap, the profile never reaches the inside
    level and lies below the step inside, so the fitted step stops short of the interface (a rod of radius 1 nm,
    interface width 0.45 nm, blur 0.26 nm: 0.014 nm inside, 2.8 % of its volume; ``m`` 0.985 puts it on the
    interface within 1e-4 nm; a 3 nm sphere: 0.004 nm). With the inside level taken as
    ``outside + m (inside - outside)`` the step fitted to the normalised profile ``u / m`` is stationary where
    ``sum n s (u / m - Phi(-d / w)) = 0`` (``n`` the atoms of each bin, ``s`` the step's slope, ``w`` its width,
    which the placement reads off the same normalised profile): with ``u`` the fitted ball's profile
    (:func:`ball_profile`) binned by the distances of the object's own ions from where the placement should
    stop (the fitted interface less ``lift``),

        m = sum n s u / sum n s Phi(-d / w),

    solved together with ``w`` by fixed-point iteration. ``m`` is 1 for a planar step.

    Parameters
    ----------
    distance, total : (b,) float64
        Signed distances (nm, negative inside) and basis atoms of the object's ions.
    fit : BallFit
        Its fitted ball (:func:`fit_ball`) on these distances.
    radius, dims, blur : float
        The ball (:func:`object_shapes`) and the isotropic blur sigma, nm.
    lift : float, nm
        How far the blur stage moves the surface out after the placement.
    half_width, bin_width : float, nm
        The placement's profile bins.

    Returns
    -------
    float
    """
    from scipy.special import ndtr

    d = distance - (fit.offset - lift)
    use = np.abs(d) < half_width
    n_bins = int(round(2 * half_width / bin_width))
    idx = np.clip(((d[use] + half_width) / bin_width).astype(int), 0, n_bins - 1)
    g = ball_profile(distance[use] - fit.offset, radius=max(radius + fit.offset, 0.0), dims=dims,
                     width=max(fit.width, 0.02), blur=blur)
    n = np.bincount(idx, weights=total[use], minlength=n_bins)
    u = np.divide(np.bincount(idx, weights=total[use] * g, minlength=n_bins), n, out=np.zeros(n_bins), where=n > 0)
    centre = -half_width + bin_width * (np.arange(n_bins) + 0.5)
    step = (centre < 0).astype(np.float64)
    m = 1.0
    for _ in range(50):
        v = np.clip(np.where(n > 0, u / m, step), 0.0, 1.0)
        width = max(float(np.sqrt(np.pi) * np.sum(v * (1 - v)) * bin_width), bin_width)
        slope = np.exp(-0.5 * (centre / width) ** 2)
        den = float(np.sum(n * slope * ndtr(-centre / width)))
        if den <= 0:
            return 1.0
        new = float(np.sum(n * slope * u)) / den
        if abs(new - m) < 1e-6:
            return new
        m = new
    return m
