"""Restricted Delaunay triangulation of the generators, read off the labelled refined mesh.

Every refined face carries the generator whose restricted Voronoi cell it lies in. A refined
vertex where three or more cells meet is a Voronoi vertex of the restricted diagram; the
cells around it, in counter-clockwise order about the outward normal, are the corners of a
dual polygon (a triangle, or a polygon to triangulate where four or more cells meet).
Orientation therefore follows the input's.

Peak memory: 8 bytes per refined vertex (the first two labels met at each), then 4 bytes per
refined face around a Voronoi vertex (a few per cent of them), all in one compiled kernel.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from apt_filters.contour.metrics import face_quality
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh.sampling import Samples, lattice_ids


def triangulate_polygon(poly, positions: np.ndarray, pinned: np.ndarray, sliver=None) -> np.ndarray:
    """(k - 2, 3) faces of a small convex-ish polygon of k generator ids (counter-clockwise):
    :func:`triangulate_polygons` of one."""
    return triangulate_polygons(np.asarray(poly, np.int64)[None], positions, pinned, sliver)[0]


def triangulate_polygons(polys: np.ndarray, positions: np.ndarray, pinned: np.ndarray, sliver=None) -> np.ndarray:
    """(n, k - 2, 3) faces of n small convex-ish polygons of k generator ids each ((n, k), counter-clockwise),
    all at once (one at a time, the polygons where five or more cells meet cost a tenth of the remesh on
    bumpy surfaces).

    Diagonals between two feature generators (``pinned``) are taken first, since the edge
    between consecutive generators on a feature curve must exist; otherwise the fan that
    maximises the smallest angle is used (the first apex on ties). Never a fan with a face that
    ``sliver(p, q, r)`` -> (m,) bool forbids (:func:`apt_filters.remesh.remesh.curve_slivers`: three generators
    along one feature curve, whose diagonal skips the middle one) where another fan has none.
    """
    n, k = polys.shape
    if n == 0:
        return np.empty((0, k - 2, 3), np.int64)
    apex = np.arange(k)[:, None]
    j = np.arange(1, k - 1)[None]
    corners = np.stack([np.broadcast_to(apex, (k, k - 2)), (apex + j) % k, (apex + j + 1) % k], axis=2)
    fans = polys[:, corners]  # (n, apex, k - 2, 3)
    faces = fans.reshape(-1, 3)
    angles = face_quality(TriMesh(positions, faces))[0]
    score = angles.min(axis=1).reshape(n, k, k - 2).min(axis=2)  # degrees
    # 180 for every diagonal of the fan (apex to its corner apex + 2 .. apex + k - 2) between pinned generators
    diagonal = pinned[polys][:, corners[:, 1:, 1]]  # (n, apex, k - 3)
    score += 180.0 * (pinned[polys][:, :, None] & diagonal).sum(axis=2)
    if sliver is not None:
        score[sliver(*faces.T).reshape(n, k, k - 2).any(axis=2)] = -np.inf
    return fans[np.arange(n), np.argmax(score, axis=1)]


def triangulate_quads(quads: np.ndarray, positions: np.ndarray, pinned: np.ndarray, sliver=None) -> np.ndarray:
    """:func:`triangulate_polygon` for many quadrilaterals (q, 4) at once: (2q, 3) faces.

    Of the two diagonals, one that makes a ``sliver`` loses, then the one between two ``pinned``
    generators wins, then the one whose two triangles have the larger smallest angle (the diagonal 0-2 on
    ties).
    """
    first = np.stack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1)  # diagonal 0-2
    second = np.stack([quads[:, [1, 2, 3]], quads[:, [1, 3, 0]]], axis=1)  # diagonal 1-3
    both = np.concatenate([first, second]).reshape(-1, 3)
    angles = face_quality(TriMesh(positions, both))[0].min(axis=1).reshape(2, -1, 2).min(axis=2)
    angles[0] += 180.0 * (pinned[quads[:, 0]] & pinned[quads[:, 2]])
    angles[1] += 180.0 * (pinned[quads[:, 1]] & pinned[quads[:, 3]])
    if sliver is not None:
        angles[sliver(*both.T).reshape(2, -1, 2).any(axis=2)] = -np.inf
    return np.where((angles[1] > angles[0])[:, None, None], second, first).reshape(-1, 3)


@njit(cache=True)
def _voronoi_fans(lattice, labels, n_vertices):
    """The cells around every refined vertex where three or more meet (a Voronoi vertex), in fan order.

    Two passes over the refined faces (made face by face from ``lattice``, :meth:`Lattice.args`) find
    those vertices (the first two labels met at each vertex, int32) and the faces around them (a CSR
    table of the meeting vertices only; each entry 3·face + the vertex's corner in that face, known when the
    table is filled: found again from the corners' ids, it was a third of this kernel's time); each fan is
    then walked counter-clockwise from connectivity alone: face ``(v, x, y)`` is followed by the face holding
    ``(v, y, z)``, from the face without a predecessor (an open fan) or else from the lowest face id, so no
    geometry enters and sliver faces cannot swap places. Along the walk, runs of one label (compared
    cyclically, the last with the first) become one polygon corner.

    Returns (k,) int64 counts of corners per Voronoi vertex, in vertex order, and the corners' labels
    concatenated.
    """
    pattern = lattice[5]
    per_face = len(pattern)
    ids = np.empty(len(lattice[4]), np.int64)  # refined vertex ids of one input face's lattice points
    seen = np.full((n_vertices, 2), -1, np.int32)  # the first two labels met at each vertex
    n_meet = 0
    for f in range(len(labels) // per_face):
        lattice_ids(lattice, f, ids)
        for j in range(per_face):
            label = labels[f * per_face + j]
            for k in range(3):
                v = ids[pattern[j, k]]
                if seen[v, 1] == -2:  # already a meeting vertex
                    continue
                if seen[v, 0] < 0 or seen[v, 0] == label:
                    seen[v, 0] = label
                elif seen[v, 1] < 0 or seen[v, 1] == label:
                    seen[v, 1] = label
                else:
                    seen[v, 1] = -2  # a third label: a meeting vertex; seen[v, 0] becomes its rank below
                    n_meet += 1
    rank = 0
    for v in range(n_vertices):
        if seen[v, 1] == -2:
            seen[v, 0] = rank
            rank += 1
        else:
            seen[v, 0] = -1
    ptr = np.zeros(n_meet + 1, np.int64)
    meets = np.zeros(len(labels) // per_face, np.bool_)  # input faces with a meeting vertex: the next pass's
    for f in range(len(labels) // per_face):
        lattice_ids(lattice, f, ids)
        for j in range(per_face):
            for k in range(3):
                r = seen[ids[pattern[j, k]], 0]
                if r >= 0:
                    ptr[r + 1] += 1
                    meets[f] = True
    for r in range(n_meet):
        ptr[r + 1] += ptr[r]
    around = np.empty(ptr[-1], np.int32)
    fill = ptr[:-1].copy()
    for f in range(len(labels) // per_face):  # faces in ascending order: each fan's list is sorted
        if not meets[f]:
            continue
        lattice_ids(lattice, f, ids)
        for j in range(per_face):
            for k in range(3):
                r = seen[ids[pattern[j, k]], 0]
                if r >= 0:
                    around[fill[r]] = (f * per_face + j) * 3 + k  # the face and which of its corners is the vertex
                    fill[r] += 1
    counts = np.zeros(n_meet, np.int64)
    corners = np.empty(ptr[-1], np.int64)
    n_corners = 0
    widest = 0
    for r in range(n_meet):
        widest = max(widest, ptr[r + 1] - ptr[r])
    nxt = np.empty(widest, np.int64)  # x and y of the face (v, x, y), per face of the fan
    prv = np.empty(widest, np.int64)
    order = np.empty(widest, np.int64)
    last = -1  # the input face whose lattice points' ids ``ids`` holds
    for v in range(n_vertices):
        r = seen[v, 0]
        if r < 0:
            continue
        lo, hi = ptr[r], ptr[r + 1]
        m = hi - lo
        for j in range(m):
            face, k = around[lo + j] // 3, around[lo + j] % 3
            f, p = face // per_face, face % per_face
            if f != last:
                lattice_ids(lattice, f, ids)
                last = f
            nxt[j] = ids[pattern[p, (k + 1) % 3]]
            prv[j] = ids[pattern[p, (k + 2) % 3]]
        first = 0
        for j in range(m):  # an open fan starts at its face without a predecessor (no face ends at its x)
            has_pred = False
            for i in range(m):
                if prv[i] == nxt[j]:
                    has_pred = True
                    break
            if not has_pred:
                first = j
                break
        order[0] = first
        length = 1
        while length < m:
            j, succ = order[length - 1], -1
            for i in range(m):
                if nxt[i] == prv[j]:
                    succ = i
                    break
            if succ < 0 or succ == first:
                break
            order[length] = succ
            length += 1
        start = n_corners
        for j in range(length):
            label = labels[around[lo + order[j]] // 3]
            if label != labels[around[lo + order[length - 1 if j == 0 else j - 1]] // 3]:
                corners[n_corners] = label
                n_corners += 1
        counts[r] = n_corners - start
    return counts, corners[:n_corners]


def dual_faces(samples: Samples, labels: np.ndarray, positions: np.ndarray,
               pinned: np.ndarray, sliver=None) -> tuple[np.ndarray, int]:
    """Faces (k, 3) of the restricted Delaunay triangulation, and the number of skipped Voronoi vertices.

    Where four or more cells meet, the polygon's triangulation avoids faces that ``sliver`` forbids
    (:func:`triangulate_polygon`).

    A Voronoi vertex is skipped when a cell appears twice around it (a cell that is not a
    disk there); the repair step closes the resulting gap.
    """
    if 3 * samples.n_samples >= 2**31:  # the fans' table holds 3·face + corner in int32
        raise AptFiltersError(f"{samples.n_samples} refined faces: at most {(2**31 - 1) // 3} can be extracted")
    counts, cl = _voronoi_fans(samples.lattice.args(), labels, samples.n_vertices)
    cstart = np.r_[0, np.cumsum(counts)[:-1]]
    tri = np.flatnonzero(counts == 3)
    out = [np.stack([cl[cstart[tri]], cl[cstart[tri] + 1], cl[cstart[tri] + 2]], 1)]
    quads = cl[cstart[counts == 4, None] + np.arange(4)]
    repeated = (quads[:, [0, 0, 0, 1, 1, 2]] == quads[:, [1, 2, 3, 2, 3, 3]]).any(axis=1)
    out.append(triangulate_quads(quads[~repeated], positions, pinned, sliver))
    skipped = int(repeated.sum())
    # five or more cells: polygons of each size at once, their faces then put back in the Voronoi vertices' order
    big, keys, faces = np.flatnonzero(counts > 4), [], []
    for k in np.unique(counts[big]).tolist():
        at = big[counts[big] == k]
        polys = cl[cstart[at, None] + np.arange(k)]
        ordered = np.sort(polys, axis=1)
        repeated = (ordered[:, 1:] == ordered[:, :-1]).any(axis=1)  # a cell twice round the vertex: skipped
        skipped += int(repeated.sum())
        faces.append(triangulate_polygons(polys[~repeated], positions, pinned, sliver).reshape(-1, 3))
        keys.append(np.repeat(at[~repeated], k - 2))
    if faces:
        out.append(np.concatenate(faces)[np.argsort(np.concatenate(keys), kind="stable")])
    result = np.vstack(out) if out else np.empty((0, 3), np.int64)
    bad = (result[:, 0] == result[:, 1]) | (result[:, 1] == result[:, 2]) | (result[:, 0] == result[:, 2])
    skipped += int(bad.sum())
    return result[~bad], skipped
