"""Mesh quality and fidelity measures used to judge a remesh.

Triangle shape, sampling and point-to-mesh distances come from :mod:`apt_filters.contour.metrics`;
this module adds what judging a remesh against its input (not an analytic shape) needs. All
functions take :class:`~apt_filters.core.mesh.TriMesh` objects; lengths are in the
mesh's units (nm). Peak memory is a few arrays of the mesh's size (plus pymeshlab's copy
for the topological measures).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from apt_filters.contour.metrics import face_quality, sample_mesh
from apt_filters.core.checks import self_intersecting_faces
from apt_filters.core.distance import mesh_distance
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh._arrays import isin, unique_rows


def hausdorff(a: TriMesh, b: TriMesh, n_samples: int = 200_000) -> float:
    """Two-sided Hausdorff distance, estimated from vertices plus about ``n_samples`` area samples of each mesh."""
    pa = np.vstack([a.vertices, sample_mesh(a, n_samples / a.area(), np.random.default_rng(1))[0]])
    pb = np.vstack([b.vertices, sample_mesh(b, n_samples / b.area(), np.random.default_rng(2))[0]])
    return float(max(mesh_distance(b, pa).max(), mesh_distance(a, pb).max()))


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
    self_intersections: int  # faces crossing another (core.checks.self_intersecting_faces)
    orientation_conflicts: int
    components: int
    boundary_loops: int
    genus: int

    def as_dict(self) -> dict:
        return asdict(self)


def assess(mesh: TriMesh, reference: TriMesh, n_samples: int = 200_000, intersections: bool = True) -> Quality:
    """All the measures at once: angles, Q, Hausdorff to ``reference``, manifoldness, topology.

    ``intersections=False`` skips the self-intersection test and reports -1 for it.
    """
    angles, q = face_quality(mesh)
    angles = angles.min(axis=1)
    topo = topology(mesh)
    return Quality(len(mesh.faces), float(angles.min()), float(np.mean(angles >= 30.0)), float(q.mean()), hausdorff(mesh, reference, n_samples),
                   topo.non_manifold_edges, topo.non_manifold_vertices, int(self_intersecting_faces(mesh.vertices, mesh.faces).sum()) if intersections else -1,
                   orientation_conflicts(mesh), topo.components, topo.boundary_loops, topo.genus)
