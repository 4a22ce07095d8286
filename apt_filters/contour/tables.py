"""Marching-cubes case tables, generated from the cube's geometry (not typed in).

Cube conventions (shared by marching cubes and dual contouring)
----------------------------------------------------------------
Corner ``c`` (0..7) sits at offset ``(c & 1, c >> 1 & 1, c >> 2 & 1)`` in x, y, z.
Edge ``e = 4 * a + k`` runs along axis ``a`` from the corner whose other two bits are
``k & 1`` (axis ``(a + 1) % 3``) and ``k >> 1`` (axis ``(a + 2) % 3``).

How a table entry is built
--------------------------
Each of the six faces is contoured on its own (marching squares). A face whose two
inside corners are diagonal is ambiguous; a *face bit* says whether its inside corners
are connected (set at run time by the asymptotic decider, which depends only on the four
face values, so both cells that share the face decide alike: closed objects come out
watertight). Every face segment is oriented so that, seen from outside the cube, the
inside corners lie on its right; chaining the segments gives closed, consistently
oriented loops, one per surface sheet in the cell (the sheets dual contouring needs).
Each loop is triangulated without diagonals between two points on one cube face (such a
diagonal could coincide with the neighbour's and make a non-manifold edge), choosing the
triangulation with the largest minimum angle.

A table key is ``case * 64 + face_bits`` with ``case`` the 8-bit inside-corner mask and
only bits of ambiguous faces set.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

CORNERS = np.array([[c & 1, c >> 1 & 1, c >> 2 & 1] for c in range(8)], dtype=np.int64)


def _edge_corners(e: int) -> tuple[int, int]:
    a, k = divmod(e, 4)
    u, v = (a + 1) % 3, (a + 2) % 3
    c0 = ((k & 1) << u) | ((k >> 1) << v)
    return c0, c0 | (1 << a)


EDGES = np.array([_edge_corners(e) for e in range(12)], dtype=np.int64)  # (12, 2) corner ids
EDGE_AXIS = np.repeat(np.arange(3), 4)
EDGE_START = CORNERS[EDGES[:, 0]]  # (12, 3) offset of each edge's start corner
CENTRE = 12  # triangle corner ids >= CENTRE name the centre vertex of loop (id - CENTRE)


def _faces() -> list[tuple[np.ndarray, list[int], list[int]]]:
    """(outward normal, 4 corners in cyclic order, 4 edges between consecutive corners) per face."""
    faces = []
    for a in range(3):
        u, v = (a + 1) % 3, (a + 2) % 3
        for s in (0, 1):
            cyc = [(0, 0), (1, 0), (1, 1), (0, 1)]
            corners = [(s << a) | (bu << u) | (bv << v) for bu, bv in cyc]
            edges = []
            for i in range(4):
                pair = {corners[i], corners[(i + 1) % 4]}
                edges.append(next(e for e in range(12) if set(EDGES[e]) == pair))
            normal = np.zeros(3)
            normal[a] = 2 * s - 1
            faces.append((normal, corners, edges))
    return faces


FACES = _faces()
FACE_CORNERS = np.array([f[1] for f in FACES], dtype=np.int64)  # (6, 4) cyclic order
_MID = (CORNERS[EDGES[:, 0]] + CORNERS[EDGES[:, 1]]) / 2.0  # edge midpoints


def ambiguous_faces(case: int) -> list[int]:
    """Faces whose inside corners are exactly one diagonal pair."""
    out = []
    for f, corners in enumerate(FACE_CORNERS):
        inside = [(case >> c) & 1 for c in corners]
        if inside in ([1, 0, 1, 0], [0, 1, 0, 1]):
            out.append(f)
    return out


def _face_segments(case: int, f: int, connected: bool) -> list[tuple[int, int]]:
    """Oriented segments (edge_from, edge_to) of face ``f``."""
    normal, corners, edges = FACES[f]
    inside = [(case >> c) & 1 for c in corners]
    n_in = sum(inside)
    if n_in in (0, 4):
        return []
    # A segment cuts off corner i (between face edges i-1 and i) when that corner differs
    # from the majority; two adjacent inside corners give one straight cut instead.
    if n_in == 2 and inside[0] != inside[2]:
        crossed = [edges[i] for i in range(4) if inside[i] != inside[(i + 1) % 4]]
        pairs = [(crossed[0], crossed[1], corners[0])]
    else:
        if n_in == 2:  # ambiguous: cut the corners that are *not* connected
            cut = [i for i in range(4) if inside[i] != connected]
        else:
            minority = 1 if n_in == 1 else 0
            cut = [i for i in range(4) if inside[i] == minority]
        pairs = [(edges[i - 1], edges[i], corners[i]) for i in cut]
    segments = []
    for e0, e1, corner in pairs:
        d, r = _MID[e1] - _MID[e0], CORNERS[corner] - _MID[e0]
        left = float(np.dot(normal, (d[1] * r[2] - d[2] * r[1], d[2] * r[0] - d[0] * r[2], d[0] * r[1] - d[1] * r[0]))) > 0
        corner_inside = bool((case >> corner) & 1)
        segments.append((e1, e0) if left == corner_inside else (e0, e1))
    return segments


def _loops(case: int, face_bits: int) -> list[list[int]]:
    nxt: dict[int, int] = {}
    for f in range(6):
        for e0, e1 in _face_segments(case, f, bool(face_bits >> f & 1)):
            assert e0 not in nxt, "two segments leave one crossing"
            nxt[e0] = e1
    loops, seen = [], set()
    for start in sorted(nxt):
        if start in seen:
            continue
        loop, e = [], start
        while e not in seen:
            seen.add(e)
            loop.append(e)
            e = nxt[e]
        assert e == start, "open face-segment chain"
        loops.append(loop)
    return loops


_SHARES_FACE = np.array([[any(e0 in f[2] and e1 in f[2] for f in FACES) for e1 in range(12)] for e0 in range(12)])


@functools.lru_cache(maxsize=None)
def _min_angle_of(e0: int, e1: int, e2: int) -> float:
    """Smallest angle (rad) of the triangle on three edge midpoints."""
    angles = []
    for p, q, r in ((e0, e1, e2), (e1, e2, e0), (e2, e0, e1)):
        u, w = _MID[q] - _MID[p], _MID[r] - _MID[p]
        cosine = np.dot(u, w) / (np.linalg.norm(u) * np.linalg.norm(w))
        angles.append(np.arccos(np.clip(cosine, -1, 1)))
    return float(min(angles))


@functools.lru_cache(maxsize=None)
def _triangulate(loop: tuple[int, ...], centre_id: int) -> list[tuple[int, int, int]]:
    """Max-min-angle triangulation of a loop, never using a diagonal inside one cube face.

    Loops without such a triangulation are fanned around vertex ``CENTRE + centre_id``
    (the mean of the loop's crossings, added at run time).
    """
    n = len(loop)

    def ok(i: int, j: int) -> bool:
        return (j - i) % n in (1, n - 1) or not _SHARES_FACE[loop[i], loop[j]]

    @functools.lru_cache(maxsize=None)
    def best(i: int, j: int) -> tuple[float, tuple]:
        if j - i < 2:
            return np.inf, ()
        result: tuple[float, tuple] = (-np.inf, ())
        for k in range(i + 1, j):
            if not (ok(i, k) and ok(k, j)):
                continue
            left, right = best(i, k), best(k, j)
            score = min(left[0], right[0], _min_angle_of(loop[i], loop[k], loop[j]))
            if score > result[0]:
                result = (score, left[1] + right[1] + ((i, k, j),))
        return result

    score, tris = best(0, n - 1)
    if not np.isfinite(score):
        # Every triangulation would need an in-face diagonal: fan around a centre vertex.
        return [(loop[i], loop[(i + 1) % n], CENTRE + centre_id) for i in range(n)]
    return [(loop[i], loop[k], loop[j]) for i, k, j in tris]


@dataclass(frozen=True)
class CaseTable:
    """Flat lookup arrays indexed by key = case * 64 + face_bits.

    Attributes
    ----------
    ambiguous : (256, 6) bool
        Faces whose bit matters for each case.
    crossed : (256, 12) bool
        Edges with a sign change for each case.
    n_tris, tri_start : (16384,) int64
        Triangle count and offset into ``tris`` per key.
    tris : (t, 3) int64
        Cube-edge ids of each triangle, oriented so normals point to lower values.
    n_loops : (16384,) int64
        Surface sheets per key.
    edge_loop : (16384, 12) int64
        Sheet of each crossed edge (-1 where not crossed).
    """

    ambiguous: np.ndarray
    crossed: np.ndarray
    n_tris: np.ndarray
    tri_start: np.ndarray
    tris: np.ndarray
    n_loops: np.ndarray
    edge_loop: np.ndarray


@functools.lru_cache(maxsize=1)
def case_table() -> CaseTable:
    """Build (once per process, ~0.2 s) the 256-case table with all face resolutions."""
    n_keys = 256 * 64
    ambiguous = np.zeros((256, 6), dtype=bool)
    crossed = np.zeros((256, 12), dtype=bool)
    n_tris = np.zeros(n_keys, dtype=np.int64)
    n_loops = np.zeros(n_keys, dtype=np.int64)
    edge_loop = np.full((n_keys, 12), -1, dtype=np.int64)
    tri_lists: dict[int, list] = {}
    for case in range(256):
        inside = (case >> np.arange(8)) & 1
        crossed[case] = inside[EDGES[:, 0]] != inside[EDGES[:, 1]]
        amb = ambiguous_faces(case)
        ambiguous[case, amb] = True
        for combo in range(1 << len(amb)):
            bits = sum(1 << f for i, f in enumerate(amb) if combo >> i & 1)
            key = case * 64 + bits
            loops = _loops(case, bits)
            tris = []
            for li, loop in enumerate(loops):
                edge_loop[key, loop] = li
                tris += _triangulate(tuple(loop), li)
            n_loops[key] = len(loops)
            n_tris[key] = len(tris)
            tri_lists[key] = tris
    tri_start = np.concatenate([[0], np.cumsum(n_tris)[:-1]])
    tris = np.zeros((int(n_tris.sum()), 3), dtype=np.int64)
    for key, lst in tri_lists.items():
        if lst:
            tris[tri_start[key]: tri_start[key] + len(lst)] = lst
    return CaseTable(ambiguous, crossed, n_tris, tri_start, tris, n_loops, edge_loop)
