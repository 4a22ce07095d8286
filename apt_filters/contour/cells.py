"""Active cells and edge crossings shared by marching cubes and dual contouring.

Work beyond one cheap pass over the box is proportional to the number of *active* cells
(cells whose corners straddle the iso-value): the field is thresholded and a compiled scan
lists the active cells with their cases (a few ns per cell). Peak memory beyond the input
is one byte per voxel plus O(active cells) index arrays.

All geometry here is in *index space* (voxel units, point ``(i, j, k)`` at ``(i, j, k)``);
the public functions map to world coordinates at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from apt_filters.contour.tables import CORNERS, EDGE_AXIS, EDGE_START, FACE_CORNERS, case_table
from apt_filters.core.errors import AptFiltersError

BLOCK = 8


@dataclass
class Field:
    """A validated scalar field ready for contouring.

    Attributes
    ----------
    values : (nx, ny, nz) ndarray, C-contiguous
        Field samples; after closing, masked-out voxels hold ``fill`` and a one-voxel frame
        of ``fill`` surrounds the box.
    iso : float
    mask : (nx, ny, nz) bool or None
        True = inside the specimen. Cells touching a False voxel emit nothing.
    edge : (nx, ny, nz) bool or None
        Voxels that closing replaced (specimen edge and frame): faces touching them are caps.
    spacing, origin : (3,) float64
        World position of point ``(i, j, k)`` is ``origin + (i, j, k) * spacing`` (nm).
    """

    values: np.ndarray
    iso: float
    mask: np.ndarray | None
    edge: np.ndarray | None
    spacing: np.ndarray
    origin: np.ndarray

    def to_world(self, index_points: np.ndarray) -> np.ndarray:
        return self.origin + index_points * self.spacing


def as_dense(values) -> np.ndarray:
    """A dense array from an ndarray or from an object with a ``dense()`` view (sparse fields)."""
    if hasattr(values, "dense") and callable(values.dense):
        values = values.dense()
    return np.asarray(values)


def prepare_field(values, iso: float, spacing, origin, mask, close: bool) -> Field:
    """Check inputs and, with ``close``, cap objects at the specimen edge and the box.

    Closing replaces masked-out voxels (and a one-voxel frame around the box) by
    ``fill = iso - (max(values) - iso)``, the mirror of the highest value, so that caps sit
    about half-way between the last inside voxel and the first outside one.
    The input arrays are never modified.
    """
    arr = as_dense(values)
    if arr.ndim != 3 or min(arr.shape) < 2:
        raise AptFiltersError(f"contouring needs a 3-D field of at least 2 points per axis, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.floating):
        arr = arr.astype(np.float64)
    spacing = np.broadcast_to(np.asarray(spacing, dtype=np.float64), (3,)).copy()
    origin = np.broadcast_to(np.asarray(origin, dtype=np.float64), (3,)).copy()
    if np.any(spacing <= 0):
        raise AptFiltersError(f"voxel spacing must be positive, got {tuple(spacing)}")
    iso = float(iso)
    if mask is not None:
        mask = np.asarray(as_dense(mask), dtype=bool)
        if mask.shape != arr.shape:
            raise AptFiltersError(f"mask shape {mask.shape} differs from the field shape {arr.shape}")
    finite = np.isfinite(arr)
    if not finite.all():
        # Undefined voxels (e.g. concentrations of empty voxels) behave like the specimen edge.
        mask = finite if mask is None else mask & finite
        arr = np.where(finite, arr, iso)
    if not close:
        return Field(np.ascontiguousarray(arr), iso, mask, None, spacing, origin)
    high = float(arr.max()) if mask is None or not mask.any() else float(arr[mask].max())
    fill = iso - abs(high - iso) - 1e-12 * max(1.0, abs(iso))
    edge = np.ones(tuple(s + 2 for s in arr.shape), dtype=bool)
    edge[1:-1, 1:-1, 1:-1] = False if mask is None else ~mask
    out = np.full(edge.shape, fill, dtype=arr.dtype)
    out[1:-1, 1:-1, 1:-1] = arr
    out[edge] = fill
    return Field(out, iso, None, edge, spacing, origin - spacing)


@dataclass
class ActiveCells:
    """Sign-changing cells and the crossings on their edges.

    Attributes
    ----------
    cell : (A,) int64
        Flat point index of each active cell's corner 0.
    key : (A,) int64
        Table key ``case * 64 + face_bits``.
    edge_crossing : (A, 12) int64
        Crossing id of each crossed cube edge, -1 elsewhere.
    crossing_start : (V,) int64
        Flat point index where each crossed grid edge starts.
    crossing_axis : (V,) int64
    crossing_t : (V,) float64
        Fraction along the edge (linear interpolation).
    """

    cell: np.ndarray
    key: np.ndarray
    edge_crossing: np.ndarray
    crossing_start: np.ndarray
    crossing_axis: np.ndarray
    crossing_t: np.ndarray

    def crossing_points(self, shape: tuple[int, int, int]) -> np.ndarray:
        """(V, 3) crossing positions in index space."""
        pts = np.stack(np.unravel_index(self.crossing_start, shape), axis=1).astype(np.float64)
        pts[np.arange(len(pts)), self.crossing_axis] += self.crossing_t
        return pts


def strides(shape: tuple[int, int, int]) -> np.ndarray:
    return np.array([shape[1] * shape[2], shape[2], 1], dtype=np.int64)


@njit(nogil=True, cache=True)
def _scan_cells(inside: np.ndarray, shape: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat corner-0 indices and cases of the sign-changing cells, block by block.

    ``inside`` is the flat (uint8) threshold of the field. A cell's case is the 4 bits of
    its lower x-y face (corners 0-3 of :data:`CORNERS`) and the 4 of its upper one, so
    each face is read once per z run. Cells are listed in ``block``³ blocks (blocks in x, y, z order,
    cells within a block likewise): the order marching cubes' faces follow. One pass over
    the box, a few ns per cell; the output grows by doubling.
    """
    nx, ny, nz = shape[0], shape[1], shape[2]
    sx, sy = ny * nz, nz
    cells = np.empty(1 << 16, dtype=np.int64)
    cases = np.empty(1 << 16, dtype=np.int64)
    n = 0
    for bx in range(0, nx - 1, block):
        for by in range(0, ny - 1, block):
            for bz in range(0, nz - 1, block):
                for i in range(bx, min(bx + block, nx - 1)):
                    for j in range(by, min(by + block, ny - 1)):
                        row = (i * ny + j) * nz
                        p = row + bz
                        below = (inside[p] | inside[p + sx] << 1 | inside[p + sy] << 2 | inside[p + sx + sy] << 3)
                        for k in range(bz, min(bz + block, nz - 1)):
                            p = row + k + 1
                            above = (inside[p] | inside[p + sx] << 1 | inside[p + sy] << 2 | inside[p + sx + sy] << 3)
                            case = np.int64(below | above << 4)
                            below = above
                            if case == 0 or case == 255:
                                continue
                            p -= 1
                            if n == len(cells):
                                cells = np.concatenate((cells, np.empty_like(cells)))
                                cases = np.concatenate((cases, np.empty_like(cases)))
                            cells[n] = p
                            cases[n] = case
                            n += 1
    return cells[:n].copy(), cases[:n].copy()


def _face_bits(corner_values: np.ndarray, case: np.ndarray) -> np.ndarray:
    """Asymptotic decider on ambiguous faces: bit f set when the inside corners connect."""
    table = case_table()
    bits = np.zeros(len(case), dtype=np.int64)
    amb = table.ambiguous[case]  # (A, 6)
    rows, faces = np.nonzero(amb)
    if len(rows):
        a = corner_values[rows[:, None], FACE_CORNERS[faces]]  # (r, 4) cyclic, relative to iso
        saddle = (a[:, 0] * a[:, 2] - a[:, 1] * a[:, 3]) / (a[:, 0] + a[:, 2] - a[:, 1] - a[:, 3])
        np.add.at(bits, rows, (saddle > 0).astype(np.int64) << faces)
    return bits


def find_active_cells(field: Field) -> ActiveCells:
    """Sign-changing cells (all corners inside the mask) with their crossings."""
    f = field.values
    shape = f.shape
    flat = f.reshape(-1)
    offsets = CORNERS @ strides(shape)
    inside = (flat > field.iso).view(np.uint8)
    cell, case = _scan_cells(inside, np.array(shape, dtype=np.int64), BLOCK)
    idx = cell[:, None] + offsets[None, :]  # (A, 8)
    if field.mask is not None:
        keep = field.mask.reshape(-1)[idx].all(axis=1)
        cell, case, idx = cell[keep], case[keep], idx[keep]
    corner_values = flat[idx].astype(np.float64) - field.iso
    key = case * 64 + _face_bits(corner_values, case)
    table = case_table()
    crossed = table.crossed[case]  # (A, 12)
    rows, edges = np.nonzero(crossed)
    edge_start = cell[rows] + (EDGE_START @ strides(shape))[edges]
    gkey = edge_start * 3 + EDGE_AXIS[edges]
    ukey, inverse = np.unique(gkey, return_inverse=True)
    edge_crossing = np.full((len(cell), 12), -1, dtype=np.int64)
    edge_crossing[rows, edges] = inverse
    start, axis = ukey // 3, ukey % 3
    v0 = flat[start].astype(np.float64)
    v1 = flat[start + strides(shape)[axis]].astype(np.float64)
    t = (field.iso - v0) / (v1 - v0)
    return ActiveCells(cell, key, edge_crossing, start, axis, t)


def near_cells(cells: np.ndarray, seeds: np.ndarray, shape: tuple[int, int, int], reach: int) -> np.ndarray:
    """(n,) bool: which of the flat cell indices ``cells`` lie within ``reach`` cells of a seed.

    Chebyshev distance, answered on blocks of ``reach``³ cells: a cell within reach of a
    seed lies in the seed's block or a neighbouring one, so the answer is a superset
    (cells up to ``3 * reach - 1`` away may be included). Cost follows the number of
    cells and seeds, not the box.
    """
    def blocks(flat):
        return np.stack(np.unravel_index(flat, shape), axis=1) // reach + 1  # +1: no negative neighbours

    dims = np.array(shape) // reach + 3
    offsets = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    seed_blocks = np.unique(blocks(seeds) @ strides(tuple(dims)))
    near = np.unique((seed_blocks[:, None] + (offsets @ strides(tuple(dims)))[None]).reshape(-1))
    key = blocks(cells) @ strides(tuple(dims))
    where = np.minimum(np.searchsorted(near, key), len(near) - 1)
    return near[where] == key


def trilinear(values: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of ``values`` at (n, 3) index-space points (clamped to the box)."""
    shape = np.array(values.shape)
    p = np.clip(points, 0, shape - 1)
    base = np.minimum(np.floor(p).astype(np.int64), shape - 2)
    w = p - base
    factors = (1 - w, w)  # factors[c][:, axis]: weight of corner coordinate c along axis
    flat = values.reshape(-1)
    first = base @ strides(values.shape)
    out = np.zeros(len(p))
    for c, offset in zip(CORNERS, CORNERS @ strides(values.shape)):
        weight = factors[c[0]][:, 0] * factors[c[1]][:, 1] * factors[c[2]][:, 2]
        out += weight * flat[first + offset]
    return out
