"""Closest points on a mesh found by walking across its faces from a face or vertex known to be near.

The remesher asks for closest points of points that are already near a known place of the mesh:
the samples of a Voronoi cell near the cell's vertex, a relaxed vertex near the face it was on one
step before. A walk from there (the closest face of a start ring, then across edges while a
neighbour comes strictly closer) costs a few triangle tests per point, where a grid search
(:class:`apt_filters.core.distance.SurfaceDistance`) needs the grid built and tens of cells visited.
The walk is a local search: it stops where no edge-neighbour of its face is closer, which is not
always the closest face (where the closest point of its face is a corner, a face round that corner
but not across an edge can be closer: 4 % of points 0.05-0.2 nm off a marching-cubes sphere,
walked from their nearest vertex). Its distance is thus an upper bound of the true one: exact
enough for the centring's least-squares step and the relaxation's projections (both are followed
by the exact check), and only a bound where exactness matters (:func:`apt_filters.remesh.verify.farthest`
searches exactly where a bound could hide the farthest point).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from apt_filters.core.triangle import closest_on_triangle


def face_neighbours(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(f, 3) int64 face across half-edge k (corner k to k + 1) of every face, -1 on a boundary."""
    from apt_filters.core.mesh import Topology

    top = Topology.of(faces, n_vertices)
    pair = top.edge_pairs()[top.face_edge]  # (f, 3, 2)
    own = np.arange(len(faces))[:, None]
    return np.ascontiguousarray(np.where(pair[..., 0] == own, pair[..., 1], pair[..., 0]))


def vertex_rings(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """The faces round every vertex as CSR: (v + 1,) start and (3f,) face ids, in increasing face id."""
    return _vertex_rings(np.ascontiguousarray(faces, np.int64), n_vertices)


@njit(cache=True, nogil=True)
def _vertex_rings(faces, n_vertices):
    """:func:`vertex_rings` by a counting sort: no (3f,) temporaries besides the result."""
    start = np.zeros(n_vertices + 1, np.int64)
    for f in range(len(faces)):
        for k in range(3):
            start[faces[f, k] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    ring = np.empty(3 * len(faces), np.int64)
    for f in range(len(faces)):
        for k in range(3):
            v = faces[f, k]
            ring[fill[v]] = f
            fill[v] += 1
    return start, ring


@njit(cache=True, nogil=True)
def walk_closest(vertices, faces, neighbour, ring_start, ring, start, points):
    """Closest point of every point (n, 3) on the faces reached by walking from ring ``start[i]``
    (faces ``ring[ring_start[s]:ring_start[s + 1]]``, e.g. :func:`vertex_rings`; one face per ring:
    ``ring_start = arange(f + 1)``, ``ring = arange(f)``): the closest face of the ring, then across
    edges (``neighbour`` (f, 3), -1: none, :func:`face_neighbours`) while a neighbour is strictly
    closer. Returns faces (n,), barycentric weights (n, 3) and the closest points (n, 3)."""
    n = len(points)
    face = np.empty(n, np.int64)
    bary = np.empty((n, 3))
    near = np.empty((n, 3))
    for i in range(n):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best, bf, bu, bw = np.inf, -1, 0.0, 0.0
        v = start[i]
        for r in range(ring_start[v], ring_start[v + 1]):
            f = ring[r]
            d, u, w = _to_face(vertices, faces, f, px, py, pz)
            if d < best:
                best, bf, bu, bw = d, f, u, w
        for _ in range(len(faces)):  # strictly closer each step: never a face twice
            nf = -1
            for k in range(3):
                g = neighbour[bf, k]
                if g >= 0:
                    d, u, w = _to_face(vertices, faces, g, px, py, pz)
                    if d < best:
                        best, nf, bu, bw = d, g, u, w
            if nf < 0:
                break
            bf = nf
        face[i] = bf
        bary[i, 0], bary[i, 1], bary[i, 2] = 1.0 - bu - bw, bu, bw
        a, b, c = faces[bf, 0], faces[bf, 1], faces[bf, 2]
        for k in range(3):
            near[i, k] = (vertices[a, k] + bu * (vertices[b, k] - vertices[a, k])
                          + bw * (vertices[c, k] - vertices[a, k]))
    return face, bary, near


@njit(cache=True, nogil=True, inline="always")
def _to_face(vertices, faces, f, px, py, pz):
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    d, u, w, _ = closest_on_triangle(px, py, pz, vertices[a, 0], vertices[a, 1], vertices[a, 2], vertices[b, 0],
                                     vertices[b, 1], vertices[b, 2], vertices[c, 0], vertices[c, 1], vertices[c, 2])
    return d, u, w
