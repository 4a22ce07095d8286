"""Removing self-intersections that noise-driven vertex moves can leave (dents that touch the opposite side).

Folds between neighbouring faces are prevented by :func:`~apt_filters.refine.surface.guarded_move`;
two faces far apart on the mesh can still cross (a dent pushed through), which would flip the
sign of proxigram distances near them. :func:`untangle` finds intersecting faces (pymeshlab,
CPU filter) and smooths their vertices and one ring around them locally, then, if that does not
separate them, moves those vertices back toward their positions in the (intersection-free) input.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.sparse import csr_matrix

SMOOTH_ROUNDS = 6
REVERT_ROUNDS = 6


def intersecting_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces that intersect another face of the mesh."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces.astype(np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    return ms.current_mesh().face_selection_array().astype(bool)


def untangle(vertices: np.ndarray, faces: np.ndarray, original: np.ndarray, mean_of_neighbours: csr_matrix,
             move: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> tuple[np.ndarray, int]:
    """Vertices with no face crossing another (see the module docstring), and the rounds used.

    ``move(vertices, step)`` applies a fold-guarded step; ``original`` (n, 3) are the input
    positions, which must be free of intersections for the last resort to end them.
    """
    adj = mean_of_neighbours > 0
    for rounds in range(SMOOTH_ROUNDS + REVERT_ROUNDS):
        bad = intersecting_faces(vertices, faces)
        if not bad.any():
            return vertices, rounds
        region = np.zeros(len(vertices), dtype=bool)
        region[faces[bad].ravel()] = True
        region |= np.asarray(adj @ region.astype(np.float64) > 0).ravel()
        if rounds < SMOOTH_ROUNDS:
            step = (mean_of_neighbours @ vertices) - vertices
        else:
            step = (original - vertices) * (1.0 if rounds == SMOOTH_ROUNDS + REVERT_ROUNDS - 1 else 0.5)
        vertices = move(vertices, np.where(region[:, None], step, 0.0))
    return vertices, SMOOTH_ROUNDS + REVERT_ROUNDS
