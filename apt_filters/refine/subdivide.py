"""Midpoint subdivision: more vertices, so that a refined surface can bend at sharp edges."""

from __future__ import annotations

import numpy as np

from apt_filters.core.mesh import TriMesh


def subdivide(mesh: TriMesh) -> TriMesh:
    """Each triangle split into four at its edge midpoints (shape unchanged; shared edges split once).

    Vertex scalars are interpolated linearly; face scalars are repeated for the four children.
    """
    f = mesh.faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    mid = mesh.n_vertices + inverse.reshape(3, -1).T  # (m, 3): midpoints of edges 01, 12, 20
    vertices = np.concatenate([mesh.vertices, mesh.vertices[unique].mean(axis=1)])
    a, b, c = f[:, 0], f[:, 1], f[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    faces = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    scalars = {k: np.concatenate([v, v[unique].mean(axis=1)]) for k, v in mesh.vertex_scalars.items()}
    face_scalars = {k: np.tile(v, 4) for k, v in mesh.face_scalars.items()}
    return TriMesh(vertices, faces, scalars, face_scalars)
