"""Marching cubes over the active cells only: the table triangles of each cell, compiled."""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from apt_filters.contour.cells import (ActiveCells, Field, crossed_bits, crossing_id, find_active_cells, prepare_field,
                                       strides, trilinear, world_points)
from apt_filters.contour.tables import CENTRE, CORNERS, EDGE_AXIS, EDGE_START, case_table
from apt_filters.core.threads import available_cores, on_threads, shares
from apt_filters.core.mesh import TriMesh


@njit(nogil=True, cache=True)
def _count(key, n_tris, centre_loops, c0, c1):
    """Faces and loop-centre vertices of cells ``c0:c1``."""
    n_faces, n_centres = 0, 0
    for c in range(c0, c1):
        n_faces += n_tris[key[c]]
        loops = centre_loops[key[c]]
        while loops:
            n_centres += loops & 1
            loops >>= 1
    return n_faces, n_centres


@njit(nogil=True, cache=True)
def _triangles(cell, key, c0, c1, face0, centre0, n_points, table, marks, rank, start, axis, t, stride,
               faces, centres):
    """Write the faces of cells ``c0:c1`` from row ``face0`` of ``faces`` (T, 3), and the loop centres
    they use from row ``centre0`` of ``centres`` (C, 3).

    ``table`` is ``(n_tris, tri_start, tris, edge_loop, centre_loops, crossed, edge_offset, edge_axis)``.
    A triangle corner code below :data:`CENTRE` names a cube edge (its crossing's vertex, numbered
    by :func:`~apt_filters.contour.cells.crossing_id`), one at or above names the centre of loop
    ``code - CENTRE`` of the cell: one vertex per used (cell, loop), numbered after the ``n_points``
    crossings in cell then loop order, at the index-space mean of the loop's crossings.
    """
    n_tris, tri_start, tris, edge_loop, centre_loops, crossed, edge_offset, edge_axis = table
    ids = np.empty(CENTRE + 4, dtype=np.int64)
    f, m = face0, centre0
    for c in range(c0, c1):
        k = key[c]
        row = crossed[k >> 6]
        for e in range(12):
            if row >> e & 1:
                ids[e] = crossing_id(cell[c] + edge_offset[e], edge_axis[e], marks, rank)
        if centre_loops[k]:
            for loop in range(4):
                if centre_loops[k] >> loop & 1:
                    ids[CENTRE + loop] = n_points + m
                    members = 0
                    for e in range(12):
                        if edge_loop[k, e] == loop:
                            v = ids[e]
                            p = start[v]
                            ijk = (p // stride[0], p % stride[0] // stride[1], p % stride[1])
                            for a in range(3):
                                centres[m, a] += np.float64(ijk[a]) + (t[v] if a == axis[v] else 0.0)
                            members += 1
                    for a in range(3):
                        centres[m, a] /= members
                    m += 1
        for i in range(tri_start[k], tri_start[k] + n_tris[k]):
            for j in range(3):
                faces[f, j] = ids[tris[i, j]]
            f += 1


@functools.lru_cache(maxsize=1)
def _centre_loops() -> np.ndarray:
    """(16384,) int64: bit l set where a key's triangles use the centre of loop l."""
    table = case_table()
    codes = table.tris.reshape(-1)
    used = np.where(codes >= CENTRE, 1 << np.maximum(codes - CENTRE, 0), 0).reshape(-1, 3)
    per_tri = np.bitwise_or.reduce(used, axis=1)
    tri_key = np.repeat(np.arange(len(table.n_tris)), table.n_tris)
    out = np.zeros(len(table.n_tris), dtype=np.int64)
    np.bitwise_or.at(out, tri_key, per_tri)
    return out


def triangulate_cells(field: Field, act: ActiveCells) -> TriMesh:
    """The marching-cubes mesh of already found active cells.

    Threads take consecutive ranges of cells; each range's faces and centres start where the
    previous range's end (counted first), so the output does not depend on the thread count.
    """
    table = case_table()
    shape = field.values.shape
    stride = strides(shape)
    lookup = (table.n_tris, table.tri_start, table.tris, table.edge_loop, _centre_loops(), crossed_bits(),
              EDGE_START @ stride, EDGE_AXIS)
    n_points = len(act.crossing_start)
    ranges = shares(len(act.key), max(1, min(available_cores(), len(act.key) // 65536)))
    counts = np.array(on_threads(lambda c0, c1: _count(act.key, table.n_tris, lookup[4], c0, c1), ranges),
                      dtype=np.int64).reshape(-1, 2)
    first = np.cumsum(counts, axis=0) - counts
    faces = np.empty((int(counts[:, 0].sum()), 3), dtype=np.int64)
    centres = np.zeros((int(counts[:, 1].sum()), 3))
    vertices = np.empty((n_points + len(centres), 3))

    def work(part: int) -> None:
        (c0, c1), (f0, m0) = ranges[part], first[part]
        _triangles(act.cell, act.key, c0, c1, f0, m0, n_points, lookup, act.edge_marks, act.edge_rank,
                   act.crossing_start, act.crossing_axis, act.crossing_t, stride, faces, centres)
        p0, p1 = shares(n_points, len(ranges))[part]
        world_points(act.crossing_start[p0:p1], act.crossing_axis[p0:p1], act.crossing_t[p0:p1], stride,
                     field.spacing, field.origin, vertices[p0:p1])

    on_threads(work, [(i,) for i in range(len(ranges))])
    vertices[n_points:] = field.to_world(centres)
    values = np.empty(len(vertices))
    values[:n_points] = field.iso
    values[n_points:] = trilinear(field.values, centres)
    mesh = TriMesh(vertices, faces, {"value": values})
    if field.edge is not None:
        rep = np.repeat(np.arange(len(act.key)), table.n_tris[act.key])
        mesh.face_scalars["at_edge"] = cap_cells(field, act)[rep]
    return mesh


def cap_cells(field: Field, act: ActiveCells) -> np.ndarray:
    """(A,) True for cells touching a voxel that closing filled (specimen edge or frame)."""
    idx = act.cell[:, None] + (CORNERS @ strides(field.values.shape))[None]
    return field.edge.reshape(-1)[idx].any(axis=1)


def marching_cubes(values, iso: float, spacing=(1.0, 1.0, 1.0), origin=(0.0, 0.0, 0.0), mask=None,
                   close: bool = False) -> TriMesh:
    """Iso-surface by marching cubes (full 256-case table, asymptotic decider on faces).

    Parameters
    ----------
    values : (nx, ny, nz) array_like, or an object with a ``dense()`` view
        Field samples in x, y, z order; point ``(i, j, k)`` sits at ``origin + (i, j, k) * spacing``.
        NaN voxels are treated like voxels outside ``mask``.
    iso : float
        Iso-value; the region above it is inside.
    spacing, origin : float or (3,) floats, nm
    mask : (nx, ny, nz) bool, optional
        True inside the specimen. Cells touching outside voxels emit no faces, so surfaces
        meeting the specimen edge stay open (boundary loops).
    close : bool
        Cap objects at the specimen edge and at the box instead ("proxies"); cap faces get
        ``face_scalars["at_edge"] = True``.

    Returns
    -------
    TriMesh
        Shared vertices (one per crossed grid edge), faces wound so normals point toward
        lower values; ``vertex_scalars["value"]`` (interpolated field) and
        ``face_scalars["component"]`` (see :func:`~apt_filters.contour.components.component_table`).
        Closed objects are watertight and 2-manifold.

    Notes
    -----
    Time and memory scale with the number of active cells plus one thresholding pass over
    the box; peak extra memory is about three bytes per voxel plus ~24 bytes per active cell,
    besides the output (32 bytes per vertex and per face). The scan, the triangles and the
    vertex positions run on threads; the result does not depend on their number.
    """
    field = prepare_field(values, iso, spacing, origin, mask, close)
    mesh = triangulate_cells(field, find_active_cells(field))
    mesh.face_scalars["component"] = mesh.face_components()
    return mesh
