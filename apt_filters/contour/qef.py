"""Quadratic error functions of dual contouring: truncated minimisers constrained to the cell.

A vertex's QEF is ``E(x) = |A x - b|²`` over its Hermite planes (rows of ``A`` are unit
normals, ``b`` the normals dotted with the crossing points), stored as the 3×3 normal
matrix ``AᵀA`` and ``Aᵀb``. All solves work relative to the mass point (mean of the
crossings) so that directions the planes do not constrain stay at the mass point.
"""

from __future__ import annotations

import itertools

import numpy as np

# Every face of a box (3 free axes = the box itself, then its 6 facets, 12 edges, 8 corners):
# per axis 0 = free, 1 = at the lower bound, 2 = at the upper bound.
_ACTIVE_SETS = np.array(list(itertools.product(range(3), repeat=3)))
_TIE = 1e-9  # values closer than this times trace(AᵀA) are equal (see minimise_in_box)


def solve_qef(ata: np.ndarray, atb: np.ndarray, mass: np.ndarray, lo: np.ndarray, hi: np.ndarray,
              cutoff: float, max_rank: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Minimisers of ``|A x - b|²`` in the boxes ``lo <= x <= hi``, by rank: (max_rank + 1, n, 3).

    Rank ``r`` keeps the ``r`` strongest eigen-directions of ``AᵀA`` whose singular value
    is at least ``cutoff`` times the largest (a truncated pseudo-inverse about the mass
    point, rank 0 being the mass point itself). Where that minimiser leaves the box, the
    rank-``r`` QEF is minimised over the box instead (see :func:`minimise_in_box`), so a
    corner that lies just outside the cell gives the best point inside it rather than a
    point with fewer features. ``mass`` must lie in its box.

    Parameters
    ----------
    ata : (n, 3, 3), atb : (n, 3)
        Normal equations of each vertex's planes (index space).
    mass, lo, hi : (n, 3)
        Mass points and box corners.

    Returns
    -------
    points : (max_rank + 1, n, 3)
    clamped : (max_rank + 1, n) bool
        Where the box constrained the minimiser (the unconstrained one lay outside).
    """
    w, u = np.linalg.eigh(ata)  # ascending eigenvalues = squared singular values of A
    keep = np.sqrt(np.clip(w, 0, None)) > cutoff * np.sqrt(np.clip(w[:, -1:], 0, None))
    w = np.where(keep, w, 0.0)
    rhs = atb - np.einsum("nij,nj->ni", ata, mass)
    proj = np.einsum("nji,nj->ni", u, rhs)  # rhs in the eigen-basis
    coef = np.where(keep, proj / np.where(keep, w, 1.0), 0.0)
    out = np.empty((max_rank + 1,) + mass.shape)
    out[0] = mass
    clamped = np.zeros((max_rank + 1, len(mass)), dtype=bool)
    free = mass  # the unconstrained rank-r minimiser; a clamped rank is no base for the next
    for r in range(1, max_rank + 1):
        free = free + u[:, :, 3 - r] * coef[:, 3 - r, None]
        out[r] = free
        outside = np.flatnonzero(np.any((free < lo - 1e-9) | (free > hi + 1e-9), axis=1))
        clamped[r] = clamped[r - 1]  # a rank built on a clamped point is a compromise too
        clamped[r, outside] = True
        if len(outside):
            top = u[outside, :, 3 - r:]  # (k, 3, r) the r strongest directions
            a_r = np.einsum("nik,nk,njk->nij", top, w[outside, 3 - r:], top)
            r_r = np.einsum("nik,nk->ni", top, proj[outside, 3 - r:] * keep[outside, 3 - r:])
            out[r, outside] = minimise_in_box(a_r, r_r, mass[outside], lo[outside], hi[outside], cutoff**2)
    return out, clamped


def plane_misfit(ata: np.ndarray, atb: np.ndarray, btb: np.ndarray, count: np.ndarray,
                 points: np.ndarray) -> np.ndarray:
    """(..., n) root-mean-square distance of ``points`` (..., n, 3) to each vertex's planes.

    ``btb`` (n,) is the sum of squared plane offsets and ``count`` (n,) the number of
    planes; the error ``xᵀ AᵀA x - 2 xᵀ Aᵀb + bᵀb`` is clipped at 0 against round-off.
    """
    err = (np.einsum("...ni,nij,...nj->...n", points, ata, points) - 2 * np.einsum("...ni,ni->...n", points, atb)
           + btb)
    return np.sqrt(np.clip(err, 0, None) / count)


def minimise_in_box(a: np.ndarray, r: np.ndarray, mass: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                    rcond: float) -> np.ndarray:
    """(n, 3) minimisers of ``yᵀ a y - 2 rᵀ y`` over ``lo <= mass + y <= hi``, returned as ``mass + y``.

    Exact active-set enumeration: a convex quadratic's minimiser over a box lies in the
    relative interior of one of the box's 27 faces (the box, 6 facets, 12 edges, 8
    corners), where it minimises the quadratic over that face's affine hull. Each hull's
    minimiser is solved with a pseudo-inverse (``rcond`` relative to the largest
    eigenvalue of the free block), which keeps weakly constrained directions at the mass
    point; the feasible one of least value wins. Where several tie (the quadratic is flat
    along a direction the truncation dropped, so a facet, its edges and its corners can all
    be minimal), the one nearest the mass point wins: without that rule round-off chose,
    and it could pick a far corner. Cost: 27 small pseudo-inverses per row, so callers
    pass only the rows whose unconstrained minimiser left the box.
    """
    sets = _ACTIVE_SETS  # (27, 3)
    free = sets == 0
    bound = np.where(sets[:, None] == 1, (lo - mass)[None], (hi - mass)[None])  # (27, n, 3)
    y_fixed = np.where(free[:, None], 0.0, bound)
    block = free[:, None, :, None] & free[:, None, None, :]  # (27, 1, 3, 3)
    sub = np.where(block, a[None], 0.0)
    rhs = np.where(free[:, None], r[None] - np.einsum("nij,snj->sni", a, y_fixed), 0.0)
    y = np.einsum("snij,snj->sni", np.linalg.pinv(sub, rcond=rcond, hermitian=True), rhs) + y_fixed
    value = np.einsum("sni,nij,snj->sn", y, a, y) - 2 * np.einsum("sni,ni->sn", y, r)
    x = y + mass[None]
    feasible = np.all((x >= lo[None] - 1e-9) & (x <= hi[None] + 1e-9), axis=2)
    value = np.where(feasible, value, np.inf)
    # Values are O(trace(a)) over a unit box; round-off is ~1e-16 of that, real gaps far larger.
    tie = value <= value.min(axis=0) + _TIE * np.trace(a, axis1=1, axis2=2)
    best = np.argmin(np.where(tie, np.einsum("sni,sni->sn", y, y), np.inf), axis=0)
    return x[best, np.arange(len(mass))]
