"""Each ion's nearest mesh vertex, followed as the mesh moves, by walking the mesh's edges.

Refinement needs, for every ion within a few nm of an iso-surface, its nearest mesh vertex, and
it needs it again after every move of the vertices. A KD-tree query costs ~2-5 µs per ion (10^7
ions: minutes per iteration); :func:`descend` instead walks from a start vertex (the nearest
corner of the face holding the ion's closest point when the ions are selected,
:func:`apt_filters.core.nearby.select_near`; its previous nearest vertex when the mesh has moved)
to the neighbour closest to the ion, until no neighbour is closer (numba, O(steps × degree) per ion).

A 1-ring walk stops at a local minimum on marching-cubes slivers for a few % of the ions; where
it stops within ``exact`` nm the 2-ring is searched as well, which leaves < 1 % of the ions within
1.5 nm on a vertex other than the nearest (tests/test_refine_nearest.py). Farther ions, which only
count in the plateaus, keep the 1-ring minimum.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True)
def _closer(x, y, z, vertices, ptr2, ring2, v, best):
    """The vertex of ``v``'s second ring nearest to (x, y, z) if nearer than ``best``."""
    found, found_d = -1, best
    for k in range(ptr2[v], ptr2[v + 1]):
        u = ring2[k]
        d = (vertices[u, 0] - x) ** 2 + (vertices[u, 1] - y) ** 2 + (vertices[u, 2] - z) ** 2
        if d < found_d:
            found, found_d = u, d
    return found, found_d


@njit(cache=True, nogil=True)
def _second_ring(indptr, indices):
    n = indptr.shape[0] - 1
    mark = np.full(n, -1, np.int64)
    counts = np.zeros(n + 1, np.int64)
    for sweep in range(2):
        if sweep == 1:
            for v in range(n):
                counts[v + 1] += counts[v]
            out = np.empty(counts[n], np.int64)
            fill = counts[:n].copy()
            mark[:] = -1
        for v in range(n):
            mark[v] = v
            for k in range(indptr[v], indptr[v + 1]):
                mark[indices[k]] = v
            for k in range(indptr[v], indptr[v + 1]):
                w = indices[k]
                for l in range(indptr[w], indptr[w + 1]):
                    u = indices[l]
                    if mark[u] != v:
                        mark[u] = v
                        if sweep == 0:
                            counts[v + 1] += 1
                        else:
                            out[fill[v]] = u
                            fill[v] += 1
    return counts, out


def second_ring(indptr: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR (ptr, ring) of each vertex's neighbours' neighbours that are neither it nor its neighbours, in the
    order a walk over its neighbours' rows meets them first (``indptr``, ``indices``: the vertex adjacency)."""
    return _second_ring(indptr.astype(np.int64), indices.astype(np.int64))


@njit(cache=True, nogil=True, parallel=True)
def _descend(points, vertices, indptr, indices, ptr2, ring2, start, exact2, out, out_d2):
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
                # a local minimum over the 1-ring (sliver triangles): look one ring further (the 1-ring and v
                # itself are no nearer)
                w, d = _closer(x, y, z, vertices, ptr2, ring2, v, best)
                if w < 0:
                    break
                best, v = d, w
        out[i] = v
        out_d2[i] = best


def descend(points: np.ndarray, vertices: np.ndarray, indptr: np.ndarray, indices: np.ndarray,
            start: np.ndarray, exact: float = np.inf,
            second: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Nearest vertex of each point (m, 3), walking the mesh's edges from ``start`` (m,).

    ``indptr``, ``indices``: the CSR vertex adjacency (:func:`~apt_filters.refine.band.adjacency`).
    Where the walk stops within ``exact`` nm, the 2-ring is searched as well (it steps over
    sliver triangles, which trap a 1-ring walk for ~5% of the ions); farther points keep the
    1-ring minimum. ``second``: :func:`second_ring` of the adjacency, if kept from an earlier call.
    Returns the (m,) int64 vertices and (m,) float64 squared distances (nm²).
    """
    ptr2, ring2 = second_ring(indptr, indices) if second is None else second
    out, d2 = np.empty(len(points), dtype=np.int64), np.empty(len(points))
    # as they are where they are int64 already (no copy of the ions' start vertices on every walk)
    _descend(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(vertices, dtype=np.float64),
             np.asarray(indptr, dtype=np.int64), np.asarray(indices, dtype=np.int64), ptr2, ring2,
             np.asarray(start, dtype=np.int64), exact * exact, out, d2)
    return out, d2
