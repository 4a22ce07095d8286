"""Ions near a mesh: signed distance to the mesh around the nearest vertex, binned per vertex.

Each ion is assigned to its nearest mesh vertex ``v`` and gets its signed distance to the faces
around ``v`` (closest point on each triangle of the fan; the sign from the pseudo-normal there),
which is its exact signed distance to the mesh wherever the closest surface point lies in that
fan (every ion within 1 nm of a convex polyhedral mesh). The offset along ``v``'s normal,
``(p - v) . n_v``, as Felfer's toolbox measures proxigrams, is kept as ``distance="tangent"``:
on a convex surface the faces lie below ``v``'s tangent plane, so it places the ions' interface
inside the mesh. Binned against the distance, each vertex owns a short 1D composition profile
across the interface made of the ions of its Voronoi patch; pooling the profiles of nearby
vertices gives enough ions per bin while each ion keeps the distance to its own local surface,
so pooling adds no curvature bias.

:class:`NearIons` holds the ions near a mesh (selected in one streamed pass,
:func:`apt_filters.core.nearby.select_near`, so 10^8-10^9 memory-mapped ions are read once in bounded memory) and keeps their nearest vertices
up to date as the mesh moves; :class:`Pairs` and :func:`pooled` pool the profiles of vertices
within a radius (numba).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from numba import njit, prange
from scipy.spatial import cKDTree

from apt_filters.core.mesh import TriMesh, face_normals, topology
from apt_filters.core.nearby import select_near
from apt_filters.core.triangle import closest_on_triangle
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.composition import IonAtoms, basis_atoms, ion_atoms
from apt_filters.refine.nearest import descend, second_ring
from apt_filters.voxel import ConcentrationBasis

REASSIGN = 0.15
"""nm a vertex may move before the ions' nearest vertices are found again."""

EXACT = 2.5
"""nm from the surface within which an ion's nearest vertex is searched exactly (beyond the 1-ring walk):
the profiles' reach (1.5 nm) and the inner plateau bins; farther ions only count in a plateau."""


def adjacency(faces: np.ndarray, n_vertices: int) -> csr_matrix:
    """(n, n) symmetric 0/1 vertex adjacency through mesh edges."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    a = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_vertices, n_vertices)).tocsr()
    a = ((a + a.T) > 0).astype(np.float64)
    return a


def normal_weight(normals: np.ndarray, i: np.ndarray, j: np.ndarray, power: float) -> np.ndarray:
    """``max(0, n_i . n_j) ** power``: how much vertex ``j`` may speak for vertex ``i``.

    The bilateral factor that keeps sharp edges: across a 90° edge the two faces' vertices do
    not pool (power 8: weight 0.46 at 25°, 0.06 at 45°, 0 at 90°).
    """
    return np.maximum(np.einsum("ij,ij->i", normals[i], normals[j]), 0.0) ** power


@dataclass
class Pairs:
    """Neighbours of each vertex in its own component within ``radius`` nm, kept while the mesh moves little: each
    pair once, under its lower vertex (CSR: row ``i`` holds the ``j > i``, ascending).

    Found by a KD-tree at ``radius + slack`` and found again (:meth:`update`) only when a vertex
    has moved more than ``slack / 2`` since: no pair within ``radius`` is missed.
    """

    indptr: np.ndarray
    indices: np.ndarray
    anchor: np.ndarray
    radius: float
    slack: float

    @classmethod
    def find(cls, vertices: np.ndarray, components: np.ndarray, radius: float, slack: float = 0.6) -> "Pairs":
        ij = cKDTree(vertices).query_pairs(radius + slack, output_type="ndarray")
        ij = ij[components[ij[:, 0]] == components[ij[:, 1]]]
        indptr, indices = _upper_csr(ij.astype(np.int64), len(vertices))
        return cls(indptr, indices, vertices.copy(), radius, slack)

    def update(self, vertices: np.ndarray, components: np.ndarray) -> "Pairs":
        """These pairs, or the pairs found again if a vertex has moved more than ``slack / 2``."""
        if _largest_move(vertices, self.anchor) <= self.slack / 2:
            return self
        return Pairs.find(vertices, components, self.radius, self.slack)


def _upper_csr(ij: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(indptr, indices) int64 of the (n, n) upper triangle of the symmetric 0/1 matrix with the pairs ``ij`` (p, 2)
    int64 (each once, i != j, either order): each row's columns (all above it) sorted, as scipy's canonical CSR of the
    same matrix."""
    # each pair as one key row * n + column with the lower vertex as row (< n**2, far inside int64 for any mesh),
    # sorted: rows in order, each row's columns sorted. numpy's sort, not a compiled kernel: the kernel's cold compile
    # (~5 s CPU, numba's quicksort inside a parallel loop) cost more than this takes on any mesh here
    keys = np.minimum(ij[:, 0], ij[:, 1]) * n + np.maximum(ij[:, 0], ij[:, 1])
    keys.sort()
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(keys // n, minlength=n), out=indptr[1:])
    return indptr, keys % n


@njit(cache=True, nogil=True)
def _pool(vertices, normals, indptr, indices, radius, power, profiles, out):
    inv = 2.0 / (radius * radius)  # exp(-r² / 2 sigma²) with sigma = radius / 2
    # element by element: a row copy would compile numba's shape-check error path and its string formatting
    # (~4 s CPU in every cold process, st30)
    for i in range(vertices.shape[0]):
        for col in range(profiles.shape[1]):
            out[i, col] = profiles[i, col]
    # each pair's weight once, added to both of its rows (the same bits either way round: the differences only change
    # sign, the products commute). Row i gets its neighbours j < i while the rows before it are visited and then its
    # own j > i: every row sums them in ascending order of j, as a pass over its full row would
    for i in range(vertices.shape[0]):
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            r2 = ((vertices[i, 0] - vertices[j, 0]) ** 2 + (vertices[i, 1] - vertices[j, 1]) ** 2
                  + (vertices[i, 2] - vertices[j, 2]) ** 2)
            if r2 <= radius * radius:
                c = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
                w = np.exp(-r2 * inv) * (1.0 if power == 0.0 else max(c, 0.0) ** power)
                for col in range(profiles.shape[1]):
                    out[i, col] += w * profiles[j, col]
                    out[j, col] += w * profiles[i, col]


def pooled(profiles: np.ndarray, vertices: np.ndarray, normals: np.ndarray, pairs: Pairs,
           normal_power: float) -> np.ndarray:
    """(n, k) each vertex's row of ``profiles`` (n, k) plus its neighbours' (``pairs`` within
    ``pairs.radius``) weighted by exp(-r²/2σ²) (σ = radius/2) × :func:`normal_weight`, in ascending order of the
    neighbour."""
    if pairs.radius <= 0:
        return profiles.copy()
    out = np.empty_like(profiles, dtype=np.float64)
    _pool(vertices, normals, pairs.indptr, pairs.indices, float(pairs.radius), float(normal_power),
          np.ascontiguousarray(profiles, dtype=np.float64), out)
    return out


@dataclass
class Band:
    """Ions within ``reach`` of a mesh: which vertex each belongs to and its signed distance.

    Attributes
    ----------
    index : (b,) int64
        Rows of the ions in the band (into the :class:`NearIons` it came from).
    vertex : (b,) int64
        Nearest mesh vertex.
    distance : (b,) float64
        Signed distance (nm) along that vertex's normal; positive outside (below iso).
    """

    index: np.ndarray
    vertex: np.ndarray
    distance: np.ndarray


@dataclass
class NearIons:
    """The ions within ``radius`` nm of a mesh, their atoms and their nearest vertices, kept up to date.

    Select them once (:meth:`select`: one streamed pass over the ion table), take subsets of them
    (:meth:`subset`: the halves of the cross-fit by row parity, those within a smaller reach), and ask for a
    :class:`Band` after every move of the vertices (:meth:`band`): each ion's nearest vertex is found again by
    walking from its previous one (:func:`~apt_filters.refine.nearest.descend`), no KD-tree.
    The ions within ``reach`` of a moved mesh are all here while no face has moved more than
    ``radius - reach`` since it was covered; :meth:`cover` adds those of the faces that have (one streamed
    pass against those faces alone).

    Attributes
    ----------
    rows : (b,) int64
        Rows of these ions in the ion table: each selection's (:meth:`cover`'s) in the order of their nearest
        vertices then, within a vertex, of the table (cache locality: a table's rows need not be in spatial order).
    positions : (b, 3) float64
    atoms : IonAtoms
        Basis atoms of these ions.
    everything : IonAtoms
        Atoms of every ranged element (the segregants the basis leaves out too).
    vertex : (b,) int64
        Nearest vertex of each ion (as of the last :meth:`band`).
    radius : float, nm
    faces : (m, 3) int64
    covered : (m, 3, 3) float64
        Each face's corners when the ions within ``radius`` of it were last selected.
    indptr, indices : int64 arrays
        CSR vertex adjacency of the mesh (the walk's edges).
    second : (ptr, ring) int arrays
        The vertices' second rings (:func:`~apt_filters.refine.nearest.second_ring`), where a walk looks further.
    fan : Fan
        The faces around each vertex.
    source : (IonTable, RangeTable, ConcentrationBasis)
        Where the ions come from (for :meth:`cover`).
    parity : int
        0 or 1: only the even or odd rows of the table (the cross-fit's halves); -1: all.
    assigned : (n, 3) float64
        The vertices when ``vertex`` was last found.
    settled : bool
        Whether every ion's ``vertex`` is where a walk on ``assigned`` ended (not so for ions :meth:`cover` added
        after the mesh moved): a walk from it on the same vertices would not move, so :meth:`subset` on
        ``assigned`` itself keeps ``vertex`` without walking.
    """

    rows: np.ndarray
    positions: np.ndarray
    atoms: IonAtoms
    everything: IonAtoms
    vertex: np.ndarray
    radius: float
    faces: np.ndarray
    covered: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    second: tuple
    fan: "Fan"
    source: tuple
    parity: int = -1
    assigned: np.ndarray | None = None
    settled: bool = False

    @classmethod
    def select(cls, ions: IonTable, ranges: RangeTable, basis: ConcentrationBasis, vertices: np.ndarray,
               faces: np.ndarray, radius: float) -> "NearIons":
        """The ions whose nearest vertex lies within ``radius`` nm.

        Memory: one chunk of the positions at a time (``ions.positions`` may be memory-mapped),
        then 24 + 8 + 8 + 4 (k + K) bytes per selected ion (k basis elements of K).
        """
        adj = adjacency(faces, len(vertices))
        faces = np.asarray(faces, dtype=np.int64)
        empty = np.zeros(0, dtype=np.int64)
        everything = ion_atoms(IonTable(np.zeros((0, 3), np.float32), np.zeros(0, np.float32)), ranges,
                               ConcentrationBasis())
        out = cls(empty, np.zeros((0, 3)), basis_atoms(everything, basis), everything, empty, radius, faces,
                  np.full((len(faces), 3, 3), np.inf), adj.indptr.astype(np.int64), adj.indices.astype(np.int64),
                  second_ring(adj.indptr, adj.indices),
                  Fan.of(faces, len(vertices)),
                  (ions, ranges, basis))
        return out.cover(vertices, 0.0)

    def cover(self, vertices: np.ndarray, reach: float) -> "NearIons":
        """These ions, completed (in place) for ``reach`` nm around ``vertices`` (this mesh, moved): the ions
        within ``radius`` of the faces that moved more than ``radius - reach`` since they were covered are read
        from the table (one streamed pass, :func:`~apt_filters.core.nearby.select_near`, against those faces
        alone) and added, assigned to their nearest vertices."""
        corners = vertices[self.faces]
        moved = np.sqrt(((corners - self.covered) ** 2).sum(axis=2)).max(axis=1)
        slack = self.radius - reach
        if not np.any(moved > slack):
            return self
        # the faces halfway there are covered again too: one pass serves several iterations
        far = np.flatnonzero(moved > 0.5 * slack) if np.isfinite(moved).all() else np.arange(len(moved))
        ions, ranges, basis = self.source
        used, local = np.unique(self.faces[far], return_inverse=True)
        # only the rows not held yet (and of this half's parity) are searched exactly
        held = np.zeros(len(ions.positions), dtype=bool)
        held[self.rows] = True
        candidates = _near_cells(ions.positions, vertices[used], self.radius, held, self.parity)
        near = select_near(ions.positions[candidates], TriMesh(vertices[used], local.reshape(-1, 3)), self.radius)
        rows, positions = candidates[near.rows], near.positions
        # each walk to the nearest vertex starts at the nearest corner of the face holding the closest point
        start = _nearest_corner(positions, vertices, used[local.reshape(-1, 3)[near.face]])
        vertex, d2 = descend(positions, vertices, self.indptr, self.indices, start, EXACT, self.second)
        # kept in the order of their vertices: every later pass over them (bands, walks, profiles) then reads each
        # vertex's neighbourhood for a run of ions, not for ions scattered over the table
        keep = np.flatnonzero(d2 <= self.radius * self.radius)
        keep = keep[np.argsort(vertex[keep], kind="stable")]
        rows, positions, vertex = rows[keep], positions[keep], vertex[keep]
        everything = ion_atoms(IonTable(positions.astype(np.float32), ions.mz[rows]), ranges, ConcentrationBasis())
        self.rows = np.concatenate([self.rows, rows])
        self.positions = np.concatenate([self.positions, positions])
        self.everything = IonAtoms(everything.elements, np.concatenate([self.everything.atoms, everything.atoms]))
        self.atoms = basis_atoms(self.everything, basis)
        # the ions already here keep their assignment until the next band finds the mesh moved
        self.vertex = np.concatenate([self.vertex, vertex])
        # the new ions' walks ended on ``vertices``, the others' on ``assigned``
        self.settled = self.assigned is None or (self.settled and _same(vertices, self.assigned))
        self.assigned = vertices.copy() if self.assigned is None else self.assigned
        self.covered[far] = corners[far]
        return self

    def subset(self, keep: np.ndarray, vertices: np.ndarray, radius: float | None = None) -> "NearIons":
        """The ions ``keep`` (bool or indices) of these whose nearest vertex of ``vertices`` lies within ``radius``
        (default: the selection's), assigned to their nearest vertices: complete for ``radius`` around
        ``vertices`` where these are (:meth:`cover` them first)."""
        radius = self.radius if radius is None else radius
        keep = np.flatnonzero(keep) if keep.dtype == bool else keep
        if self.settled and _same(vertices, self.assigned):
            # every walk would stop where it starts (the walk's own distances, without the rings' search)
            vertex = self.vertex[keep]
            d2 = np.empty(len(keep))
            _vertex_d2(np.ascontiguousarray(self.positions[keep], dtype=np.float64), vertex, np.ascontiguousarray(vertices),
                       d2)
        else:
            vertex, d2 = descend(self.positions[keep], vertices, self.indptr, self.indices, self.vertex[keep], EXACT,
                                 self.second)
        inside = d2 <= radius * radius
        keep, vertex = keep[inside], vertex[inside]
        return NearIons(self.rows[keep], self.positions[keep], IonAtoms(self.atoms.elements, self.atoms.atoms[keep]),
                        IonAtoms(self.everything.elements, self.everything.atoms[keep]), vertex, radius, self.faces,
                        vertices[self.faces], self.indptr, self.indices, self.second, self.fan, self.source,
                        self.parity, vertices.copy(), True)

    def take(self, keep: np.ndarray) -> "NearIons":
        """The ions ``keep`` (indices) of these as they are: their nearest vertices and the mesh those were found on
        kept, so that later :meth:`band` calls give each of them what they would give it among all of these."""
        return replace(self, rows=self.rows[keep], positions=self.positions[keep],
                       atoms=IonAtoms(self.atoms.elements, self.atoms.atoms[keep]),
                       everything=IonAtoms(self.everything.elements, self.everything.atoms[keep]),
                       vertex=self.vertex[keep], covered=self.covered.copy(),
                       assigned=None if self.assigned is None else self.assigned.copy())

    def half(self, parity: int, vertices: np.ndarray) -> "NearIons":
        """The ions of these in the even (``parity`` 0) or odd (1) rows of the table (the cross-fit's halves),
        assigned to ``vertices``; later :meth:`cover` calls add only rows of that parity."""
        out = self.subset(self.rows % 2 == parity, vertices)
        out.parity = parity
        return out

    def band(self, vertices: np.ndarray, normals: np.ndarray, reach: float, distance: str = "mesh",
             shell: tuple[float, float] | None = None) -> Band:
        """The ions within ``reach`` nm of ``vertices`` (same mesh, moved), with signed distances.

        ``distance="mesh"``: each ion's signed distance to the faces around its nearest vertex
        (the mesh itself, :func:`_fan_offsets`; beyond :data:`EXACT` nm, where ions only count in
        the outer part of the plateau windows, their offset along the normal); ``"tangent"``: its offset along that vertex's
        normal, i.e. from the vertex's tangent plane. On a convex surface the tangent plane lies
        outside the faces (by ``rho * h / 2R`` at a lateral offset ``rho`` with edges ``h``, and
        by ``rho * sin(theta / 2)`` near an edge of dihedral ``theta``), so ``"tangent"`` sees
        the interface inside the mesh and pulls vertices inward: on a constructed 6 nm cube
        and 3 nm sphere free of noise and blur, -0.021 nm at cube edges, -0.033 nm at corners
        and -0.012 nm on spheres, besides the chord deficit of the faces.

        Nearest vertices are found again only once some vertex has moved more than
        :data:`REASSIGN` nm since they were last found (late iterations move by hundredths of a
        nm: the Voronoi patches of the vertices, ~0.4 nm across, barely change).

        ``shell=(lo, hi)`` (``distance="mesh"``), for a caller that only compares the distances beyond ``lo`` with
        ``lo`` and ``hi`` (profile bins within ``lo``, plateau windows between ``lo`` and ``hi``): an ion whose
        distance the planes of its fan's faces prove beyond ``lo`` (each face's plane is nearer than the face, and
        on the same side for every face: the side of the closest point's pseudo-normal), and within ``hi`` by its
        vertex or beyond ``hi`` by the planes, gets the nearest plane's signed distance instead of its own: the
        same side, and the same place relative to ``lo`` and ``hi``. Most of the ions a plateau window counts are
        spared the closest-point search.
        """
        return self._bands(vertices, normals, reach, distance, shell, False)[0]

    def bands(self, vertices: np.ndarray, normals: np.ndarray, reach: float, distance: str = "mesh",
              shell: tuple[float, float] | None = None) -> tuple[Band, Band]:
        """``(band(..., shell), band(...))`` of :meth:`band` in one pass over the ions: the planes' bounds and the
        closest-point search of each ion once (those the shell spares are searched for the second band alone)."""
        return self._bands(vertices, normals, reach, distance, shell, True)

    def _bands(self, vertices: np.ndarray, normals: np.ndarray, reach: float, distance: str,
               shell: tuple[float, float] | None, exact: bool) -> tuple[Band, Band | None]:
        """The band with ``shell``'s distances and, if ``exact``, the one with every ion's own (see :meth:`band`)."""
        if self.assigned is None or _largest_move(vertices, self.assigned) > REASSIGN:
            self.vertex, _ = descend(self.positions, vertices, self.indptr, self.indices, self.vertex, EXACT,
                                     self.second)
            self.assigned, self.settled = vertices.copy(), True
        n = len(self.vertex)
        d2, signed, spared = np.empty(n), np.empty(n), np.full(n if exact else 0, np.nan)
        if distance == "mesh":
            _fan_offsets(self.positions, self.vertex, vertices, normals, self.fan.indptr, self.fan.a, self.fan.b,
                         face_normals(vertices, self.faces)[self.fan.face], EXACT, reach * reach,
                         *(shell if shell is not None else (np.inf, np.inf)), d2, signed, spared)
        elif distance == "tangent":
            _offsets(self.positions, self.vertex, vertices, normals, d2, signed)
        else:
            raise ValueError(f"distance must be 'mesh' or 'tangent', got {distance!r}")
        keep = np.flatnonzero(d2 <= reach * reach)
        if not exact:
            return Band(keep, self.vertex[keep], signed[keep]), None
        shelled = np.where(np.isnan(spared), signed, spared)
        return Band(keep, self.vertex[keep], shelled[keep]), Band(keep, self.vertex[keep], signed[keep])


@njit(cache=True, nogil=True, parallel=True)
def _offsets(points, vertex, vertices, normals, d2, signed):
    for i in prange(points.shape[0]):
        v = vertex[i]
        dx, dy, dz = points[i, 0] - vertices[v, 0], points[i, 1] - vertices[v, 1], points[i, 2] - vertices[v, 2]
        d2[i] = dx * dx + dy * dy + dz * dz
        signed[i] = dx * normals[v, 0] + dy * normals[v, 1] + dz * normals[v, 2]


@dataclass
class Fan:
    """The faces around each vertex (CSR): ``a[k], b[k]`` for ``k`` in ``indptr[v]:indptr[v + 1]`` are the other
    two corners of a face of ``v`` in the face's winding order (``(v, a, b)`` has the outward normal), and
    ``face[k]`` that face."""

    indptr: np.ndarray
    a: np.ndarray
    b: np.ndarray
    face: np.ndarray

    @classmethod
    def of(cls, faces: np.ndarray, n_vertices: int) -> "Fan":
        indptr, order = topology(faces, n_vertices).vertex_corners
        a, b = np.roll(faces, -1, axis=1).T.ravel(), np.roll(faces, -2, axis=1).T.ravel()
        # a copy of the cache's read-only indptr: the kernels are compiled for writeable arrays
        return cls(indptr.copy(), a[order].astype(np.int64), b[order].astype(np.int64), order % max(len(faces), 1))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _closest_point(px, py, pz, qx, qy, qz, ax, ay, az, bx, by, bz):
    """Closest point to p on triangle (q, a, b) as (x, y, z, inner) (see :func:`closest_on_triangle`)."""
    _, u, w, inner = closest_on_triangle(px, py, pz, qx, qy, qz, ax, ay, az, bx, by, bz)
    return qx + u * (ax - qx) + w * (bx - qx), qy + u * (ay - qy) + w * (by - qy), qz + u * (az - qz) + w * (bz - qz), inner


@njit(cache=True, nogil=True, error_model="numpy")
def _face_normal(vertices, q, a, b):
    """Unit normal of the face (q, a, b) (q a point, a and b vertex indices) as (x, y, z); zeros if degenerate."""
    ux, uy, uz = vertices[a, 0] - q[0], vertices[a, 1] - q[1], vertices[a, 2] - q[2]
    wx, wy, wz = vertices[b, 0] - q[0], vertices[b, 1] - q[1], vertices[b, 2] - q[2]
    fx, fy, fz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    length = np.sqrt(fx * fx + fy * fy + fz * fz)
    if length == 0.0:
        return 0.0, 0.0, 0.0
    return fx / length, fy / length, fz / length


@njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def _fan_offsets(points, vertex, vertices, normals, fan_ptr, fan_a, fan_b, plane, exact, limit, lo, hi, d2, signed,
                 spared):
    """Signed distance of each point to the faces around its nearest vertex; the sign is that of the offset
    from the closest point along the pseudo-normal there (the face's normal inside a face, the sum of the
    unit normals of the fan faces sharing the point on an edge or corner). Points farther than ``exact``
    from the vertex's tangent plane keep their offset along its normal; points farther than ``sqrt(limit)`` from
    their vertex (left out of the band) get NaN. ``plane`` (k, 3): the unit normal of each fan face (zeros if
    degenerate), whose plane's distance bounds the face's from below. Points the planes prove beyond ``lo`` (on
    one side of every plane), and within ``hi`` of the vertex or beyond ``hi`` by the planes, get the nearest
    plane's signed distance (``NearIons.band``'s ``shell``; ``lo`` = inf: none). ``spared`` (n,) NaN on entry, or
    (0,): where given, those points get the nearest plane's distance there and their own in ``signed``
    (``NearIons.bands``)."""
    # relative margin of the shell's proofs, far above the rounding of the planes' and faces' distances
    tight = 1.0 + 1e-9
    n = points.shape[0]
    widest = 0
    for v in range(fan_ptr.shape[0] - 1):
        widest = max(widest, fan_ptr[v + 1] - fan_ptr[v])
    size = 4096
    for block in prange((n + size - 1) // size):
        # each fan face's closest point (NaN where its plane alone was too far), for the pseudo-normal's
        # search of the faces sharing the best one
        near = np.empty((widest, 3))
        for i in range(block * size, min(n, (block + 1) * size)):
            v = vertex[i]
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            q = vertices[v]
            d2[i] = (px - q[0]) ** 2 + (py - q[1]) ** 2 + (pz - q[2]) ** 2
            if d2[i] > limit:
                signed[i] = np.nan
                continue
            tangent = (px - q[0]) * normals[v, 0] + (py - q[1]) * normals[v, 1] + (pz - q[2]) * normals[v, 2]
            if abs(tangent) > exact:
                signed[i] = tangent
                continue
            first = fan_ptr[v]
            if lo < np.inf:
                # the distance to the fan is at least the nearest plane's, at most the vertex's
                lower, sides = np.inf, 0
                for k in range(first, fan_ptr[v + 1]):
                    h = (px - q[0]) * plane[k, 0] + (py - q[1]) * plane[k, 1] + (pz - q[2]) * plane[k, 2]
                    lower = min(lower, abs(h))
                    sides |= 1 if h > 0.0 else (2 if h < 0.0 else 3)
                if (sides == 1 or sides == 2) and lower > lo * tight and (d2[i] * tight <= hi * hi
                                                                          or lower > hi * tight):
                    if spared.shape[0] == 0:
                        signed[i] = lower if sides == 1 else -lower
                        continue
                    spared[i] = lower if sides == 1 else -lower
            best, bx_, by_, bz_, best_k, inner = np.inf, q[0], q[1], q[2], -1, False
            for k in range(first, fan_ptr[v + 1]):
                h = (px - q[0]) * plane[k, 0] + (py - q[1]) * plane[k, 1] + (pz - q[2]) * plane[k, 2]
                # farther than the best by a margin far above rounding: neither nearer nor sharing its closest
                # point (which would put it within 2e-6 of the best, relatively)
                if h * h > best * (1.0 + 1e-5) + 1e-18:
                    near[k - first, 0] = np.nan
                    continue
                a, b = fan_a[k], fan_b[k]
                cx, cy, cz, on_face = _closest_point(px, py, pz, q[0], q[1], q[2], vertices[a, 0], vertices[a, 1],
                                                     vertices[a, 2], vertices[b, 0], vertices[b, 1], vertices[b, 2])
                near[k - first, 0], near[k - first, 1], near[k - first, 2] = cx, cy, cz
                d = (px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2
                if d < best:
                    best, bx_, by_, bz_, best_k, inner = d, cx, cy, cz, k, on_face
            if best_k < 0:
                signed[i] = tangent
                continue
            if inner:
                nx, ny, nz = _face_normal(vertices, q, fan_a[best_k], fan_b[best_k])
            else:
                nx = ny = nz = 0.0
                tol = 1e-18 + 1e-12 * best
                for k in range(first, fan_ptr[v + 1]):
                    cx, cy, cz = near[k - first, 0], near[k - first, 1], near[k - first, 2]
                    if (cx - bx_) ** 2 + (cy - by_) ** 2 + (cz - bz_) ** 2 <= tol:
                        fx, fy, fz = _face_normal(vertices, q, fan_a[k], fan_b[k])
                        nx += fx
                        ny += fy
                        nz += fz
            side = (px - bx_) * nx + (py - by_) * ny + (pz - bz_) * nz
            signed[i] = np.sqrt(best) if side >= 0.0 else -np.sqrt(best)


@njit(cache=True, nogil=True)
def _in_cells(part, start, low, reach, shape, occupied, held, parity, out):
    """Rows ``start + i`` of the chunk ``part`` (k, 3) whose grid cell (see :func:`_near_cells`) is occupied and
    that are wanted (not ``held``, of the ``parity`` if >= 0), written to ``out``; returns how many."""
    n = 0
    for i in range(part.shape[0]):
        row = start + i
        if held[row] or (parity >= 0 and row % 2 != parity):
            continue
        # the same arithmetic as numpy's floor((p - low) / reach) + 1, clipped to the padded grid
        cx = min(max(np.int64(np.floor((np.float64(part[i, 0]) - low[0]) / reach)) + 1, 0), shape[0] + 1)
        cy = min(max(np.int64(np.floor((np.float64(part[i, 1]) - low[1]) / reach)) + 1, 0), shape[1] + 1)
        cz = min(max(np.int64(np.floor((np.float64(part[i, 2]) - low[2]) / reach)) + 1, 0), shape[2] + 1)
        if occupied[cx, cy, cz]:
            out[n] = row
            n += 1
    return n


def _near_cells(positions: np.ndarray, points: np.ndarray, reach: float, held: np.ndarray | None = None,
                parity: int = -1, chunk: int = 1 << 21) -> np.ndarray:
    """(c,) int64 rows of ``positions`` (N, 3; may be memory-mapped, read ``chunk`` rows at a time) that lie in
    a grid cell (edge ``reach``) within one cell of a cell holding one of ``points`` (n, 3): every row within
    ``reach`` of the points is among them. A coarse filter in front of the exact distance: one compiled pass
    instead of the search's ordering of the whole table. Rows ``held`` (N,) bool, and with ``parity`` 0 or 1
    the rows of the other parity, are left out (they would be dropped after the exact search)."""
    if not len(points) or not len(positions):
        return np.zeros(0, dtype=np.int64)
    low = points.min(axis=0) - 1.5 * reach
    shape = np.floor((points.max(axis=0) + 1.5 * reach - low) / reach).astype(np.int64) + 1
    occupied = np.zeros(shape + 2, dtype=bool)
    cell = np.floor((points - low) / reach).astype(np.int64) + 1
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                occupied[cell[:, 0] + dx, cell[:, 1] + dy, cell[:, 2] + dz] = True
    held = np.zeros(len(positions), dtype=bool) if held is None else held
    out, buffer = [], np.empty(min(chunk, len(positions)), dtype=np.int64)
    for start in range(0, len(positions), chunk):
        part = np.asarray(positions[start:start + chunk])
        n = _in_cells(part, start, low.astype(np.float64), float(reach), shape, occupied, held, int(parity), buffer)
        out.append(buffer[:n].copy())
    return np.concatenate(out)


@njit(cache=True, nogil=True, parallel=True)
def _nearest_corners(points, vertices, ring, out):
    for i in prange(points.shape[0]):
        best, out[i] = np.inf, ring[i, 0]
        for k in range(3):
            v = ring[i, k]
            d = (vertices[v, 0] - points[i, 0]) ** 2 + (vertices[v, 1] - points[i, 1]) ** 2 + (
                vertices[v, 2] - points[i, 2]) ** 2
            if d < best:  # the first of equals, as argmin
                best, out[i] = d, v


def _nearest_corner(points: np.ndarray, vertices: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """(m,) int64: of each point's three vertices ``ring`` (m, 3), the nearest to it (points (m, 3) and vertices
    float64, nm), the first of equals; the squared distances summed x, y, z in turn, as numpy's
    ``argmin(((vertices[ring] - points[:, None]) ** 2).sum(axis=2), axis=1)`` sums them (the same vertex bit for
    bit, without its (m, 3, 3) temporaries)."""
    out = np.empty(len(points), dtype=np.int64)
    _nearest_corners(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(vertices, dtype=np.float64),
                     np.ascontiguousarray(ring, dtype=np.int64), out)
    return out


@njit(cache=True, nogil=True, parallel=True)
def _vertex_d2(points, vertex, vertices, d2):
    """Squared distance of each point to its vertex, summed as :func:`~apt_filters.refine.nearest.descend` sums it."""
    for i in prange(points.shape[0]):
        v = vertex[i]
        d2[i] = (vertices[v, 0] - points[i, 0]) ** 2 + (vertices[v, 1] - points[i, 1]) ** 2 + (
            vertices[v, 2] - points[i, 2]) ** 2


def profile_reach(vertices: np.ndarray, faces: np.ndarray, half_width: float) -> float:
    """nm from its nearest vertex within which every ion lies whose :meth:`NearIons.band` distance (``"mesh"``) is
    under ``half_width`` (at most :data:`EXACT`): ``half_width`` plus the mesh's longest edge.

    An ion's distance to the faces around its vertex ``v`` is its distance to their closest point ``c``, and ``c``
    lies within the fan's longest edge of ``v`` (the distance to ``v`` is convex over a face, largest at a corner),
    so the ion lies within that distance plus the edge of ``v``; an ion farther than :data:`EXACT` from the vertex's
    tangent plane, which keeps its offset along the normal, and one the shell spares (beyond its ``lo``) lie beyond
    ``half_width`` anyway. A band at this reach holds every ion of one at a larger reach whose distance is under
    ``half_width``, with the same distance, in the same order. The margin is far above the rounding of the squared
    distances."""
    if half_width > EXACT:
        raise ValueError(f"half_width {half_width:g} nm beyond EXACT ({EXACT:g} nm): tangent offsets are not bounded")
    corners = vertices[faces]
    edge = np.sqrt(np.max(((corners - np.roll(corners, 1, axis=1)) ** 2).sum(axis=2), initial=0.0))
    return (half_width + edge) * (1.0 + 1e-9) + 1e-9


def _same(vertices: np.ndarray, other: np.ndarray | None) -> bool:
    """Whether two vertex arrays are the same bit for bit."""
    if other is None or vertices.shape != other.shape or vertices.dtype != np.float64 or other.dtype != np.float64:
        return False
    return bool(np.array_equal(np.ascontiguousarray(vertices).view(np.uint64),
                               np.ascontiguousarray(other).view(np.uint64)))


def _largest_move(vertices: np.ndarray, before: np.ndarray) -> float:
    return float(np.sqrt(np.max(np.sum((vertices - before) ** 2, axis=1)))) if len(vertices) else 0.0


def binned(vertex: np.ndarray, distance: np.ndarray, weights: tuple[np.ndarray, ...], n_vertices: int,
           half_width: float, bin_width: float) -> list[np.ndarray]:
    """For each of ``weights`` (b,): the (n_vertices, n_bins) sum of it per vertex and distance bin over
    [-half_width, half_width) (bin ``floor((distance + half_width) / bin_width)``), each bin summed in the order of
    the ions, as ``np.bincount`` sums it."""
    n_bins = int(round(2 * half_width / bin_width))
    out = np.zeros((len(weights), n_vertices * n_bins))
    _binned(np.ascontiguousarray(vertex, dtype=np.int64), np.ascontiguousarray(distance, dtype=np.float64),
            np.ascontiguousarray(np.stack(weights) if weights else np.zeros((0, len(vertex))), dtype=np.float64),
            float(half_width), float(bin_width), n_bins, out)
    return [row.reshape(n_vertices, n_bins) for row in out]


@njit(cache=True, nogil=True)
def _binned(vertex, distance, weights, half_width, bin_width, n_bins, out):
    """:func:`binned`'s sums: one pass over the ions for every weight (``weights`` (w, b), ``out`` (w, n * n_bins))."""
    for i in range(vertex.shape[0]):
        b = np.int64(np.floor((distance[i] + half_width) / bin_width))
        if b < 0 or b >= n_bins:
            continue
        key = vertex[i] * n_bins + b
        for w in range(weights.shape[0]):
            out[w, key] += weights[w, i]
