"""Quadratic error functions of dual contouring: truncated and box-constrained minimisers.

A vertex's QEF is ``E(x) = |A x - b|²`` over its Hermite planes (rows of ``A`` are unit
normals, ``b`` the normals dotted with the crossing points), stored as the 3×3 normal
matrix ``AᵀA`` and ``Aᵀb``. All solves work relative to the mass point (mean of the
crossings) so that directions the planes do not constrain stay at the mass point.
"""

from __future__ import annotations

import itertools

import numpy as np


def solve_qef(ata: np.ndarray, atb: np.ndarray, mass: np.ndarray, cutoff: float) -> np.ndarray:
    """Minimisers of ``|A x - b|²`` by rank: (4, n, 3) for ranks 0 (mass point) .. 3.

    Solved about the mass point with a truncated pseudo-inverse: eigen-directions whose
    singular value is below ``cutoff`` times the largest are dropped, and rank ``r`` keeps
    at most the ``r`` strongest ones.
    """
    w, u = np.linalg.eigh(ata)  # ascending eigenvalues = squared singular values of A
    sigma = np.sqrt(np.clip(w, 0, None))
    keep = sigma > cutoff * sigma[:, -1:]
    rhs = atb - np.einsum("nij,nj->ni", ata, mass)
    coef = np.einsum("nji,nj->ni", u, rhs) / np.where(keep, w, 1.0)
    coef = np.where(keep, coef, 0.0)
    out = np.empty((4,) + mass.shape)
    out[0] = mass
    for r in range(1, 4):
        out[r] = out[r - 1] + u[:, :, 3 - r] * coef[:, 3 - r, None]
    return out


# Every face of a box (3 free axes = the box itself, then its 6 faces, 12 edges, 8 corners):
# per axis 0 = free, 1 = at the lower bound, 2 = at the upper bound.
_ACTIVE_SETS = np.array(sorted(itertools.product(range(3), repeat=3), key=lambda s: sum(c > 0 for c in s)))


def solve_qef_in_box(ata: np.ndarray, atb: np.ndarray, mass: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                     cutoff: float) -> np.ndarray:
    """(n, 3) minimisers of ``|A x - b|²`` constrained to the boxes ``lo <= x <= hi``.

    Exact active-set enumeration: a convex quadratic's minimiser over a box lies in the
    relative interior of one of the box's 27 faces (the box, 6 facets, 12 edges, 8
    corners), where it is the minimiser over that face's affine hull. Each hull's
    minimiser is solved with the truncated pseudo-inverse about the mass point (as in
    :func:`solve_qef`); the feasible one of least error wins.
    ``mass`` must lie in its box. Cost: 27 small pseudo-inverses per vertex, so call it
    only on vertices whose unconstrained minimiser left the box.
    """
    n = len(mass)
    r = atb - np.einsum("nij,nj->ni", ata, mass)  # gradient/2 of E at the mass point, negated
    sets = _ACTIVE_SETS  # (27, 3)
    free = sets == 0
    bound = np.where(sets[:, None] == 1, (lo - mass)[None], (hi - mass)[None])  # (27, n, 3)
    y_fixed = np.where(free[:, None], 0.0, bound)
    proj = free[:, None, :, None] & free[:, None, None, :]  # (27, 1, 3, 3)
    sub = np.where(proj, ata[None], 0.0)
    rhs = np.where(free[:, None], r[None] - np.einsum("nij,snj->sni", ata, y_fixed), 0.0)
    y = np.einsum("snij,snj->sni", np.linalg.pinv(sub, rcond=cutoff**2, hermitian=True), rhs) + y_fixed
    energy = np.einsum("sni,nij,snj->sn", y, ata, y) - 2 * np.einsum("sni,ni->sn", y, r)
    x = y + mass[None]
    tol = 1e-9
    feasible = np.all((x >= lo[None] - tol) & (x <= hi[None] + tol), axis=2)
    best = np.argmin(np.where(feasible, energy, np.inf), axis=0)
    return x[best, np.arange(n)]
