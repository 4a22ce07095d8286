"""Compiled union-find over a triangle list: face components of a mesh without an edge table.

Kept apart from :mod:`apt_filters.core.mesh` so that importing the mesh type does not load numba
(the CLI reports mistakes before any heavy library loads).
"""

import numpy as np
from numba import njit


@njit(inline="always")
def _root(parent, v):
    while parent[v] != v:
        parent[v] = parent[parent[v]]  # path halving
        v = parent[v]
    return v


@njit(nogil=True, cache=True)
def face_components(faces, parent):
    """Connected components of faces sharing a vertex, numbered in the order of each one's first face.

    Union-find over the vertices: ``parent`` (n,) is ``arange(n)`` on entry (int32 where it fits,
    half the memory traffic of int64); a root is the lowest vertex of its set, so every vertex
    points below itself and one forward pass flattens all trees before the faces are labelled.

    Returns
    -------
    components : (m,) int64
    n_components : int
    """
    n_vertices = parent.shape[0]
    for f in range(faces.shape[0]):
        for j in range(3):
            if faces[f, j] < 0 or faces[f, j] >= n_vertices:
                raise ValueError("a face uses a vertex index outside the mesh")
    for f in range(faces.shape[0]):
        r0 = _root(parent, faces[f, 0])
        for j in range(1, 3):
            r = _root(parent, faces[f, j])
            if r != r0:
                if r < r0:
                    r, r0 = r0, r
                parent[r] = r0
    for v in range(n_vertices):
        parent[v] = parent[parent[v]]
    label = np.full(n_vertices, -1, dtype=parent.dtype)
    components = np.empty(faces.shape[0], dtype=np.int64)
    n = 0
    for f in range(faces.shape[0]):
        r = parent[faces[f, 0]]
        if label[r] < 0:
            label[r] = n
            n += 1
        components[f] = label[r]
    return components, n
