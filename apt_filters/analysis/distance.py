"""Exact signed distance of points to an oriented triangle mesh, in a narrow band.

The closest point on the surface comes from open3d's BVH (``RaycastingScene.compute_closest_points``);
the sign from the angle-weighted pseudo-normal of the feature (face, edge or vertex) on which the
closest point lies (Bærentzen & Aanæs 2005). That sign is provably right for any point of a closed
manifold, including at sharp edges and corners, and stays meaningful on open surfaces, unlike
open3d's own ``compute_signed_distance`` (ray parity; assumes a watertight mesh).

Sign convention: mesh normals point OUT of the region above the iso-value, and distances are
positive inside that region (the precipitate side), as AP Suite plots proxigrams.

Only points that may lie within ``max_distance`` of the surface are queried: a coarse voxel
mask (:class:`NarrowBand`, a Euclidean distance transform of the voxels the surface touches)
rejects the rest with one table lookup per point, conservatively (no point within range is lost).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from apt_filters.core.deps import open3d
from apt_filters.core.mesh import TriMesh

FACE, EDGE, VERTEX = 0, 1, 2
"""Feature of the closest point (``SignedDistance.feature``)."""

_BARY_EPS = 1e-5
"""Barycentric weight below which the closest point counts as lying on an edge/vertex.

Erring toward the lower-dimensional feature is safe: the edge (vertex) pseudo-normal gives the
right sign for a point whose closest point is inside an adjacent face, too.
"""


@dataclass
class MeshTopology:
    """Edge and vertex structure of a triangle mesh, with the pseudo-normals for the sign.

    Attributes
    ----------
    face_normals : (m, 3) float64
        Unit face normals.
    face_edge : (m, 3) int64
        Undirected edge id of half-edge ``(f[k], f[(k+1) % 3])`` of each face.
    edge_vertices : (e, 2) int64
        Vertex pair of each undirected edge.
    edge_faces : (e,) int64
        Number of faces using each edge (1 = boundary, 2 = manifold interior).
    edge_normals : (e, 3) float64
        Sum of the unit normals of the faces using the edge (edge pseudo-normal).
    vertex_normals : (n, 3) float64
        Angle-weighted sum of incident unit face normals (vertex pseudo-normal).
    corner_angles : (m, 3) float64
        Interior angle (radians) of each face at each of its corners.
    boundary_vertex : (n,) bool
        Vertices on a boundary edge.
    """

    face_normals: np.ndarray
    face_edge: np.ndarray
    edge_vertices: np.ndarray
    edge_faces: np.ndarray
    edge_normals: np.ndarray
    vertex_normals: np.ndarray
    corner_angles: np.ndarray
    boundary_vertex: np.ndarray

    @classmethod
    def of(cls, mesh: TriMesh) -> "MeshTopology":
        v, f = mesh.vertices, mesh.faces
        nf = mesh.face_normals()
        half = np.sort(np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        edge_vertices, inverse, counts = np.unique(half, axis=0, return_inverse=True, return_counts=True)
        face_edge = inverse.reshape(-1, 3)
        edge_normals = np.zeros((len(edge_vertices), 3))
        np.add.at(edge_normals, face_edge.ravel(), np.repeat(nf, 3, axis=0))
        corner_angles = _corner_angles(v[f])
        vertex_normals = np.zeros((len(v), 3))
        np.add.at(vertex_normals, f.ravel(), (corner_angles[:, :, None] * nf[:, None, :]).reshape(-1, 3))
        boundary_vertex = np.zeros(len(v), dtype=bool)
        boundary_vertex[edge_vertices[counts == 1].ravel()] = True
        return cls(nf, face_edge, edge_vertices, counts, edge_normals, vertex_normals, corner_angles,
                   boundary_vertex)

    def face_components(self, n_vertices: int) -> np.ndarray:
        """(m,) int64 connected-component label of each face (faces sharing an edge or a vertex)."""
        a, b = self.edge_vertices.T
        graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n_vertices, n_vertices))
        _, labels = connected_components(graph, directed=False)
        first_vertex = self.edge_vertices[self.face_edge[:, 0], 0]
        _, relabelled = np.unique(labels[first_vertex], return_inverse=True)
        return relabelled.astype(np.int64)


def _corner_angles(tri: np.ndarray) -> np.ndarray:
    """(m, 3) interior angles of triangles given as (m, 3, 3) corner coordinates."""
    a = np.roll(tri, -1, axis=1) - tri
    b = np.roll(tri, 1, axis=1) - tri
    cross = np.linalg.norm(np.cross(a, b), axis=2)
    return np.arctan2(cross, np.einsum("ijk,ijk->ij", a, b))


@dataclass
class NarrowBand:
    """Conservative voxel mask of the points that may lie within ``max_distance`` of a surface.

    A point is a candidate when its voxel is flagged. Every point whose distance to the surface
    is at most ``max_distance`` is flagged (proof in :meth:`build`); others may be, too (the band
    is about ``max_distance + 2 voxel`` wide).

    Attributes
    ----------
    origin : (3,) float64
        Corner of voxel (0, 0, 0), nm.
    voxel : float
        Voxel edge, nm.
    mask : (nx, ny, nz) bool
        Flagged voxels, x, y, z order.
    """

    origin: np.ndarray
    voxel: float
    mask: np.ndarray

    @classmethod
    def build(cls, mesh: TriMesh, max_distance: float, voxel: float = 0.5,
              max_voxels: int = 1 << 23) -> "NarrowBand":
        """Flag the voxels within reach of the surface.

        The surface is sampled so that each surface point is within ``h <= voxel / 2`` of a sample;
        the voxels holding samples are seeds, and ``D`` is the Euclidean distance (in voxels) of
        a voxel centre to the nearest seed centre. For a point ``p`` at distance ``d`` from the
        surface, with closest point ``q`` near sample ``s``, ``D * voxel <= |p - c_p| + d + h +
        |s - c_s| <= sqrt(3) voxel + d + h``, so ``D <= sqrt(3) + (max_distance + h) / voxel``
        flags every point within range.

        Peak memory about 21 bytes per voxel of the mesh's bounding box grown by the range (the
        distance transform); the voxel grows until the box holds at most ``max_voxels`` (8.4 M by
        default: about 180 MB). The mask kept is 1 byte per voxel.
        """
        lo = mesh.vertices.min(axis=0)
        hi = mesh.vertices.max(axis=0)
        while True:
            h = voxel / 2
            pad = max_distance + h + 2 * voxel
            origin = lo - pad
            shape = np.floor((hi + pad - origin) / voxel).astype(np.int64) + 1
            if np.prod(shape) <= max_voxels:
                break
            voxel *= 1.25
        samples = surface_samples(mesh, h)
        seeds = np.zeros(shape, dtype=bool)
        cells = np.floor((samples - origin) / voxel).astype(np.int64)
        seeds[cells[:, 0], cells[:, 1], cells[:, 2]] = True
        reach = np.sqrt(3.0) + (max_distance + h) / voxel
        mask = ndimage.distance_transform_edt(~seeds) <= reach
        return cls(origin, float(voxel), mask)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: points (N, 3) nm that may lie within range of the surface."""
        cells = np.floor((points - self.origin.astype(points.dtype)) / points.dtype.type(self.voxel))
        shape = np.array(self.mask.shape)
        inside = np.all((cells >= 0) & (cells < shape), axis=1)
        out = np.zeros(len(points), dtype=bool)
        c = cells[inside].astype(np.int64)
        out[inside] = self.mask[c[:, 0], c[:, 1], c[:, 2]]
        return out


def _cell_order(points: np.ndarray, cell: float) -> np.ndarray:
    """Indices that visit ``points`` cell by cell (cells of ``cell`` nm, x-major)."""
    if len(points) == 0:
        return np.empty(0, np.int64)
    c = np.floor((points - points.min(axis=0)) / np.float32(cell)).astype(np.int64)
    n = c.max(axis=0) + 1
    return np.argsort((c[:, 0] * n[1] + c[:, 1]) * n[2] + c[:, 2], kind="stable")


def surface_samples(mesh: TriMesh, spacing: float) -> np.ndarray:
    """(k, 3) points on the surface such that every surface point is within ``spacing`` of one.

    Each triangle is split into ``n**2`` similar sub-triangles with ``n = ceil(longest edge /
    spacing)``; their corners are the samples (any point of a triangle is within its longest
    edge of each corner).
    """
    tri = mesh.vertices[mesh.faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    n_sub = np.maximum(1, np.ceil(longest / spacing)).astype(np.int64)
    out = []
    for n in np.unique(n_sub):
        i, j = np.nonzero(np.add.outer(np.arange(n + 1), np.arange(n + 1)) <= n)
        w = np.stack([n - i - j, i, j], axis=1) / n  # barycentric weights of the lattice
        out.append(np.einsum("sk,fkd->fsd", w, tri[n_sub == n]).reshape(-1, 3))
    return np.concatenate(out) if out else np.empty((0, 3))


@dataclass
class SignedDistance:
    """Exact signed distances of queried points.

    Attributes
    ----------
    distance : (N,) float32
        Signed distance in nm, positive inside the region above the iso-value.
    face : (N,) int64
        Triangle holding the closest point.
    feature : (N,) int8
        ``FACE``, ``EDGE`` or ``VERTEX``: where on that triangle the closest point lies.
    on_boundary : (N,) bool
        The closest point lies on a boundary edge or vertex of an open surface (the specimen
        edge): the point is beyond the surface's rim rather than across it.
    """

    distance: np.ndarray
    face: np.ndarray
    feature: np.ndarray
    on_boundary: np.ndarray


class SurfaceDistance:
    """Signed-distance queries against one mesh (BVH and pseudo-normals built once).

    Parameters
    ----------
    mesh : TriMesh
        Oriented surface (normals out of the region above the iso-value); may be open.
    batch : int
        Points per open3d call; memory about 60 bytes per point of a batch (plus 30 bytes per
        queried point for the results and the visiting order).
    sort_cell : float
        Edge (nm) of the cells whose order the queries follow.

    Notes
    -----
    open3d works in float32: distances are exact to about 1e-7 of the coordinates' magnitude
    (1e-5 nm at 100 nm).
    """

    def __init__(self, mesh: TriMesh, batch: int = 1 << 20, sort_cell: float = 2.0):
        o3d = open3d()
        self.mesh = mesh
        self.sort_cell = sort_cell
        self.topology = MeshTopology.of(mesh)
        self.batch = batch
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                                  o3d.core.Tensor(mesh.faces.astype(np.uint32)))
        self._tensor = o3d.core.Tensor

    def query(self, points: np.ndarray) -> SignedDistance:
        """Exact signed distance of every point (N, 3) nm to the surface, in batches.

        Points are visited in the order of coarse spatial cells (``sort_cell`` nm), so that
        consecutive BVH traversals touch the same nodes: 1.5-2.5x faster than random order.
        """
        order = _cell_order(points, self.sort_cell)
        out = SignedDistance(np.empty(len(points), np.float32), np.empty(len(points), np.int64),
                             np.empty(len(points), np.int8), np.empty(len(points), bool))
        for a in range(0, len(points), self.batch):
            idx = order[a:a + self.batch]
            part = self._query_batch(np.ascontiguousarray(points[idx], dtype=np.float32))
            out.distance[idx], out.face[idx], out.feature[idx], out.on_boundary[idx] = (
                part.distance, part.face, part.feature, part.on_boundary)
        return out

    def _query_batch(self, points: np.ndarray) -> SignedDistance:
        result = self._scene.compute_closest_points(self._tensor(points))
        closest = result["points"].numpy()
        face = result["primitive_ids"].numpy().astype(np.int64)
        uv = result["primitive_uvs"].numpy()
        feature, normal, on_boundary = self._classify(face, uv)
        offset = points - closest
        side = np.einsum("ij,ij->i", offset, normal)
        # Normals point out of the above-iso region, so the inside has negative `side`.
        distance = np.linalg.norm(offset, axis=1) * np.where(side > 0, -1, 1).astype(np.float32)
        return SignedDistance(distance.astype(np.float32), face, feature, on_boundary)

    def _classify(self, face: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Feature, pseudo-normal (N, 3) and boundary flag of closest points given by barycentrics."""
        top = self.topology
        weights = np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]])
        small = weights < _BARY_EPS
        n_small = small.sum(axis=1)
        feature = np.minimum(n_small, VERTEX).astype(np.int8)
        normal = top.face_normals[face]
        on_boundary = np.zeros(len(face), dtype=bool)

        at_edge = np.flatnonzero(n_small == 1)
        # the edge opposite corner k is half-edge (k + 1) % 3
        edge = top.face_edge[face[at_edge], (np.argmax(small[at_edge], axis=1) + 1) % 3]
        normal[at_edge] = top.edge_normals[edge]
        on_boundary[at_edge] = top.edge_faces[edge] == 1

        at_vertex = np.flatnonzero(n_small >= 2)
        vertex = self.mesh.faces[face[at_vertex], np.argmax(weights[at_vertex], axis=1)]
        normal[at_vertex] = top.vertex_normals[vertex]
        on_boundary[at_vertex] = top.boundary_vertex[vertex]
        return feature, normal, on_boundary
