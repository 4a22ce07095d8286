"""The one triangle-mesh type that flows between pipeline steps, and its topology (built once per mesh)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import weakref

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
        return face_normals(self.vertices, self.faces, normalize)

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

    @property
    def topology(self) -> "Topology":
        """Edges, face pairs, components and boundary of the faces (:func:`topology`, cached on ``faces``)."""
        return topology(self.faces, self.n_vertices)

    def vertex_normals(self) -> np.ndarray:
        """(n, 3) unit area-weighted vertex normals (:func:`vertex_normals`)."""
        return vertex_normals(self.vertices, self.faces)

    def edges(self) -> np.ndarray:
        """(3m, 2) directed half-edges (v_i, v_{i+1}) of every face."""
        f = self.faces
        return np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)

    def boundary_edges(self) -> np.ndarray:
        """(k, 2) undirected edges used by exactly one face (the open boundary), sorted."""
        t = self.topology
        return t.edge_vertices[t.edge_faces == 1]

    def non_manifold_edge_count(self) -> int:
        """Number of undirected edges shared by more than two faces."""
        return int((self.topology.edge_faces > 2).sum())

    def face_components(self) -> np.ndarray:
        """(m,) int64 connected component of each face (:attr:`Topology.components`), a copy."""
        return self.topology.components.copy()

    def copy(self) -> "TriMesh":
        return TriMesh(self.vertices.copy(), self.faces.copy(),
                       {k: v.copy() for k, v in self.vertex_scalars.items()},
                       {k: v.copy() for k, v in self.face_scalars.items()})


@dataclass(frozen=True)
class Topology:
    """Connectivity of a triangle mesh, derived from its faces alone.

    Attributes
    ----------
    edge_vertices : (e, 2) int64
        Vertex pair (lower index first) of each undirected edge, edges sorted by that pair.
    face_edge : (m, 3) int64
        Edge of half-edge ``(f[k], f[(k + 1) % 3])`` of each face.
    edge_faces : (e,) int64
        Faces using each edge: 1 on the open boundary, 2 inside a manifold, more where it is
        non-manifold.
    face_pairs : (p, 2) int64
        The two faces of each edge used by exactly two faces, in edge order (lower face first).
    components : (m,) int64
        Connected component of each face (faces sharing a vertex), numbered in the order of
        each component's first face: the one numbering every step uses.
    vertex_components : (n,) int64
        The component of each vertex, -1 for vertices no face uses.
    n_components : int
    boundary_vertex : (n,) bool
        Vertices on a boundary edge.
    closed_component : (c,) bool
        Components without a boundary edge.
    boundary_loops : int
        Closed loops of boundary edges (holes and open rims), counted as cycles of the boundary
        graph: ``E_b - V_b + C_b`` per its connected pieces (1 per simple loop).
    genus : int
        Sum over components of ``(2 - chi - b) / 2`` with the Euler characteristic
        ``chi = V - E + F`` and ``b`` boundary loops (0 for spheres and discs, 1 for a torus).
    """

    edge_vertices: np.ndarray
    face_edge: np.ndarray
    edge_faces: np.ndarray
    face_pairs: np.ndarray
    components: np.ndarray
    vertex_components: np.ndarray
    n_components: int
    boundary_vertex: np.ndarray
    closed_component: np.ndarray
    boundary_loops: int
    genus: int

    @classmethod
    def of(cls, faces: np.ndarray, n_vertices: int) -> "Topology":
        """The topology of ``faces`` (m, 3) over ``n_vertices`` vertices."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        m = len(faces)
        half = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        # one int64 key per vertex pair: np.unique on it is ~10x faster than on rows
        n = max(n_vertices, 1)
        keys, inverse, counts = np.unique(half[:, 0] * n + half[:, 1], return_inverse=True, return_counts=True)
        edge_vertices = np.stack([keys // n, keys % n], axis=1)
        inverse = inverse.ravel()
        two = counts[inverse] == 2
        order = np.argsort(inverse[two], kind="stable")
        face_pairs = np.repeat(np.arange(m, dtype=np.int64), 3)[two][order].reshape(-1, 2)

        graph = coo_matrix((np.ones(len(keys), dtype=np.int8), (edge_vertices[:, 0], edge_vertices[:, 1])),
                           shape=(n_vertices, n_vertices))
        _, vertex_label = connected_components(graph, directed=False)
        components = np.zeros(m, dtype=np.int64)
        n_components = 0
        if m:
            uniq, first, face_inverse = np.unique(vertex_label[faces[:, 0]], return_index=True, return_inverse=True)
            rank = np.empty(len(uniq), dtype=np.int64)
            rank[np.argsort(first)] = np.arange(len(uniq))
            components = rank[face_inverse.ravel()]
            n_components = len(uniq)

        vertex_components = np.full(n_vertices, -1, dtype=np.int64)
        vertex_components[faces.T.ravel()] = np.tile(components, 3)
        boundary = edge_vertices[counts == 1]
        boundary_vertex = np.zeros(n_vertices, dtype=bool)
        boundary_vertex[boundary.ravel()] = True
        edge_component = np.zeros(len(keys), dtype=np.int64)
        edge_component[inverse] = np.repeat(components, 3)  # any face of an edge: one component
        closed = np.ones(n_components, dtype=bool)
        closed[edge_component[counts == 1]] = False
        loops = 0
        if len(boundary):
            bv, b_inv = np.unique(boundary, return_inverse=True)
            b_inv = b_inv.reshape(-1, 2)
            bgraph = coo_matrix((np.ones(len(boundary), dtype=np.int8), (b_inv[:, 0], b_inv[:, 1])),
                                shape=(len(bv), len(bv)))
            loops = len(boundary) - len(bv) + connected_components(bgraph, directed=False)[0]
        used = np.zeros(n_vertices, dtype=bool)
        used[faces.ravel()] = True
        chi = int(used.sum()) - len(keys) + m
        genus = (2 * n_components - chi - loops) // 2
        arrays = (edge_vertices, inverse.reshape(-1, 3), counts.astype(np.int64), face_pairs, components,
                  vertex_components)
        for a in (*arrays, boundary_vertex, closed):
            a.flags.writeable = False  # shared by every caller of the cache
        return cls(*arrays, n_components, boundary_vertex, closed, int(loops), int(genus))

    def edge_pairs(self) -> np.ndarray:
        """(e, 2) int64 per edge its first face and, where exactly two faces use it, the other one
        (-1 otherwise: boundary and non-manifold edges keep only their first face)."""
        m = len(self.face_edge)
        pair = np.full((len(self.edge_vertices), 2), -1, dtype=np.int64)
        first = np.full(len(self.edge_vertices), m, dtype=np.int64)
        np.minimum.at(first, self.face_edge.ravel(), np.repeat(np.arange(m, dtype=np.int64), 3))
        pair[:, 0] = first
        pair[self.edge_faces == 2] = self.face_pairs
        return pair


_CACHE_SIZE = 8
_cache: list = []
"""(weak reference to a faces array, n_vertices, Topology) of the latest meshes, newest last."""


def topology(faces: np.ndarray, n_vertices: int) -> Topology:
    """The :class:`Topology` of ``faces`` (m, 3) int over ``n_vertices`` vertices, built once per faces array.

    Cached on the identity of the ``faces`` array (the last few arrays asked about): a step that
    moves the vertices of a mesh keeps its topology. Treat a faces array as immutable; changing
    the connectivity means a new array.
    """
    for entry in reversed(_cache):
        if entry[0]() is faces and entry[1] == n_vertices:
            return entry[2]
    top = Topology.of(np.asarray(faces, dtype=np.int64).reshape(-1, 3), n_vertices)
    try:
        ref = weakref.ref(faces)
    except TypeError:  # not an ndarray (a list, say): nothing to key the cache on
        return top
    _cache.append((ref, n_vertices, top))
    del _cache[:-_CACHE_SIZE]
    return top


def face_normals(vertices: np.ndarray, faces: np.ndarray, normalize: bool = True) -> np.ndarray:
    """(m, 3) normals ``cross(v1 - v0, v2 - v0)`` of ``faces`` (m, 3) over ``vertices`` (n, 3): unit length
    (zero for degenerate faces), or with ``normalize=False`` twice the face area."""
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    if normalize:
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    return n


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit area-weighted vertex normals (zero for vertices no face uses)."""
    fn = face_normals(vertices, faces, normalize=False)  # length = 2 x area: area weighting
    corner = faces.T.ravel()  # corner-major: each vertex sums its faces as corner 0, then 1, then 2
    out = np.stack([np.bincount(corner, np.tile(fn[:, k], 3), minlength=len(vertices)) for k in range(3)], axis=1)
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, length, out=np.zeros_like(out), where=length > 0)


def split_components(mesh: TriMesh) -> list[TriMesh]:
    """One TriMesh per connected component (:attr:`Topology.components` order; vertices shared with ``mesh``,
    unused ones kept)."""
    labels = mesh.face_components()
    return [TriMesh(mesh.vertices, mesh.faces[labels == c]) for c in range(int(labels.max()) + 1 if len(labels) else 0)]
