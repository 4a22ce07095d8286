"""Manifold harmonics of a closed object: its shape low-passed in its own Laplace-Beltrami eigenbasis.

The refined surface of a small precipitate is rough: each vertex is placed from the ions of a ~2 nm
patch, and the refinement smooths its *moves*, not the shape, so errors the start had at short
wavelengths (marching cubes on a 1 nm grid) and the patches' counting noise stay in it. On a 3 nm
sphere of the gamma-prime specimen that error lives at spherical-harmonic degrees 2-8 and is what
inflates its area by 2-8 % and its mean distance to the truth to ~0.17 nm.

The eigenfunctions ``phi_k`` of the cotangent Laplacian (``L phi = mu M phi``, ``M`` the lumped mass)
are the surface's own Fourier basis: ordered by ``mu`` (1/nm², a squared spatial frequency), they are the
spherical harmonics on a sphere, whose coordinates lie in the first four (degree <= 1) exactly. Keeping
the first ``k`` coefficients of the coordinates (:func:`low_pass`) removes everything shorter than the
``k``-th wavelength without shrinking what is kept (unlike Laplacian smoothing of the positions, which
shrinks a sphere at every pass). How many modes the ions support differs per object (a 3 nm sphere: 4-9;
an elongated object more; a cube 4-36 when the facets rebuild its edges afterwards), so
:mod:`apt_filters.refine.crossval` chooses ``k`` per object from held-out ions.

Cost: one shift-inverted sparse eigensolve per object, ``k`` modes (``scipy.sparse.linalg.eigsh``), or a dense one
where ``k`` is a tenth of the vertices or more (:data:`DENSE`); memory ``n x k`` float64 (an object of 1,500 vertices
and 47 modes: 0.6 MB).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csc_matrix, diags
from scipy.sparse.linalg import eigsh

from apt_filters.refine.blur import vertex_areas


DENSE = 10
"""The dense eigensolver is used where ``DENSE`` times the modes wanted reach the vertices: measured on a disc's
mesh, 182 modes of 1,082 vertices 4.3 s by ``eigsh``, 1.0 s dense; of 2,054 vertices 3.5 and 3.3 s; 82 of 1,082
0.25 and 0.72 s."""


@dataclass
class Harmonics:
    """The lowest eigenpairs of an object's Laplace-Beltrami operator.

    Attributes
    ----------
    values : (k,) float64, 1/nm²
        Eigenvalues ``mu``, ascending (the first is 0: the constant).
    vectors : (n, k) float64
        Eigenfunctions, orthonormal in the mass inner product (``vectors.T @ (mass * vectors) = I``).
    mass : (n,) float64, nm²
        Lumped (barycentric) vertex areas.
    """

    values: np.ndarray
    vectors: np.ndarray
    mass: np.ndarray

    @property
    def size(self) -> int:
        return len(self.values)

    def cut(self, k: int, reach: float = 0.25) -> int:
        """The number of modes nearest ``k`` that splits no (near-)degenerate group: the index within
        ``reach * k`` of ``k`` where the spectrum's ratio gap ``values[j] / values[j - 1]`` is largest.

        Below such a gap the low-pass is the projection onto a whole invariant subspace, which is the
        same whatever basis the eigensolver returned for it; a cut through a group of equal eigenvalues
        (a cube's, or a sphere's at a k other than a square) would keep an arbitrary part of it, and
        reruns would differ. On a sphere the gaps are at 4, 9, 16, ... (complete degrees).
        """
        lo, hi = max(2, int(np.ceil(k * (1 - reach)))), min(self.size - 1, int(k * (1 + reach)) + 1)
        if lo > hi:
            return min(k, self.size)
        j = np.arange(lo, hi + 1)
        ratio = self.values[j] / np.maximum(self.values[j - 1], 1e-300)
        return int(j[np.argmax(ratio)])


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> csc_matrix:
    """(n, n) symmetric positive semi-definite cotangent stiffness matrix (linear finite elements).

    ``x @ L @ x`` is the Dirichlet energy of the piecewise linear function ``x``; each edge weighs half
    the sum of the cotangents of its two opposite angles.
    """
    n = len(vertices)
    rows, cols, vals = [], [], []
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        u = vertices[faces[:, b]] - vertices[faces[:, a]]
        w = vertices[faces[:, c]] - vertices[faces[:, a]]
        # cotangent of the angle at a, opposite the edge (b, c); degenerate faces weigh nothing
        cross = np.linalg.norm(np.cross(u, w), axis=1)
        cot = np.divide(np.einsum("ij,ij->i", u, w), cross, out=np.zeros(len(faces)), where=cross > 1e-12)
        rows += [faces[:, b], faces[:, c]]
        cols += [faces[:, c], faces[:, b]]
        vals += [-0.5 * cot, -0.5 * cot]
    off = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsc()
    return (off - diags(np.asarray(off.sum(axis=1)).ravel())).tocsc()


def harmonics(vertices: np.ndarray, faces: np.ndarray, k: int) -> Harmonics:
    """The ``k`` lowest manifold harmonics of one connected mesh (``vertices`` only those its faces use).

    Parameters
    ----------
    vertices : (n, 3) float64, nm
    faces : (m, 3) int
    k : int
        Modes wanted; at most ``n`` are returned.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    n = len(vertices)
    k = min(k, n)
    stiffness = cotangent_laplacian(vertices, faces)
    mass = np.maximum(vertex_areas(vertices, faces), 1e-12)
    if k >= n - 1 or n <= 200 or DENSE * k >= n:
        # small meshes, or many modes of one: the dense problem is cheaper (ARPACK's Lanczos basis of 2k + 1 vectors
        # nears n), and eigsh cannot return all n modes
        from scipy.linalg import eigh

        values, vectors = eigh(stiffness.toarray(), np.diag(mass), subset_by_index=[0, k - 1])
        return Harmonics(values, vectors, mass)
    # shift-invert just below 0: the operator is singular (constants), its lowest modes converge fast; a
    # fixed start vector, since ARPACK's random one makes reruns differ in the last digits
    start = np.random.default_rng(0).random(n)
    values, vectors = eigsh(stiffness, k=k, M=diags(mass).tocsc(), sigma=-1e-3, which="LM", v0=start)
    order = np.argsort(values)
    return Harmonics(values[order], vectors[:, order], mass)


def low_pass(vertices: np.ndarray, basis: Harmonics, k: int) -> np.ndarray:
    """(n, 3) the coordinates reconstructed from their first ``k`` harmonic coefficients (see
    :meth:`Harmonics.cut` for a ``k`` that splits no degenerate group)."""
    coeffs = basis.vectors[:, :k].T @ (basis.mass[:, None] * vertices)
    return basis.vectors[:, :k] @ coeffs


def rim_held_low_pass(vertices: np.ndarray, faces: np.ndarray, length: float) -> np.ndarray:
    """(n, 3) an open mesh's coordinates low-passed at ``length`` nm, its rim (boundary vertices) held.

    An open surface (an interface leaving the specimen) has no basis in which its coordinates lie in a few
    modes: the Neumann harmonics' low-pass of a flat sheet pulls its rim inward, as Laplacian smoothing does.
    Held at its rim, the coordinates split into the harmonic extension of the rim (which the filter keeps:
    a minimal surface spanning it) and a part vanishing on the rim, low-passed in the Dirichlet harmonics
    ``L_II phi = mu M phi`` without computing them: Tikhonov's ``z = (M + l^4 L M^-1 L)^-1 M x`` damps
    harmonic ``mu`` by ``1 / (1 + a)``, ``a = (l^2 mu)^2`` (cut-off wavelength ``2 pi l``); applied twice as
    ``2 z - F z`` (Tukey's twicing) the damping is ``(1 + 2a) / (1 + a)^2``, ``1 - a^2`` at long wavelengths.
    A curved sheet's part vanishing on the rim is not band-limited (a sphere cap's is the torsion function of
    its outline, with content up to the rim's corners): a 30 nm cap over a 24 nm square (4.9 nm sagitta) keeps
    its shape to 0.034 nm at ``l`` = 1.4 nm and loses up to 0.14 nm at 2.8 nm (0.23 without the twicing). That
    bias grows with ``l`` and the noise removed with it: :func:`~apt_filters.refine.crossval.cross_validated_lengths`
    lets held-out ions weigh the two.

    Parameters
    ----------
    vertices : (n, 3) float64, nm
        One connected open mesh (only the vertices its faces use).
    faces : (m, 3) int
    length : float, nm
        ``l``; 0 returns the vertices as they are.

    Cost: one sparse LU of the (interior) bi-Laplacian, two solves.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    if length <= 0:
        return vertices.copy()
    from scipy.sparse.linalg import splu

    n = len(vertices)
    rim = np.zeros(n, dtype=bool)
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    edges, count = np.unique(e, axis=0, return_counts=True)
    rim[edges[count == 1].ravel()] = True
    inner, held = np.flatnonzero(~rim), np.flatnonzero(rim)
    if not len(inner):
        return vertices.copy()
    stiffness = cotangent_laplacian(vertices, faces)
    mass = np.maximum(vertex_areas(vertices, faces), 1e-12)[inner]
    l_ii, l_ib = stiffness[inner][:, inner], stiffness[inner][:, held]
    inv = diags(1.0 / mass)
    weight = length ** 4
    solve = splu((diags(mass) + weight * (l_ii @ inv @ l_ii)).tocsc()).solve
    # the rim's pull on the interior: the bi-Laplacian's terms in the held coordinates
    pull = weight * (l_ii @ (inv @ (l_ib @ vertices[held])))
    once = solve(mass[:, None] * vertices[inner] - pull)
    out = vertices.copy()
    out[inner] = 2.0 * once - solve(mass[:, None] * once - pull)
    return out
