"""Sharp edges and corners of faceted objects: planar facets found on the refined surface, edges rebuilt.

The refinement (:mod:`apt_filters.refine.surface`) pools each vertex's profile over ~2 nm and smooths
its moves, so where two faces of a cuboid precipitate meet it keeps an edge rounded by ~1 nm (its
start, marching cubes on a field delocalized by ~1 nm, is rounder still): a 6 nm cube lost 7-9 % of
its volume and 9-10 % of its area, and its corners stood 1-1.3 nm inside the true ones. Each face,
though, is fixed by thousands of ions, so its plane is known far better than the rounding.

Method
------
1. **Facets.** Per object, the vertex normals (of a copy smoothed by ``smooth`` umbrella passes) are
   searched for modes: the direction whose ``cap``-degree cone holds the most area, mean-shifted.
   A mode is a facet when that cone holds at least ``share`` of the object's area *and* ``min_area``
   nm² in absolute terms: on a sphere every 20° cone holds 3 % of the area (6-7 % with the refined
   surface's noise), and a 3 nm sphere's most crowded cone held 7-8 nm², a 6-7 nm cube's faces 14-32 nm²
   (gamma-prime seeds 1-3). A 5 nm cube's faces hold only 7-15 nm² (the `many` specimen), so an object
   whose facets do not close it is searched again down to ``closed_area`` = 8 nm², and those modes count
   only if they close it (:func:`closes`): a cube's six do, a sphere's few noisy cones or a rod's strips
   round its axis do not. The facet's plane is fitted (area-weighted, least squares) to the connected
   part of the vertices within ``fit_cap`` degrees of the mode: the wider cone takes in the start of
   the rounded rims, which balances the faces' slight pillowing (their centres stand out from their rims).
   **1b. Planes from the ions** (:func:`fit_to_ions`). Where an object's facets close it (:func:`closes`,
   a cuboid with all six faces found), all its planes are refitted together to its ions, modelled as a
   blurred convex polyhedron, the product of one error-function step per plane, with opposite facets
   sharing one normal. The vertices' planes inherit the refinement's pooling and the rims' rounding: on
   the 16 cubes of gamma-prime seeds 1-8 they were tilted by 4.1° on average (up to 14°, a 6 nm cube's
   face, which put its corner 0.9 nm out). Each face alone fixes its tilt only to ~5° (the scores of its
   ~2000 core ions, bootstrapped); the joint fit adds the edges' ions, and the pairing each face's
   opposite one, which is what brought the tilts to 2.0° on average (4.1° at most). Where the fit fails (a plane
   turned away, or the planes no longer close), the planes the ions do not support by the information criterion
   are left out one at a time and the rest refitted: a small cube's half found a 7th patch at a corner or edge,
   whose plane turned by 44-50° and failed the whole fit (dev cuboid 30024 and 30037's ion redraws).
2. **Rims.** A vertex outside every facet moves along its normal onto the envelope of the
   facets' planes near it (within ``reach`` nm): inside all of them (a convex rim) to where its ray
   first leaves their intersection, outside all of them (a concave fillet) to where it enters their
   union; mixed cases stay. Only where at least two facets are near, where its normal is a
   non-negative mix of their normals (to within ``span_tol``: a face not found as a facet would
   otherwise run out to the other planes' intersection), and at most ``max_move`` nm; every move is
   fold-guarded (:func:`~apt_filters.refine.surface.guarded_move`).
3. **Edges and corners** (:func:`edge_and_corner_steps`). Moving rims along their normals lands them on the
   planes but few vertices on an edge and none on a corner, so the triangles there cut them off (a cube's
   corner ~0.9 nm in). Where three facets of an object meet in a point that lies near all three and
   inside the object's other planes, the vertex nearest that point moves onto it; along each edge, the
   vertices nearest to points one mesh edge apart move onto it. Corners: gamma-prime seeds 1, 2, 5, 6, 8
   (10 cubes), area 2.9 -> 2.3 % mean abs. Edges, with the planes from the ions:
   the mesh's area fell 1.3-3.7 % short of its own fitted polyhedron's without the rows (seeds 1, 2, 3, 6),
   and lies between 1.1 % over and 2.0 % short of it with them (seeds 1-8).

4. **The profile at edges, rounded edges** (:func:`edge_rounding`). The planes' joint fit (1b) models a blurred
   sharp polyhedron, a quarter of the contrast on an edge; an interface's own profile follows the distance to
   it, round outside an edge and half the contrast on it, and read as the former it moves the planes out (a
   3 nm lath's by 0.06-0.17 nm under a 0.6 nm interface). So the object's ions are fitted again by the
   interface's profile in the signed distance to the polyhedron, blurred (:func:`rounded_scores`, the blur's
   share of the width fitted), its edges rounded by a radius: first sharp (offsets, share, width), then the
   radius at that share, kept where it stands two standard errors above 0 (with the offsets refitted
   alongside). A rounded object's rims then go onto the fillets (step 2 against the planes moved in by the
   radius and grown by a ball of it) and its edge rows and corners onto the fillets' middles (step 3). A
   cuboid rounded by 0.7 nm had kept its facets and came out +8 % in area with sharp edges (dev `cuboid`
   seed 31 rebuilt with rounded edges); +1 % with them. The planes beyond an ion's nearest two take only the
   blur's share off its score (the interface's offset is one draw for every plane): with the whole width each, a
   4 nm cube under a 1 nm interface read low inside and its planes moved out by 0.05-0.10 nm from their true
   places (V +7 to +16 %); the held-out test then preferred its smooth surface and it kept rounded edges (dev
   cuboid 30037's 4.2 nm cube: A -21.5 % -> -3.0 % with its facets kept).

5. **A slab's rims** (:func:`slab_pair`, :func:`slab_side`, :func:`slab_fit`). An object bounded by two opposite
   facets that do not close it (a plate's two flats) has a side that is not a facet: a disc's rim normals are radial,
   no mix of its faces' normals, so step 2 left its rims where the refinement rounded them (dev plate 10038: rims
   0.14-0.18 nm in, 38-44 % of their area lost, the side's middle pushed 0.03-0.17 nm out). Its side is taken as
   the surface parallel to the facets' normal through the equator's curve (polar, about the object's axis), placed
   by its ions as one offset against the facets' (the interface's profile about the prism of the two planes and the
   side, :func:`edge_rounding`), and every vertex off the facets' cores moves along its normal onto that prism (onto
   its fillets where the ions show the rims rounded), one row of vertices onto each rim (step 3). The slab's other
   facets lie on its side, which takes their place. Dev 10038: rims -0.14 / -0.18 -> 0.00 nm, V -2.1 / -5.4 ->
   +0.1 / +1.0 %, A -6.6 / -11.3 -> +0.1 / +0.3 %. A thin object its facets close is a slab all the same where
   its side does not crowd at the other facets (:func:`slab_pair`): strips on a disc's round side and rounded rims
   closed it in a square prism that the held-out ions refused (dev plates 31002, 31003, 31009: A -6 to -13 %).

A sphere has no facet and is left exactly as it is, and so is every open surface (an interface that meets
the specimen edge is not a polyhedron). :func:`~apt_filters.refine.surface.refine_surface` lets the facets be
switched off (``facets=False``).
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.sparse.csgraph import connected_components
from scipy.special import ndtr, ndtri
from scipy.spatial import ConvexHull, QhullError, cKDTree

from apt_filters.core.mesh import TriMesh, topology, vertex_normals
from apt_filters.core.special import erfc, erfc_scalar
from apt_filters.refine.band import adjacency
from apt_filters.refine.blur import vertex_areas

MAX_CANDIDATES = 400
"""Candidate directions tried per mode search (vertex normals, subsampled evenly)."""


@dataclass
class Facet:
    """A planar face of one object: the plane ``normal . x = offset`` and the vertices it was fitted to.

    Attributes
    ----------
    component : int
        Object (vertex component) the facet belongs to.
    normal : (3,) float64
        Unit outward normal of the plane.
    offset : float, nm
    vertices : (k,) int64
        Vertices the plane was fitted to (within ``fit_cap`` of the mode, connected).
    core : (j,) int64
        Of those, the vertices within ``cap`` of the mode: the facet proper, which does not move.
    area : float, nm²
        Area within ``cap`` of the mode (the detection criterion).
    rms : float, nm
        Root-mean-square distance of ``vertices`` to the plane.
    rounding : float, nm
        Radius of the object's rounded edges and corners where its ions fit that better than sharp ones
        (:func:`fit_to_ions`, :func:`slab_fit`); 0 for sharp edges.
    side : Side or None
        Of a slab's two facets (:func:`slab_fit`), the side between them; None elsewhere.
    fitted : bool
        Whether the plane was refitted to the object's ions (:func:`fit_to_ions`, :func:`slab_fit`); False where it
        is the plane of its vertices (found so, or the ions' fit refused).
    """

    component: int
    normal: np.ndarray
    offset: float
    vertices: np.ndarray
    core: np.ndarray
    area: float
    rms: float
    rounding: float = 0.0
    side: Side | None = None
    fitted: bool = False


@dataclass(frozen=True)
class Side:
    """The side of a slab, the surface parallel to its facets' common normal ``axis`` through a closed curve given in
    polar form about ``centre`` (3,) nm: radius ``radii[k]`` (K,) nm at the angle ``2 pi k / K`` from ``e1`` toward
    ``e2`` (unit vectors normal to ``axis``), linear between (:func:`slab_side`)."""

    centre: np.ndarray
    axis: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    radii: np.ndarray

    def moved(self, shift: float) -> Side:
        """The side moved out by ``shift`` nm (to first order in the curve's slope)."""
        return Side(self.centre, self.axis, self.e1, self.e2, self.radii + shift)

    def distance(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(b,) signed distances (nm, positive outside) of ``points`` (b, 3) to the side, to first order about the
        curve (the radial gap times the cosine of the curve's slope), and (b, 3) its outward unit normals there."""
        q = points - self.centre
        x, y = q @ self.e1, q @ self.e2
        rho, phi = np.hypot(x, y), np.mod(np.arctan2(y, x), 2 * np.pi)
        k = len(self.radii)
        t = phi / (2 * np.pi) * k
        lo = np.floor(t).astype(np.int64) % k
        hi, frac = (lo + 1) % k, t - np.floor(t)
        r = (1 - frac) * self.radii[lo] + frac * self.radii[hi]
        slope = (self.radii[hi] - self.radii[lo]) * k / (2 * np.pi)  # dr / dphi
        norm = np.hypot(r, slope)
        radial = np.cos(phi)[:, None] * self.e1 + np.sin(phi)[:, None] * self.e2
        around = -np.sin(phi)[:, None] * self.e1 + np.cos(phi)[:, None] * self.e2
        return (rho - r) * r / norm, (r[:, None] * radial - slope[:, None] * around) / norm[:, None]


def _mode(nn: np.ndarray, aa: np.ndarray, free: np.ndarray, start: np.ndarray, detect: float) -> np.ndarray:
    """Area-weighted mean shift of a unit direction within the cone ``detect`` (cosine) among ``free`` normals."""
    mode = start
    for _ in range(5):
        sel = free & (_dot(nn, mode) > detect)
        if not sel.any():
            break
        mode = (nn[sel] * aa[sel, None]).sum(axis=0)
        mode /= np.linalg.norm(mode)
    return mode


@njit(cache=True, nogil=True)
def _held(directions, normals, areas, detect):
    """(c,) area of ``normals`` (n, 3) within the cone ``detect`` (cosine) of each of ``directions`` (c, 3).

    Compiled rather than a matrix product: these small products are many, and BLAS's threads cost far more
    than they compute (find_facets on the 47 objects of the `many` specimen: 3.7 s of CPU with BLAS's two
    threads on a busy 2-core machine, 0.16 s with one)."""
    out = np.zeros(directions.shape[0])
    for i in range(directions.shape[0]):
        for k in range(normals.shape[0]):
            if (directions[i, 0] * normals[k, 0] + directions[i, 1] * normals[k, 1]
                    + directions[i, 2] * normals[k, 2]) > detect:
                out[i] += areas[k]
    return out


def _dot(nn: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(n,) ``nn @ direction`` without BLAS (see :func:`_modes`)."""
    return nn[:, 0] * direction[0] + nn[:, 1] * direction[1] + nn[:, 2] * direction[2]


def _modes(nn: np.ndarray, aa: np.ndarray, detect: float, share: float, min_area: float, opposite: float) -> list:
    """One object's facet modes, as (mode, detected, fit_from, area in the cone) (:func:`find_facets`, step 1)."""
    total = aa.sum()
    free = np.ones(len(nn), dtype=bool)
    mine, weak = [], []  # (mode, detected, fit_from, area in the cone) of modes above / below min_area
    while free.any():
        cand = np.flatnonzero(free)[:: max(1, int(free.sum()) // MAX_CANDIDATES)]
        held = _held(nn[cand], nn[free], aa[free], detect)
        if held.max() < share * total:
            break
        mode = _mode(nn, aa, free, nn[cand[np.argmax(held)]], detect)
        detected = free & (_dot(nn, mode) > detect)
        found = aa[detected].sum()
        if found < share * total:
            break
        fit_from = free.copy()  # later facets do not fit to earlier ones' cones
        free &= ~detected
        (mine if found >= min_area else weak).append((mode, detected, fit_from, found))
    if len(mine) >= 2:
        # a mode opposite a facet needs less (``opposite``), whether the search above met it (weak) or
        # not (searched for from the facet's antipode among the vertices left)
        for mode in [m[0] for m in mine]:
            if any(m[0] @ -mode > detect for m in mine):
                continue
            pick = [m for m in weak if m[0] @ -mode > detect]
            if not pick:
                anti = _mode(nn, aa, free, -mode, detect)
                detected = free & (_dot(nn, anti) > detect)
                if anti @ -mode > detect:
                    pick = [(anti, detected, free.copy(), aa[detected].sum())]
                    free &= ~detected
            # a pick within twice the cone of a facet found is the rest of that face, which the search left
            # when the facet's mode settled off its normal (a 5 nm cube's face at 20° got a second facet, and
            # the pair's joint fit to the ions tilted it by 38°; `many` seed 0)
            if (pick and pick[0][3] >= opposite * max(min_area, share * total)
                    and all(pick[0][0] @ m[0] <= 2 * detect ** 2 - 1 for m in mine)):
                mine.append(pick[0])
    return mine


def _peaks(nn: np.ndarray, aa: np.ndarray, detect: float, mine: list, peak: float) -> list:
    """``mine`` (:func:`_modes`) and the further modes where the normals crowd (step 1, ``peak``).

    A mode counts when the area per solid angle of the normals in its cone not yet taken is at least ``peak``
    times that in the ring around it (out to twice the cone's angle, every vertex counted: a cone beside a
    facet found has that facet in its ring), its cone holds at least half of what it would on a sphere of
    the object's area, and it lies more than three cones' angle from every mode found (nearer, the crowd
    is the rounded rim beside that mode's face). Candidates are taken in order of the area their cone
    holds among the normals no mode has taken yet.
    """
    ring = np.cos(2 * np.arccos(detect))
    apart = np.cos(3 * np.arccos(detect))
    solid = (1.0 - detect) / (detect - ring)  # cone's solid angle over the ring's
    floor = 0.5 * 0.5 * (1.0 - detect) * aa.sum()
    free = np.ones(len(nn), dtype=bool)
    for m in mine:
        free &= ~m[1]
    out = list(mine)
    spent = ~free  # normals no longer tried as a start: taken, tried, or within three cones of a mode
    for m in out:
        spent |= _dot(nn, m[0]) > apart
    clear = free.copy()  # normals beyond every mode's ring
    for m in out:
        clear &= _dot(nn, m[0]) <= ring
    while not spent.all():
        cand = np.flatnonzero(~spent)[:: max(1, int((~spent).sum()) // MAX_CANDIDATES)]
        held = _held(nn[cand], nn[free], aa[free], detect)
        around = _held(nn[cand], nn, aa, ring) - _held(nn[cand], nn, aa, detect)
        crowded = (held >= floor) & (held >= peak * solid * around)
        if not crowded.any():
            break
        # mean-shifted within the ring's cone over the normals away from every mode's rim: a thin object's
        # narrow face is a ridge of normals from one broad facet to the opposite one, and its centre (the
        # face's normal) is the middle of what the broad facets' rims leave of it
        best = cand[np.argmax(np.where(crowded, held, -1.0))]
        spent[best] = True
        mode = nn[best]
        for _ in range(3):
            mode = _mode(nn, aa, clear, mode, ring)
        if any(mode @ m[0] > apart for m in out):  # shifted onto a mode's rim after all
            continue
        cosine = _dot(nn, mode)
        detected = free & (cosine > detect)
        found = aa[detected].sum()
        out.append((mode, detected, free.copy(), float(found)))
        free &= ~detected
        clear &= cosine <= ring
        spent |= cosine > apart
    return out


def _fit(vertices: np.ndarray, adj, idx: np.ndarray, nn: np.ndarray, aa: np.ndarray, fit_from: np.ndarray,
         detected: np.ndarray, mode: np.ndarray, fit: float, component: int, found: float) -> Facet:
    """The plane of a facet: least squares over the connected part of ``fit_from`` within ``fit`` of ``mode``."""
    sel = np.flatnonzero(fit_from & (nn @ mode > fit))
    _, label = connected_components(adj[idx[sel]][:, idx[sel]], directed=False)
    keep = sel[label == np.bincount(label, weights=aa[sel]).argmax()]
    p, w = vertices[idx[keep]], aa[keep]
    centre = (p * w[:, None]).sum(axis=0) / w.sum()
    q = (p - centre) * np.sqrt(w)[:, None]
    eigval, eigvec = np.linalg.eigh(q.T @ q)
    normal = eigvec[:, 0] if eigvec[:, 0] @ mode > 0 else -eigvec[:, 0]
    return Facet(component, normal, float(normal @ centre), idx[keep], idx[keep[detected[keep]]], float(found),
                 float(np.sqrt(max(eigval[0], 0.0) / w.sum())))


def find_facets(vertices: np.ndarray, faces: np.ndarray, cap: float = 20.0, fit_cap: float = 40.0,
                share: float = 0.06, min_area: float = 12.0, smooth: int = 5, opposite: float = 0.5,
                closed_area: float = 8.0, peak: float = 1.5) -> list[Facet]:
    """Planar facets of every object of a closed or open surface (method: module docstring, step 1).

    Parameters
    ----------
    vertices : (n, 3) float64, nm
    faces : (m, 3) int
    cap, fit_cap : float, degrees
        Cone half-angle of the mode search and of the plane fit.
    share : float
        Smallest fraction of the object's area in a facet's ``cap`` cone.
    min_area : float, nm²
        Smallest area in that cone.
    smooth : int
        Umbrella passes over a copy of the vertices before their normals are taken.
    opposite : float
        Of an object with at least two facets, a mode opposite a facet (within ``cap``) needs only this
        fraction of ``share`` and ``min_area``: crystal facets come in {hkl} / {-h-k-l} pairs (the
        gamma-prime cuboids, any centrosymmetric habit), and a face that the start left rounder than its
        opposite one then still counts (a 6 nm cube's face held 8.7 nm² within 20° where its opposite
        held 16; gamma-prime seed 6).
    closed_area : float, nm²
        Of an object whose facets at ``min_area`` do not close it, modes down to this area count where they,
        with their opposites, close it (:func:`closes`): the faces of a small cube (5 nm: 7-15 nm² each on
        the `many` specimen, which kept its edges rounded at 12). A cylinder's strips of normals, which hold
        as much on a 1.5 nm rod, lie on one plane, and a 2.5-3 nm sphere's noisy cones held at most 7.8 nm²
        and at most three of them 7 nm² or more, so neither closes (measured: no facet moved on the
        `default` preset's seeds 0-4 or gamma-prime's 1-8 between 12 and 8).

    Returns
    -------
    list of Facet
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    adj = adjacency(faces, len(vertices))
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    smoothed = vertices
    for _ in range(smooth):
        smoothed = (adj @ smoothed) / deg[:, None]
    normals = vertex_normals(smoothed, faces)
    area = vertex_areas(vertices, faces)
    components = topology(faces, len(vertices)).vertex_components
    detect, fit = np.cos(np.radians(cap)), np.cos(np.radians(fit_cap))
    # open surfaces (interfaces that meet the specimen edge) are not polyhedra: only closed objects
    open_components = np.unique(components[TriMesh(vertices, faces).boundary_edges().ravel()])
    out = []
    for c in np.setdiff1d(np.unique(components[components >= 0]), open_components):
        idx = np.flatnonzero(components == c)
        nn, aa = normals[idx], area[idx]
        mine = _modes(nn, aa, detect, share, min_area, opposite)
        if not _normals_close(np.array([m[0] for m in mine])):
            small = _modes(nn, aa, detect, share, closed_area, opposite)
            if _normals_close(np.array([m[0] for m in small])):
                mine = small
            else:
                peaked = _peaks(nn, aa, detect, mine, peak)
                if _normals_close(np.array([m[0] for m in peaked])):
                    mine = peaked
        out += [_fit(vertices, adj, idx, nn, aa, fit_from, detected, mode, fit, int(c), found)
                for mode, detected, fit_from, found in mine]
    return out


def facet_steps(vertices: np.ndarray, faces: np.ndarray, facets: list[Facet], reach: float = 2.5,
                max_move: float = 1.5, min_cos: float = 0.2, span_tol: float = 0.25,
                flatten: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(n,) signed steps (nm, along the normals) onto the envelope of nearby facets' planes, and the normals.

    Method: module docstring, step 2. ``min_cos``: a plane counts for a vertex only if the vertex
    normal's cosine to it exceeds this (its ray meets the plane at a finite distance).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    normals = vertex_normals(vertices, faces)
    step = np.zeros(len(vertices))
    components = topology(faces, len(vertices)).vertex_components
    on_facet = np.zeros(len(vertices), dtype=bool)
    for f in facets:
        on_facet[f.core] = True
    if flatten > 0:
        for f in facets:
            k = normals[f.core] @ f.normal
            step[f.core] = flatten * (f.offset - vertices[f.core] @ f.normal) / np.maximum(k, 0.5)
    for c in sorted({f.component for f in facets}):
        mine = [f for f in facets if f.component == c]
        idx = np.flatnonzero((components == c) & ~on_facet)
        pair = [f for f in mine if f.side is not None]
        if len(pair) == 2 and len(idx):  # a slab's rims: onto its two planes and its side (:func:`slab_fit`)
            step[idx] = _slab_steps(vertices[idx], normals[idx], pair, min_cos, max_move)
            continue
        if len(mine) < 2 or not len(idx):
            continue
        near = np.stack([cKDTree(vertices[f.vertices]).query(vertices[idx])[0] < reach for f in mine], axis=1)
        plane_n = np.array([f.normal for f in mine])
        signed = vertices[idx] @ plane_n.T - np.array([f.offset for f in mine])
        cosine = normals[idx] @ plane_n.T
        use = near & (cosine > min_cos)
        rows = np.flatnonzero(use.sum(axis=1) >= 2)
        # each vertex's normal as a mix of its planes' normals: one solve per set of planes, for all its vertices
        # (the same numbers as one per vertex)
        spanned = np.zeros(len(rows), dtype=bool)  # its normal a non-negative mix of its planes' (to span_tol)
        patterns, which = np.unique(use[rows], axis=0, return_inverse=True)
        for g, u in enumerate(patterns):
            sel = np.flatnonzero(which.ravel() == g)
            planes = plane_n[u].T
            mixes = np.ascontiguousarray(np.linalg.lstsq(planes, normals[idx[rows[sel]]].T, rcond=None)[0].T)
            residual = np.linalg.norm(mixes @ planes.T - normals[idx[rows[sel]]], axis=1)
            spanned[sel] = ~((mixes.min(axis=1) < -0.1) | (residual > span_tol))
        rows = rows[spanned]
        u, s = use[rows], signed[rows]
        with np.errstate(divide="ignore", invalid="ignore"):  # the planes a vertex does not use are masked
            ray = -s / cosine[rows]
        first, last = np.where(u, ray, np.inf).min(axis=1), np.where(u, ray, -np.inf).max(axis=1)
        inside, outside = np.all(~u | (s <= 0), axis=1), np.all(~u | (s >= 0), axis=1)
        # convex rim: first plane the outward ray meets (a rounded object's: onto its fillets, below); concave
        # fillet: last plane the inward ray meets
        convex, concave = inside & (mine[0].rounding <= 0), ~inside & outside
        step[idx[rows[convex]]] = np.clip(first[convex], -max_move, max_move)
        step[idx[rows[concave]]] = np.clip(last[concave], -max_move, max_move)
        rounded = rows[inside] if mine[0].rounding > 0 else rows[:0]
        if len(rounded):
            rows = rounded
            step[idx[rows]] = _onto_fillet(np.where(use[rows], signed[rows], -np.inf), cosine[rows],
                                           mine[0].rounding, max_move)
    return step, normals


def _slab_steps(points: np.ndarray, normals: np.ndarray, pair: list[Facet], min_cos: float,
                max_move: float) -> np.ndarray:
    """(r,) steps (nm) along the unit ``normals`` (r, 3) that put ``points`` (r, 3) on the prism of a slab's two
    facets ``pair`` and their side (rounded by their radius, :func:`_onto_fillet`): where each point's ray first
    leaves it, from inside or outside, of the planes its normal meets at a cosine above ``min_cos`` (the side's at
    the point's angle about its axis); 0 where it meets none. A prism is convex across its rims, so its side and
    flats are reached along the normal from either side: the side's middle, which the refinement pushed out, comes
    in as its rims go out (:func:`slab_fit`)."""
    side, rounding = pair[0].side, pair[0].rounding
    distance, outward = side.distance(points)
    plane_n = np.array([f.normal for f in pair])
    signed = np.c_[points @ plane_n.T - np.array([f.offset for f in pair]), distance]
    cosine = np.c_[normals @ plane_n.T, np.einsum("ij,ij->i", normals, outward)]
    use = cosine > min_cos
    out = np.zeros(len(points))
    rows = np.flatnonzero(use.any(axis=1))
    if rounding > 0:
        out[rows] = _onto_fillet(np.where(use, signed, -np.inf)[rows], np.where(use, cosine, 0.0)[rows], rounding,
                                 max_move)
        return out
    with np.errstate(divide="ignore", invalid="ignore"):  # the planes a point does not use are masked
        first = np.where(use, -signed / cosine, np.inf).min(axis=1)
    out[rows] = np.clip(first[rows], -max_move, max_move)
    return out


def _onto_fillet(signed: np.ndarray, cosine: np.ndarray, rounding: float, max_move: float) -> np.ndarray:
    """(r,) steps (nm) along the normals that put points inside their planes (``signed`` (r, m) nm, -inf for a
    plane that does not count; ``cosine`` of each normal to each plane) on the polyhedron rounded by ``rounding``
    nm (:func:`rounded_distance` = 0), by bisection within ``max_move``: along an outward normal the rounded
    distance grows monotonically."""
    lo, hi = np.full(len(signed), -max_move), np.full(len(signed), max_move)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        outside = rounded_distance(signed + mid[:, None] * cosine, rounding) > 0
        hi = np.where(outside, mid, hi)
        lo = np.where(outside, lo, mid)
    return 0.5 * (lo + hi)


def rounded_distance(signed: np.ndarray, rounding: float) -> np.ndarray:
    """(b,) signed distance (nm) to a convex polyhedron whose edges and corners are rounded by ``rounding`` nm (its
    planes moved in by ``rounding``, grown by a ball of that radius), from the points' signed distances ``signed``
    (b, m) to the sharp polyhedron's planes. Outside the inner polyhedron the distance to it is the root sum of
    squares of the positive distances to its planes: exact where the planes that meet are at right angles."""
    inner = signed + rounding
    outside = np.sqrt(np.sum(np.maximum(inner, 0.0) ** 2, axis=1))
    return np.where(outside > 0, outside, inner.max(axis=1)) - rounding


@dataclass(frozen=True)
class FacetFrame:
    """One object's facets and what their planes alone fix of its edges and corners (:func:`facet_frames`),
    the same for every surface the facets finish.

    Attributes
    ----------
    component : int
    facets : list of Facet
        The object's facets (in the order given).
    corners : (q, 3) float64, nm
        The corners' targets, on the planes' rounded intersections: those of trios of facets whose normals are
        well apart and that lie inside every other plane.
    sharp : (q, 3) float64, nm
        The same corners before rounding (the planes moved in by the radius meeting): a corner is taken where
        this point lies within reach of its three facets' vertices.
    trios : (q, 3) int
        Each corner's facets (indices into ``facets``).
    lines : list of (int, int, (3,) float64, (3,) float64, float, float)
        Each edge: its pair of facets, a point (nm) of the rounded intersection line, the line's unit direction,
        and its stretch (nm along the direction from the point) inside every other plane.
    """

    component: int
    facets: list
    corners: np.ndarray
    sharp: np.ndarray
    trios: np.ndarray
    lines: list


def facet_frames(facets: list[Facet], slack: float = 0.1, edges: bool = True) -> list[FacetFrame]:
    """Each object's :class:`FacetFrame` (by component, in increasing order): the geometry of
    :func:`edge_and_corner_steps` that depends on the facets' planes alone, computed once for all the surfaces
    the same facets finish (``slack``, ``edges``: as there)."""
    frames = []
    for c in sorted({f.component for f in facets}):
        mine = [f for f in facets if f.component == c]
        normals = np.array([f.normal for f in mine])
        # a rounded object's edges and corners are those of its planes moved in by the radius, grown by a ball
        rounding = mine[0].rounding
        offsets = np.array([f.offset for f in mine]) - rounding
        corners, sharp, trios = [], [], []
        for trio in itertools.combinations(range(len(mine)), 3):
            n3 = normals[list(trio)]
            if abs(np.linalg.det(n3)) < 0.5:
                continue
            corner = np.linalg.solve(n3, offsets[list(trio)])
            if np.any(normals @ corner - offsets > slack):
                continue
            out = n3.sum(axis=0)
            corners.append(corner + rounding * out / np.linalg.norm(out))
            sharp.append(corner)
            trios.append(trio)
        lines = []
        for i, j in itertools.combinations(range(len(mine)), 2) if edges else ():
            direction = np.cross(normals[i], normals[j])
            if np.linalg.norm(direction) < np.sin(np.radians(30.0)):
                continue
            direction /= np.linalg.norm(direction)
            point = np.linalg.lstsq(normals[[i, j]], offsets[[i, j]], rcond=None)[0]
            # the line's stretch inside every other plane
            rate, room = normals @ direction, offsets + slack - normals @ point
            others = np.setdiff1d(np.arange(len(mine)), [i, j])
            lo = max([room[k] / rate[k] for k in others if rate[k] < -1e-9], default=-np.inf)
            hi = min([room[k] / rate[k] for k in others if rate[k] > 1e-9], default=np.inf)
            outside = any(room[k] < 0 for k in others if abs(rate[k]) <= 1e-9)
            if outside or not np.isfinite(lo) or not np.isfinite(hi):
                continue
            out = normals[i] + normals[j]
            lines.append((i, j, point + rounding * out / np.linalg.norm(out), direction, lo, hi))
        frames.append(FacetFrame(c, mine, np.array(corners).reshape(-1, 3), np.array(sharp).reshape(-1, 3),
                                 np.array(trios, dtype=np.int64).reshape(-1, 3), lines))
    return frames


def edge_and_corner_steps(vertices: np.ndarray, faces: np.ndarray, facets: list[Facet], reach: float = 2.5,
                          max_move: float = 1.5, slack: float = 0.1, edges: bool = True,
                          frames: list[FacetFrame] | None = None) -> np.ndarray:
    """(n, 3) moves that put one vertex on each convex corner of an object's facets and a row of vertices along
    each of its edges (module docstring, step 3).

    A corner is the intersection of three facets of one object whose normals are well apart (determinant
    > 0.5), within ``reach`` nm of each facet's fitted vertices and inside every other facet's plane (to
    ``slack`` nm); the vertex of that object nearest to it moves onto it if it is within ``max_move`` nm.
    With ``edges``, an edge is the stretch of two facets' intersection line (normals more than 30° apart)
    inside every other facet's plane; points along it one mean mesh edge apart, within ``reach`` of both
    facets' vertices, each take the nearest vertex not yet taken if it is within ``max_move / 2`` (a
    shorter reach than a corner's: an edge's rim is rounded less deeply than a corner's).

    ``frames``: :func:`facet_frames` of ``facets`` (with the same ``slack`` and ``edges``), where the caller
    finishes several surfaces with the same facets; taken from ``facets`` if not given.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    components = topology(faces, len(vertices)).vertex_components
    moves = np.zeros_like(vertices)
    taken = np.zeros(len(vertices), dtype=bool)
    # faces around each vertex (CSR: those of v are order[start[v]:start[v + 1]])
    order = np.argsort(faces.ravel(), kind="stable") // 3
    start = np.searchsorted(np.sort(faces.ravel()), np.arange(len(vertices) + 1))
    edge = vertices[faces[:, 1]] - vertices[faces[:, 0]]
    spacing = float(np.mean(np.linalg.norm(edge, axis=1))) if len(faces) else 1.0
    for frame in facet_frames(facets, slack, edges) if frames is None else frames:
        # the candidate points (the corners, then each edge's row), where each is tested for reach (a corner
        # before its rounding, a row's points as they are) and the facets each must be within reach of
        points, probes, owners = [frame.corners], [frame.sharp], [frame.trios]
        for i, j, point, direction, lo, hi in frame.lines:
            if hi - lo < 2 * spacing:
                continue
            points.append(point + np.arange(lo + spacing, hi - 0.5 * spacing, spacing)[:, None] * direction)
            probes.append(points[-1])
            owners.append(np.broadcast_to([i, i, j], (len(points[-1]), 3)))  # (a corner's three columns)
        for k, f in enumerate(frame.facets):  # a slab's rims: the side's curve on each of its two planes
            if f.side is not None:
                points.append(_rim_row(f, spacing))
                probes.append(points[-1])
                owners.append(np.full((len(points[-1]), 3), k))
        points, probes, owners = np.concatenate(points), np.concatenate(probes), np.concatenate(owners)
        # one KD-tree query per facet, of all the points that must be near it (the same distances as point by point)
        near_all = np.ones(len(points), dtype=bool)
        for k, f in enumerate(frame.facets):
            sel = np.flatnonzero((owners == k).any(axis=1))
            if len(sel):
                near_all[sel] &= cKDTree(vertices[f.vertices]).query(probes[sel])[0] <= reach
        if not near_all.any():
            continue
        n_corners = int(np.count_nonzero(near_all[:len(frame.corners)]))
        targets = points[near_all]
        idx = np.flatnonzero(components == frame.component)
        near = idx[cKDTree(vertices[idx]).query(targets, k=min(8, len(idx)))[1].reshape(len(targets), -1)]
        limit = np.where(np.arange(len(targets)) < n_corners, max_move, 0.5 * max_move)
        _take_nearest(targets, near, limit, vertices, faces, order, start, taken, moves)
    return moves


def _rim_row(facet: Facet, spacing: float) -> np.ndarray:
    """(p, 3) points (nm) ``spacing`` nm apart along the rim where a slab's ``facet`` meets its side
    (:func:`slab_fit`), on the middle of its fillet where the rims are rounded (the facet's plane and the side moved
    in by the radius, the point moved out by it along their normals' mean)."""
    side, rounding = facet.side, facet.rounding
    k = len(side.radii)
    count = max(int(round(2 * np.pi * side.radii.mean() / spacing)), k)
    phi = 2 * np.pi * (np.arange(count) + 0.5) / count
    radius = np.interp(phi, 2 * np.pi * np.arange(k) / k, side.radii, period=2 * np.pi) - rounding
    radial = np.cos(phi)[:, None] * side.e1 + np.sin(phi)[:, None] * side.e2
    base = side.centre + radius[:, None] * radial
    height = (facet.offset - rounding - base @ facet.normal) / (facet.normal @ side.axis)
    out = radial + facet.normal
    return base + height[:, None] * side.axis + rounding * out / np.linalg.norm(out, axis=1, keepdims=True)


@njit(cache=True, nogil=True)
def _take_nearest(targets, near, limit, vertices, faces, order, start, taken, moves):
    """For each of ``targets`` (t, 3) in turn, of its candidates ``near`` (t, k) the nearest vertex not yet
    ``taken`` moves onto it (``moves``, ``taken`` updated) if it is within ``limit`` (t,) nm
    (:func:`edge_and_corner_steps`)."""
    for k in range(targets.shape[0]):
        best, nearest = np.inf, -1
        for c in range(near.shape[1]):
            v = near[k, c]
            if taken[v]:
                continue
            # not a vertex whose triangle would then have all three corners on the line (zero area: the
            # pseudo-normals that sign ion distances need every face to have one)
            flat = False
            for e in range(start[v], start[v + 1]):
                f = order[e]
                if int(taken[faces[f, 0]]) + int(taken[faces[f, 1]]) + int(taken[faces[f, 2]]) == 2:
                    flat = True
            if flat:
                continue
            d = math.sqrt((vertices[v, 0] - targets[k, 0]) ** 2 + (vertices[v, 1] - targets[k, 1]) ** 2
                          + (vertices[v, 2] - targets[k, 2]) ** 2)
            if d < best:
                best, nearest = d, v
        if nearest >= 0 and best < limit[k]:
            for a in range(3):
                moves[nearest, a] = targets[k, a] - vertices[nearest, a]
            taken[nearest] = True


def judged(found: list[Facet], halves: list[list[Facet]], cap: float = 20.0) -> list[Facet]:
    """The facets of ``found`` as the held-out test judged them: of an object they close (:func:`closes`) where
    no half's facets (``halves``, each half of the ions' own) closed it, only those with a counterpart on a
    half (a facet of the same object whose normal lies within ``cap`` degrees, :func:`find_facets`' cone).

    The held-out test of :func:`~apt_filters.refine.crossval.cross_validated_modes` judges each half's own
    facets. Facets that close an object have their planes refitted to its ions as a polyhedron
    (:func:`fit_to_ions`); where no half closed it, that model was never judged, and the facets that
    closed it are ones no half found (held-out plate 10024: four rim "facets" of 5-12 vertices on a disc's
    curved side closed it, and its rim moved out to the corners of their square, +11.8 % in volume where
    the two faces the halves found give +0.2 %). A small cube one half closed keeps what the whole found.
    """
    cosine = np.cos(np.radians(cap))
    out = []
    for c in sorted({f.component for f in found}):
        mine = [f for f in found if f.component == c]
        theirs = [[h for h in half if h.component == c] for half in halves]
        if closes(mine) and not any(len(t) and closes(t) for t in theirs):
            mine = [f for f in mine if any(float(h.normal @ f.normal) > cosine for t in theirs for h in t)]
        out += mine
    return out


def missed(found: list[Facet], halves: list[list[Facet]], cap: float = 20.0) -> dict[int, list[Facet]]:
    """Per object whose facets ``found`` close it (:func:`closes`): the facets of the halves that close it too
    (``halves``, each half of the ions' own) with no counterpart among ``found`` (none within ``cap`` degrees), in
    turn: the faces the whole's search may have missed (:func:`~apt_filters.refine.surface.refine_surface` adds
    them only where the whole's planes fail the ions' fit, :func:`fit_to_ions`).

    Held-out artefact 10004's 4 x 5 x 4 nm cuboid: the whole's search missed its -x face, and its five facets
    closed it only because the neighbouring faces' planes, fitted to vertices, tilted toward the gap by up to
    38°; its corners stood 1.3 nm out. One half had found all six.
    """
    cosine = np.cos(np.radians(cap))
    out = {}
    for c in sorted({f.component for f in found}):
        mine = [f for f in found if f.component == c]
        if not closes(mine):
            continue
        extra: list[Facet] = []
        for t in ([h for h in half if h.component == c] for half in halves):
            if len(t) and closes(t):
                extra += [h for h in t if not any(float(h.normal @ f.normal) > cosine for f in mine + extra)]
        if extra:
            out[c] = extra
    return out


def closes(facets: list[Facet], margin: float = 0.25) -> bool:
    """Whether the facets' half-spaces bound a polyhedron: the hull of their unit normals holds the origin at
    least ``margin`` inside (a cube's at 0.58, a regular tetrahedron's at 0.33).

    Only then does every ion near the object lie near one of its planes: a cube with a face not found as a
    facet has its other five normals' hull pass through (within a few degrees of tilt, near) the origin,
    and its ions past the missing face would pull the neighbouring planes.
    """
    return _normals_close(np.array([f.normal for f in facets]), margin)


def unclosed_margin(planes: int, one: float) -> float:
    """Standard errors by which facets of ``planes`` planes that do not close their object (:func:`closes`) must
    beat the smooth surface on held-out ions (:func:`~apt_filters.refine.crossval.cross_validated_modes`): the
    one-sided rate of ``one`` standard error (the cross-validation's one-standard-error rule,
    :data:`~apt_filters.refine.crossval.ONE_SE`; 16 %) held over the planes by Bonferroni, ``ndtri(1 - Phi(-one) /
    planes)``: ``one`` for a single plane, 1.41 for a plate's two faces, 2.06 for eight. Each plane is a direction
    the search picked from every vertex normal's cone, so a smooth object offers more chances to fit its noise the
    more planes it is cut into: a 1.8 nm capsule's rough surface (development rod 10039's second rod) crowded its
    normals into 8 strips round its axis (5-6 on each half), and the held-out ions preferred the halves' prisms
    to the smooth surface by 1.85 and 1.21 SE, past the one standard error that kept them (volume -9 points, area
    +3 to +8). The speck test's rate (:data:`~apt_filters.refine.specks.ALPHA`) would ask 3.29 SE of two planes,
    more than true plates' two faces gain (2.7-3.7 SE: development plates 10038 and dev plate 2)."""
    return float(ndtri(1.0 - ndtr(-one) / max(planes, 1)))


def _normals_close(normals: np.ndarray, margin: float = 0.25) -> bool:
    """Whether the hull of unit ``normals`` (k, 3) holds the origin at least ``margin`` inside (:func:`closes`)."""
    if len(normals) < 4:
        return False
    try:
        hull = ConvexHull(normals)
    except QhullError:  # normals on one plane
        return False
    return bool(np.all(hull.equations[:, 3] < -margin))


def fit_to_ions(facets: list[Facet], positions: np.ndarray, u: np.ndarray, weight: np.ndarray, width: float,
                pairs: bool = True, cap: float = 20.0, iterations: int = 10, max_step: float = 0.2,
                tolerance: float = 1e-5, min_ions: int = 200) -> list[Facet]:
    """The planes of one closed polyhedral object refitted jointly to its ions (module docstring, step 1b).

    The model of an ion's normalised score at ``x`` is the intersection of the blurred half-spaces,
    ``u(x) = prod_k Phi(-s_k(x) / width)`` with ``s_k = n_k . x - d_k`` and ``Phi`` the normal CDF: each
    face an error-function step, and an edge or corner the product of its faces' steps, which is what a
    Gaussian blur makes of a sharp convex wedge where it is sharper than the blur. Every plane's tilt (two
    angles) and offset are fitted by Gauss-Newton on the atoms-weighted squared residuals, from the planes
    fitted to the vertices (:func:`find_facets`).

    Parameters
    ----------
    facets : list of Facet
        The facets of one object; they should close it (:func:`closes`).
    positions : (b, 3) float64, nm
        Ions near the object.
    u : (b,) float64
        Their normalised scores (0 on the outside plateau, 1 inside).
    weight : (b,) float64
        Atoms per ion.
    width : float, nm
        Sigma of the object's profile.
    pairs : bool
        Two facets whose normals are opposite to within ``cap`` degrees share one normal (each keeps its
        offset): crystal facets come in parallel {hkl} / {-h-k-l} pairs (see ``opposite`` of
        :func:`find_facets`).
    iterations, max_step, tolerance
        At most ``iterations`` Gauss-Newton steps, each parameter clamped to ``max_step`` (radians of
        tilt, nm of offset) per step; stop when no parameter moves more than ``tolerance``.
    min_ions : int
        Fewest ions per plane to fit at all.

    Returns
    -------
    list of Facet
        The facets with their normals and offsets refitted and the radius of the object's rounded edges
        where its ions show one (:func:`edge_rounding`; vertex sets unchanged; ``rms`` as fitted to the
        vertices); the facets as given if there are too few ions, or if the fit has found something
        else: a plane turned by more than twice ``cap`` from its start, or planes that no longer close
        (:func:`closes`), unless leaving out planes the ions do not support (:func:`_unsupported`) makes the
        fit of the rest hold: then the rest, refitted (fewer facets than given). A plane may turn further than
        ``cap``: the narrow faces of a thin lath, found where the normals crowd on the ridge from one broad face
        to the other, start 15-25° off theirs and turned by 17-30° (held-out `lath` seed 10007).
    """
    m = len(facets)
    if len(positions) < min_ions * m:
        return list(facets)
    centre = positions.mean(axis=0)
    q = positions - centre
    kept = tuple(range(m))
    fits = {kept: _joint_fit(facets, centre, q, u, weight, width, pairs, cap, iterations, max_step, tolerance)}
    # the fit has found something else where a plane has turned out of twice the cone its facet was found in,
    # or the planes no longer bound a polyhedron. Where a plane the ions do not support caused it (a half of a
    # 4 nm cube: a 1.7 nm² patch at a corner, 52° from every true face, turned by 47°), the fit is tried again
    # without it: of the planes whose removal leaves the rest closed and the misfit no worse than the information
    # criterion allows (:func:`_unsupported`), the one whose removal leaves a fit that holds, at the least misfit
    while not _holds(facets, kept, fits[kept][0], cap):
        left = [kept[:i] + kept[i + 1:] for i in range(len(kept))]
        left = [k for k in left if closes([facets[i] for i in k])]
        for k in left:
            fits.setdefault(k, _joint_fit([facets[i] for i in k], centre, q, u, weight, width, pairs, cap, iterations,
                                          max_step, tolerance))
        left = [k for k in left if _unsupported(fits[kept], fits[k], len(u))]
        if not left:
            return list(facets)
        kept = min(left, key=lambda k: (not _holds(facets, k, fits[k][0], cap), fits[k][2]))
    normals, params, _, _ = fits[kept]
    facets = [facets[i] for i in kept]
    m = len(facets)
    # one face fitted twice (a face a half found and the whole found tilted, :func:`missed`): the outer plane
    # bounds nothing the inner one does not, and its vertices are the inner face's
    same = np.cos(np.radians(cap))
    face = [k for k in range(m) if not any(normals[k] @ normals[j] > same and
                                           (params[j, 2], j) < (params[k, 2], k) for j in range(m) if j != k)]
    normals, params = normals[face], params[face]
    shift, rounding = edge_rounding(q @ normals.T - params[:, 2], u, weight, width)
    return [Facet(facets[k].component, normals[i], float(normals[i] @ centre + params[i, 2] + shift[i]),
                  facets[k].vertices, facets[k].core, facets[k].area, facets[k].rms, rounding, fitted=True)
            for i, k in enumerate(face)]


def _joint_fit(facets: list[Facet], centre: np.ndarray, q: np.ndarray, u: np.ndarray, weight: np.ndarray,
               width: float, pairs: bool, cap: float, iterations: int, max_step: float, tolerance: float) -> tuple:
    """:func:`fit_to_ions`' Gauss-Newton fit of the planes of ``facets`` to the ions at ``q`` (b, 3; nm from their
    mean ``centre``): the planes' unit normals (m, 3), their parameters (m, 3: tilts along two tangents, radians;
    offset from the centre, nm), the atoms-weighted sum of squared residuals there, and the number of free
    parameters (two tilts per plane, one pair's shared, and one offset per plane)."""
    m = len(facets)
    n0 = np.array([f.normal for f in facets])
    # each plane's point nearest the centre: its offset stays put when its normal is averaged with a partner's
    anchor = centre + (np.array([f.offset for f in facets]) - n0 @ centre)[:, None] * n0
    # tie[k] = (j, sign): plane k's tilts are sign times those of plane j
    tie = [(k, 1.0) for k in range(m)]
    if pairs:
        for i, j in itertools.combinations(range(m), 2):
            if tie[i][0] == i and tie[j][0] == j and n0[i] @ -n0[j] > np.cos(np.radians(cap)):
                n0[i] = (n0[i] - n0[j]) / np.linalg.norm(n0[i] - n0[j])
                n0[j] = -n0[i]
                tie[j] = (i, -1.0)
    # two tangent directions per plane to tilt it along (a pair's: the same two)
    e1 = np.cross(n0, np.where(np.abs(n0[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e1[[k for k in range(m) if tie[k][0] != k]] = e1[[tie[k][0] for k in range(m) if tie[k][0] != k]]
    e2 = np.cross(n0, e1)
    e2[[k for k in range(m) if tie[k][0] != k]] *= -1.0
    # free parameters -> per-plane (tilt along e1, tilt along e2, offset from the centre)
    own = [k for k in range(m) if tie[k][0] == k]
    spread = np.zeros((3 * m, 2 * len(own) + m))
    for k, (j, sign) in enumerate(tie):
        spread[3 * k, 2 * own.index(j)] = spread[3 * k + 1, 2 * own.index(j) + 1] = sign
        spread[3 * k + 2, 2 * len(own) + k] = 1.0
    # d s_k = tilt_1 da + tilt_2 db - dd to first order in the tilts: the levers (b, m, 3) do not change with the fit
    lever = np.stack([q @ e1.T, q @ e2.T, np.full((len(q), m), -1.0)], axis=2)
    params = np.zeros((m, 3))
    params[:, 2] = np.einsum("ij,ij->i", n0, anchor - centre)

    def planes(p: np.ndarray) -> np.ndarray:
        n = n0 + p[:, :1] * e1 + p[:, 1:2] * e2
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def steps(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        z = (q @ planes(p).T - p[:, 2]) / (np.sqrt(2) * width)
        step = np.clip(0.5 * erfc(z), 1e-12, None)
        return z, step, step.prod(axis=1)

    for _ in range(iterations):
        z, step, model = steps(params)
        slope = model[:, None] / step * -np.exp(-z ** 2) / (np.sqrt(2 * np.pi) * width)  # d model / d s_k
        jac = (slope[:, :, None] * lever).reshape(len(q), 3 * m)
        free = _least_squares(jac @ spread, u - model, weight)
        delta = (spread @ np.clip(free, -max_step, max_step)).reshape(m, 3)
        params += delta
        if np.abs(free).max() < tolerance:
            break
    return planes(params), params, float(weight @ (u - steps(params)[2]) ** 2), spread.shape[1]


def _holds(facets: list[Facet], kept: tuple, normals: np.ndarray, cap: float) -> bool:
    """Whether the planes fitted from the facets ``kept`` (their indices) are what those facets were: none turned
    out of twice the cone its facet was found in (``cap`` degrees), and together they still bound a polyhedron."""
    turned = np.einsum("ij,ij->i", normals, [facets[k].normal for k in kept]) < np.cos(2 * np.radians(cap))
    return not turned.any() and _normals_close(normals)


def _unsupported(more: tuple, fewer: tuple, ions: int) -> bool:
    """Whether the ions do not support the plane(s) by which fit ``more`` exceeds fit ``fewer`` (each a
    :func:`_joint_fit`): by the Bayesian information criterion, as :func:`edge_rounding` keeps its share, the
    misfit without them rises by less than ``log(ions)`` times their free parameters, in units of the residuals'
    variance per unit weight (from ``more``'s fit)."""
    variance = more[2] / max(ions - more[3], 1)
    return bool((fewer[2] - more[2]) / variance < (more[3] - fewer[3]) * np.log(ions))


def slab_pair(facets: list[Facet], vertices: np.ndarray, normals: np.ndarray, cap: float = 20.0,
              steep: float = 0.5) -> tuple[Facet, Facet] | None:
    """Of one object's facets, the two opposite ones (normals opposite to within ``cap`` degrees) of the largest
    area: a slab's faces (a plate's two flats), whose side is not a facet; None where there are none, or where the
    facets close the object as a polyhedron (:func:`fit_to_ions`).

    Facets that close the object are a slab's all the same where the object is thin (the pair's planes closer than
    its side's median distance from their axis, as a plate's 2-3 nm to its 4-7 nm radius; a cuboid's, however
    rounded, are not) and its side does not crowd at the other facets' directions round the axis
    (:func:`_round_side`: the object's vertices ``vertices`` (n, 3), unit ``normals`` (n, 3); a lath's four sides
    do). A disc's side and rims, radial all round and rounded by the refinement, offer their noise a strip in every
    direction: four strips of 2-7 nm² (on the side, or 24-36° up its rounded rims) closed the discs of dev plates
    31003 (R 5.0 / 5.9 nm) and 31009 (R 4.1 nm) on a half, whose prisms, square where the discs are round, the
    held-out ions refused (-2.5 / -7.8 / -4.3 SE), so the plates kept the rims the refinement rounded (A -6.3 /
    -6.3 / -13.5 %)."""
    pairs = [(a, b) for a, b in itertools.combinations(facets, 2) if a.normal @ -b.normal > np.cos(np.radians(cap))]
    pair = max(pairs, key=lambda ab: ab[0].area + ab[1].area, default=None)
    if pair is None or not closes(facets):
        return pair
    axis = pair[0].normal - pair[1].normal
    axis /= np.linalg.norm(axis)
    strips = np.array([f.normal for f in facets if f is not pair[0] and f is not pair[1]])
    side = np.abs(normals @ axis) < steep
    centre = vertices[side].mean(axis=0)
    radial = vertices[side] - centre
    radial -= np.outer(radial @ axis, axis)
    thickness = sum(f.offset - f.normal @ centre for f in pair)  # the planes' distances from the centre
    if thickness > np.median(np.linalg.norm(radial, axis=1)):  # thick: a polyhedron
        return None
    return pair if _round_side(axis, strips, normals[side], cap / 2) else None


def _round_side(axis: np.ndarray, strips: np.ndarray, side: np.ndarray, within: float) -> bool:
    """Whether a slab's side (the unit normals ``side`` (m, 3) of its vertices off its faces) is round about
    ``axis`` (3,) rather than the prism of its other facets (unit normals ``strips`` (k, 3)): its share of vertices
    whose normal's direction round the axis lies within ``within`` degrees of a strip's is under twice a round
    side's, ``k 2 within / 360``. A prism's side normals crowd at its faces' (a lath's four sides hold most of its
    side), a disc's are spread evenly (its strips' cones hold their angular share)."""
    def around(n: np.ndarray) -> np.ndarray:  # directions in the midplane
        n = n - np.outer(n @ axis, axis)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)

    crowded = (around(side) @ around(strips).T).max(axis=1) > np.cos(np.radians(within))
    return bool(np.mean(crowded) < 2 * len(strips) * 2 * within / 360)


def slab_side(pair: tuple[Facet, Facet], vertices: np.ndarray, normals: np.ndarray, spacing: float = 0.5,
              band: float = 0.25, steep: float = 0.5) -> Side | None:
    """The side of a slab (:func:`slab_pair`) as the surface ``vertices`` (n, 3) of its object (unit ``normals``
    (n, 3)) shows it at mid-height: its equator, the vertices within ``band`` of the thickness of the midplane whose
    normals are within ``asin(steep)`` of it (30°), in polar form about their centre in bins of ``spacing`` nm of arc,
    each bin their mean radius, smoothed by (1, 2, 1) / 4 around the curve. None where more than a quarter of the bins
    are empty (no side goes round the object) or fewer than 8 would hold it."""
    top, bottom = pair
    axis = top.normal - bottom.normal
    axis /= np.linalg.norm(axis)
    high, low = top.offset / (top.normal @ axis), -bottom.offset / (-bottom.normal @ axis)
    height = vertices @ axis
    mid = 0.5 * (high + low)
    equator = (np.abs(height - mid) < band * (high - low)) & (np.abs(normals @ axis) < steep)
    if equator.sum() < 8:
        return None
    centre = vertices[equator].mean(axis=0)
    centre += (mid - centre @ axis) * axis
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    q = vertices[equator] - centre
    rho, phi = np.hypot(q @ e1, q @ e2), np.mod(np.arctan2(q @ e2, q @ e1), 2 * np.pi)
    k = int(round(2 * np.pi * np.median(rho) / spacing))
    if k < 8:
        return None
    which = np.minimum((phi / (2 * np.pi) * k).astype(np.int64), k - 1)
    count = np.bincount(which, minlength=k)
    if np.count_nonzero(count == 0) > k / 4:
        return None
    # each bin's mean radius at its centre angle; empty bins interpolated around the curve
    mean = np.bincount(which, weights=rho, minlength=k) / np.maximum(count, 1)
    angle = (np.arange(k) + 0.5) * 2 * np.pi / k
    held = count > 0
    mean = np.interp(angle, angle[held], mean[held], period=2 * np.pi)
    smooth = 0.25 * np.roll(mean, 1) + 0.5 * mean + 0.25 * np.roll(mean, -1)
    # radii at the angles 2 pi j / k (the bins' edges), between the bins' centres
    return Side(centre, axis, e1, e2, 0.5 * (smooth + np.roll(smooth, 1)))


def slab_fit(pair: tuple[Facet, Facet], side: Side, positions: np.ndarray, u: np.ndarray, weight: np.ndarray,
             width: float, iterations: int = 10, max_step: float = 0.2, tolerance: float = 1e-5) -> tuple[Side, float]:
    """A slab's side placed by its ions, and the radius of its rims: the ions' scores fitted by the interface's
    profile about the prism of its two facets and the side (:func:`edge_rounding`, three planes: the side's
    distance taken at each ion), the side moved by its shift less the mean of the two facets' shifts.

    The side is where the equator of the refined surface stands (:func:`slab_side`), and that stands out: the
    refinement pools each vertex's profile over ~2 nm and smooths its moves, so it rounds a plate's rims, and its
    equal-area rule then pushes the short side between them out (dev plate 10038: rims 0.14-0.18 nm in, the side's
    middle 0.11-0.17 nm out). The facets' planes, fitted to vertices of wide flats, stand where the truth does
    (0.002-0.008 nm), while every plane fitted to a thin object's ions moves with the inside level it is scored by
    (a 2.6 nm lath's by +0.08 nm read at 0.9 of the contrast); so the side is placed against the facets, by the
    difference of the shifts, and the level's common part cancels.

    Parameters
    ----------
    pair : (Facet, Facet)
        The slab's two facets.
    side : Side
    positions : (b, 3) float64, nm
        The object's ions.
    u, weight : (b,) float64
        Their normalised scores and atoms.
    width : float, nm
        Sigma of the object's profile.
    iterations, max_step, tolerance
        Of the sharp prism's Gauss-Newton fit, as :func:`fit_to_ions`'s (nm of offset).

    Returns
    -------
    Side, float
        The side moved, and the rims' radius (nm; 0 where the ions show none).
    """
    top, bottom = pair
    signed = np.stack([positions @ top.normal - top.offset, positions @ bottom.normal - bottom.offset,
                       side.distance(positions)[0]], axis=1)
    # first the blurred sharp prism (the product of the three steps), as the planes of a polyhedron are fitted
    # (:func:`fit_to_ions`), its offsets alone: the side's curve and the facets' tilts are the surface's
    moved = np.zeros(3)
    for _ in range(iterations):
        z = (signed - moved) / (np.sqrt(2) * width)
        step = np.clip(0.5 * erfc(z), 1e-12, None)
        model = step.prod(axis=1)
        jac = model[:, None] / step * np.exp(-z ** 2) / (np.sqrt(2 * np.pi) * width)  # d model / d offset
        delta = np.clip(_least_squares(jac, u - model, weight), -max_step, max_step)
        moved += delta
        if np.abs(delta).max() < tolerance:
            break
    shift, rounding = edge_rounding(signed - moved, u, weight, width)
    shift = moved + shift
    return side.moved(float(shift[2] - 0.5 * (shift[0] + shift[1]))), rounding


def _least_squares(jac: np.ndarray, residual: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(k,) the Gauss-Newton step: the weighted least-squares solution of ``jac`` (b, k) ``x = residual`` (b,), weights
    ``weight`` (b,), from the normal equations (k x k; the minimum-norm solution where they are singular). The
    same step as a least-squares solve of the (b, k) system, at a fifth of its cost (60,000 x 8: 6 ms against 31,
    the SVD's); the fits' Jacobians are well conditioned (k <= 3 per plane, their columns of one scale)."""
    weighted = jac * weight[:, None]
    return np.linalg.lstsq(weighted.T @ jac, weighted.T @ residual, rcond=None)[0]


def rounded_scores(signed: np.ndarray, rounding: float, width: float, share: float = 1.0,
                   nodes: int = 8) -> np.ndarray:
    """(b,) a convex polyhedron's profile at points whose signed distances to its planes are ``signed`` (b, m, nm),
    its edges rounded by ``rounding`` nm, the profile's sigma ``width`` nm: an interface profile in the signed
    distance to the polyhedron, blurred by a Gaussian that holds ``share`` of the profile's variance.

    The profile is that of the refinement (:mod:`apt_filters.refine.surface`): an error function of the signed
    distance ``D`` to the surface, of sigma ``a = width sqrt(1 - share)``, blurred by the reconstruction, a Gaussian
    of sigma ``b = width sqrt(share)``. Across a plane that is one error function of sigma ``width``; around a convex
    edge the two differ. The interface's part is round outside an edge (``D`` is the distance to it) and puts half
    the contrast on the edge; a blurred sharp wedge puts a quarter there. ``Phi(-D / a)`` is the mixture over ``t ~
    N(0, a^2)`` of the indicators of the polyhedra parallel at ``t`` (planes moved out by ``t``, edges rounded by
    ``max(rounding + t, 0)``), so where the blur is not much the narrower (``b >= 0.7 a``) the profile is their
    blurred indicators mixed by Gauss-Hermite quadrature over ``t`` (8 nodes); elsewhere ``Phi(-D / a)``
    blurred in the edge's plane (5 x 5 Gauss-Hermite nodes; ``D`` exact for a right-angled edge). Each blurred
    indicator: each point's two nearest planes (the largest distances, ``s_1 >=
    s_2``) make its edge, taken as a right-angled one; the edge's rounded quadrant, in the coordinates ``(s_1,
    s_2)`` about the sharp edge, holds ``x <= X(t)`` at ``s_2 = t``: ``X = 0`` for ``t <= -r``, ``X = -r + sqrt(r^2
    - (t + r)^2)`` on the arc, none for ``t > 0``. Blurred, ``Phi(-s_1 / b) Phi(-(r + s_2) / b)`` plus the arc's
    integral ``int phi_b(t - s_2) Phi((X(t) - s_1) / b) dt`` (Gauss-Legendre over the arc's angle, ``nodes``
    points). Every other plane adds its own step, ``Phi(-s_k / b)`` (:func:`_others_width`: the interface's offset
    is one draw for all the planes, so only the blur takes more off for them; exact away from corners). With
    ``share = 1`` and ``rounding = 0`` this is the product of the planes' steps, exact for a right-angled sharp edge
    under an isotropic Gaussian blur; with ``share = 0``, ``Phi(-D / width)`` inside the other planes.
    """
    order = np.sort(signed, axis=1)
    return _edge_scores(order, rounding, width, share, nodes) * _other_steps(order, _others_width(width, share))


INTERFACE_NODES = 8
"""Gauss-Hermite nodes over the interface's parallel polyhedra where the blur is not much narrower than the interface
(:func:`rounded_scores`)."""
BLUR_NODES = 5
"""Gauss-Hermite nodes per axis over the blur in an edge's plane where it is much narrower than the interface."""
SWITCH = 0.7
"""Blur over interface sigma from which the profile is mixed over the parallel polyhedra: each way's largest error
against 40 / 16 nodes stays under 0.003 (under 0.011 with the switch at 1)."""


def _edge_scores(order: np.ndarray, rounding: float, width: float, share: float = 1.0,
                 nodes: int = 8) -> np.ndarray:
    """(b,) the rounded edge's part of :func:`rounded_scores` from each point's two largest signed distances
    (``order`` (b, m) nm, sorted along each row)."""
    # the columns copied contiguous: strided ones would compile the kernels a second time (1.4 s in a fresh process)
    second = np.ascontiguousarray(order[:, -2]) if order.shape[1] > 1 else np.full(len(order), -np.inf)
    return _edge_part(np.ascontiguousarray(order[:, -1]), second, rounding, width, share, nodes)


def _edge_part(s1: np.ndarray, s2: np.ndarray, rounding: float, width: float, share: float = 1.0,
               nodes: int = 8, slopes: bool = False):
    """:func:`_edge_scores` from each point's largest and second largest signed distances ``s1``, ``s2`` (b,) nm
    (-inf for a single plane); with ``slopes``, also its (b, 5) derivatives in ``s1``, ``s2``, the radius, the
    interface's sigma ``a = width sqrt(1 - share)`` and the blur's ``b = width sqrt(share)`` (nm / nm), computed in
    the same compiled passes as the values (the same numbers as without)."""
    interface = width * np.sqrt(max(1.0 - share, 0.0))
    blur = width * np.sqrt(max(share, 0.0))
    if interface <= 0.0:  # the blurred indicator of the edge: the mixture's one polyhedron, at t = 0
        out, grad = _parallel_mixture(s1, s2, rounding, 0.0, blur, _ZERO, _ONE, *_legendre(nodes), slopes)
        return (out, grad) if slopes else out
    # far from the edge every parallel polyhedron's edge factor is 1 and the mixture is one step of sigma ``width``
    out = 0.5 * erfc(s1 / (np.sqrt(2) * width))
    near = np.flatnonzero(s2 + rounding > -5.0 * width)
    if blur >= SWITCH * interface:  # the blurred indicators mixed over the parallel polyhedra: smooth on blur's scale
        out[near], part = _parallel_mixture(s1[near], s2[near], rounding, interface, blur, *_hermite(INTERFACE_NODES),
                                            *_legendre(nodes), slopes)
    else:  # the interface's profile blurred in the edge's plane: smooth on the scale of the interface
        out[near], part = _blurred_profile(s1[near], s2[near], rounding, interface, blur, *_hermite(BLUR_NODES),
                                           slopes)
    if not slopes:
        return out
    # the far step Phi(-s1 / w), w^2 = a^2 + b^2: d/ds1 = -phi, d/da = phi s1 a / w^2, d/db = phi s1 b / w^2
    density = np.exp(-0.5 * (s1 / width) ** 2) / (np.sqrt(2 * np.pi) * width)
    grad = np.zeros((len(s1), 5))
    grad[:, 0] = -density
    grad[:, 3] = density * s1 * interface / width ** 2
    grad[:, 4] = density * s1 * blur / width ** 2
    grad[near] = part
    return out, grad


_ZERO, _ONE = np.zeros(1), np.ones(1)
"""The one node and weight of the blurred indicator of one polyhedron (no interface) as a mixture."""


@njit(cache=True, nogil=True)
def _parallel_mixture(s1, s2, rounding, interface, blur, t, g, x, gx, slopes=False):
    """(b,) the blurred indicators of the parallel polyhedra at ``interface * t`` mixed with weights ``g``
    (:func:`rounded_scores`; ``x``, ``gx`` Gauss-Legendre nodes of the arc), and with ``slopes`` their (b, 5)
    derivatives in ``s1``, ``s2``, ``rounding``, ``interface`` and ``blur`` (else (0, 5)).

    The derivatives are those of the same sums, term by term: each error function's is a Gaussian density, each
    density's its own times ``-u / blur`` in its argument ``u`` and ``(u^2 - 1) / blur`` in ``blur``; the
    polyhedron at ``t`` has ``s - interface t`` and the radius ``max(rounding + interface t, 0)``, whose
    derivative is taken as 1 where the argument is 0 (the right derivative: the radius is bounded below by 0)."""
    out = np.zeros(len(s1))
    grad = np.zeros((len(s1) if slopes else 0, 5))
    root2b = math.sqrt(2.0) * blur
    norm = math.sqrt(2.0 * math.pi) * blur
    # the arc's nodes depend on the parallel polyhedron only: computed once, not once per point
    sine, cosine, weight = np.empty(len(x)), np.empty(len(x)), np.empty(len(x))
    arc_sum = 0.0  # the quadrature of int_0^(pi/2) cos: the arc's derivative in the radius at radius 0 is its multiple
    for j in range(len(x)):
        theta = 0.25 * math.pi * (x[j] + 1.0)
        sine[j], cosine[j] = math.sin(theta), math.cos(theta)
        weight[j] = 0.25 * math.pi * gx[j] * cosine[j]
        arc_sum += weight[j]
    # and the arc's points and weights on each parallel polyhedron: once per polyhedron, not once per point
    along, edge, arc = np.empty(len(x)), np.empty(len(x)), np.empty(len(x))
    for k in range(len(t)):
        shift = interface * t[k]
        radius = max(rounding + shift, 0.0)
        rounds = rounding + shift >= 0.0
        for j in range(len(x)):
            along[j] = -radius + radius * sine[j]
            edge[j] = -radius + radius * cosine[j]
            arc[j] = weight[j] * radius
        for i in range(len(s1)):
            a, b = s1[i] - shift, s2[i] - shift
            e1, e2 = erfc_scalar(a / root2b), erfc_scalar((radius + b) / root2b)
            value = 0.25 * e1 * e2
            if slopes:
                f1, f2 = 0.5 * e1, 0.5 * e2
                p1 = math.exp(-0.5 * (a / blur) ** 2) / norm
                p2 = math.exp(-0.5 * ((radius + b) / blur) ** 2) / norm
                d_a, d_b = -p1 * f2, -f1 * p2
                d_radius = -f1 * p2 * (1.0 - arc_sum) if radius == 0.0 else -f1 * p2
                d_blur = (p1 * a * f2 + (f1 * p2 * (radius + b) if p2 > 0.0 else 0.0)) / blur
            if radius > 0.0:
                for j in range(len(x)):
                    u = (along[j] - b) / blur
                    density = math.exp(-0.5 * u ** 2) / norm
                    inner = 0.5 * erfc_scalar((a - edge[j]) / root2b)
                    value += density * inner * 0.25 * math.pi * gx[j] * radius * cosine[j]
                    if slopes and density > 0.0:
                        p_edge = math.exp(-0.5 * ((a - edge[j]) / blur) ** 2) / norm
                        d_a -= density * p_edge * arc[j]
                        d_b += density * u / blur * inner * arc[j]
                        d_radius += arc[j] * density * (p_edge * (cosine[j] - 1.0) - u / blur * (sine[j] - 1.0)
                                                        * inner) + density * inner * weight[j]
                        d_blur += arc[j] * density * ((u * u - 1.0) / blur * inner + p_edge * (a - edge[j]) / blur)
            out[i] += g[k] * value
            if slopes:
                if not rounds:
                    d_radius = 0.0  # the radius is held at 0
                grad[i, 0] += g[k] * d_a
                grad[i, 1] += g[k] * d_b
                grad[i, 2] += g[k] * d_radius
                grad[i, 3] += g[k] * t[k] * (d_radius - d_a - d_b)
                grad[i, 4] += g[k] * d_blur
    return out, grad


@njit(cache=True, nogil=True)
def _blurred_profile(s1, s2, rounding, interface, blur, t, g, slopes=False):
    """(b,) ``Phi(-D / interface)`` of the distance ``D`` to a right-angled edge rounded by ``rounding``, blurred by
    ``blur`` in the edge's plane (:func:`rounded_scores`; ``t``, ``g`` Gauss-Hermite nodes and weights), and with
    ``slopes`` its (b, 5) derivatives in ``s1``, ``s2``, ``rounding``, ``interface`` and ``blur`` (else (0, 5)):
    ``D - rounding`` is one moved distance, ``s + blur t``, off the quadrant where both are positive (``D`` moves
    with it; the radius cancels) and ``sqrt(a^2 + b^2) - rounding`` on it, ``a = s_1 + blur t_j + rounding``."""
    out = np.zeros(len(s1))
    grad = np.zeros((len(s1) if slopes else 0, 5))
    root2a = math.sqrt(2.0) * interface
    norm = math.sqrt(2.0 * math.pi) * interface
    n = len(t)
    a, b = np.empty(n), np.empty(n)
    step_a, step_b = np.empty(n), np.empty(n)
    density_a, density_b = np.zeros(n), np.zeros(n)
    for i in range(len(s1)):
        # off the quadrant where both moved distances are positive, D is one of them less the radius: its error
        # function is computed once per node, not once per pair of nodes
        for j in range(n):
            a[j] = s1[i] + blur * t[j] + rounding
            b[j] = s2[i] + blur * t[j] + rounding
            step_a[j] = erfc_scalar((a[j] - rounding) / root2a)
            step_b[j] = erfc_scalar((b[j] - rounding) / root2a)
            if slopes:
                density_a[j] = math.exp(-0.5 * ((a[j] - rounding) / interface) ** 2) / norm
                density_b[j] = math.exp(-0.5 * ((b[j] - rounding) / interface) ** 2) / norm
        value = 0.0
        for j in range(n):
            for k in range(n):
                # along_a, along_b: the derivatives of D in a[j] and b[k]; distance: D - rounding, density its
                # Gaussian's
                outside = 0.0
                if a[j] <= 0.0 and b[k] <= 0.0:
                    along_a = 1.0 if a[j] >= b[k] else 0.0
                    step = step_a[j] if a[j] >= b[k] else step_b[k]
                    distance = max(a[j], b[k]) - rounding
                    density = density_a[j] if a[j] >= b[k] else density_b[k]
                else:
                    outside = math.sqrt(max(a[j], 0.0) ** 2 + max(b[k], 0.0) ** 2)
                    if b[k] <= 0.0 and outside == a[j]:
                        along_a = 1.0
                        step = step_a[j]
                        distance = a[j] - rounding
                        density = density_a[j]
                    elif a[j] <= 0.0 and outside == b[k]:
                        along_a = 0.0
                        step = step_b[k]
                        distance = b[k] - rounding
                        density = density_b[k]
                    else:
                        along_a = 1.0 if a[j] >= b[k] else 0.0
                        distance = (outside if outside > 0.0 else max(a[j], b[k])) - rounding
                        step = erfc_scalar(distance / root2a)
                        density = math.exp(-0.5 * (distance / interface) ** 2) / norm if slopes else 0.0
                        if outside > 0.0:
                            along_a = -1.0  # on the quadrant: D's gradient is the unit vector to (a, b)
                value += g[j] * g[k] * 0.5 * step
                if slopes:
                    if along_a < 0.0:
                        along_a, along_b = max(a[j], 0.0) / outside, max(b[k], 0.0) / outside
                    else:
                        along_b = 1.0 - along_a
                    weight = g[j] * g[k] * density
                    grad[i, 0] -= weight * along_a
                    grad[i, 1] -= weight * along_b
                    grad[i, 2] -= weight * (along_a + along_b - 1.0)
                    grad[i, 3] += weight * distance / interface
                    grad[i, 4] -= weight * (along_a * t[j] + along_b * t[k])
        out[i] = value
    return out, grad


@functools.cache
def _legendre(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [-1, 1], computed once per count: the radius search evaluates the arc
    many times."""
    return np.polynomial.legendre.leggauss(nodes)


@functools.cache
def _hermite(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Hermite nodes and weights of the standard normal (weights summing to 1)."""
    t, g = np.polynomial.hermite_e.hermegauss(nodes)
    return t, g / g.sum()


def _other_steps(order: np.ndarray, width: float) -> np.ndarray:
    """(b,) the product of the steps of sigma ``width`` (:func:`_others_width`) of every plane but each point's two
    nearest (``order`` as in :func:`_edge_scores`): the part of :func:`rounded_scores` the radius does not change."""
    return np.prod(0.5 * erfc(order[:, :-2] / (np.sqrt(2) * width)), axis=1)


SHARE_STEP = 1e-3
"""The share's one-sided difference at its bounds 0 and 1 (:func:`_scores_and_slopes`), and the least share the
other planes' steps are blurred by (:func:`_others_width`)."""


def _others_width(width: float, share: float) -> float:
    """Sigma (nm) of the steps of the planes other than a point's two nearest (:func:`rounded_scores`): the blur's,
    ``width sqrt(share)``. The interface's part is one profile in the distance to the polyhedron, the nearest plane's
    (the edge's) where the others lie farther: the same draw of the interface's offset moves every plane, so it takes
    nothing more off for the others; only the blur, independent across them, does. Steps of the whole width there
    took ``Phi(-d / width)`` off per plane: an object whose planes lie 1-2 widths from its inside points (a 4 nm cube
    under a 1 nm tanh interface) read 1-4 % low inside, and its planes fitted from their true places moved out by
    0.09-0.10 nm (an 8 nm cube's by 0.05). Not under ``SHARE_STEP`` of the variance: the steps stay continuous."""
    return width * np.sqrt(max(share, SHARE_STEP))


@njit(cache=True, nogil=True)
def _product_of_others(distance, scaled, slopes):
    """:func:`_other_steps` from the planes' distances ``distance`` (b, m), the same over ``sqrt(2) width``
    ``scaled`` (b, m) (each step is ``0.5 erfc(scaled)``, computed here: the same numbers as the ufunc's) and the
    steps' derivatives ``slopes`` (b, m) in the distances: the (b,) products of the steps of all but each point's
    two largest distances, taken in ascending order of distance as ``np.prod`` takes them from the sorted distances
    (the same numbers); (b, m) their derivatives in each plane's distance (0 for the two largest); (b, 2) the
    planes of the largest and second largest distances (-1 for a single plane). Each row is sorted once (stably:
    equal distances in the planes' order, as ``np.sort`` leaves them), on a copy of its distances beside their
    planes rather than through the planes' indices."""
    b, m = distance.shape
    base = np.empty(b)
    grad = np.zeros((b, m))
    top = np.full((b, 2), -1, dtype=np.int64)
    rank = np.empty(m, dtype=np.int64)
    key = np.empty(m)
    steps = np.empty(m)
    for i in range(b):
        for j in range(m):  # insertion sort of the planes by distance (stable): m is small
            value = distance[i, j]
            steps[j] = 0.5 * erfc_scalar(scaled[i, j])
            k = j
            while k > 0 and key[k - 1] > value:
                key[k] = key[k - 1]
                rank[k] = rank[k - 1]
                k -= 1
            key[k] = value
            rank[k] = j
        value = 1.0
        for j in range(m - 2):
            value *= steps[rank[j]]
        base[i] = value
        for j in range(m - 2):  # each factor's derivative times the others (not a division: a step may be 0)
            slope = slopes[i, rank[j]]
            for k in range(m - 2):
                if k != j:
                    slope *= steps[rank[k]]
            grad[i, rank[j]] = slope
        top[i, 0] = rank[m - 1]
        if m > 1:
            top[i, 1] = rank[m - 2]
    return base, grad, top


def _scores_and_slopes(signed: np.ndarray, shift: np.ndarray, rounding: float, share: float, width: float,
                       free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rounded_scores` ``(b,)`` of the planes moved out by ``shift`` (m,) nm with edges rounded by
    ``rounding`` nm, the blur's ``share`` and the profile's ``width``, and its derivatives (its Jacobian) in each
    shift, the radius, the share and the width, the columns where ``free`` (m + 3,) bool is set: ``(b, free.sum())``.

    The derivatives are closed-form (the profile's error functions give Gaussians; :func:`_parallel_mixture`,
    :func:`_blurred_profile`), computed in the profile's own pass: an ion's edge term moves with its two nearest
    planes, every other plane's step with its own distance. The share moves the interface's and the blur's sigmas,
    ``a = w sqrt(1 - share)`` and ``b = w sqrt(share)``, whose derivatives are infinite at the share's bounds 0 and
    1; there (the fit clamps the share to them) the share's column is the difference to the share ``h = 1e-3``
    inside, as a bounded parameter's one-sided slope."""
    m = signed.shape[1]
    distance = signed - shift
    sigma = _others_width(width, share)
    scaled = distance / (np.sqrt(2) * sigma)  # once for the steps and their slopes
    others, d_others, top = _product_of_others(distance, scaled, -np.exp(-scaled ** 2) / (np.sqrt(2 * np.pi) * sigma))
    rows = np.arange(len(signed))
    second = top[:, 1] >= 0
    s1 = distance[rows, top[:, 0]]
    s2 = np.where(second, distance[rows, np.maximum(top[:, 1], 0)], -np.inf)
    edge, grad = _edge_part(s1, s2, rounding, width, share, slopes=True)
    base = edge * others
    jac = np.empty((len(signed), m + 3))
    # a plane's shift lowers its distances: minus the derivatives in the distance
    jac[:, :m] = -edge[:, None] * d_others
    jac[rows, top[:, 0]] = -others * grad[:, 0]
    jac[rows[second], top[second, 1]] = -(others * grad[:, 1])[second]
    jac[:, m] = others * grad[:, 2]
    interface, blur = width * np.sqrt(max(1.0 - share, 0.0)), width * np.sqrt(max(share, 0.0))
    if free[m + 1] and (interface <= 0.0 or blur <= 0.0):
        h = SHARE_STEP if share <= 0.0 else -SHARE_STEP
        moved = _other_steps(np.sort(distance, axis=1), _others_width(width, share + h))
        jac[:, m + 1] = (_edge_part(s1, s2, rounding, width, share + h) * moved - base) / h
    elif free[m + 1]:
        # the others' sigma sqrt(share) w: d step / d share = -(d step / d s) s / (2 share), above SHARE_STEP
        jac[:, m + 1] = others * width ** 2 / 2 * (grad[:, 4] / blur - grad[:, 3] / interface) \
            - (edge * np.einsum("ij,ij->i", d_others, distance) / (2 * share) if share > SHARE_STEP else 0.0)
    # the width scales both sigmas, and every other plane's step: d step / d width = -(d step / d s) s / width
    jac[:, m + 2] = others * (grad[:, 3] * interface + grad[:, 4] * blur) / width \
        - edge * np.einsum("ij,ij->i", d_others, distance) / width
    return base, jac[:, free]


LINE_SEARCH = 4
"""Lengths along each Gauss-Newton step that :func:`edge_rounding`'s fits try before they take the misfit as at its
minimum."""


def edge_rounding(signed: np.ndarray, u: np.ndarray, weight: np.ndarray, width: float, iterations: int = 10,
                  max_step: float = 0.2, tolerance: float = 1e-2) -> tuple[np.ndarray, float]:
    """How far an object's planes move out, and the radius (nm) of its rounded edges, as its ions show them.

    The ions' normalised scores ``u`` against the planes fitted by :func:`fit_to_ions` (``signed`` (b, m), nm) are
    fitted by :func:`rounded_scores` (atoms-weighted least squares, closed-form derivatives; at most ``iterations``
    Gauss-Newton steps, each scaled to move no parameter more than ``max_step`` and taken only as far along as
    lowers the misfit, a line search by quadratic interpolation; a parameter at its bound that a step would push
    past is held there, the radius in ``[0, depth of the deepest ion]``, the share in ``[0, 1]``; converged when the
    misfit falls by less than ``tolerance`` of the residuals' variance): first with sharp edges, every plane's
    offset and the share of the profile's variance due to the blur (from half); then the radius alone at that share
    (bounded scalar search), then the radius and every offset together. The planes' own fit (the product of their
    steps: a blurred sharp polyhedron) reads an interface profile's edges, which are round outside and hold half the
    contrast on the edge, as planes moved out (a 3 nm lath's by 0.05-0.17 nm under a 0.6 nm interface) and a rounded
    edge's as a smaller radius. The share and the radius are not fitted together: an emptier edge is either a sharp
    edge more blurred or a rounded one less so, and sharp cuboids fitted both ways came out rounded (0.2-0.4 nm,
    area -7 %). The share is kept where the ions choose it over share 1 by the Bayesian information criterion
    (likelihood ratio above ``log(b)``); otherwise the share is 1 and the width and offsets are those given (the
    blurred sharp polyhedron). A radius within two standard errors of 0, or whose standard error is not finite, is
    not one the ions show: the edges stay sharp, their offsets as the first fit has them.

    Returns
    -------
    shift : (m,) float64, nm
        Outward moves of the planes' offsets.
    rounding : float, nm
    """
    from scipy.optimize import minimize_scalar

    m = signed.shape[1]
    root_w = np.sqrt(weight)
    deepest = float(np.max(-signed.max(axis=1), initial=0.0))  # the inner polyhedron must hold a point

    # the parameters (m offsets, radius, share, width) stay within these bounds
    lower = np.r_[np.full(m, -np.inf), 0.0, 0.0, 0.05 * width]
    upper = np.r_[np.full(m, np.inf), deepest, 1.0, np.inf]

    def evaluate(params: np.ndarray, free: np.ndarray):
        base, jac = _scores_and_slopes(signed, params[:m], params[m], params[m + 1], params[m + 2], free)
        residual = u - base
        return float(weight @ residual ** 2), residual, jac

    def fit(params: np.ndarray, free: np.ndarray):
        """The free parameters fitted from ``params`` (m + 3,): the parameters, their misfit (the atoms-weighted
        sum of squared residuals) and the Jacobian at them. Each Gauss-Newton step is taken only as far as lowers
        the misfit: the full steps overshot, and on a 10M refinement's fits 65 of 66 ran all their steps, the last
        still at ``max_step`` (a radius swinging 1.19 -> 1.29 -> 1.17); these end 236 of 264 there."""
        index = np.flatnonzero(free)
        cost, residual, jac = evaluate(params, free)
        for _ in range(iterations):
            weighted = jac * weight[:, None]
            normal, gradient = weighted.T @ jac, weighted.T @ residual
            at, moving = params[index], np.ones(len(index), dtype=bool)
            # a parameter at its bound that the step would push past is held there, and the others' step solved
            # without it: the projected step need not lower the misfit, this one does
            for _ in range(len(index)):
                step = np.zeros(len(index))
                step[moving] = np.linalg.lstsq(normal[np.ix_(moving, moving)], gradient[moving], rcond=None)[0]
                past = ((at <= lower[index]) & (step < 0)) | ((at >= upper[index]) & (step > 0))
                if not past.any():
                    break
                moving &= ~past
            # scaled, not clipped per parameter, so that it keeps its direction; cut short at the nearest bound
            step *= min(1.0, max_step / max(np.abs(step).max(), 1e-300))
            room = np.where(step > 0, upper[index] - at, np.where(step < 0, lower[index] - at, np.inf))
            length = min(1.0, float(np.min(room / np.where(step != 0, step, 1.0), initial=1.0)))
            # the misfit along the step is a parabola from its value and slope here and its value at a trial length:
            # a trial that overshoots (the full steps land ~1.7 times past the minimum, so the fits oscillated) is
            # followed by the parabola's minimum, as a line search by quadratic interpolation does
            slope, best = -2.0 * float(step @ gradient), (cost,)
            for _ in range(LINE_SEARCH):
                trial = params.copy()
                trial[index] = np.clip(at + length * step, lower[index], upper[index])
                tried = (*evaluate(trial, free), trial)
                best = min(best, tried, key=lambda t: t[0])
                curvature = (tried[0] - cost - slope * length) / length ** 2
                shorter = -slope / (2 * curvature) if curvature > 0 else length
                if best[0] < cost and shorter > 0.75 * length:
                    break
                length = max(shorter, length / 10)
            if len(best) == 1:  # no length along the descent direction lowers the misfit: at its minimum
                break
            trial_cost, trial_residual, trial_jac, trial = best
            # converged when the misfit falls by less than ``tolerance`` of the residuals' variance (the steps
            # left are then far below the parameters' standard errors)
            fell = cost - trial_cost
            params, cost, residual, jac = trial, trial_cost, trial_residual, trial_jac
            if fell < tolerance * cost / max(len(u) - len(index), 1):
                break
        return params, cost, jac

    sharp = np.r_[np.ones(m, dtype=bool), False, True, True]
    fitted_params, fitted, _ = fit(np.r_[np.zeros(m), 0.0, 0.5, width], sharp)
    shift, share, width_fitted = fitted_params[:m], fitted_params[m + 1], fitted_params[m + 2]
    # the share is one parameter more than the blurred sharp polyhedron (share 1, offsets and width refitted), and
    # it moves every plane: kept where the ions choose it by the Bayesian information criterion, the likelihood
    # ratio (atoms-weighted residuals taken as Gaussian, their variance from the fit) above log(ions). A share
    # the ions do not show moves the planes by its noise: on a 7 nm gamma-prime cube (0.1 Al contrast) the data
    # hardly tell share 0 from 1 (ratio -3 to +6.5 over its fits, 12,000-34,000 ions), the offsets move ~0.03 nm
    # per unit of share, and a share clamped at 0 moved every plane in (volume -1.5 %)
    offsets_and_width = np.r_[np.ones(m, dtype=bool), False, False, True]
    _, blurred, _ = fit(np.r_[np.zeros(m), 0.0, 1.0, width], offsets_and_width)
    ratio = (blurred - fitted) / (fitted / max(len(u) - m - 2, 1))
    if not ratio > np.log(len(u)):
        shift, share = np.zeros(m), 1.0
    else:
        width = width_fitted
    order = np.sort(signed - shift, axis=1)
    others = _other_steps(order, _others_width(width, share))
    alone = minimize_scalar(lambda r: float(np.sum(weight * (u - _edge_scores(order, r, width, share) * others) ** 2)),
                            bounds=(0.0, deepest), method="bounded", options={"xatol": 1e-3})
    rounded = np.r_[np.ones(m, dtype=bool), True, False, False]
    params, cost, jac = fit(np.r_[shift, float(alone.x), share, width], rounded)
    moved, rounding = params[:m], float(params[m])
    # the radius's standard error from the Gauss-Newton normal matrix at the fit, scaled by the residuals' variance;
    # one that is not finite (a singular normal matrix) shows no radius either
    scaled = jac * root_w[:, None]
    with np.errstate(invalid="ignore"):  # a negative diagonal (a singular matrix's rounding) gives NaN: refused
        error = np.sqrt(cost / max(len(u) - m - 1, 1) * np.linalg.pinv(scaled.T @ scaled)[m, m])
    if not rounding > 2 * error:
        return shift, 0.0
    return moved, rounding
