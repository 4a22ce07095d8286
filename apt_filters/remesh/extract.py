"""Restricted Delaunay triangulation of the generators, read off the labelled refined mesh.

Every refined face carries the generator whose restricted Voronoi cell it lies in. A refined
vertex where three or more cells meet is a Voronoi vertex of the restricted diagram; the
cells around it, in counter-clockwise order about the outward normal, are the corners of a
dual polygon (a triangle, or a polygon to triangulate where four or more cells meet).
Orientation therefore follows the input's.

Peak memory: 17 bytes per refined vertex (the labels met at each, in one compiled pass), then
arrays of the refined faces around the Voronoi vertices only.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from apt_filters.contour.metrics import face_quality
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh.sampling import Samples


def fan_order(faces: np.ndarray, n_vertices: int, wanted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Incidences (vertex, face) sorted counter-clockwise around each vertex, from connectivity alone.

    Face ``(v, x, y)`` is followed around ``v`` by the face holding ``(v, y, z)``. Each fan
    is cut once (at its boundary, or anywhere for a closed fan) and ranked by list ranking
    (pointer jumping), so no geometry enters: sliver faces cannot swap places.

    Returns ``vertex`` and ``face`` arrays of the incidences in that order, only around the
    vertices flagged in ``wanted`` (v,) bool when given.
    """
    v = faces.ravel()
    nxt = np.roll(faces, -1, axis=1).ravel()
    prv = np.roll(faces, 1, axis=1).ravel()
    face = np.repeat(np.arange(len(faces)), 3)
    if wanted is not None:  # fans only link incidences of one vertex, so others can go
        keep = wanted[v]
        v, nxt, prv, face = v[keep], nxt[keep], prv[keep], face[keep]
    key = v * n_vertices + nxt
    order = np.argsort(key)
    want = v * n_vertices + prv
    pos = np.minimum(np.searchsorted(key[order], want), len(key) - 1)
    succ = np.where(key[order[pos]] == want, order[pos], -1)
    has_pred = np.zeros(len(v), bool)
    has_pred[succ[succ >= 0]] = True
    # closed fans: cut before their lowest incidence
    open_vertex = np.zeros(n_vertices, bool)
    open_vertex[v[~has_pred]] = True
    first = np.full(n_vertices, len(v))
    np.minimum.at(first, v, np.arange(len(v)))
    cut = (succ >= 0) & ~open_vertex[v] & (succ == first[v])
    succ[cut] = -1
    dist = (succ >= 0).astype(np.int64)
    jump = succ.copy()
    while (jump >= 0).any():
        live = jump >= 0
        dist[live] += dist[jump[live]]
        jump[live] = jump[jump[live]]
    ranked = np.lexsort((-dist, v))
    return v[ranked], face[ranked]


def triangulate_polygon(poly: list, positions: np.ndarray, pinned: np.ndarray) -> list:
    """Triangulate a small convex-ish polygon of generator ids (counter-clockwise).

    Diagonals between two feature generators (``pinned``) are taken first, since the edge
    between consecutive generators on a feature curve must exist; otherwise the fan that
    maximises the smallest angle is used.
    """
    k = len(poly)
    fans = [[(poly[apex], poly[(apex + j) % k], poly[(apex + j + 1) % k]) for j in range(1, k - 1)]
            for apex in range(k)]
    angles = face_quality(TriMesh(positions, np.array(fans).reshape(-1, 3)))[0]
    score = angles.min(axis=1).reshape(k, k - 2).min(axis=1)  # degrees
    for apex in range(k):
        score[apex] += sum(180.0 for j in range(2, k - 1) if pinned[poly[apex]] and pinned[poly[(apex + j) % k]])
    return fans[int(np.argmax(score))]


def triangulate_quads(quads: np.ndarray, positions: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """:func:`triangulate_polygon` for many quadrilaterals (q, 4) at once: (2q, 3) faces.

    Of the two diagonals, the one between two ``pinned`` generators wins, then the one whose
    two triangles have the larger smallest angle (the diagonal 0-2 on ties).
    """
    first = np.stack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1)  # diagonal 0-2
    second = np.stack([quads[:, [1, 2, 3]], quads[:, [1, 3, 0]]], axis=1)  # diagonal 1-3
    both = np.concatenate([first, second]).reshape(-1, 3)
    angles = face_quality(TriMesh(positions, both))[0].min(axis=1).reshape(2, -1, 2).min(axis=2)
    angles[0] += 180.0 * (pinned[quads[:, 0]] & pinned[quads[:, 2]])
    angles[1] += 180.0 * (pinned[quads[:, 1]] & pinned[quads[:, 3]])
    return np.where((angles[1] > angles[0])[:, None, None], second, first).reshape(-1, 3)


@njit(cache=True)
def _meeting_vertices(faces, labels, n_vertices):
    """(v,) bool: refined vertices where faces of three or more labels (cells) meet."""
    seen = np.full((n_vertices, 2), -1, np.int64)  # the first two labels met at each vertex
    out = np.zeros(n_vertices, np.bool_)
    for i in range(len(faces)):
        label = labels[i]
        for k in range(3):
            v = faces[i, k]
            if seen[v, 0] < 0 or seen[v, 0] == label:
                seen[v, 0] = label
            elif seen[v, 1] < 0 or seen[v, 1] == label:
                seen[v, 1] = label
            else:
                out[v] = True
    return out


def dual_faces(samples: Samples, labels: np.ndarray, positions: np.ndarray,
               pinned: np.ndarray) -> tuple[np.ndarray, int]:
    """Faces (k, 3) of the restricted Delaunay triangulation, and the number of skipped Voronoi vertices.

    A Voronoi vertex is skipped when a cell appears twice around it (a cell that is not a
    disk there); the repair step closes the resulting gap.
    """
    meeting = _meeting_vertices(samples.faces, labels, len(samples.vertices))
    # only the refined faces around those vertices (a few per cent) take part from here
    around = np.flatnonzero(meeting[samples.faces].any(axis=1))
    inc_v, inc_f = fan_order(samples.faces[around].astype(np.int64), len(samples.vertices), meeting)
    inc_f = around[inc_f]
    inc_l = labels[inc_f]
    first = np.r_[True, inc_v[1:] != inc_v[:-1]]
    start = np.flatnonzero(first)
    group = np.cumsum(first) - 1
    last = np.r_[start[1:], len(inc_v)] - 1
    prev = np.r_[-1, inc_l[:-1]]
    prev[start] = inc_l[last]
    change = inc_l != prev
    cl = inc_l[change]
    cgroup = group[change]
    counts = np.bincount(cgroup, minlength=len(start))
    cstart = np.r_[0, np.cumsum(counts)[:-1]]
    tri = np.flatnonzero(counts == 3)
    out = [np.stack([cl[cstart[tri]], cl[cstart[tri] + 1], cl[cstart[tri] + 2]], 1)]
    quads = cl[cstart[counts == 4, None] + np.arange(4)]
    repeated = (quads[:, [0, 0, 0, 1, 1, 2]] == quads[:, [1, 2, 3, 2, 3, 3]]).any(axis=1)
    out.append(triangulate_quads(quads[~repeated], positions, pinned))
    skipped = int(repeated.sum())
    for g in np.flatnonzero(counts > 4):
        poly = cl[cstart[g]:cstart[g] + counts[g]].tolist()
        if len(set(poly)) != len(poly):
            skipped += 1
            continue
        out.append(np.array(triangulate_polygon(poly, positions, pinned)))
    result = np.vstack(out) if out else np.empty((0, 3), np.int64)
    bad = (result[:, 0] == result[:, 1]) | (result[:, 1] == result[:, 2]) | (result[:, 0] == result[:, 2])
    skipped += int(bad.sum())
    return result[~bad], skipped
