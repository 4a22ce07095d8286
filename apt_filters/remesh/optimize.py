"""Post-optimisation of the extracted mesh: valence-improving edge flips and tangential relaxation.

Lloyd iterations stop in local minima with many pairs of valence-5/7 vertices, which cap the
mean radius ratio near 0.88. Flipping edges that reduce the valence excess, then moving each
free vertex to the centroid of its neighbours (tangentially, projected back onto its patch)
removes most of those pairs, as in isotropic explicit remeshing. Both steps are vectorised:
each flip pass applies an independent set of flips (no two share a face). Two last passes move
vertices to the best of a few candidate points: the vertices of flat rings to raise their ring's mean
quality (:func:`improve_quality`), then only the vertices of triangles still under 30 degrees to raise
their ring's smallest angle (:func:`improve_angles`).

Peak memory: a few arrays of 3 x the number of faces in the flips and the relaxation; the last pass holds
the faces round every vertex (24 bytes per face) and one angle per face.
"""

from __future__ import annotations

import numpy as np

from numba import njit

from apt_filters.core.mesh import TriMesh
from apt_filters.remesh.sampling import chunk_length
from apt_filters.remesh.walk import vertex_rings


def _interior_edges(faces: np.ndarray, n_vertices: int) -> tuple[tuple, tuple]:
    """For each edge shared by two faces: a, b (edge), c, d (opposite corners), f1, f2 (faces).

    Face f1 holds the directed edge a->b (a < b) and f2 the edge b->a, in the order of f1's half-edges
    (face by face). Also returns the faces round every vertex (:func:`walk.vertex_rings`), to look up
    whether an edge exists (:func:`_absent`). Compiled over the rings: no (3f,) keys, sort or search
    (a sort of the half-edges' keys and its temporaries were about 250 bytes per face).
    """
    faces = np.ascontiguousarray(faces, np.int64)
    rings = vertex_rings(faces, n_vertices)
    return _twins(faces, *rings), rings


@njit(cache=True, nogil=True)
def _twins(faces, start, ring):
    """:func:`_interior_edges`' edges: each half-edge a->b (a < b) of face f1 with the half-edge b->a of
    the first face round a that holds one."""
    count = 0
    twin = np.full(3 * len(faces), -1, np.int64)
    for f in range(len(faces)):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            if a < b:
                for s in range(start[a], start[a + 1]):
                    g = ring[s]
                    for j in range(3):
                        if twin[3 * f + k] < 0 and faces[g, j] == b and faces[g, (j + 1) % 3] == a:
                            twin[3 * f + k] = 3 * g + j
                    if twin[3 * f + k] >= 0:
                        count += 1
                        break
    out = np.empty((6, count), np.int64)
    i = 0
    for h in range(3 * len(faces)):
        t = twin[h]
        if t >= 0:
            f, k, g, j = h // 3, h % 3, t // 3, t % 3
            out[0, i], out[1, i], out[2, i] = faces[f, k], faces[f, (k + 1) % 3], faces[f, (k + 2) % 3]
            out[3, i], out[4, i], out[5, i] = faces[g, (j + 2) % 3], f, g
            i += 1
    return out[0], out[1], out[2], out[3], out[4], out[5]


def _face_normals(v: np.ndarray, tri: np.ndarray) -> np.ndarray:
    p = v[tri[:, 0]]  # the corners one at a time: no (f, 3, 3) copy
    n = np.cross(v[tri[:, 1]] - p, v[tri[:, 2]] - p)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _flippable(vertices: np.ndarray, faces: np.ndarray, edge: tuple, rings: tuple, idx: np.ndarray,
               fixed_edge, max_dihedral: float, sliver=None) -> np.ndarray:
    """The edges ``idx`` that may be flipped: flat enough, not fixed, the new faces not folded, c-d new.

    Nor may a new face be one that ``sliver(p, q, r)`` -> bool array forbids (three vertices along one
    feature curve, which come to lie on one line as they slide along it). Only the edges that passed
    the cheap test of the caller are looked at geometrically.
    """
    a, b, c, d, f1, f2 = (x[idx] for x in edge)
    n1, n2 = _face_normals(vertices, faces[f1]), _face_normals(vertices, faces[f2])
    flat = np.einsum("ij,ij->i", n1, n2) > np.cos(np.radians(max_dihedral))
    m1, m2 = _face_normals(vertices, np.stack([c, a, d], 1)), _face_normals(vertices, np.stack([d, b, c], 1))
    mean = n1 + n2
    ok = (np.einsum("ij,ij->i", m1, mean) > 0.5) & (np.einsum("ij,ij->i", m2, mean) > 0.5) & (c != d) \
        & flat & ~fixed_edge(a, b)
    if sliver is not None:
        ok &= ~sliver(c, a, d) & ~sliver(d, b, c)
    return idx[ok & _absent(faces, rings, c, d)]


def _absent(faces: np.ndarray, rings: tuple, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(k,) bool: no edge c-d yet (no face round c holds d; ``rings`` from :func:`_interior_edges`); a flip
    must not duplicate one."""
    return _no_edge(faces, rings[0], rings[1], np.ascontiguousarray(c, np.int64), np.ascontiguousarray(d, np.int64))


@njit(cache=True, nogil=True)
def _no_edge(faces, start, ring, c, d):
    ok = np.ones(len(c), np.bool_)
    for i in range(len(c)):
        for s in range(start[c[i]], start[c[i] + 1]):
            g = ring[s]
            if faces[g, 0] == d[i] or faces[g, 1] == d[i] or faces[g, 2] == d[i]:
                ok[i] = False
                break
    return ok


def _apply_independent(faces: np.ndarray, n: int, edge: tuple, idx: np.ndarray, gain: np.ndarray,
                       seed: int) -> tuple[np.ndarray, int]:
    """Flip an independent set of the edges ``idx``: a flip wins if its priority (``gain`` (len(idx),)
    plus a random tie-break) is the highest around all four of its corners, so no two flips touch
    the same vertex."""
    a, b, c, d, f1, f2 = edge
    if len(idx) == 0:
        return faces, 0
    prio = np.random.default_rng(seed).random(len(idx)) + gain
    best = np.full(n, -np.inf)
    quad = np.stack([a[idx], b[idx], c[idx], d[idx]], 1)
    np.maximum.at(best, quad.ravel(), np.repeat(prio, 4))
    idx = idx[(best[quad] == prio[:, None]).all(axis=1)]
    faces = faces.copy()
    faces[f1[idx]] = np.stack([c[idx], a[idx], d[idx]], 1)
    faces[f2[idx]] = np.stack([d[idx], b[idx], c[idx]], 1)
    return faces, len(idx)


def flip_pass(vertices: np.ndarray, faces: np.ndarray, fixed_edge, target: np.ndarray,
              max_dihedral: float = 20.0, seed: int = 0, sliver=None) -> tuple[np.ndarray, int]:
    """Apply one independent set of valence-reducing flips; returns new faces and the flip count.

    ``fixed_edge(a, b)`` -> bool array marks edges that must stay (feature curves); ``target``
    (v,) is the ideal valence of each vertex (6 inside, 4 on the boundary); ``sliver(p, q, r)`` -> bool
    array marks faces no flip may make.
    """
    edge, rings = _interior_edges(faces, len(vertices))
    a, b, c, d = edge[:4]
    val = np.bincount(faces.ravel(), minlength=len(vertices)).astype(float)  # faces = valence inside; +1 on the boundary
    before = np.abs(val[a] - target[a]) + np.abs(val[b] - target[b]) + np.abs(val[c] - target[c]) \
        + np.abs(val[d] - target[d])
    after = np.abs(val[a] - 1 - target[a]) + np.abs(val[b] - 1 - target[b]) + np.abs(val[c] + 1 - target[c]) \
        + np.abs(val[d] + 1 - target[d])
    idx = np.flatnonzero((after < before) & (val[a] > 3) & (val[b] > 3))
    idx = _flippable(vertices, faces, edge, rings, idx, fixed_edge, max_dihedral, sliver)
    return _apply_independent(faces, len(vertices), edge, idx, (before - after)[idx], seed)


def delaunay_pass(vertices: np.ndarray, faces: np.ndarray, fixed_edge, max_dihedral: float = 20.0,
                  seed: int = 0, sliver=None) -> tuple[np.ndarray, int]:
    """Apply one independent set of Delaunay flips (the two angles opposite an edge sum to more than 180°)."""
    edge, rings = _interior_edges(faces, len(vertices))
    a, b, c, d = edge[:4]
    excess = _angle(vertices, c, a, b) + _angle(vertices, d, a, b) - np.pi
    idx = _flippable(vertices, faces, edge, rings, np.flatnonzero(excess > 1e-6), fixed_edge, max_dihedral,
                     sliver)
    return _apply_independent(faces, len(vertices), edge, idx, excess[idx], seed)


def _angle(vertices: np.ndarray, apex: np.ndarray, p: np.ndarray, q: np.ndarray, chunk: int = 1 << 12) -> np.ndarray:
    """(k,) angle (radians) at vertices ``apex`` of the triangles (apex, p, q), ``chunk`` at a time: over all
    edges at once, its (k, 3) temporaries were the peak of a Delaunay pass (150 bytes per output face)."""
    out = np.empty(len(apex))
    for s in range(0, len(apex), chunk):
        a = vertices[apex[s:s + chunk]]
        u, v = vertices[p[s:s + chunk]] - a, vertices[q[s:s + chunk]] - a
        out[s:s + chunk] = np.arctan2(np.linalg.norm(np.cross(u, v), axis=1), np.einsum("ij,ij->i", u, v))
    return out


def flip_caps(vertices: np.ndarray, faces: np.ndarray, pinned: np.ndarray, max_angle: float = 150.0,
              rounds: int = 16) -> np.ndarray:
    """Flip the long edge of every cap made of three pinned vertices (an angle over ``max_angle`` degrees).

    Extraction can join three consecutive generators of one straight feature curve into a triangle
    of zero area (a cell squeezed between its two neighbours on the curve: on a refined cube,
    corners 0.14 and 0.21 nm apart on a line). The flips and moves after it cannot mend it: edges
    between pinned vertices are taken for feature edges and never flipped, and curve vertices only
    slide along their line. The long edge of such a cap is not a feature edge (the curve runs
    through the apex), so flipping it splits the neighbouring triangle at the apex and keeps the
    curve. Caps in a row (a fan of k generators of one curve round one of them, each cap's long edge
    shared with the next cap: the bumpy gyroid's retries, whose curve cells are finer than the samples)
    open one per round from the end whose neighbour is no cap, so ``rounds`` bounds the longest such
    chain mended (4 rounds left 3 caps of a 6-cap fan on a try of the bumpy gyroid). Returns the new faces.
    """
    limit = np.radians(max_angle)
    for r in range(rounds):
        # a cap is a face of three pinned vertices with an angle over the limit: where there is none (most
        # calls, after every relaxation), the edge tables over the whole mesh are not built
        whole = faces[pinned[faces].all(axis=1)]
        if not any((_angle(vertices, whole[:, k], whole[:, k - 1], whole[:, k - 2]) > limit - 1e-9).any()
                   for k in range(3)):
            break
        edge, rings = _interior_edges(faces, len(vertices))
        a, b, c, d, f1, f2 = edge
        # the angles only where a cap can be, at a pinned apex over a pinned edge: over every interior edge they
        # were half of this call's CPU where caps are found (bumpy gyroid: 0.21 -> 0.10 s a remesh)
        near = np.flatnonzero(pinned[a] & pinned[b] & (pinned[c] | pinned[d]))
        at_c, at_d = np.zeros(len(a)), np.zeros(len(a))
        at_c[near] = _angle(vertices, c[near], a[near], b[near])
        at_d[near] = _angle(vertices, d[near], a[near], b[near])
        cap = pinned[a] & pinned[b] & ((pinned[c] & (at_c > limit)) | (pinned[d] & (at_d > limit)))
        # the new faces (c, a, d) and (d, b, c) split the other face at the apex: they keep its normal
        other = np.where(at_c > at_d, f2, f1)
        normal = _face_normals(vertices, faces[other[cap]])
        ca, cb = (_face_normals(vertices, np.stack(t, 1)[cap]) for t in ((c, a, d), (d, b, c)))
        idx = np.flatnonzero(cap)
        ok = (np.einsum("ij,ij->i", ca, normal) > 0.5) & (np.einsum("ij,ij->i", cb, normal) > 0.5)
        idx = idx[ok & (c[idx] != d[idx]) & _absent(faces, rings, c[idx], d[idx])]
        faces, flipped = _apply_independent(faces, len(vertices), edge, idx, np.maximum(at_c, at_d)[idx], seed=r)
        if flipped == 0:
            break
    return faces


def relax(vertices: np.ndarray, faces: np.ndarray, movable: np.ndarray, project) -> np.ndarray:
    """Move ``movable`` vertices to the mean of their incident faces' centroids, tangentially.

    The mean is unweighted (a uniform Laplacian, as in isotropic explicit remeshing): against
    area weights it raised the mean radius ratio on the test shapes from 0.898-0.905 to
    0.906-0.915, since area weights pull vertices towards their large triangles and keep
    the small ones small. ``project(points, ids)`` puts the moved vertices ``ids`` back on the
    surface.
    """
    p = vertices[faces]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    centre = p.mean(axis=1)
    del p  # the face arrays go before the projection: they were its peak (220 bytes per face)
    n = len(vertices)
    count = np.bincount(faces.ravel(), minlength=n).astype(float)
    target = np.stack([np.bincount(faces.ravel(), np.repeat(centre[:, k], 3), minlength=n) for k in range(3)], 1)
    normal = np.stack([np.bincount(faces.ravel(), np.repeat(cross[:, k], 3), minlength=n) for k in range(3)], 1)
    del cross, centre
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    ids = np.flatnonzero(movable & (count > 0))
    move = target[ids] / count[ids, None] - vertices[ids]
    move -= np.einsum("ij,ij->i", move, normal[ids])[:, None] * normal[ids]
    out = vertices.copy()
    out[ids] = project(vertices[ids] + move, ids)
    return out


def boundary_vertices(mesh: TriMesh) -> np.ndarray:
    """(v,) bool: vertices on the open boundary."""
    flag = np.zeros(mesh.n_vertices, bool)
    flag[mesh.boundary_edges().ravel()] = True
    return flag


@njit(cache=True)
def _min_angles(vertices, faces):
    """(f,) smallest interior angle (radians) of every triangle ``faces`` (f, 3) of ``vertices`` (v, 3), face by
    face: no (f, 3, 3) temporaries (those were the largest memory of the whole remesh where the output is
    finer than the input)."""
    angle = np.empty(len(faces))
    for f in range(len(faces)):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, az = vertices[a, 0], vertices[a, 1], vertices[a, 2]
        bx, by, bz = vertices[b, 0], vertices[b, 1], vertices[b, 2]
        cx, cy, cz = vertices[c, 0], vertices[c, 1], vertices[c, 2]
        angle[f] = min(_angle_at(ax, ay, az, bx, by, bz, cx, cy, cz), _angle_at(bx, by, bz, cx, cy, cz, ax, ay, az),
                       _angle_at(cx, cy, cz, ax, ay, az, bx, by, bz))
    return angle


def improve_angles(vertices: np.ndarray, faces: np.ndarray, movable: np.ndarray, project,
                   threshold: float = 30.0, rounds: int = 8, max_turn: float = 45.0, moved=None) -> np.ndarray:
    """Move the vertices of triangles under ``threshold`` degrees to where their ring's smallest
    angle is largest (optimisation-based smoothing on the worst elements only).

    Candidates for a vertex are points part-way to and away from each ring neighbour and the
    ring's centroid, put back on the surface by ``project(points, ids)`` (curve vertices thus
    slide along their curve); the best one is kept if it raises the ring's smallest angle and
    turns no ring face by more than ``max_turn`` degrees. The uniform relaxation before it
    optimises the mean shape; near feature corners, where curves meet at acute angles, it leaves
    triangles that a move of one neighbour fixes.

    Vertices move in batches of non-adjacent ones (a greedy independent set, the vertices of the
    worst triangles first):
    no vertex of a batch lies in another's ring, so each sees its ring as a one-by-one sweep
    would, and the candidates of a whole batch are projected in one call (vertex by vertex, the
    Python loop and one projection per vertex were most of the remesh's time on bumpy surfaces).
    A vertex is tried again only once something in its ring has moved since its last try (the
    same ring gives the same answer), for up to ``rounds`` rounds while anything moves. ``moved(ids, points)``,
    if given, is told where each batch's vertices went (the caller's record of where curve vertices sit along
    their curve, :class:`apt_filters.remesh.remesh.CurveSlides`).
    """
    out = np.ascontiguousarray(vertices, np.float64).copy()
    faces = np.ascontiguousarray(faces, np.int64)
    sweep = _Sweep(out, faces, project, max_turn, floor=-1.0, moved=moved)
    for _ in range(rounds):
        angle = _min_angles(out, faces)
        bad = angle < np.radians(threshold)
        todo = _unique_ids(faces[bad], movable)
        worst = np.full(len(out), np.inf)
        np.minimum.at(worst, faces[bad].ravel(), np.repeat(angle[bad], 3))
        todo = todo[np.argsort(worst[todo], kind="stable")]  # the worst rings first: they win the batches
        if not sweep.run(todo, ANGLE_STEPS):
            break
    return out


def improve_quality(vertices: np.ndarray, faces: np.ndarray, movable: np.ndarray, project,
                    floor: float = 33.0, rounds: int = 3, max_turn: float = 10.0, bend: float = 20.0,
                    moved=None, projected: int = 3) -> np.ndarray:
    """Move every ``movable`` vertex of a flat ring to where the sum of its ring's Q = 6/√3 · A/(p · h_max)
    is largest, never taking the ring's smallest angle under ``floor`` degrees (or under its present smallest
    angle where that is lower): optimisation-based smoothing of the mean shape.

    The uniform relaxation (:func:`relax`) moves a vertex to its ring's mean whatever the ring's shape;
    around valence-5 and -7 vertices and where feature curves cut the rings (corners, curve vertices
    that slide along their line) that is not where its triangles are best. On the pipeline's
    dual-contoured specimen (a refined cube and sphere at half a voxel) it left mean Q at 0.899-0.906
    (0.9 is the issue's target; a change of 1e-12 in the voxel fields moved it across) and 0.897-0.906 over
    seeds 0-3, uniform and adaptive; this pass lifts it to 0.907-0.916 (6 rounds: +0.0007 more, at twice the
    pass's CPU). No ring face may turn by more than ``max_turn`` (10°): at 45° (:func:`improve_angles`') the
    faces of the bumpy tilted sheet came out farther from the input (its first try's check failed
    otherwise than without the pass). Only vertices whose ring is flat (every face within ``bend``, 20°, of
    the ring's mean normal) move: where the surface bends across a ring (the thin plate's rounded rim) a
    tangential move shifts the chords, and the thin plate's sampled Hausdorff distance rose from 0.116 to
    0.128 nm (tolerance 0.125) with all vertices moving; 0.117 with flat rings only. The floor keeps the pass from
    trading smallest angles for the mean: at 30° it left faces at 30.0° that the centring step
    (:func:`centre_on_samples`) tipped to 29.9°; a ring already under the floor is left to :func:`improve_angles`,
    which runs after it. Candidates and batches as in :func:`improve_angles` (a vertex is tried again only once its
    ring has moved), up to ``rounds`` sweeps over all movable vertices; ``moved`` as there. The candidates are
    scored where they stand (on the chords to the ring's neighbours: in a flat ring within a sagitta of the
    surface) and only each vertex's ``projected`` best winners are projected, scored again and the best kept if it
    still wins: projecting all 42 was half of this pass's CPU, and projecting only the best one (a winner that
    loses once projected left the vertex where it was) gave the bumpy gyroid's component back on 6 of seeds 0-19
    against 2 projecting all and 1 projecting three.
    """
    out = np.ascontiguousarray(vertices, np.float64).copy()
    faces = np.ascontiguousarray(faces, np.int64)
    sweep = _Sweep(out, faces, project, max_turn, floor=np.radians(floor), moved=moved, projected=projected)
    todo = np.flatnonzero(movable & (np.diff(sweep.start) > 0) & _flat_rings(out, faces, bend))
    for _ in range(rounds):
        if not sweep.run(todo, QUALITY_STEPS):
            break
    return out


def _flat_rings(vertices: np.ndarray, faces: np.ndarray, bend: float) -> np.ndarray:
    """(v,) bool: every face round the vertex within ``bend`` degrees of the ring's mean normal (area-weighted)."""
    n = _face_normals(vertices, faces)
    area = np.linalg.norm(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                   vertices[faces[:, 2]] - vertices[faces[:, 0]]), axis=1)
    mean = np.stack([np.bincount(faces.ravel(), np.repeat(n[:, k] * area, 3), minlength=len(vertices))
                     for k in range(3)], 1)
    mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
    least = np.ones(len(vertices))
    for k in range(3):  # corner by corner: the (3f, 3) copies of the normals and means were 144 bytes a face
        np.minimum.at(least, faces[:, k], np.einsum("ij,ij->i", n, mean[faces[:, k]]))
    return least > np.cos(np.radians(bend))


# candidate moves, as fractions of the way to each ring neighbour and to the ring's centroid (negative: away)
ANGLE_STEPS = np.array([0.05, 0.1, 0.2, 0.35, 0.6, -0.05, -0.1, -0.2])
QUALITY_STEPS = np.array([0.05, 0.1, 0.2, 0.35, -0.05, -0.1])
RING_CANDIDATES = 7
"""Candidates per step of a vertex of valence 6 (its six neighbours and their centroid), to size the parts of
a batch that :class:`_Sweep` projects at once (about :func:`~apt_filters.remesh.sampling.chunk_length` points)."""


class _Sweep:
    """Moves of batches of non-adjacent vertices of ``out`` (v, 3), updated in place, to their best
    candidate (:func:`_choose`); remembers when each vertex last moved and was tried, so that a vertex is
    tried again only once something in its ring has moved (the same ring gives the same answer).
    ``floor`` < 0: the score is the ring's smallest angle; else the ring's summed Q, its smallest angle
    kept at least min(``floor``, its present smallest angle) (radians). ``moved(ids, points)`` (optional) is told
    of every batch's moves. ``projected`` > 0: the candidates are scored where they stand and only each vertex's
    ``projected`` best winners (:func:`_winners`) are projected and chosen from; 0: all are projected."""

    def __init__(self, out, faces, project, max_turn, floor, moved=None, projected=0):
        self.out, self.faces, self.project, self.floor, self.moved = out, faces, project, floor, moved
        self.projected = projected
        n = len(out)
        self.start, self.ring_of = vertex_rings(faces, n)  # faces around vertex v: ring_of[start[v]:start[v + 1]]
        self.cos_turn = np.cos(np.radians(max_turn))
        self.clock = 0  # one tick per batch
        self.last_move = np.zeros(n, np.int64)  # tick of each vertex's last move
        self.last_try = np.full(n, -1, np.int64)  # tick at each vertex's last try

    def run(self, todo: np.ndarray, steps: np.ndarray) -> int:
        """Try every vertex of ``todo`` (in order: earlier ones win the batches) once; returns how many moved."""
        out, faces, start, ring_of = self.out, self.faces, self.start, self.ring_of
        moved = 0
        while len(todo):
            todo = todo[_ring_changed(todo, faces, start, ring_of, self.last_move, self.last_try)]
            batch, todo = _independent(todo, faces, start, ring_of, len(out))
            if len(batch) == 0:
                break
            self.last_try[batch] = self.clock
            self.clock += 1
            went = np.zeros(len(batch), bool)
            # a part of the batch at a time: its candidates and their projection's copies were the remesh's
            # peak (2 kB per input face of the gyroid, all movable vertices at once); the batch's vertices
            # share no ring, so a part's moves leave the others' candidates and scores as they were
            part = max(chunk_length(len(faces)) // (len(steps) * RING_CANDIDATES), 1)
            for first in range(0, len(batch), part):
                sub = batch[first:first + part]
                ptr, cands = _candidates(out, faces, start, ring_of, sub, steps)
                rings = _rings(out, faces, start, ring_of, sub, self.floor)
                keep = slice(None)
                if self.projected:
                    # the projection of every candidate was half of improve_quality's CPU; a few, not one, so
                    # that a winner which loses once projected leaves the next one to move the vertex
                    pick = _winners(out, faces, start, ring_of, sub, ptr, cands, self.cos_turn, self.floor,
                                    self.projected, rings)
                    keep = pick[:, 0] >= 0  # the winners of a vertex come first, -1 after them
                    sub, pick = sub[keep], pick[keep]
                    rings = tuple(r[keep] for r in rings)
                    cands = cands[pick[pick >= 0]]
                    ptr = np.concatenate([[0], np.cumsum((pick >= 0).sum(axis=1))])
                cands = self.project(cands, np.repeat(sub, np.diff(ptr)))
                went[first:first + part][keep] = _choose(out, faces, start, ring_of, sub, ptr,
                                                   np.ascontiguousarray(cands, np.float64), self.cos_turn, self.floor,
                                                   rings)
            self.last_move[batch[went]] = self.clock
            if self.moved is not None:
                self.moved(batch[went], out[batch[went]])
            moved += int(went.sum())
        return moved


@njit(cache=True)
def _ring_changed(ids, faces, start, ring_of, last_move, last_try):
    """(k,) bool: something in the ring of vertex ``ids[i]`` moved since its last try."""
    keep = np.zeros(len(ids), np.bool_)
    for i in range(len(ids)):
        v = ids[i]
        for s in range(start[v], start[v + 1]):
            for k in range(3):
                if last_move[faces[ring_of[s], k]] > last_try[v]:
                    keep[i] = True
    return keep


@njit(cache=True)
def _independent(ids, faces, start, ring_of, n):
    """Split ``ids`` (in the given order) into a greedy independent set (no two in one face) and the rest."""
    taken = np.zeros(n, np.bool_)
    chosen = np.zeros(len(ids), np.bool_)
    for i in range(len(ids)):
        v = ids[i]
        free = True
        for s in range(start[v], start[v + 1]):
            for k in range(3):
                if taken[faces[ring_of[s], k]]:
                    free = False
        if free:
            chosen[i] = True
            for s in range(start[v], start[v + 1]):
                for k in range(3):
                    taken[faces[ring_of[s], k]] = True
    return ids[chosen], ids[~chosen]


@njit(cache=True)
def _candidates(out, faces, start, ring_of, batch, steps):
    """Candidate positions of every vertex of ``batch``: ``steps`` of the way to each ring neighbour and
    to the neighbours' centroid. Returns (len(batch) + 1,) offsets and (c, 3) points."""
    ptr = np.zeros(len(batch) + 1, np.int64)
    for b in range(len(batch)):
        v = batch[b]
        ptr[b + 1] = ptr[b] + len(steps) * (2 * (start[v + 1] - start[v]) + 1)  # neighbours at most 2 per face
    cands = np.empty((ptr[-1], 3))
    used = np.zeros(len(batch) + 1, np.int64)
    for b in range(len(batch)):
        v = batch[b]
        nbrs = np.empty(2 * (start[v + 1] - start[v]), np.int64)
        m = 0
        for s in range(start[v], start[v + 1]):
            for k in range(3):
                u = faces[ring_of[s], k]
                if u == v:
                    continue
                seen = False
                for j in range(m):
                    if nbrs[j] == u:
                        seen = True
                if not seen:
                    nbrs[m] = u
                    m += 1
        centre = np.zeros(3)
        for j in range(m):
            centre += out[nbrs[j]]
        centre /= max(m, 1)
        c = ptr[b]
        for st in steps:
            for j in range(m + 1):
                target = centre if j == m else out[nbrs[j]]
                for k in range(3):
                    cands[c, k] = out[v, k] + st * (target[k] - out[v, k])
                c += 1
        used[b] = c
    # compact: rings with fewer neighbours than the bound leave gaps
    total = 0
    new_ptr = np.zeros(len(batch) + 1, np.int64)
    for b in range(len(batch)):
        count = used[b] - ptr[b]
        # row by row, not a slice copy: numba's shape check of that copy compiles its error message's string
        # formatting, ~6 s of a fresh install's CPU (rows move only forward, onto rows already read)
        for c in range(count):
            for k in range(3):
                cands[total + c, k] = cands[ptr[b] + c, k]
        total += count
        new_ptr[b + 1] = total
    return new_ptr, cands[:total].copy()


@njit(cache=True)
def _angle_at(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Angle (radians) at corner a of the triangle (a, b, c), without temporaries."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    wx, wy, wz = cx - ax, cy - ay, cz - az
    nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    return np.arctan2(np.sqrt(nx * nx + ny * ny + nz * nz), ux * wx + uy * wy + uz * wz)


# inlined: called per candidate (millions a remesh), a compiled call cost _winners a third of its CPU (bumpy
# gyroid: 0.41 -> 0.25 s)
@njit(cache=True, inline="always")
def _ring_score(out, faces, start, ring_of, v, point, old_normals, cos_turn, floor, bound=-np.inf):
    """Score of the ring of ``v`` with ``v`` at ``point``: its smallest angle (radians) where ``floor`` < 0,
    else the sum of its faces' Q (:func:`apt_filters.contour.metrics.face_quality`'s), -inf if an angle
    falls under ``floor``; -inf if a face turns by more than arccos(``cos_turn``) from ``old_normals`` (r, 3),
    the ring's unit normals as it is. Also returns the ring's smallest angle.

    A candidate's score only counts if it beats the best so far, so the faces stop being scored once the
    score is known to lose: with ``floor`` < 0 once an angle is at most ``bound`` (the best so far), else once
    a face's smallest angle is surely under a ``floor`` > 0 (its cosine over cos(``floor``) + 1e-9) or the
    Q so far and 1 for each face left cannot beat ``bound`` (the returned smallest angle is then not the
    ring's). The smallest angle of the Q score is one arccos of the
    largest cosine, not one per face (arccos falls monotonically): the same bits, a third of
    :func:`improve_quality`'s CPU."""
    worst, total, largest = np.inf, 0.0, -np.inf
    cos_floor = np.cos(floor) + 1e-9 if floor > 0 else np.inf
    for s in range(start[v], start[v + 1]):
        # the face's corners, v at point (scalars: an array for them was one allocation per candidate)
        f = ring_of[s]
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        q0, q1, q2 = (point[0], point[1], point[2]) if a == v else (out[a, 0], out[a, 1], out[a, 2])
        q3, q4, q5 = (point[0], point[1], point[2]) if b == v else (out[b, 0], out[b, 1], out[b, 2])
        q6, q7, q8 = (point[0], point[1], point[2]) if c == v else (out[c, 0], out[c, 1], out[c, 2])
        ux, uy, uz = q3 - q0, q4 - q1, q5 - q2
        wx, wy, wz = q6 - q0, q7 - q1, q8 - q2
        nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        length = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
        o = old_normals[s - start[v]]
        if (nx * o[0] + ny * o[1] + nz * o[2]) / length <= cos_turn:
            return -np.inf, worst
        if floor < 0:
            worst = min(worst, _angle_at(q0, q1, q2, q3, q4, q5, q6, q7, q8),
                        _angle_at(q3, q4, q5, q6, q7, q8, q0, q1, q2),
                        _angle_at(q6, q7, q8, q0, q1, q2, q3, q4, q5))
            if worst <= bound:
                return worst, worst
            continue
        # the smallest angle from the sides (the law of cosines: one arccos a face, not three arctan2s; it is
        # only held against the floor), and Q
        a2, c2 = ux * ux + uy * uy + uz * uz, wx * wx + wy * wy + wz * wz
        e2 = (q6 - q3) ** 2 + (q7 - q4) ** 2 + (q8 - q5) ** 2
        a, c, e = np.sqrt(a2), np.sqrt(c2), np.sqrt(e2)
        cosine = max((a2 + c2 - e2) / max(2 * a * c, 1e-300), (a2 + e2 - c2) / max(2 * a * e, 1e-300),
                     (c2 + e2 - a2) / max(2 * c * e, 1e-300))
        if cosine > cos_floor:
            return -np.inf, np.arccos(min(cosine, 1.0))
        largest = max(largest, cosine)
        total += 6 / np.sqrt(3) * (length / 2) / max((a + c + e) / 2 * max(a, c, e), 1e-300)
        if total + (start[v + 1] - s - 1) * (1.0 + 1e-9) + 1e-9 <= bound:  # Q <= 1 a face: it cannot win
            return -np.inf, worst
    if floor < 0:
        return worst, worst
    if largest > -np.inf:
        worst = np.arccos(min(largest, 1.0))
    return (total if worst >= floor else -np.inf), worst


@njit(cache=True)
def _gain(floor, r):
    """How much a candidate's score must beat the present ring's: 1e-3 rad of smallest angle (``floor`` < 0),
    else 1e-4 of summed Q per face (``r`` faces)."""
    return 1e-3 if floor < 0 else 1e-4 * r


@njit(cache=True)
def _rings(out, faces, start, ring_of, batch, floor):
    """The rings of ``batch``'s vertices as they are: (len(batch), r, 3) their faces' unit normals (r the largest
    ring; rows past a vertex's own ring are zero), (len(batch),) their scores (:func:`_ring_score`) and
    (len(batch),) the smallest angle a candidate's ring must keep (``floor`` < 0: ``floor``; else min(``floor``,
    its present smallest angle)). Computed once for a part of a batch, for :func:`_winners` and then
    :func:`_choose` (between them only the projection runs: the rings are as they were; each computing them
    again, with an array a vertex and three a face, was a fifth of the pair's CPU)."""
    widest = 0
    for b in range(len(batch)):
        widest = max(widest, start[batch[b] + 1] - start[batch[b]])
    normals = np.zeros((len(batch), widest, 3))
    now, least = np.empty(len(batch)), np.empty(len(batch))
    for b in range(len(batch)):
        v = batch[b]
        for s in range(start[v + 1] - start[v]):
            f = ring_of[start[v] + s]
            a, bb, c = faces[f, 0], faces[f, 1], faces[f, 2]
            ux, uy, uz = out[bb, 0] - out[a, 0], out[bb, 1] - out[a, 1], out[bb, 2] - out[a, 2]
            wx, wy, wz = out[c, 0] - out[a, 0], out[c, 1] - out[a, 1], out[c, 2] - out[a, 2]
            nx, ny, nz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
            length = max(np.sqrt(nx * nx + ny * ny + nz * nz), 1e-300)
            normals[b, s, 0], normals[b, s, 1], normals[b, s, 2] = nx / length, ny / length, nz / length
        now[b], smallest = _ring_score(out, faces, start, ring_of, v, out[v], normals[b], -2.0,
                                       -1.0 if floor < 0 else 0.0)
        least[b] = min(floor, smallest) if floor >= 0 else floor
    return normals, now, least


@njit(cache=True)
def _choose(out, faces, start, ring_of, batch, ptr, cands, cos_turn, floor, rings):
    """Move each vertex of ``batch`` to its best candidate (:func:`_ring_score`) if that raises its ring's
    smallest angle by over 1e-3 rad (``floor`` < 0) or its summed Q by over 1e-4 per face, its smallest angle
    at least min(``floor``, its present smallest angle); ``out`` is updated in place. ``rings``: the batch's
    rings as they are (:func:`_rings`). Returns (len(batch),) bool: moved."""
    went = np.zeros(len(batch), np.bool_)
    normals, present, floors = rings
    for b in range(len(batch)):
        v = batch[b]
        old, now, least = normals[b, :start[v + 1] - start[v]], present[b], floors[b]
        best, arg = -np.inf, -1
        for c in range(ptr[b], ptr[b + 1]):
            score = _ring_score(out, faces, start, ring_of, v, cands[c], old, cos_turn, least, best)[0]
            if score > best:
                best, arg = score, c
        if arg >= 0 and best > now + _gain(floor, start[v + 1] - start[v]):
            for k in range(3):
                out[v, k] = cands[arg, k]
            went[b] = True
    return went


@njit(cache=True)
def _winners(out, faces, start, ring_of, batch, ptr, cands, cos_turn, floor, count, rings):
    """(len(batch), ``count``) indices into ``cands`` (offsets ``ptr``) of each vertex's ``count`` best
    candidates as they stand, best first, among those that would move it (:func:`_choose`'s rule; ``rings``
    :func:`_rings`'); -1 after them."""
    pick = np.full((len(batch), count), -1, np.int64)
    score = np.full(count, -np.inf)
    normals, present, floors = rings
    for b in range(len(batch)):
        v = batch[b]
        old, now, least = normals[b, :start[v + 1] - start[v]], present[b], floors[b]
        score[:] = now + _gain(floor, start[v + 1] - start[v])  # a candidate must beat this to be kept
        for c in range(ptr[b], ptr[b + 1]):
            s = _ring_score(out, faces, start, ring_of, v, cands[c], old, cos_turn, least, score[count - 1])[0]
            if s > score[count - 1]:  # insert, the scores kept in falling order
                i = count - 1
                while i > 0 and s > score[i - 1]:
                    score[i], pick[b, i] = score[i - 1], pick[b, i - 1]
                    i -= 1
                score[i], pick[b, i] = s, c
    return pick


def _unique_ids(tris: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Sorted vertex ids of ``tris`` (k, 3) for which ``keep`` (v,) holds."""
    ids = np.unique(tris)
    return ids[keep[ids]]


CENTRING_SAMPLES = 4
"""Samples per output face that :func:`centre_on_samples` visits (about: every k-th sample)."""


def centring_stride(n_samples: int, n_faces: int) -> int:
    """k: :func:`centre_on_samples` visits every k-th of ``n_samples`` samples, about :data:`CENTRING_SAMPLES`
    per face of an output of ``n_faces`` faces."""
    return max(n_samples // (CENTRING_SAMPLES * n_faces), 1)


def centre_on_samples(vertices: np.ndarray, faces: np.ndarray, movable: np.ndarray, samples, start: np.ndarray,
                      stride: int, rounds: int = 2) -> np.ndarray:
    """Move the ``movable`` vertices along their normals so that the mesh straddles the input
    surface instead of lying inside its curvature (a least-squares fit of vertex offsets).

    Vertices on the input and flat triangles between them cut every convex bend as chords: the
    remesh of a 2-voxel sphere at half-voxel edges lost 2.9 % of the input's area and sat 0.26
    edge inside it. Each round finds the closest output point of every input sample (``samples``,
    :class:`apt_filters.remesh.sampling.Samples`, taken a chunk at a time: centroids, unit normals
    and areas), takes the signed distance along the output face's normal, and moves each vertex by
    the weighted mean of the distances of the samples on its faces (barycentric weights): one Jacobi
    step of the least-squares fit of a piecewise-linear offset. Samples whose closest face faces the
    other way (the far side of a thin plate) are left out. Every ``stride``-th sample takes part
    (:func:`centring_stride`: about :data:`CENTRING_SAMPLES` per output face): the fit has about half as many
    unknowns as faces.

    The closest face is found by walking, not searched for: each sample starts at the faces round
    the output vertex of its Voronoi cell (``start`` (ceil(n_samples / stride),) int: the output vertex of the
    generator of every ``stride``-th sample, -1 where that generator left the mesh: such samples start at
    the nearest vertex; only these, not a label per sample, are kept until here) and steps to an edge-neighbour while
    that comes closer (:func:`apt_filters.remesh.walk.walk_closest`, a local search: a few % of
    samples stop at a face near, not at, their closest). The cell's vertex is within a cell of the
    sample, so the walk takes a step or two; a search in a grid over the output, built every
    round, was a quarter of the remesh's time on the gyroid, with the same quality figures.
    Returns the new (v, 3) vertices.
    """
    from scipy.spatial import cKDTree

    from apt_filters.core.mesh import vertex_normals
    from apt_filters.remesh.walk import face_neighbours, walk_closest

    faces = np.ascontiguousarray(faces, np.int64)
    neighbour = face_neighbours(faces, len(vertices))
    ring_start, ring = vertex_rings(faces, len(vertices))
    out = vertices.copy()
    for _ in range(rounds):
        face_normal = _face_normals(out, faces)
        num = np.zeros(len(out))
        den = np.zeros(len(out))
        tree = None
        for ids, points, normals, weights in samples.chunks(stride):
            first = start[ids // stride].astype(np.int64)
            lost = np.flatnonzero(first < 0)
            if len(lost):  # a generator that left the mesh: the nearest vertex instead
                tree = cKDTree(out) if tree is None else tree
                first[lost] = tree.query(points[lost])[1]
            face, bary, near = walk_closest(out, faces, neighbour, ring_start, ring, first, points)
            normal = face_normal[face]
            residual = np.einsum("ij,ij->i", points - near, normal)
            keep = np.einsum("ij,ij->i", normal, normals) > 0.5
            bary *= (weights * keep)[:, None]
            num += np.bincount(faces[face].ravel(), (bary * residual[:, None]).ravel(), minlength=len(out))
            den += np.bincount(faces[face].ravel(), bary.ravel(), minlength=len(out))
        del face_normal  # before the vertex normals: both at once were the centring's peak (180 B per input face)
        move = movable & (den > 0)
        out[move] += (num[move] / den[move])[:, None] * vertex_normals(out, faces)[move]
    return out


def undo_crossings(before: np.ndarray, after: np.ndarray, faces: np.ndarray, rounds: int = 3) -> np.ndarray:
    """``after`` (v, 3) with the vertices of faces that cross another face
    (:func:`apt_filters.core.checks.self_intersecting_faces`) put back where they were ``before``
    (v, 3) the moves, for up to ``rounds`` rounds while crossings remain.

    Curve vertices slide along their curve; four generators of one curve in a tent around a
    valence-3 vertex (a dual-contoured box's corner) slid into one another's faces.
    """
    from apt_filters.core.checks import self_intersecting_faces

    out = after.copy()
    for _ in range(rounds):
        hit = self_intersecting_faces(out, faces)
        if not hit.any():
            break
        ids = np.unique(faces[hit])
        out[ids] = before[ids]
    return out
