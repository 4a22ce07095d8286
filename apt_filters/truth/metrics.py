"""A mesh against an analytic shape (:mod:`apt_filters.truth.shapes`): distances, normals, edges, sanity.

Distances are returned in the mesh's units (nm); :func:`evaluate` also reports them in
voxels. Definitions (thresholds scale with the voxel size ``h``):

- Hausdorff / Chamfer: distances between dense uniform samples of the mesh and of the
  true surface (``density`` points per h²), both ways; mesh→truth uses ``|sdf|`` where the
  SDF is exact, else the nearest true sample. Chamfer is the mean of the two mean distances.
- Normal consistency: mean dot product of a mesh sample's face normal with the true
  normal of the nearest true sample (1 = perfect, signed so that flipped winding shows).
- Edge metrics (after NMC/NDC, Chen et al.): a sample is an *edge point* when another
  sample within ``EDGE_RADIUS`` = 0.3 h has a normal more than 78.5° away (dot < 0.2),
  the same rule on the mesh samples and on the true samples (analytic normals). Edge
  Chamfer distance = mean of the two mean nearest distances between the edge points of
  mesh and truth; edge F1 = harmonic mean of precision (mesh edge points within
  ``EDGE_TAU`` = 0.3 h of a true edge point) and recall (the converse); always on
  ``EDGE_DENSITY`` = 40 samples per h² (the rule needs several neighbours within the radius). NDC's own values
  (radius 0.004, threshold 0.005 on unit-size shapes) are 0.26 h and 0.32 h at 64³. :func:`edge_against` scores
  a mesh against one shape; :func:`truth_edge_f1` against the sharp-edged ones of several true objects (a
  specimen's), each scored on the mesh component that matches it.
- Triangle quality: :func:`apt_filters.contour.metrics.triangle_quality`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from apt_filters.contour.metrics import sample_mesh, self_intersection_count, triangle_quality
from apt_filters.core.checks import folded_pairs, non_manifold_vertex_count
from apt_filters.core.distance import mesh_distance
from apt_filters.core.mesh import TriMesh, split_components
from apt_filters.truth.shapes import Union
from apt_filters.truth.surface import match_objects

EDGE_DOT = 0.2
EDGE_RADIUS = 0.3  # voxels
EDGE_TAU = 0.3  # voxels
EDGE_DENSITY = 40.0  # samples per voxel area for edge detection (~11 neighbours within the radius)


def edge_points(points: np.ndarray, normals: np.ndarray, radius: float, k: int = 24) -> np.ndarray:
    """(n,) bool: samples with a neighbour within ``radius`` whose normal differs by dot < 0.2."""
    if len(points) < 2:
        return np.zeros(len(points), dtype=bool)
    dist, idx = cKDTree(points).query(points, k=min(k, len(points)), distance_upper_bound=radius)
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, 0)
    dots = np.einsum("nj,nkj->nk", normals, normals[idx])
    return np.any(valid & (dots < EDGE_DOT), axis=1)


def edge_metrics(pred: tuple[np.ndarray, np.ndarray], true: tuple[np.ndarray, np.ndarray], voxel: float) -> dict:
    """Edge Chamfer distance (nm), edge precision, recall and F1 (see module notes)."""
    pe = pred[0][edge_points(*pred, EDGE_RADIUS * voxel)]
    te = true[0][edge_points(*true, EDGE_RADIUS * voxel)]
    if len(te) == 0:
        return {"edge_chamfer": np.nan, "edge_precision": np.nan, "edge_recall": np.nan, "edge_f1": np.nan}
    if len(pe) == 0:
        return {"edge_chamfer": np.inf, "edge_precision": 0.0, "edge_recall": 0.0, "edge_f1": 0.0}
    d_pt = cKDTree(te).query(pe)[0]
    d_tp = cKDTree(pe).query(te)[0]
    precision = float(np.mean(d_pt < EDGE_TAU * voxel))
    recall = float(np.mean(d_tp < EDGE_TAU * voxel))
    f1 = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return {"edge_chamfer": 0.5 * (d_pt.mean() + d_tp.mean()), "edge_precision": precision,
            "edge_recall": recall, "edge_f1": f1}


def edge_against(mesh: TriMesh, shape, voxel: float, rng: np.random.Generator) -> dict:
    """:func:`edge_metrics` of ``mesh`` against ``shape``'s surface, both sampled at ``EDGE_DENSITY`` per h²
    (the mesh first, then the shape, from ``rng``)."""
    density = EDGE_DENSITY / voxel**2
    return edge_metrics(sample_mesh(mesh, density, rng), shape.sample(density, rng), voxel)


def is_sharp(shape, voxel: float, seed: int = 0) -> bool:
    """Whether ``shape`` has sharp edges at voxel ``voxel`` (nm): any of its samples an edge point by the rule of
    :func:`edge_metrics` (a rounded edge whose normal turns by 78.5° over more than ``EDGE_RADIUS`` h has none)."""
    points, normals = shape.sample(EDGE_DENSITY / voxel**2, np.random.default_rng(seed))
    return bool(edge_points(points, normals, EDGE_RADIUS * voxel).any())


def truth_edge_f1(mesh: TriMesh, shapes: list, voxel: float, seed: int = 0) -> tuple[float, list[int]]:
    """Edge F1 of ``mesh`` against the sharp edges of the true objects ``shapes`` (:mod:`apt_filters.synth.shapes`
    solids in the mesh's frame, nm) at voxel ``voxel`` (the rule of :func:`edge_metrics`: edge points 78.5° apart
    within 0.3 h, matched within 0.3 h), and the indices of the objects scored.

    Objects without a sharp edge (:func:`is_sharp`: spheres, capsules, rounded cuboids) are left out, not given
    edges; so is the part of ``mesh`` matched to no sharp object (:func:`~apt_filters.truth.surface.match_objects`,
    one component per object). One object is scored against the whole mesh. NaN where no object is sharp or
    none is matched. Precision and recall are pooled over the objects scored (their union's samples)."""
    sharp = [i for i, s in enumerate(shapes) if is_sharp(s, voxel, seed)]
    if len(shapes) > 1:
        parts = split_components(mesh)
        found = match_objects(parts, [shapes[i].sdf for i in sharp])
        sharp = [i for i, m in zip(sharp, found) if m is not None]
        faces = [parts[m].faces for m in found if m is not None]
        mesh = TriMesh(mesh.vertices, np.concatenate(faces) if faces else np.zeros((0, 3), np.int64))
    if not sharp or mesh.n_faces == 0:
        return float("nan"), sharp
    truth = shapes[sharp[0]] if len(sharp) == 1 else Union(*(shapes[i] for i in sharp))
    return edge_against(mesh, truth, voxel, np.random.default_rng(seed))["edge_f1"], sharp


@dataclass
class MeshReport:
    """Quality of one mesh against one true surface; distances in voxels."""

    hausdorff: float
    chamfer: float
    normal_consistency: float
    edge_chamfer: float
    edge_f1: float
    edge_precision: float
    edge_recall: float
    min_angle: float
    mean_min_angle: float
    q_min: float
    q_mean: float
    n_faces: int
    boundary_edges: int
    non_manifold_edges: int
    non_manifold_vertices: int
    folded_pairs: int
    self_intersections: int
    signed_volume: float

    def as_dict(self) -> dict:
        return asdict(self)


def evaluate(mesh: TriMesh, shape, voxel: float, density: float = 20.0, seed: int = 0,
             intersections: bool = True, edges: bool = True) -> MeshReport:
    """Full report of ``mesh`` against an analytic :mod:`apt_filters.truth.shapes` shape.

    ``density`` is in samples per voxel area (h²) for the distance metrics; edge metrics
    always use ``EDGE_DENSITY`` (``edges=False`` skips them, and ``intersections=False``
    the pymeshlab test: both are the slow parts).
    """
    rng = np.random.default_rng(seed)
    per_area = density / voxel**2
    mp, mn = sample_mesh(mesh, per_area, rng)
    tp, tn = shape.sample(per_area, rng)
    if shape.exact_sdf:
        to_true = np.abs(shape.sdf(mp))
    else:  # nearest of 4x denser true samples (overestimates by about their spacing)
        to_true = cKDTree(shape.sample(per_area * 4, rng)[0]).query(mp)[0]
    to_mesh = mesh_distance(mesh, tp)
    nearest = cKDTree(tp).query(mp)[1]
    edge_rng = np.random.default_rng(seed + 1)
    edges = (edge_against(mesh, shape, voxel, edge_rng) if edges
             else dict.fromkeys(["edge_chamfer", "edge_precision", "edge_recall", "edge_f1"], np.nan))
    quality = triangle_quality(mesh)
    return MeshReport(
        hausdorff=max(to_true.max(), to_mesh.max()) / voxel,
        chamfer=0.5 * (to_true.mean() + to_mesh.mean()) / voxel,
        normal_consistency=float(np.einsum("ij,ij->i", mn, tn[nearest]).mean()),
        edge_chamfer=edges["edge_chamfer"] / voxel,
        edge_f1=edges["edge_f1"], edge_precision=edges["edge_precision"], edge_recall=edges["edge_recall"],
        **quality,
        n_faces=mesh.n_faces,
        boundary_edges=len(mesh.boundary_edges()),
        non_manifold_edges=mesh.non_manifold_edge_count(),
        non_manifold_vertices=non_manifold_vertex_count(mesh.vertices, mesh.faces),
        folded_pairs=len(folded_pairs(mesh.vertices, mesh.faces)),
        self_intersections=self_intersection_count(mesh) if intersections else -1,
        signed_volume=mesh.signed_volume(),
    )
