"""Mesh samples and sanity checks: uniform surface samples, triangle quality, self-intersections.

Triangle quality: minimum angle, and Q = 6/√3 · A / (p · h_max) (p half-perimeter, h_max longest
side; 1 for an equilateral triangle). Comparisons with a true surface are in :mod:`apt_filters.truth`.
"""

from __future__ import annotations

import numpy as np

from apt_filters.core.checks import self_intersecting_faces
from apt_filters.core.mesh import TriMesh


def sample_mesh(mesh: TriMesh, density: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random points on the mesh (``density`` per unit area) with their face normals."""
    areas = mesh.face_areas()
    n = int(rng.poisson(areas.sum() * density))
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.stack([1 - s, s * (1 - r2), s * r2], 1)
    pts = np.einsum("ni,nij->nj", w, mesh.vertices[mesh.faces[face]])
    return pts, mesh.face_normals()[face]


def face_quality(mesh: TriMesh) -> tuple[np.ndarray, np.ndarray]:
    """Per face: (m, 3) interior angles in degrees (at corners 0, 1, 2) and (m,) Q = 6/√3 · A/(p · h_max)."""
    v = mesh.vertices[mesh.faces]
    sides = np.linalg.norm(v[:, [1, 2, 0]] - v, axis=2)  # (m, 3): |v1-v0|, |v2-v1|, |v0-v2|
    area = mesh.face_areas()
    p = sides.sum(axis=1) / 2
    q = 6 / np.sqrt(3) * area / np.maximum(p * sides.max(axis=1), 1e-300)
    a, b, c = sides[:, 0], sides[:, 1], sides[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):  # a side of length 0: that corner's angle reads 0 below
        cosines = np.stack([(a**2 + c**2 - b**2) / (2 * a * c), (a**2 + b**2 - c**2) / (2 * a * b),
                            (b**2 + c**2 - a**2) / (2 * b * c)], 1)
    return np.degrees(np.arccos(np.clip(np.nan_to_num(cosines, nan=1.0), -1, 1))), q


def triangle_quality(mesh: TriMesh) -> dict:
    """Minimum angle (degrees) and Q = 6/√3 · A/(p · h_max): min and mean over faces."""
    angles, q = face_quality(mesh)
    return {"min_angle": float(angles.min()), "mean_min_angle": float(angles.min(axis=1).mean()),
            "q_min": float(q.min()), "q_mean": float(q.mean())}


def self_intersection_count(mesh: TriMesh) -> int:
    """Faces that intersect another face (pymeshlab ``compute_selection_by_self_intersections_per_face``)."""
    return int(self_intersecting_faces(mesh.vertices, mesh.faces).sum())
