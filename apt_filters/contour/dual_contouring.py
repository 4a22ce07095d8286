"""Dual contouring (Ju et al. 2002) with one vertex per surface sheet (manifold) and no folds."""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from apt_filters.contour.cells import ActiveCells, Field, find_active_cells, near_cells, prepare_field, trilinear
from apt_filters.contour.gradients import hermite_crossings
from apt_filters.contour.marching_cubes import cap_cells
from apt_filters.contour.qef import plane_misfit, solve_qef
from apt_filters.contour.tables import case_table
from apt_filters.core.checks import folded_pairs, self_intersecting_faces
from apt_filters.core.mesh import TriMesh, face_normals, topology

# Position of a cell around a grid edge, by the cube-edge sub-index k (e % 4): the four
# cells, in this order, run counter-clockwise about the edge's axis.
_QUAD_SLOT = np.array([0, 1, 3, 2])

# Vertices farther than this (voxels) from their mass point are the ones a rank fallback
# can move appreciably; the self-intersection test looks only near them.
_MOVED = 0.1

# A vertex clamped to its cell that misses its Hermite planes by more than this (rms,
# voxels) is a compromise; one clamped onto a cell face but still on its planes (an edge
# or corner point that lies exactly on the face) holds the feature and is not.
_MISFIT = 0.05


def _unit(g: np.ndarray) -> np.ndarray:
    length = np.linalg.norm(g, axis=1, keepdims=True)
    return np.divide(g, length, out=np.zeros_like(g), where=length > 0)


def _hermite_data(field: Field, act: ActiveCells, gradient, method: str) -> tuple[np.ndarray, ...]:
    """Crossings and unit normals in index space (sign irrelevant to the QEF), twice.

    Returns (V, 3) points, normals, and the linear crossings with their normals. With an
    exact gradient both pairs are the linear crossings and their normals; with estimated
    ones the first pair is re-placed along kinked edges
    (:func:`~apt_filters.contour.gradients.hermite_crossings`) and the second is the QEF's
    fallback for compromise vertices whose planes it fits better.
    """
    shape = field.values.shape
    linear = act.crossing_points(shape)
    if gradient is not None:
        g = np.asarray(gradient(field.to_world(linear)), dtype=np.float64).reshape(-1, 3)
        g = _unit(g * field.spacing)  # world plane normal -> index-space plane normal
        return linear, g, linear, g
    t, g, g_linear = hermite_crossings(field.values, act.crossing_start, act.crossing_axis, act.crossing_t, method)
    return replace(act, crossing_t=t).crossing_points(shape), _unit(g), linear, _unit(g_linear)


def _intersecting_near(field: Field, pos: np.ndarray, seeds: np.ndarray, tris: np.ndarray,
                       vertex_cell: np.ndarray) -> np.ndarray:
    """(k, 3) vertex ids of faces that self-intersect near the ``seeds`` (bool per vertex).

    A triangle lies in the 2×2 block of cells around its dual grid edge, so a face that
    crosses a face of a seed has its vertices within 3 cells of the seed's cell: the
    pymeshlab test (confirmed exactly) runs on those faces only.
    """
    if not seeds.any():
        return np.zeros((0, 3), dtype=np.int64)
    check = np.flatnonzero(near_cells(vertex_cell, vertex_cell[seeds], field.values.shape, 3)[tris].any(axis=1))
    used, local = np.unique(tris[check], return_inverse=True)
    hit = self_intersecting_faces(field.to_world(pos[used]), local.reshape(-1, 3))
    return tris[check[hit]]


def _culprits(groups: np.ndarray, rank: np.ndarray, clamped: np.ndarray) -> np.ndarray:
    """Vertex ids to lower for each offending group of vertices ((k, g) ids).

    A vertex whose QEF point was clamped to its cell is a compromise, and at a corner
    such neighbours fold against the vertex that holds the true corner; so where a group
    has clamped vertices only they are lowered, otherwise every vertex above rank 0.
    """
    can = rank[groups] > 0
    suspect = can & clamped[groups]
    return groups[np.where(suspect.any(axis=1)[:, None], suspect, can)]


def _splits(quads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two ways to split (q, 4) quads: (q, 2, 3) triangles along diagonal 0-2 and along 1-3."""
    q0, q1, q2, q3 = quads.T
    return (np.stack([np.stack([q0, q1, q2], 1), np.stack([q0, q2, q3], 1)], axis=1),
            np.stack([np.stack([q0, q1, q3], 1), np.stack([q1, q2, q3], 1)], axis=1))


def _folds(pos: np.ndarray, a: np.ndarray, b: np.ndarray, max_fold: float) -> np.ndarray:
    """(k,) bool: whether triangles ``a`` and ``b`` ((k, 3) vertex ids) fold against each other."""
    na, nb = face_normals(pos, a), face_normals(pos, b)
    return np.einsum("ij,ij->i", na, nb) < np.cos(np.radians(max_fold))


def _choose_split(values: np.ndarray, iso: float, pos: np.ndarray, quads: np.ndarray, max_fold: float) -> np.ndarray:
    """(q, 2, 3) triangles per quad, split along the better diagonal.

    Prefer the split that does not fold; otherwise the diagonal whose midpoint lies closer
    to the iso-surface (trilinear field), which follows ridges and valleys.
    """
    q0, q1, q2, q3 = quads.T
    split_a, split_b = _splits(quads)
    err_a = np.abs(trilinear(values, 0.5 * (pos[q0] + pos[q2])) - iso)
    err_b = np.abs(trilinear(values, 0.5 * (pos[q1] + pos[q3])) - iso)
    fold_a = _folds(pos, split_a[:, 0], split_a[:, 1], max_fold)
    fold_b = _folds(pos, split_b[:, 0], split_b[:, 1], max_fold)
    use_b = (fold_a & ~fold_b) | ((fold_a == fold_b) & (err_b < err_a))
    return np.where(use_b[:, None, None], split_b, split_a)


def _flip_diagonals(pos: np.ndarray, split: np.ndarray, quads: np.ndarray, folded: np.ndarray,
                    max_fold: float) -> np.ndarray:
    """Re-split the quads of ``folded`` faces ((k, 2) ids into ``split``) where that folds less.

    A quad's other diagonal leaves its four outer edges, and so its neighbours across them,
    unchanged: the folds it takes part in are counted for both diagonals (inside the quad
    and against each outer neighbour) and the quad is re-split in place where the other
    diagonal has fewer. Vertices stay where they are, so sharp vertices keep their place.
    Returns the (f,) ids of the re-split quads.
    """
    cand = np.unique(folded // 2)
    tris = split.reshape(-1, 3)
    near = np.flatnonzero(np.isin(tris, split[cand]).any(axis=1))
    pairs = near[topology(tris[near], len(pos)).face_pairs]
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    pairs = pairs[np.isin(pairs[:, 0] // 2, cand) & (pairs[:, 0] // 2 != pairs[:, 1] // 2)]
    split_a, split_b = _splits(quads[cand])
    alt = np.where((split[cand] == split_a).all(axis=(1, 2))[:, None, None], split_b, split_a)
    slot = np.searchsorted(cand, pairs[:, 0] // 2)
    other = tris[pairs[:, 1]]
    # The outer edge shared with the neighbour lies in whichever new triangle holds both its ends.
    holds = (alt[slot, 0][:, :, None] == other[:, None, :]).any(axis=2).sum(axis=1) == 2
    alt_face = np.where(holds[:, None], alt[slot, 0], alt[slot, 1])
    count = len(cand)
    now = (np.bincount(slot, _folds(pos, tris[pairs[:, 0]], other, max_fold), count)
           + _folds(pos, split[cand, 0], split[cand, 1], max_fold))
    then = (np.bincount(slot, _folds(pos, alt_face, other, max_fold), count)
            + _folds(pos, alt[:, 0], alt[:, 1], max_fold))
    better = then < now
    split[cand[better]] = alt[better]
    return cand[better]


def dual_contouring(values, iso: float, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), mask=None,
                    gradient: Callable[[np.ndarray], np.ndarray] | None = None, *, close: bool = False,
                    field_gradient: str = "eno", cutoff: float = 0.1, max_rank: int = 3,
                    max_fold_angle: float = 120.0, repair_intersections: bool = True) -> TriMesh:
    """Iso-surface by manifold dual contouring: sharp edges and corners are kept.

    Parameters
    ----------
    values, iso, spacing, origin, mask, close
        As for :func:`~apt_filters.contour.marching_cubes.marching_cubes`.
    gradient : callable, optional
        Exact gradient: maps (n, 3) world points (nm) to (n, 3) gradients. Without it the
        Hermite normals come from the field by ``field_gradient``; with ``"eno"`` a crossing
        on an edge whose ends lie on two faces is also re-placed onto the face that holds
        there (vertices whose planes then miss their cell keep the linear crossings).
    field_gradient : {"eno", "central", "fit"}
        Estimator of normals from the samples (see :mod:`apt_filters.contour.gradients`);
        ``"fit"`` suits noisy counted fields, ``"eno"`` sharp analytic ones.
    cutoff : float
        Relative singular-value cutoff of the QEF pseudo-inverse.
    max_rank : int
        Highest QEF rank used (0 gives surface nets: vertices at the mass point).
    max_fold_angle : float
        Degrees; adjacent triangles whose normals differ more count as folded. A quad
        holding a folded face is first re-split along its other diagonal where that folds
        less (no vertex moves). Vertices of the folds left step half a QEF rank down per
        round (the point moves half-way toward the next lower rank's minimiser) until no
        fold is left (rank 0, the mass point, is the floor); where a folded pair holds
        compromise vertices (QEF point clamped to the cell and more than 0.05 voxel rms
        off its planes), only those move: next to a corner they fold against the vertex
        that holds it.
    repair_intersections : bool
        Treat vertices of self-intersecting faces the same way (pymeshlab test confirmed
        exactly, run on the faces within 3 cells of vertices more than 0.1 voxel from
        their mass point: the only places a lower rank changes anything).

    Returns
    -------
    TriMesh
        One vertex per surface sheet in each active cell, always inside its cell (the QEF
        minimiser constrained to the cell), one quad per crossed edge split into two
        triangles; normals point toward lower values. ``vertex_scalars["value"]`` is the
        trilinear field at the vertices, ``vertex_scalars["rank"]`` the QEF rank used
        (x.5: half-way between ranks x and x + 1).

    Notes
    -----
    Cells whose corners form two or more sheets (the marching-cubes table, with the
    asymptotic decider on faces) get one vertex per sheet, which keeps the output
    2-manifold. Memory: ~1 kB per active cell on top of the thresholding pass.
    """
    field = prepare_field(values, iso, spacing, origin, mask, close)
    act = find_active_cells(field)
    table = case_table()
    shape = field.values.shape
    points, normals, linear, linear_normals = _hermite_data(field, act, gradient, field_gradient)

    n_loops = table.n_loops[act.key]
    first = np.cumsum(n_loops) - n_loops
    rows, edges = np.nonzero(act.edge_crossing >= 0)
    crossing = act.edge_crossing[rows, edges]
    vertex = first[rows] + table.edge_loop[act.key[rows], edges]
    n_vertices = int(n_loops.sum())
    cell_of_vertex = np.repeat(np.arange(len(act.cell)), n_loops)
    vertex_cell = act.cell[cell_of_vertex]
    lo = np.stack(np.unravel_index(vertex_cell, shape), axis=1).astype(np.float64)

    def total(weights: np.ndarray) -> np.ndarray:
        return np.bincount(vertex, weights=weights, minlength=n_vertices)

    def solve(pts: np.ndarray, nrm: np.ndarray, rows: np.ndarray):
        """Mass points, minimisers by rank (clamped to the cell), compromise flags and the
        top rank's plane misfit of the vertices ``rows`` from Hermite data ``pts``, ``nrm``."""
        n, p = nrm[crossing], pts[crossing]
        d = np.einsum("ij,ij->i", n, p)
        ata = np.stack([np.stack([total(n[:, a] * n[:, b]) for b in range(3)], -1) for a in range(3)], -2)[rows]
        atb = np.stack([total(n[:, a] * d) for a in range(3)], -1)[rows]
        count = total(np.ones(len(vertex)))[rows]
        mass = np.stack([total(p[:, a]) for a in range(3)], -1)[rows] / count[:, None]
        cand, clamp = solve_qef(ata, atb, mass, lo[rows], lo[rows] + 1.0, cutoff, max_rank)
        misfit = plane_misfit(ata, atb, total(d * d)[rows], count, cand)
        return mass, cand, clamp & (misfit > _MISFIT), misfit[max_rank]

    mass, candidates, compromise, misfit = solve(points, normals, slice(None))
    # A re-placed crossing carries an end's plane to the true crossing; next to a corner that
    # end's gradient can point at the corner rather than along the face, and the planes then
    # meet outside the cell. Such compromise vertices keep the linear Hermite data where its
    # planes fit better.
    re_placed = np.any(points != linear, axis=1)[crossing]
    retry = np.flatnonzero(compromise[max_rank] & (total(re_placed) > 0))
    if len(retry):
        mass_l, cand_l, comp_l, misfit_l = solve(linear, linear_normals, retry)
        better = misfit_l < misfit[retry]
        back = retry[better]
        mass[back], candidates[:, back], compromise[:, back] = mass_l[better], cand_l[:, better], comp_l[:, better]
    rank = np.full(n_vertices, float(max_rank))
    ids = np.arange(n_vertices)
    seeds = np.linalg.norm(candidates[max_rank] - mass, axis=1) > _MOVED

    quads = np.full((len(points), 4), -1, dtype=np.int64)
    quads[crossing, _QUAD_SLOT[edges % 4]] = vertex
    start_inside = field.values.reshape(-1)[act.crossing_start] > field.iso
    keep = np.all(quads >= 0, axis=1)
    quads = np.where(start_inside[:, None], quads, quads[:, ::-1])[keep]

    split = np.empty((len(quads), 2, 3), dtype=np.int64)
    moved = np.ones(n_vertices, dtype=bool)  # vertices moved since the last round
    touched = moved  # ... and vertices of quads re-split since then
    for _ in range(4 * max_rank + 2):  # each round lowers offenders half a rank; rank 0 is the floor
        below, t = np.floor(rank).astype(np.int64), rank % 1.0
        pos = (1 - t[:, None]) * candidates[below, ids] + t[:, None] * candidates[np.ceil(rank).astype(np.int64), ids]
        redo = moved[quads].any(axis=1)
        split[redo] = _choose_split(field.values, field.iso, pos, quads[redo], max_fold_angle)
        tris = split.reshape(-1, 3)
        # Only faces of touched vertices and the faces next to them can have changed folds.
        ring = np.zeros(n_vertices, dtype=bool)
        ring[tris[touched[tris].any(axis=1)]] = True
        local = np.flatnonzero(ring[tris].any(axis=1))
        folded = local[folded_pairs(pos, tris[local], max_fold_angle)]
        # First cure: the other diagonal of a folded quad, which moves no vertex.
        flipped = (_flip_diagonals(pos, split, quads, folded, max_fold_angle) if len(folded)
                   else np.zeros(0, dtype=np.int64))
        if len(flipped):
            folded = local[folded_pairs(pos, tris[local], max_fold_angle)]
        groups = [tris[folded].reshape(-1, 6)]
        if repair_intersections:
            # First round: near every vertex off its mass point (elsewhere a lower rank moves
            # nothing); later rounds: near the vertices the last round touched.
            groups.append(_intersecting_near(field, pos, seeds, tris, vertex_cell))
        suspect = compromise[np.ceil(rank).astype(np.int64), ids]
        lower = np.unique(np.concatenate([_culprits(g, rank, suspect) for g in groups]))
        if not len(lower) and not len(flipped):
            break
        rank[lower] -= 0.5
        moved = np.zeros(n_vertices, dtype=bool)
        moved[lower] = True
        touched = moved.copy()
        touched[quads[flipped]] = True
        seeds = touched

    used, faces = np.unique(tris, return_inverse=True)
    faces = faces.reshape(-1, 3)
    pos = pos[used]
    mesh = TriMesh(field.to_world(pos), faces,
                   {"value": trilinear(field.values, pos), "rank": rank[used]})
    if field.edge is not None:
        mesh.face_scalars["at_edge"] = cap_cells(field, act)[cell_of_vertex][used][faces].any(axis=1)
    mesh.face_scalars["component"] = mesh.face_components()
    return mesh


def surface_nets(values, iso: float, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), mask=None, *,
                 close: bool = False) -> TriMesh:
    """Surface nets: dual contouring with every vertex at the mass point of its crossings."""
    return dual_contouring(values, iso, spacing, origin, mask, close=close, max_rank=0)
