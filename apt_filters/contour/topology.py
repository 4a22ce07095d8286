"""Edge adjacency and fold detection on indexed triangle meshes."""

from __future__ import annotations

import numpy as np


def face_pairs(faces: np.ndarray) -> np.ndarray:
    """(k, 2) pairs of faces that share an edge used by exactly two faces."""
    m = len(faces)
    a, b = faces.reshape(-1), np.roll(faces, -1, axis=1).reshape(-1)
    key = np.minimum(a, b) * (int(faces.max()) + 1) + np.maximum(a, b)  # 1-D keys sort fast
    owner = np.repeat(np.arange(m), 3)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    two = counts[inverse] == 2
    order = np.argsort(inverse[two], kind="stable")
    return owner[two][order].reshape(-1, 2)


def unit_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def folded_pairs(vertices: np.ndarray, faces: np.ndarray, max_angle_deg: float = 120.0) -> np.ndarray:
    """(k, 2) edge-adjacent face pairs whose normals differ by more than ``max_angle_deg``.

    A fold is a triangle flipped against its neighbour; the default of 120° is beyond any
    dihedral the benchmark shapes have (their sharpest edges are 90°).
    """
    pairs = face_pairs(faces)
    n = unit_normals(vertices, faces)
    dots = np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]])
    return pairs[dots < np.cos(np.radians(max_angle_deg))]


def self_intersecting_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces that cross another face (pymeshlab, imported on first use).

    pymeshlab's test has absolute tolerances: call it on world coordinates (nm), as the
    metrics do.
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces.astype(np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return ms.current_mesh().face_selection_array().astype(bool)
