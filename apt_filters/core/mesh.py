"""The one triangle-mesh type that flows between pipeline steps, and its topology (built once per mesh)."""

from __future__ import annotations

import functools
import weakref
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


class Topology:
    """Connectivity of a triangle mesh, derived from its faces alone; each part built on first use.

    The components (a compiled union-find over the faces' vertices, about 10 ns per face) need no
    edges; the edge parts share one sort of the 3m half-edges. All arrays are read-only: one
    :class:`Topology` is shared by every caller of the :func:`topology` cache.

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
    edge_pair : (e,) int64
        Each edge's row of ``face_pairs``, -1 where it has none (:meth:`pairs_of`).
    vertex_corners : (indptr, corner) int64
        CSR of the faces around each vertex (:meth:`faces_around`).
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

    def __init__(self, faces: np.ndarray, n_vertices: int) -> None:
        self._faces = faces
        self._n_vertices = n_vertices

    @classmethod
    def of(cls, faces: np.ndarray, n_vertices: int) -> "Topology":
        """The topology of ``faces`` (m, 3) over ``n_vertices`` vertices."""
        return cls(np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3), int(n_vertices))

    @functools.cached_property
    def _edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        faces = self._faces
        # one int64 key per vertex pair, lower index first: np.unique on it is ~10x faster than on rows; made from
        # (m, 3) arrays in place (a (3m, 2) stack of the half-edges and its sorted copy were 100 bytes per face)
        n = max(self._n_vertices, 1)
        following = np.roll(faces, -1, axis=1)
        keys = np.minimum(faces, following)
        keys *= n
        keys += np.maximum(faces, following)
        del following
        # np.unique(keys, return_inverse=True, return_counts=True) by hand: it held a flat copy of the keys, the
        # sorted keys and the cumulative sum beside its order and inverse (55 bytes per half-edge at its peak,
        # the remesh's on the gyroid and the box-sphere-plate); here each goes as soon as it is used (29)
        order = np.argsort(keys, axis=None)
        keys = keys.ravel()[order]
        first = np.empty(len(keys), dtype=bool)
        first[:1] = True
        np.not_equal(keys[1:], keys[:-1], out=first[1:])
        keys = keys[first]
        rank = np.cumsum(first)
        rank -= 1
        inverse = np.empty(len(rank), dtype=np.int64)
        inverse[order] = rank
        del order, rank
        counts = np.diff(np.append(np.flatnonzero(first), len(first)))
        return _frozen(np.stack([keys // n, keys % n], axis=1), inverse.reshape(-1, 3), counts)

    @property
    def edge_vertices(self) -> np.ndarray:
        return self._edges[0]

    @property
    def face_edge(self) -> np.ndarray:
        return self._edges[1]

    @property
    def edge_faces(self) -> np.ndarray:
        return self._edges[2]

    @functools.cached_property
    def face_pairs(self) -> np.ndarray:
        inverse = self.face_edge.ravel()
        two = self.edge_faces[inverse] == 2
        order = np.argsort(inverse[two], kind="stable")
        pairs = np.repeat(np.arange(len(self._faces), dtype=np.int64), 3)[two][order].reshape(-1, 2)
        return _frozen(pairs)[0]

    @functools.cached_property
    def edge_pair(self) -> np.ndarray:
        """(e,) int64 the row of :attr:`face_pairs` of each edge, -1 where the edge is not used by exactly two
        faces: the pairs holding a face are ``edge_pair[face_edge[f]]`` (those >= 0)."""
        out = np.full(len(self.edge_faces), -1, dtype=np.int64)
        out[self.edge_faces == 2] = np.arange(len(self.face_pairs), dtype=np.int64)
        return _frozen(out)[0]

    @functools.cached_property
    def vertex_corners(self) -> tuple[np.ndarray, np.ndarray]:
        """(indptr (n + 1,), corner (3m,)) int64 CSR of the faces around each vertex: ``corner[indptr[v]:
        indptr[v + 1]]`` are the slots ``k`` of ``faces.T.ravel()`` that hold ``v`` (face ``k % m``, as corner
        ``k // m``), in slot order."""
        slots = self._faces.T.ravel()
        corner = np.argsort(slots, kind="stable")
        indptr = np.zeros(self._n_vertices + 1, dtype=np.int64)
        np.cumsum(np.bincount(slots, minlength=self._n_vertices), out=indptr[1:])
        return _frozen(indptr, corner.astype(np.int64))

    def faces_around(self, vertices: np.ndarray) -> np.ndarray:
        """(k,) int64 sorted: the faces that use any of ``vertices`` (int indices)."""
        indptr, corner = self.vertex_corners
        start, count = indptr[vertices], indptr[vertices + 1] - indptr[vertices]
        # each vertex's run of slots, concatenated: start of its run plus the position within it
        at = np.repeat(start - np.cumsum(count) + count, count) + np.arange(int(count.sum()))
        return np.unique(corner[at] % max(len(self._faces), 1))

    def pairs_of(self, faces: np.ndarray) -> np.ndarray:
        """(k,) int64 sorted: the rows of :attr:`face_pairs` that hold any of ``faces`` (int indices)."""
        pair = self.edge_pair[self.face_edge[faces]].ravel()
        return np.unique(pair[pair >= 0])

    @functools.cached_property
    def _components(self) -> tuple[np.ndarray, int]:
        from apt_filters.core.unionfind import face_components  # numba loads only when asked

        n = self._n_vertices
        components, count = face_components(self._faces, np.arange(n, dtype=np.int32 if n < 2**31 else np.int64))
        return _frozen(components)[0], int(count)

    @property
    def components(self) -> np.ndarray:
        return self._components[0]

    @property
    def n_components(self) -> int:
        return self._components[1]

    @functools.cached_property
    def vertex_components(self) -> np.ndarray:
        out = np.full(self._n_vertices, -1, dtype=np.int64)
        out[self._faces.T.ravel()] = np.tile(self.components, 3)
        return _frozen(out)[0]

    @functools.cached_property
    def boundary_vertex(self) -> np.ndarray:
        out = np.zeros(self._n_vertices, dtype=bool)
        out[self.edge_vertices[self.edge_faces == 1].ravel()] = True
        return _frozen(out)[0]

    @functools.cached_property
    def closed_component(self) -> np.ndarray:
        edge_component = np.zeros(len(self.edge_faces), dtype=np.int64)
        edge_component[self.face_edge.ravel()] = np.repeat(self.components, 3)  # any face of an edge: one component
        closed = np.ones(self.n_components, dtype=bool)
        closed[edge_component[self.edge_faces == 1]] = False
        return _frozen(closed)[0]

    @functools.cached_property
    def boundary_loops(self) -> int:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        boundary = self.edge_vertices[self.edge_faces == 1]
        if not len(boundary):
            return 0
        bv, b_inv = np.unique(boundary, return_inverse=True)
        b_inv = b_inv.reshape(-1, 2)
        bgraph = coo_matrix((np.ones(len(boundary), dtype=np.int8), (b_inv[:, 0], b_inv[:, 1])),
                            shape=(len(bv), len(bv)))
        return int(len(boundary) - len(bv) + connected_components(bgraph, directed=False)[0])

    @functools.cached_property
    def boundary_half_edges(self) -> np.ndarray:
        """(k, 2) the directed edges (a, b) of the faces, in face order, that no other face uses."""
        # only the rows taken are stacked: a (m, 3, 2) stack of all half-edges was 48 bytes per face, held while
        # the edge tables were built (the remesh's peak on the gyroid)
        face, corner = np.nonzero(self.edge_faces[self.face_edge] == 1)  # in face order, then corner order
        return _frozen(np.stack([self._faces[face, corner], self._faces[face, (corner + 1) % 3]], axis=1))[0]

    @functools.cached_property
    def boundary_pieces(self) -> tuple[int, np.ndarray]:
        """The connected pieces of the boundary: their number and the (k,) piece of each of
        :attr:`boundary_half_edges`. A piece is what one fan caps; it equals a boundary loop
        except where loops touch at a vertex (then :attr:`boundary_loops` counts each circle)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        half = self.boundary_half_edges
        if not len(half):
            return 0, _frozen(np.zeros(0, dtype=np.int64))[0]
        ids, local = np.unique(half, return_inverse=True)
        local = local.reshape(-1, 2)
        graph = coo_matrix((np.ones(len(half), dtype=np.int8), (local[:, 0], local[:, 1])), shape=(len(ids),) * 2)
        label = connected_components(graph, directed=False)[1][local[:, 0]]
        used, piece = np.unique(label, return_inverse=True)
        return len(used), _frozen(piece.ravel().astype(np.int64))[0]

    @functools.cached_property
    def genus(self) -> int:
        used = np.zeros(self._n_vertices, dtype=bool)
        used[self._faces.ravel()] = True
        chi = int(used.sum()) - len(self.edge_faces) + len(self._faces)
        return int((2 * self.n_components - chi - self.boundary_loops) // 2)

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


def _frozen(*arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    for a in arrays:
        a.flags.writeable = False  # shared by every caller of the cache
    return arrays


_CACHE_SIZE = 8
_cache: list = []
"""(weak reference to a faces array, n_vertices, Topology) of the latest meshes, newest last."""


def _forget(ref: weakref.ref) -> None:
    """Drop the cache's entry of a faces array that died: its tables go with it, not at the next lookup (a
    remesh's last flips' tables were held through its centring, 630 bytes per input face of a thin plate)."""
    _cache[:] = [entry for entry in _cache if entry[0] is not ref]


def topology(faces: np.ndarray, n_vertices: int) -> Topology:
    """The :class:`Topology` of ``faces`` (m, 3) int over ``n_vertices`` vertices, built once per faces array.

    Cached on the identity of the ``faces`` array (the last few arrays asked about): a step that
    moves the vertices of a mesh keeps its topology. Treat a faces array as immutable; changing
    the connectivity means a new array.
    """
    _cache[:] = [entry for entry in _cache if entry[0]() is not None]
    for entry in reversed(_cache):
        if entry[0]() is faces and entry[1] == n_vertices:
            return entry[2]
    try:
        ref = weakref.ref(faces, _forget)
    except TypeError:  # not an ndarray (a list, say): nothing to key the cache on
        return Topology.of(faces, n_vertices)
    # On a copy of its own (24 bytes per face beside ~150 of edge tables): holding the caller's array, or a
    # view of it, would keep the weak key alive, and the last meshes' tables would outlive their steps.
    top = Topology.of(np.array(faces, dtype=np.int64), n_vertices)
    _cache.append((ref, n_vertices, top))
    del _cache[:-_CACHE_SIZE]
    return top


def face_normals(vertices: np.ndarray, faces: np.ndarray, normalize: bool = True) -> np.ndarray:
    """(m, 3) normals ``cross(v1 - v0, v2 - v0)`` of ``faces`` (m, 3) over ``vertices`` (n, 3): unit length
    (zero for degenerate faces), or with ``normalize=False`` twice the face area."""
    from apt_filters.core.triangle import face_normals_kernel  # numba loads only when asked

    # one compiled pass (refinement asks ~1,300 times a run, 48k faces: 0.85 -> 0.07 ms a call against numpy's
    # gathers, cross product and norm), the same numbers
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    out = np.empty((len(faces), 3), np.result_type(vertices.dtype, np.float32))
    face_normals_kernel(vertices, faces, normalize, out)
    return out


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


def merge(parts: list[TriMesh]) -> TriMesh:
    """One mesh of several: each part's unused vertices dropped, the scalars every part carries kept (in the
    first part's order), components relabelled (face scalar ``component``)."""
    vertex_keys = [k for k in (parts[0].vertex_scalars if parts else ()) if all(k in p.vertex_scalars for p in parts)]
    face_keys = [k for k in (parts[0].face_scalars if parts else ())
                 if k != "component" and all(k in p.face_scalars for p in parts)]
    vertices, faces, offset = [], [], 0
    vertex_scalars = {k: [] for k in vertex_keys}
    face_scalars = {k: [] for k in face_keys}
    for p in parts:
        used = np.unique(p.faces)
        index = np.full(p.n_vertices, -1, dtype=np.int64)
        index[used] = np.arange(len(used)) + offset
        vertices.append(p.vertices[used])
        faces.append(index[p.faces])
        offset += len(used)
        for k in vertex_keys:
            vertex_scalars[k].append(p.vertex_scalars[k][used])
        for k in face_keys:
            face_scalars[k].append(p.face_scalars[k])
    out = TriMesh(np.concatenate(vertices) if vertices else np.zeros((0, 3)),
                  np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64),
                  {k: np.concatenate(v) for k, v in vertex_scalars.items()},
                  {k: np.concatenate(v) for k, v in face_scalars.items()})
    out.face_scalars["component"] = out.face_components()
    return out
