"""Ions near a mesh without a KD-tree: a cell grid pre-filter and nearest-vertex descent on the mesh.

Refinement needs, for every ion within a few nm of an iso-surface, its nearest mesh vertex, and
it needs it again after every move of the vertices. A KD-tree query costs ~2-5 µs per ion (10^7
ions: minutes per iteration); here

- :class:`CellGrid` rasterises the vertices into cells of ``cell`` nm over the mesh's bounding
  box grown by the reach, and a Euclidean distance transform gives every cell its distance to
  the nearest cell holding a vertex, and one vertex of that cell (the *seed*);
- :func:`band_indices` keeps, chunk by chunk, the ions whose cell lies within reach (a lower
  bound of their distance to the mesh: no ion within reach is lost), so that a memory-mapped
  table of 10^8-10^9 ions is read once, in bounded memory, and only the band is held;
- :func:`descend` finds each ion's nearest vertex by walking the mesh's edges from a start
  vertex (the seed of its cell, or its previous nearest vertex when the mesh has moved) to the
  neighbour closest to the ion, until no neighbour is closer (numba, O(steps × degree) per ion).

A 1-ring walk stops at a local minimum on marching-cubes slivers for ~5 % of the ions; where it
stops within ``exact`` nm the 2-ring is searched as well, which leaves < 1 % of the ions within
1.5 nm on a vertex other than the nearest, on average 0.0004 nm farther (tests/test_refine_nearest.py;
on the 10M-ion ``many`` specimen: 1.0 % within 1.5 nm). Farther ions, which only count in the
plateaus, keep the 1-ring minimum.

Peak memory: the grid, 8 bytes per cell kept (cells of 1 nm over the mesh's bounding box grown
by the reach) and ~40 bytes per cell while the distance transform runs; per chunk ``chunk`` × ~30
bytes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy import ndimage

CHUNK = 1 << 21


@dataclass
class CellGrid:
    """Cells of ``cell`` nm around a mesh: distance to the mesh's nearest occupied cell and a seed vertex.

    Attributes
    ----------
    origin : (3,) float64
        Corner of cell (0, 0, 0), nm.
    cell : float
        Cell edge, nm.
    distance : (nx, ny, nz) float32
        Distance (nm) from each cell's centre to the nearest centre of a cell holding a vertex.
    seed : (nx, ny, nz) int32
        A vertex of that nearest occupied cell.
    """

    origin: np.ndarray
    cell: float
    distance: np.ndarray
    seed: np.ndarray

    @classmethod
    def around(cls, vertices: np.ndarray, reach: float, cell: float = 1.0) -> "CellGrid":
        """The grid over the bounding box of ``vertices`` (n, 3) grown by ``reach`` + one cell."""
        origin = vertices.min(axis=0) - reach - cell
        shape = tuple(np.floor((vertices.max(axis=0) + reach + cell - origin) / cell).astype(np.int64) + 1)
        ijk = np.floor((vertices - origin) / cell).astype(np.int64)
        flat = np.ravel_multi_index(ijk.T, shape)
        owner = np.full(int(np.prod(shape)), -1, dtype=np.int32)
        owner[flat] = np.arange(len(vertices), dtype=np.int32)
        owner = owner.reshape(shape)
        distance, index = ndimage.distance_transform_edt(owner < 0, sampling=cell, return_indices=True)
        return cls(origin, float(cell), distance.astype(np.float32), owner[tuple(index)])

    def cells(self, points: np.ndarray) -> np.ndarray:
        """(m,) flat cell of each point (m, 3) nm; -1 outside the grid."""
        out = np.empty(len(points), dtype=np.int64)
        _cells(np.asarray(points), self.origin, self.cell, np.array(self.distance.shape, dtype=np.int64), out)
        return out

    def within(self, points: np.ndarray, reach: float) -> np.ndarray:
        """(m,) bool: points (m, 3) that may lie within ``reach`` nm of a vertex (never misses one that does)."""
        flat = self.cells(points)
        # ion to its cell centre and vertex to its cell centre: each at most half a cell diagonal
        return (flat >= 0) & (self.distance.reshape(-1)[np.maximum(flat, 0)] <= reach + self.cell * np.sqrt(3.0))


def band_indices(positions: np.ndarray, grid: CellGrid, reach: float, chunk: int = CHUNK) -> np.ndarray:
    """(b,) int64 rows of ``positions`` (N, 3), read ``chunk`` rows at a time, that may lie within ``reach``.

    ``positions`` may be a memory map: only one chunk is in memory at a time, besides the result.
    """
    parts = [start + np.flatnonzero(grid.within(positions[start:start + chunk], reach))
             for start in range(0, len(positions), chunk)]
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


@njit(cache=True, nogil=True)
def _closer(x, y, z, vertices, indptr, indices, v, best):
    """The vertex among ``v``'s neighbours and their neighbours nearest to (x, y, z) if nearer than ``best``."""
    found, found_d = -1, best
    for k in range(indptr[v], indptr[v + 1]):
        w = indices[k]
        for l in range(indptr[w], indptr[w + 1]):
            u = indices[l]
            d = (vertices[u, 0] - x) ** 2 + (vertices[u, 1] - y) ** 2 + (vertices[u, 2] - z) ** 2
            if d < found_d:
                found, found_d = u, d
    return found, found_d


@njit(cache=True, nogil=True, parallel=True)
def _descend(points, vertices, indptr, indices, start, exact2, out, out_d2):
    for i in prange(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        v = start[i]
        best = (vertices[v, 0] - x) ** 2 + (vertices[v, 1] - y) ** 2 + (vertices[v, 2] - z) ** 2
        while True:
            moved = False
            for k in range(indptr[v], indptr[v + 1]):
                w = indices[k]
                d = (vertices[w, 0] - x) ** 2 + (vertices[w, 1] - y) ** 2 + (vertices[w, 2] - z) ** 2
                if d < best:
                    best, v, moved = d, w, True
            if not moved:
                if best > exact2:
                    break
                # a local minimum over the 1-ring (sliver triangles): look one ring further
                w, d = _closer(x, y, z, vertices, indptr, indices, v, best)
                if w < 0:
                    break
                best, v = d, w
        out[i] = v
        out_d2[i] = best


@njit(cache=True, nogil=True)
def _cells(points, origin, cell, shape, out):
    for i in range(points.shape[0]):
        flat = 0
        for a in range(3):
            c = int(np.floor((points[i, a] - origin[a]) / cell))
            if c < 0 or c >= shape[a]:
                flat = -1
                break
            flat = flat * shape[a] + c
        out[i] = flat


def descend(points: np.ndarray, vertices: np.ndarray, indptr: np.ndarray, indices: np.ndarray,
            start: np.ndarray, exact: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Nearest vertex of each point (m, 3), walking the mesh's edges from ``start`` (m,).

    ``indptr``, ``indices``: the CSR vertex adjacency (:func:`~apt_filters.refine.band.adjacency`).
    Where the walk stops within ``exact`` nm, the 2-ring is searched as well (it steps over
    sliver triangles, which trap a 1-ring walk for ~5% of the ions); farther points keep the
    1-ring minimum. Returns the (m,) int64 vertices and (m,) float64 squared distances (nm²).
    """
    out, d2 = np.empty(len(points), dtype=np.int64), np.empty(len(points))
    _descend(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(vertices, dtype=np.float64),
             indptr.astype(np.int64), indices.astype(np.int64), start.astype(np.int64), exact * exact, out, d2)
    return out, d2
