"""Removing self-intersections that noise-driven vertex moves can leave (dents that touch the opposite side).

Folds between neighbouring faces are prevented by :func:`~apt_filters.refine.surface.guarded_move`,
but the guard keeps folds it is given (:func:`unfold` removes those from the input first), and
faces two or more steps apart on the mesh can still cross (a dent pushed through, or the fan of
sliver triangles around a vertex turning over itself), which would flip the sign of proxigram
distances near them. :func:`untangle` finds crossing faces
(:func:`~apt_filters.core.checks.self_intersecting_faces`) and folded pairs and smooths their
vertices locally, then their vertices and one ring around them, then, if that does not separate
them, moves those vertices back toward their positions in the (clean) input.

The ring waits: on a thin disc whose start's two faces lie close (zoo thin, 1.6-1.9 nm thick), the placement's
moves of ~1 nm crumple a start 0.5 nm thick into 100-300 crossing faces over its flat faces, and smoothing their
vertices together with one ring (~40 % of the disc) shrank it by 11-27 % of its volume; the crossing faces'
vertices alone separate in 2-5 rounds and keep it (dev thin 30003 disc -14.0 -> -2.5 %, 30004 -13.5 -> -6.1 %
against the truth, replayed on the same meshes).

pymeshlab's test alone also flags disjoint triangles that lie exactly in one plane, which the
facet step makes by the hundred (every vertex of a cube's face projected onto its fitted plane):
on gamma-prime seed 3 it flagged 11-16 faces of well-separated coplanar pairs, whose smoothing
then moved cube vertices by up to 0.77 nm, and which 11 or 16 depended on rounding (start
vertices moved by 1e-12 nm), so each flagged face is confirmed by the exact test.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.sparse import csr_matrix

from apt_filters.core.checks import folded_pairs, self_intersecting_faces

SMOOTH_ROUNDS = 6
ALONE_ROUNDS = 6
REVERT_ROUNDS = 6
UNFOLD_ROUNDS = 30


def _folded_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    out = np.zeros(len(vertices), dtype=bool)
    out[faces[folded_pairs(vertices, faces).ravel()].ravel()] = True
    return out


def _tangled_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    out = _folded_vertices(vertices, faces)
    out[faces[self_intersecting_faces(vertices, faces)].ravel()] = True
    return out


def _relax(vertices: np.ndarray, faces: np.ndarray, mean_of_neighbours: csr_matrix,
           offending: Callable[[np.ndarray, np.ndarray], np.ndarray], smooth_rounds: int,
           original: np.ndarray | None = None, revert_rounds: int = 0, alone_rounds: int = 0) -> tuple[np.ndarray, int]:
    """Smooth the ``offending`` vertices (alone for the first ``alone_rounds`` rounds, then with one ring around
    them) until none is left (see :func:`untangle`)."""
    adj = mean_of_neighbours > 0
    total = alone_rounds + smooth_rounds + revert_rounds
    for rounds in range(total):
        region = offending(vertices, faces)
        if not region.any():
            return vertices, rounds
        if rounds >= alone_rounds:
            region |= np.asarray(adj @ region.astype(np.float64) > 0).ravel()
        if rounds < alone_rounds + smooth_rounds:
            target = mean_of_neighbours @ vertices
        else:
            target = original if rounds == total - 1 else 0.5 * (original + vertices)
        vertices = np.where(region[:, None], target, vertices)
    return vertices, total


def untangle(vertices: np.ndarray, faces: np.ndarray, original: np.ndarray,
             mean_of_neighbours: csr_matrix) -> tuple[np.ndarray, int]:
    """Vertices with no face crossing another and no folded pair (see the module docstring), and the rounds used.

    Each round moves the vertices of crossing faces and of folded pairs to the mean of their
    neighbours (``mean_of_neighbours`` (n, n) @ vertices), without the fold guard: the faces of
    a dent pushed through are turned inside out, and only a move that turns them back can
    separate them (the guard forbids exactly that). For the first :data:`ALONE_ROUNDS` rounds
    those vertices move alone (the least that separates them: the ring's smoothing shrinks thin
    objects, module docstring), then :data:`SMOOTH_ROUNDS` rounds with one ring around them.
    After that they are moved halfway back toward ``original`` (n, 3) each round, the last round
    all the way; ``original`` must be free of both for this last resort.
    """
    return _relax(vertices, faces, mean_of_neighbours, _tangled_vertices, SMOOTH_ROUNDS, original, REVERT_ROUNDS,
                  ALONE_ROUNDS)


def unfold(vertices: np.ndarray, faces: np.ndarray, mean_of_neighbours: csr_matrix,
           original: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Vertices with no folded face pair (:func:`~apt_filters.core.checks.folded_pairs`), and the rounds used.

    Marching cubes on a noisy, masked field leaves a few folds (13 pairs on the 10M-ion ``many``
    specimen, on sliver triangles of ~0.1 nm²); the fold guard of the refinement keeps folds it
    is given, so they are removed first, as :func:`untangle` removes crossings (3 rounds there,
    moves < 0.5 nm). Gives up after :data:`UNFOLD_ROUNDS` rounds; where ``original`` (n, 3), free of folds,
    is given, the folded vertices left and one ring around them are then moved halfway back toward it each
    round for :data:`REVERT_ROUNDS` rounds, the last all the way (as :func:`untangle` does).
    """
    return _relax(vertices, faces, mean_of_neighbours, _folded_vertices, UNFOLD_ROUNDS, original,
                  REVERT_ROUNDS if original is not None else 0)
