"""Mesh quality and fidelity measures used to judge a remesh.

All functions take :class:`~apt_filters.core.mesh.TriMesh` objects; lengths are in the
mesh's units (nm). Peak memory is a few arrays of the mesh's size (plus pymeshlab's copy
for the topological measures).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from apt_filters.remesh._arrays import isin, unique_rows
from apt_filters.core.deps import open3d
from apt_filters.core.mesh import TriMesh


def triangle_angles(mesh: TriMesh) -> np.ndarray:
    """(m, 3) interior angles in degrees, the angle at each face corner."""
    v = mesh.vertices[mesh.faces]
    out = np.empty((len(mesh.faces), 3))
    for i in range(3):
        a = v[:, (i + 1) % 3] - v[:, i]
        b = v[:, (i + 2) % 3] - v[:, i]
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        out[:, i] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def radius_ratio(mesh: TriMesh) -> np.ndarray:
    """(m,) quality Q = 6/sqrt(3) * A / (s * h_max): 1 for equilateral, 0 for degenerate.

    A is the area, s the semi-perimeter and h_max the longest edge.
    """
    v = mesh.vertices[mesh.faces]
    lengths = np.linalg.norm(v - np.roll(v, -1, axis=1), axis=2)
    s = lengths.sum(axis=1) / 2
    denom = np.maximum(s * lengths.max(axis=1), 1e-300)
    return 6.0 / np.sqrt(3.0) * mesh.face_areas() / denom


def sample_surface(mesh: TriMesh, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) points drawn uniformly by area on the mesh surface."""
    rng = np.random.default_rng(seed)
    areas = mesh.face_areas()
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    r1, r2 = rng.random(n), rng.random(n)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    v = mesh.vertices[mesh.faces[face]]
    return v[:, 0] + r1[:, None] * (v[:, 1] - v[:, 0]) + r2[:, None] * (v[:, 2] - v[:, 0])


def distance_to(mesh: TriMesh, points: np.ndarray) -> np.ndarray:
    """(k,) unsigned distance from each point to the mesh surface (open3d RaycastingScene)."""
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy().astype(np.float64)


def hausdorff(a: TriMesh, b: TriMesh, n_samples: int = 200_000) -> float:
    """Two-sided Hausdorff distance, estimated from vertices plus area samples of each mesh."""
    pa = np.vstack([a.vertices, sample_surface(a, n_samples, 1)])
    pb = np.vstack([b.vertices, sample_surface(b, n_samples, 2)])
    return float(max(distance_to(b, pa).max(), distance_to(a, pb).max()))


def feature_edges(mesh: TriMesh, angle: float = 40.0) -> np.ndarray:
    """(k, 2) undirected edges whose dihedral angle (between face normals) exceeds ``angle`` degrees.

    Boundary edges are not included.
    """
    e = np.sort(mesh.edges(), axis=1)
    face = np.repeat(np.arange(len(mesh.faces)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, face = e[order], face[order]
    pair = np.flatnonzero((e[1:] == e[:-1]).all(axis=1))
    pair = pair[~isin(pair, pair + 1) & ~isin(pair + 1, pair + 2)]  # exactly two faces
    n = mesh.face_normals()
    cos = np.einsum("ij,ij->i", n[face[pair]], n[face[pair + 1]])
    return e[pair[cos < np.cos(np.radians(angle))]]


def sample_edges(vertices: np.ndarray, edges: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` (or closer) along each edge, end points included."""
    if len(edges) == 0:
        return np.empty((0, 3))
    a, b = vertices[edges[:, 0]], vertices[edges[:, 1]]
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(int), 1)
    idx = np.repeat(np.arange(len(edges)), n + 1)
    t = np.concatenate([np.linspace(0, 1, k + 1) for k in n])
    return a[idx] + t[:, None] * (b[idx] - a[idx])


def edge_f1(points: np.ndarray, reference: np.ndarray, tol: float) -> float:
    """F1 score of feature-edge samples ``points`` against ``reference`` samples, match within ``tol``."""
    from scipy.spatial import cKDTree

    if len(points) == 0 or len(reference) == 0:
        return float(len(points) == len(reference))
    precision = np.mean(cKDTree(reference).query(points)[0] <= tol)
    recall = np.mean(cKDTree(points).query(reference)[0] <= tol)
    return float(0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall))


def orientation_conflicts(mesh: TriMesh) -> int:
    """Number of directed half-edges used twice (neighbouring faces with opposite orientation)."""
    counts = unique_rows(mesh.edges())[3]
    return int((counts > 1).sum())


@dataclass
class Topology:
    components: int
    boundary_loops: int
    genus: int
    non_manifold_edges: int
    non_manifold_vertices: int


def topology(mesh: TriMesh) -> Topology:
    """Connected components, boundary loops, genus and non-manifold counts (pymeshlab measures)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(mesh.vertices, mesh.faces))
    t = ms.get_topological_measures()
    return Topology(int(t["connected_components_number"]), int(t["number_holes"]), int(t["genus"]),
                    int(t["non_two_manifold_edges"]), int(t["non_two_manifold_vertices"]))


def self_intersections(mesh: TriMesh) -> int:
    """Number of intersecting pairs of non-adjacent triangles (open3d's triangle-triangle test).

    pymeshlab's ``compute_selection_by_self_intersections_per_face`` was tried first but flags
    coplanar neighbours of a rotated exact box (258 faces of a mesh with none), so open3d's
    test is the one used; it does count zero-area triangles that touch a neighbour.
    """
    o3d = open3d()
    legacy = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                       o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
    return len(np.asarray(legacy.get_self_intersecting_triangles()))


@dataclass
class Quality:
    """Summary of one mesh against the surface it stands for (``reference``)."""

    faces: int
    min_angle: float
    frac_ge_30: float
    mean_q: float
    hausdorff: float
    non_manifold_edges: int
    non_manifold_vertices: int
    self_intersections: int
    orientation_conflicts: int
    components: int
    boundary_loops: int
    genus: int

    def as_dict(self) -> dict:
        return asdict(self)


def assess(mesh: TriMesh, reference: TriMesh, n_samples: int = 200_000) -> Quality:
    """All the measures at once: angles, Q, Hausdorff to ``reference``, manifoldness, topology."""
    angles = triangle_angles(mesh).min(axis=1)
    topo = topology(mesh)
    return Quality(len(mesh.faces), float(angles.min()), float(np.mean(angles >= 30.0)),
                   float(radius_ratio(mesh).mean()), hausdorff(mesh, reference, n_samples),
                   topo.non_manifold_edges, topo.non_manifold_vertices, self_intersections(mesh),
                   orientation_conflicts(mesh), topo.components, topo.boundary_loops, topo.genus)
