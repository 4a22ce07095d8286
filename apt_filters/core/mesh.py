"""The one triangle-mesh type that flows between pipeline steps."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np


@dataclass
class TriMesh:
    """An indexed triangle mesh in world coordinates.

    Attributes
    ----------
    vertices : (n, 3) float64
        Vertex positions in nm, columns x, y, z.
    faces : (m, 3) int64
        Vertex indices per triangle. Counter-clockwise seen from outside: the normal
        ``cross(v1 - v0, v2 - v0)`` points out of the region above the iso-value.
    vertex_scalars : dict[str, (n,) float64]
        Named per-vertex values (``"value"`` = the interpolated field, concentrations, ...).
    face_scalars : dict[str, (m,) array]
        Named per-face values (``"object_id"``, ...).

    A ``TriMesh`` unpacks as ``vertices, faces = mesh``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_scalars: dict[str, np.ndarray] = field(default_factory=dict)
    face_scalars: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        for name, values in self.vertex_scalars.items():
            if len(values) != len(self.vertices):
                raise ValueError(f"vertex scalar {name!r} has {len(values)} values for {len(self.vertices)} vertices")
        for name, values in self.face_scalars.items():
            if len(values) != len(self.faces):
                raise ValueError(f"face scalar {name!r} has {len(values)} values for {len(self.faces)} faces")

    def __iter__(self) -> Iterator[np.ndarray]:
        yield self.vertices
        yield self.faces

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def face_normals(self, normalize: bool = True) -> np.ndarray:
        """(m, 3) face normals; with ``normalize=False`` their length is twice the face area."""
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        if normalize:
            length = np.linalg.norm(n, axis=1, keepdims=True)
            n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        return n

    def face_areas(self) -> np.ndarray:
        """(m,) triangle areas in nm²."""
        return 0.5 * np.linalg.norm(self.face_normals(normalize=False), axis=1)

    def area(self) -> float:
        """Total surface area in nm²."""
        return float(self.face_areas().sum())

    def signed_volume(self) -> float:
        """Signed enclosed volume in nm³ (divergence theorem); positive for outward normals.

        Only meaningful for closed meshes.
        """
        v = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)

    def edges(self) -> np.ndarray:
        """(3m, 2) directed half-edges (v_i, v_{i+1}) of every face."""
        f = self.faces
        return np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)

    def boundary_edges(self) -> np.ndarray:
        """(k, 2) undirected edges used by exactly one face (the open boundary)."""
        e = np.sort(self.edges(), axis=1)
        uniq, counts = np.unique(e, axis=0, return_counts=True)
        return uniq[counts == 1]

    def non_manifold_edge_count(self) -> int:
        """Number of undirected edges shared by more than two faces."""
        e = np.sort(self.edges(), axis=1)
        _, counts = np.unique(e, axis=0, return_counts=True)
        return int((counts > 2).sum())

    def face_components(self) -> np.ndarray:
        """(m,) int64 connected component of each face (shared vertices), numbered in order of
        each component's first face, so the numbering is deterministic."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        if self.n_faces == 0:
            return np.zeros(0, dtype=np.int64)
        f = self.faces
        rows = np.concatenate([f[:, 0], f[:, 1]])
        cols = np.concatenate([f[:, 1], f[:, 2]])
        graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(self.n_vertices,) * 2)
        _, vertex_label = connected_components(graph, directed=False)
        face_label = vertex_label[f[:, 0]]
        uniq, first, inverse = np.unique(face_label, return_index=True, return_inverse=True)
        rank = np.empty(len(uniq), dtype=np.int64)
        rank[np.argsort(first)] = np.arange(len(uniq))
        return rank[inverse.ravel()]

    def copy(self) -> "TriMesh":
        return TriMesh(self.vertices.copy(), self.faces.copy(),
                       {k: v.copy() for k, v in self.vertex_scalars.items()},
                       {k: v.copy() for k, v in self.face_scalars.items()})
