"""Local mending of a remesh where the check found it missed its input.

A first try that fails the check (:mod:`apt_filters.remesh.verify`) usually misses in a few places only: the
bumpy tilted sheet's 10,714 output faces had 37 input faces and 8 output faces beyond the tolerance, at
kinks of noise creases and needles of the refined surface, and its open rim half an edge off at an ear.
Remeshing the whole component again for them cost a whole try each time (three retries there).
:func:`mend` instead puts an output vertex at each farthest miss and leaves every other face as it was:

- an input point ``p`` farther than ``MEND_FRACTION`` of the tolerance from the output: a vertex at ``p``,
  inserted where the output's closest point to ``p`` lies;
- an output point ``q`` (vertex, edge midpoint or centroid) as far from the input: a vertex at the input's
  closest point to ``q``, inserted at ``q``;
- an open-rim point of either as far from the other's rim: a vertex on the input's rim, inserted on the
  output's boundary edge there.

A point is inserted by splitting the output face that holds it in three, or the edge it lies near in two
faces on each side (one on the rim), or by moving the corner it lies near; each keeps the Euler
characteristic and the boundary loops as they were, so topology holds by construction. No change is made
where a face would fold, lose its area, get an angle under ``ANGLE_FLOORS`` or cross another face; where a
rim split cannot be made, an ear of the rim is dropped instead (:func:`_drop_ear`). The split faces' edges
are then flipped to Delaunay (flat edges only, those of the mended faces only), and the whole is measured
again, ``MEND_ROUNDS`` times at most, until no miss over the tolerance is left; a mend that comes back to an
earlier round's mesh and misses ends at that cycle's state with the fewest misses over the tolerance. The
caller checks the result (:func:`verify.check_components`) and, where it still fails, remeshes the component
again as before.

Cost: per round, the check's distances (:func:`verify.farthest`) of the faces the last round can have made miss
(:func:`_changed`; all of the components mended in the first; none once a round comes back to an earlier
round's mesh and misses: the mend ends in that cycle), an engine over the output faces near the input's
misses (:func:`_closest_near`), and per change a scan of the faces (a few hundred changes at most).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from apt_filters.core.checks import triangles_intersect
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import optimize
from apt_filters.remesh._arrays import isin, row_keys
from apt_filters.remesh.verify import farthest

# Misses over this fraction of the tolerance are mended: a margin under the tolerance itself, so that the points
# inserted near one miss do not leave its neighbours just over it.
MEND_FRACTION = 0.8
MEND_ROUNDS = 8
# Where the point to insert lies within this share of a face's barycentric span of an edge (a corner), the edge
# is split (the corner moved) instead of the face: a split there makes a sliver.
EDGE_SHARE, CORNER_SHARE = 0.2, 0.8
DELAUNAY_PASSES = 3
# A piece of a split face with less area than this share of the edge squared is not made (an equilateral face
# has 0.43; a point inserted on the line of two rim vertices makes none).
FLAT_SHARE = 0.01
# Output vertices on an edge whose faces turn by more than this (degrees; the remesh's feature angle) stay where
# they are when the mended faces' angles are raised.
CREASE_ANGLE = 40.0
# No change of the mend makes an angle under the first of these (degrees), or under the smallest angle the remesh
# has in the components mended where that is smaller; where misses are left so, the mend starts again from the
# remesh under the next. The demo's mended cube came out with a 3.4 degree face without a floor (its first try's
# smallest: 22.8) and 0.65 % of its faces under 30 degrees (the target: 0.5); at 15, 15.6 and 0.53 %; at 20,
# 20.3 and 0.46 %. At 20 the 2M-ion surface's mend stopped short (its whole retry then cost 0.3 s more than
# remeshing it again without a mend); at 15 it passed. The same surface made again on another machine stopped short
# at 15 too (a miss of 0.15 nm at an edge midpoint: its split made 17.9 degrees, the corner's move 15.3) and its
# component was remeshed again whole; at 10 it passed: smallest angle 11.5 (pymeshlab's: 10.1), 0.15 % under 30
# degrees, 25 % less CPU. Each floor is tried only where the last left misses, so a mend that passes at 20 is as it
# was.
ANGLE_FLOORS = (20.0, 15.0, 10.0)


@dataclass
class Mended:
    """:func:`mend`'s result. ``result``'s vertices keep their order and come first, new ones after them, but for
    the tips of dropped ears (left out); ``result``'s faces keep their index (a split face keeps one piece there,
    its other pieces come after them) but for dropped ears (left out)."""

    vertices: np.ndarray  # (v', 3) nm
    faces: np.ndarray  # (f', 3)
    component: np.ndarray  # (f',) input component of each face
    parent: np.ndarray  # (f',) the face of ``result`` each face is (a piece of)
    origin: np.ndarray  # (v',) the vertex of ``result`` each vertex is (perhaps moved), -1 for a new one
    done: bool  # no miss over the tolerance left (measured as the check does)


def mend(source: TriMesh, result: TriMesh, source_component: np.ndarray, result_component: np.ndarray,
         components: np.ndarray, *, edge: float, tolerance: float, surface: SurfaceDistance,
         walks: tuple = (None, None)) -> Mended:
    """Insert output vertices where ``result`` misses ``source`` in the input components ``components``.

    Parameters
    ----------
    source, result : TriMesh
        The input and its remesh (nm).
    source_component : (f_in,) int
        Input component of each input face.
    result_component : (f_out,) int
        Input component each output face stands for (-1: several).
    components : (k,) int
        The input components to mend; faces of the others are never touched.
    edge, tolerance : float
        Target edge length (nm) and the check's distance tolerance as a fraction of it.
    surface : SurfaceDistance
        ``source``'s closest-point engine.
    walks : (Walks, Walks), optional
        The check's walked bounds of ``source`` from ``result`` and of ``result`` from ``source``
        (:class:`~apt_filters.remesh.verify.Walks`), taken by the first measure where they cover its faces.

    Returns
    -------
    Mended
        The mended mesh, its faces' components and parents, the vertex of ``result`` each vertex is, and
        whether no miss is left.
    """
    tol = tolerance * edge
    mine = np.isin(result_component, components)
    least = _smallest_angle(result.vertices, result.faces[mine]) if mine.any() else np.inf
    # no change makes an angle under the first of ANGLE_FLOORS, or under the smallest the remesh has there where
    # that is less; where misses are left so, the mend starts again from the remesh at the next
    in_mask = np.isin(source_component, components)
    # the first try's misses, measured once for every floor
    first = _misses(source, result, in_mask, mine, MEND_FRACTION * tol, edge, surface, walks=walks)
    for floor in sorted({min(np.radians(f), least) for f in ANGLE_FLOORS}, reverse=True):
        mended = _mend(source, result, in_mask, result_component, components, edge, tol, surface, floor, first)
        if mended.done:
            break
    return mended


def _mend(source: TriMesh, result: TriMesh, in_mask: np.ndarray, result_component: np.ndarray,
          components: np.ndarray, edge: float, tol: float, surface: SurfaceDistance, floor: float,
          first: tuple) -> Mended:
    """:func:`mend` with no change making an angle under ``floor`` (radians); ``tol`` the tolerance (nm);
    ``in_mask`` (f_in,) the input faces of ``components``; ``first``: :func:`_misses` of ``result``."""
    limit = MEND_FRACTION * tol
    vertices, faces = result.vertices.copy(), result.faces.copy()
    component, parent = result_component.copy(), np.arange(result.n_faces)
    near = np.zeros(len(vertices), bool)  # corners of the faces changed in any round
    placed = np.zeros(len(vertices), bool)  # vertices moved onto a miss in any round (:func:`_move`)
    halve = False  # whether a vertex moved before goes half way (:func:`_move`): once the mend has gone round
    measured = result
    where, to, gap, missing = first
    states, over = {}, []  # round of each state (mesh and its misses) met, by digest; misses over tol per round
    round_, last = 0, MEND_ROUNDS
    while True:
        if round_:
            now = TriMesh(vertices, faces.copy())  # _insert changes its faces in place
            where, to, gap, missing = _misses(source, now, in_mask, np.isin(component, components), limit, edge,
                                              surface, _changed(source, measured, now, missing, limit))
            measured = now
        # no miss over the tolerance left: done. The margin under it (MEND_FRACTION) chooses which points a round
        # inserts; chased further, the demo's mend went on for 5 rounds more after it had none, moving a corner
        # back and forth (a third of its CPU)
        if not len(to) or round_ == last or not (gap > tol).any():
            break
        over.append(int((gap > tol).sum()))
        state = _digest(vertices, faces, component, parent, *where, to, gap, *missing)
        if state in states and not halve:
            # back at an earlier state: a corner went back and forth between two misses (the zoo cuboid's, 0.129
            # and 0.133 nm against 0.125): from here a vertex moved before goes only half way to a miss that asks
            # for it again (:func:`_move`), to a point between the two that serves both (the cuboid's: 0.121 nm)
            halve = True
            states.clear()
        elif state in states:
            # a round is a function of the last one's mesh and misses alone: back at a state again, with halved
            # moves, the mend goes round the same cycle, so it ends at the cycle's state with the fewest misses over
            # the tolerance, the one the last round would have reached where none has fewer
            begin = states[state]
            at = begin + (MEND_ROUNDS - begin) % (round_ - begin)
            best = min(range(begin, round_), key=lambda r: (over[r], r != at))
            states.clear()
            last = round_ + best - begin
            if round_ == last:
                break
        states[state] = round_
        vertices, faces, component, parent, touched = _insert(vertices, faces, component, parent, where, to, edge,
                                                              floor, placed, halve)
        placed = np.r_[placed, np.zeros(len(vertices) - len(placed), bool)]
        if not touched.any():  # no miss could be mended: the next rounds would find the same
            break
        local = np.zeros(len(vertices), bool)
        local[faces[touched].ravel()] = True
        near = np.r_[near, np.zeros(len(vertices) - len(near), bool)] | local

        def fixed(a, b):
            return ~(local[a] & local[b])

        for k in range(DELAUNAY_PASSES):
            flipped_faces, flipped = optimize.delaunay_pass(vertices, faces, fixed, seed=k)
            changed = (flipped_faces != faces).any(axis=1)
            if flipped == 0 or crossing(vertices, flipped_faces[changed], flipped_faces[~changed], edge).any():
                break  # a pass whose flips would cross a face is left out whole
            faces = flipped_faces
        round_ += 1
    origin = np.r_[np.arange(result.n_vertices), np.full(len(vertices) - result.n_vertices, -1)]
    if near.any():
        # the splits' small angles raised by moving the other corners of the faces changed; kept only where that
        # leaves no more misses over the tolerance
        placed = origin < 0  # new, or moved onto a miss: they stay
        placed[:result.n_vertices] = (vertices[:result.n_vertices] != result.vertices).any(axis=1)
        smoothed = TriMesh(_relax_around(vertices, faces, near & ~placed, edge, surface), faces)
        after = _misses(source, smoothed, in_mask, np.isin(component, components), limit, edge, surface,
                        _changed(source, measured, smoothed, missing, limit))[2]
        smoothed = smoothed.vertices
        if (after > tol).sum() <= (gap > tol).sum():
            vertices, gap = smoothed, after
    used = np.zeros(len(vertices), bool)
    used[faces.ravel()] = True
    if not used.all():  # the tips of dropped ears
        index = np.cumsum(used) - 1
        vertices, origin, faces = vertices[used], origin[used], index[faces]
    return Mended(vertices, faces, component, parent, origin, not (gap > tol).any())


def _digest(*arrays: np.ndarray) -> bytes:
    """A digest of ``arrays``' shapes, types and values: equal arrays give equal digests."""
    h = hashlib.blake2b(digest_size=32)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.digest()


def _relax_around(vertices: np.ndarray, faces: np.ndarray, free: np.ndarray, edge: float,
                  surface: SurfaceDistance) -> np.ndarray:
    """:func:`optimize.improve_angles` over the vertices ``free`` (v,) bool that are on no rim and no crease (an
    edge whose faces turn by over ``CREASE_ANGLE``: a feature curve, which a move onto the closest input point
    would round off), their candidates put back on the input (``surface``)."""
    mesh = TriMesh(vertices, faces)
    top = mesh.topology
    pairs, ends = top.face_pairs, top.edge_vertices[top.edge_faces == 2]
    n = mesh.face_normals()
    bend = np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]]) < np.cos(np.radians(CREASE_ANGLE))
    free = free & ~optimize.boundary_vertices(mesh)
    free[ends[bend].ravel()] = False
    return optimize.improve_angles(vertices, faces, free, lambda points, ids: surface.closest(points, edge)[0])


def _misses(source: TriMesh, out: TriMesh, in_mask: np.ndarray, out_mask: np.ndarray, limit: float, edge: float,
            surface: SurfaceDistance, measure: tuple | None = None, walks: tuple = (None, None)) -> tuple:
    """Where to put an output vertex and where: ((m,) output face, (m, 3) its barycentric weights of the point
    to split at), (m, 3) the point on the input the vertex goes to, and (m,) the miss (nm), the farthest first;
    then ((f_in,), (f_out,)) bool, the faces of either that miss. ``measure``: ((f_in,), (f_out,)) bool, the
    faces to measure, where no other can miss (:func:`_changed`); by default all of ``in_mask``, ``out_mask``.
    ``walks``: :func:`mend`'s, the check's walked bounds of the same two meshes (not walked again)."""
    face, weights, to, gap = [], [], [], []
    measure_in, measure_out = (in_mask, out_mask) if measure is None else (in_mask & measure[0],
                                                                           out_mask & measure[1])
    # input points far from the output: the farthest probe of each input face that misses
    d = farthest(source, out, np.where(measure_in, np.arange(source.n_faces), -1), source.n_faces, limit,
                 floor=limit, walks=walks[0])
    missing = (d > limit, None)
    p = _probes(source, np.flatnonzero(missing[0]))[0].reshape(-1, 3)
    if len(p):
        y, f, w = _closest_near(out, p, float(d[missing[0]].max()), edge)
        own = out_mask[f]  # an input point whose closest output face is another component's is not this one's miss
        face.append(f[own]), weights.append(w[own]), to.append(p[own])
        gap.append(np.linalg.norm(p - y, axis=1)[own])
    # output points far from the input
    d = farthest(out, source, np.where(measure_out, np.arange(out.n_faces), -1), out.n_faces, limit,
                 surface=surface, floor=limit, walks=walks[1])
    missing = (missing[0], d > limit)
    far = np.flatnonzero(missing[1])
    q, w = _probes(out, far)
    if len(q):
        x = surface.closest(q.reshape(-1, 3), edge)[0]
        face.append(np.repeat(far, 7)), weights.append(w.reshape(-1, 3)), to.append(x)
        gap.append(np.linalg.norm(q.reshape(-1, 3) - x, axis=1))
    # open-rim points of either far from the other's rim
    rim = _rim_misses(source, out, in_mask, out_mask, limit, edge)
    if rim is not None:
        face.append(rim[0]), weights.append(rim[1]), to.append(rim[2]), gap.append(rim[3])
    if not face:
        return (np.empty(0, np.int64), np.empty((0, 3))), np.empty((0, 3)), np.empty(0), missing
    face, weights, to, gap = np.concatenate(face), np.vstack(weights), np.vstack(to), np.concatenate(gap)
    keep = gap > limit
    order = np.flatnonzero(keep)[np.argsort(-gap[keep], kind="stable")]
    # one point for misses nearer each other than a quarter edge (a vertex probe is every face's round it; the
    # rim's samples are an eighth edge apart): two vertices put at one point make a face without area
    alone = np.ones(len(order), bool)
    for i, j in sorted(cKDTree(to[order]).query_pairs(0.25 * edge)):
        if alone[i]:
            alone[j] = False
    order = order[alone]
    return (face[order], weights[order]), to[order], gap[order], missing


def _closest_near(out: TriMesh, points: np.ndarray, far: float, edge: float) -> tuple:
    """:meth:`SurfaceDistance.closest` (points, faces, weights) of ``points`` (n, 3) on ``out``, none of them
    farther than ``far`` (nm) from it, in an engine over the faces of ``out`` that can hold such a closest point
    only: a corner within ``far`` plus the face's longest edge of a point. (An engine over the whole output,
    built every round for a few input points, was a sixth of the demo's mend.)"""
    corners = out.vertices[out.faces]
    reach = (1 + 1e-6) * far + float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max())
    near = np.zeros(out.n_vertices, bool)
    near[np.concatenate([np.asarray(r, np.int64) for r in cKDTree(out.vertices).query_ball_point(points, reach)])] \
        = True
    faces = np.flatnonzero(near[out.faces].any(axis=1))
    used, local = np.unique(out.faces[faces], return_inverse=True)
    y, f, w = SurfaceDistance(TriMesh(out.vertices[used], local.reshape(-1, 3))).closest(points, edge)
    return y, faces[f], w


def _changed(source: TriMesh, before: TriMesh, after: TriMesh, missing: tuple, limit: float) -> tuple:
    """((f_in,), (f_out,)) bool: the faces of ``source`` and of ``after`` that can miss by over ``limit`` (nm) in
    ``after`` where ``before`` (the same vertex ids, more of them, faces changed, added or dropped) missed only
    at the faces ``missing`` (:func:`_misses`'): those, the faces of ``after`` not in ``before`` (or with a
    corner moved), and the input faces within reach of a face of ``before`` no longer there. An output face kept
    as it was is as far from the input as before; an input point whose closest output face is kept is no
    farther from the output than before (faces were only added round it), and one whose closest face went is
    within ``limit`` plus that face's longest edge of one of its corners."""
    moved = np.zeros(after.n_vertices, bool)
    n = before.n_vertices
    moved[n:] = True
    moved[:n] = (after.vertices[:n] != before.vertices).any(axis=1)

    # one int64 per face row, both meshes keyed together (the keys of one are those of the other): matched by
    # sorting (np.isin hashes)
    keys = row_keys(np.vstack([after.faces, before.faces]))
    keys_after, keys_before = keys[:after.n_faces], keys[after.n_faces:]
    kept_after = isin(keys_after, keys_before) & ~moved[after.faces].any(axis=1)
    gone = ~isin(keys_before, keys_after[kept_after])
    out = ~kept_after | isin(keys_after, keys_before[missing[1]])
    inside = missing[0].copy()
    if gone.any():
        corners = before.vertices[before.faces[gone]]
        longest = max(float(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max()),
                      float(_longest_edge(source)))
        reached = cKDTree(source.vertices).query_ball_point(corners.reshape(-1, 3), limit + longest)
        near = np.zeros(source.n_vertices, bool)
        near[np.concatenate([np.asarray(r, np.int64) for r in reached] or [np.empty(0, np.int64)])] = True
        inside |= near[source.faces].any(axis=1)
    return inside, out


def _longest_edge(mesh: TriMesh) -> float:
    """The longest edge of ``mesh`` (nm)."""
    ends = mesh.topology.edge_vertices
    return float(np.linalg.norm(mesh.vertices[ends[:, 0]] - mesh.vertices[ends[:, 1]], axis=1).max(initial=0.0))


def _probes(mesh: TriMesh, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, 7, 3) the check's probes of faces ``ids`` (corners, edge midpoints, centroid) and (k, 7, 3) their
    barycentric weights in the face."""
    w = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [.5, .5, 0], [0, .5, .5], [.5, 0, .5], [1 / 3, 1 / 3, 1 / 3]])
    corners = mesh.vertices[mesh.faces[ids]]
    return np.einsum("pk,nkj->npj", w, corners), np.broadcast_to(w, (len(ids), 7, 3))


def _rim_misses(source: TriMesh, out: TriMesh, in_mask: np.ndarray, out_mask: np.ndarray, limit: float,
                edge: float):
    """The rim's misses as :func:`_misses` gives them and their gaps (nm), or None: input rim points (every
    edge/8, as the check samples them) over ``limit`` from the output's rim, each inserted at the closest
    output rim point, and output rim points as far from the input's, each moved to the closest input rim point."""
    r_in, f_in, _ = _rim_samples(source, edge / 8, in_mask)
    r_out, f_out, w_out = _rim_samples(out, edge / 8, out_mask)
    if not len(r_in) or not len(r_out):
        return None
    d, j = cKDTree(r_out).query(r_in)
    a = d > limit
    e, i = cKDTree(r_in).query(r_out)
    b = e > limit
    face = np.concatenate([f_out[j[a]], f_out[b]])
    weights = np.vstack([w_out[j[a]], w_out[b]])
    return face, weights, np.vstack([r_in[a], r_in[i[b]]]), np.concatenate([d[a], e[b]])


def _rim_samples(mesh: TriMesh, spacing: float, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``spacing`` along the open boundary edges of faces ``mask``, their faces and their barycentric
    weights there."""
    top = mesh.topology
    lone = np.flatnonzero(top.edge_faces == 1)
    f_of = np.full(len(top.edge_vertices), -1, np.int64)  # a face of each edge, and the edge's corners in it
    at = np.full(len(top.edge_vertices), -1, np.int64)
    f_of[top.face_edge.ravel()] = np.repeat(np.arange(mesh.n_faces), 3)
    at[top.face_edge.ravel()] = np.tile(np.arange(3), mesh.n_faces)
    lone = lone[mask[f_of[lone]]]
    if not len(lone):
        return np.empty((0, 3)), np.empty(0, np.int64), np.empty((0, 3))
    f, k = f_of[lone], at[lone]
    a, b = mesh.faces[f, k], mesh.faces[f, (k + 1) % 3]
    n = np.maximum(np.ceil(np.linalg.norm(mesh.vertices[b] - mesh.vertices[a], axis=1) / spacing).astype(np.int64), 1)
    seg = np.repeat(np.arange(len(lone)), n + 1)
    t = (np.arange(len(seg)) - np.repeat(np.r_[0, np.cumsum(n + 1)[:-1]], n + 1)) / n[seg]
    weights = np.zeros((len(seg), 3))
    weights[np.arange(len(seg)), k[seg]] = 1.0 - t
    weights[np.arange(len(seg)), (k[seg] + 1) % 3] += t
    points = np.einsum("nk,nkj->nj", weights, mesh.vertices[mesh.faces[f[seg]]])
    return points, f[seg], weights


def _insert(vertices, faces, component, parent, where, to, edge, floor, placed, halve):
    """Put a vertex at each of ``to`` (m, 3), at the points ``where`` (faces, barycentric weights) of the output,
    in order; a miss whose faces an earlier one of the same round changed waits for the next round, and one whose
    faces would fold or lose their area (a point on the line of two rim vertices) is left. Returns the mesh, its
    faces' components and parents, and the faces changed."""
    face, weights = where
    vertices, faces = vertices.copy(), [faces]
    component, parent, touched = [component], [parent], [np.zeros(len(faces[0]), bool)]
    gone = []
    for f, w, x in zip(face, weights, to):
        if len(faces) > 1:  # the pieces of the last split are faces for the next
            faces, component = [np.vstack(faces)], [np.concatenate(component)]
            parent, touched = [np.concatenate(parent)], [np.concatenate(touched)]
        now, seen = faces[0], touched[0]
        if seen[f]:
            continue
        tri = now[f].copy()
        if w.max() >= CORNER_SHARE:
            _move(vertices, now, seen, tri[int(np.argmax(w))], x, edge, floor, placed, halve)
            continue
        n = len(vertices)
        other = None
        if w.min() >= EDGE_SHARE:  # split the face in three
            a, b, c = tri
            changed, rows = [f], [(a, b, n)]
            pieces = [(f, (b, c, n)), (f, (c, a, n))]
        else:  # split the edge p -> q opposite the corner of least weight, and its other face
            k = int(np.argmin(w))
            p, q, r = tri[(k + 1) % 3], tri[(k + 2) % 3], tri[k]
            other = np.flatnonzero((now == p).any(axis=1) & (now == q).any(axis=1))
            other = other[other != f]
            if seen[other].any():
                continue
            changed, rows, pieces = [f], [(p, n, r)], [(f, (n, q, r))]
            for g in other:  # q -> p -> s in g
                s = now[g, (int(np.flatnonzero(now[g] == q)[0]) + 2) % 3]
                changed.append(g), rows.append((q, n, s)), pieces.append((g, (n, p, s)))
        new = np.array(rows + [piece for _, piece in pieces], np.int64)
        of = np.array(changed + [g for g, _ in pieces])
        grown = np.vstack([vertices, x[None]])
        if not _fine(grown, new, _normals(vertices, now[of]), edge, now, of, floor):
            # a split that would fold (a rim's chord across a turn of the input's rim, the point beyond the
            # face's third corner): the nearest corner goes there instead, where its faces allow; else an ear
            # on the rim (a face whose corner has no other face, jutting out past the input's rim) is dropped
            if not _move(vertices, now, seen, tri[int(np.argmax(w))], x, edge, floor, placed, halve) \
                    and other is not None and not len(other):
                _drop_ear(now, seen, gone, f, (p, q))
            continue
        vertices = grown
        now[changed] = rows
        seen[changed] = True
        faces.append(new[len(rows):])
        component.append(component[0][of[len(rows):]])
        parent.append(parent[0][of[len(rows):]])
        touched.append(np.ones(len(pieces), bool))
    keep = np.ones(sum(len(f) for f in faces), bool)
    keep[gone] = False
    return (vertices, np.vstack(faces)[keep], np.concatenate(component)[keep],
            np.concatenate(parent)[keep], np.concatenate(touched)[keep])


def _drop_ear(faces: np.ndarray, seen: np.ndarray, gone: list, f: int, rim: tuple) -> None:
    """Drop face ``f`` (into ``gone``, its neighbour marked ``seen``) where one of the ends of its rim edge ``rim``
    has no other face and its third edge has a face on the other side: the rim then runs along that edge, and
    the Euler characteristic (one vertex, two edges and a face fewer) and the boundary loops stay."""
    tri = faces[f]
    for tip in rim:
        ring = np.flatnonzero((faces == tip).any(axis=1))
        if len(ring) != 1:
            continue
        a, b = (v for v in tri if v != tip)
        across = np.flatnonzero((faces == a).any(axis=1) & (faces == b).any(axis=1))
        across = across[across != f]
        if len(across) == 1 and not seen[across].any():
            gone.append(f)
            seen[f] = seen[across] = True
            return


def _move(vertices: np.ndarray, faces: np.ndarray, seen: np.ndarray, v: int, x: np.ndarray, edge: float,
          floor: float, placed: np.ndarray, halve: bool) -> bool:
    """Move vertex ``v`` to ``x`` (nm) unless a face round it changed this round (``seen``, marked if moved) or
    would fold or lose its area; whether it moved. With ``halve`` (after the mend came back to an earlier state), a
    vertex moved onto a miss before (``placed`` (v,), marked here) goes half way to ``x`` instead: two misses near
    one corner took it back and forth, each round leaving the other just over the tolerance (the zoo cuboid's,
    0.129 and 0.133 nm against 0.125, whose component was then remeshed again whole); halving the step brings it
    to a point between them that serves both (0.121 nm, mended in 5 rounds). Only after a cycle: from the first
    round, the bumpy tilted sheet's mend took 7 rounds instead of 5."""
    ring = np.flatnonzero((faces == v).any(axis=1))
    if seen[ring].any():
        return False
    before = _normals(vertices, faces[ring])
    old = vertices[v].copy()
    vertices[v] = 0.5 * (old + x) if halve and placed[v] else x
    if _fine(vertices, faces[ring], before, edge, faces, ring, floor):
        seen[ring] = placed[v] = True
        return True
    vertices[v] = old
    return False


def _smallest_angle(vertices: np.ndarray, tris: np.ndarray) -> float:
    """The smallest interior angle (radians) of the triangles ``tris`` (k, 3)."""
    p = vertices[tris]
    out = np.inf
    for k in range(3):
        u, v = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        cos = np.einsum("ij,ij->i", u, v) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-300)
        out = min(out, float(np.arccos(np.clip(cos, -1.0, 1.0)).min()))
    return out


def _normals(vertices: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(k, 3) area-weighted normals (twice the area) of the triangles ``tris`` over ``vertices``."""
    p = vertices[tris]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def _fine(vertices: np.ndarray, tris: np.ndarray, reference: np.ndarray, edge: float, faces: np.ndarray,
          replaced: np.ndarray, floor: float) -> bool:
    """Whether every triangle of ``tris`` has area (over ``FLAT_SHARE`` of the target edge squared), faces the
    way its face before did (``reference`` (k, 3) normals), no angle under ``floor`` (radians) and crosses no
    face of ``faces`` but ``replaced`` (:func:`crossing`; a bump folded over itself: a point inserted under its
    fold)."""
    n = _normals(vertices, tris)
    area = 0.5 * np.linalg.norm(n, axis=1)
    if not ((area > FLAT_SHARE * edge ** 2).all() and (np.einsum("ij,ij->i", n, reference) > 0).all()):
        return False
    if _smallest_angle(vertices, tris) < floor:
        return False
    others = np.ones(len(faces), bool)
    others[replaced] = False
    return not crossing(vertices, tris, faces[others], edge).any()


def crossing(vertices: np.ndarray, tris: np.ndarray, faces: np.ndarray, edge: float) -> np.ndarray:
    """(k,) bool: triangles ``tris`` (k, 3) that cross a face of ``faces`` sharing no edge with them, as
    :func:`apt_filters.core.checks.self_intersecting_faces` counts it (both shrunk by 1e-6 about their centroids:
    a shared corner is no crossing); faces farther than a few edges ``edge`` (nm) are not looked at."""
    def shrunk(t):
        p = vertices[t]
        c = p.mean(axis=1)
        return c[:, None] + (1 - 1e-6) * (p - c[:, None]), c

    if not len(tris):
        return np.zeros(0, bool)
    a, ca = shrunk(tris)
    # faces whose centroid is within a few edges of a triangle's: those that can reach it (faces are about an
    # edge long)
    reach = np.linalg.norm(a - ca[:, None], axis=2).max() + 2.0 * edge
    # a tree over the centroids within the triangles' box grown by the reach, not over all faces (one a change)
    # summed corner by corner: a (f, 3, 3) gather and its mean over the short axis took three times as long, and
    # this runs over every face for each split tried (a sixth of the mend's crossing tests); the same bits
    centroid = (vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]) / 3
    box = np.flatnonzero(((centroid >= ca.min(axis=0) - reach) & (centroid <= ca.max(axis=0) + reach)).all(axis=1))
    pairs = cKDTree(ca).sparse_distance_matrix(cKDTree(centroid[box]), reach, output_type="ndarray")
    i, j = pairs["i"].astype(np.int64), box[pairs["j"].astype(np.int64)]
    b = shrunk(faces[j])[0]
    faces, j = faces[j], np.arange(len(j))
    apart = (tris[i, :, None] == faces[j, None, :]).sum(axis=(1, 2)) < 2
    i, j = i[apart], j[apart]
    out = np.zeros(len(tris), bool)
    out[i[triangles_intersect(a[i], b[j])]] = True
    return out
