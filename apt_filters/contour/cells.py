"""Active cells and edge crossings shared by marching cubes and dual contouring.

Work beyond one cheap pass over the box is proportional to the number of *active* cells
(cells whose corners straddle the iso-value): the field is thresholded and a compiled scan
lists the active cells with their cases (a few ns per cell). Peak memory beyond the input
is three bytes per voxel (threshold, edge bits, running counts) plus O(active cells) index arrays.

All geometry here is in *index space* (voxel units, point ``(i, j, k)`` at ``(i, j, k)``);
the public functions map to world coordinates at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from apt_filters.contour.tables import CORNERS, EDGE_AXIS, EDGE_START, FACE_CORNERS, case_table
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.threads import available_cores, on_threads, shares

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


def threshold_words(values: np.ndarray, iso: float) -> np.ndarray:
    """(nx, ny, nw) uint64: byte k of row (i, j) is 1 where ``values[i, j, k] > iso``; rows padded with
    zeros to ``nw = nz // 8 + 2`` words, so that a row's 8 z values from a multiple of 8 and the next
    one are two aligned words."""
    nx, ny, nz = values.shape
    words = np.zeros((nx, ny, nz // 8 + 2), dtype=np.uint64)
    np.greater(values, iso, out=words.view(np.bool_)[:, :, :nz])
    return words


@njit(nogil=True, cache=True)
def _scan_cells(words: np.ndarray, nz: int, x0: int, x1: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat corner-0 indices and cases of the sign-changing cells in x blocks ``x0:x1``, block by block.

    ``words`` is :func:`threshold_words`. A cell's case is the 4 bits of its lower x-y face
    (corners 0-3 of :data:`CORNERS`) and the 4 of its upper one. The faces of 8 cells along z
    are built at once in the 8 bytes of a word from the 4 rows around them (4 bits per byte, no
    carries), and the 8 cases from that word and the next face's byte: a run of 8 cells all inside
    or all outside costs a few word operations. Cells are listed in 8³ blocks (blocks in x, y, z
    order, cells within a block likewise): the order marching cubes' faces follow. The output
    grows by doubling; threads take consecutive ranges of x blocks.
    """
    nx, ny, nw = words.shape
    cells = np.empty(1 << 16, dtype=np.int64)
    cases = np.empty(1 << 16, dtype=np.int64)
    n = 0
    for bx in range(x0 * BLOCK, min(x1 * BLOCK, nx - 1), BLOCK):
        for by in range(0, ny - 1, BLOCK):
            for bw in range((nz - 2) // BLOCK + 1):
                n_valid = min(BLOCK, nz - 1 - bw * BLOCK)
                valid = np.uint64(0xFFFFFFFFFFFFFFFF) >> np.uint64(64 - 8 * n_valid)
                for i in range(bx, min(bx + BLOCK, nx - 1)):
                    for j in range(by, min(by + BLOCK, ny - 1)):
                        face = (words[i, j, bw] | words[i + 1, j, bw] << np.uint64(1)
                                | words[i, j + 1, bw] << np.uint64(2) | words[i + 1, j + 1, bw] << np.uint64(3))
                        nxt = (words[i, j, bw + 1] | words[i + 1, j, bw + 1] << np.uint64(1)
                               | words[i, j + 1, bw + 1] << np.uint64(2) | words[i + 1, j + 1, bw + 1] << np.uint64(3))
                        word = (face | ((face >> np.uint64(8)) | (nxt << np.uint64(56))) << np.uint64(4)) & valid
                        if word == 0 or word == valid:  # 8 cells all outside or all inside
                            continue
                        row = (i * ny + j) * nz + bw * BLOCK
                        for k in range(n_valid):
                            case = np.int64(word >> np.uint64(8 * k) & np.uint64(255))
                            if case == 0 or case == 255:
                                continue
                            if n == len(cells):
                                cells = np.concatenate((cells, np.empty_like(cells)))
                                cases = np.concatenate((cases, np.empty_like(cases)))
                            cells[n] = row + k
                            cases[n] = case
                            n += 1
    return cells[:n].copy(), cases[:n].copy()


def _face_bits(flat: np.ndarray, cell: np.ndarray, case: np.ndarray, iso: float, offsets: np.ndarray) -> np.ndarray:
    """Asymptotic decider on ambiguous faces: bit f set when the inside corners connect (corner
    values read for the ambiguous faces only)."""
    bits = np.zeros(len(case), dtype=np.int64)
    rows, faces = np.nonzero(case_table().ambiguous[case])  # (A, 6)
    if len(rows):
        corners = cell[rows][:, None] + offsets[FACE_CORNERS[faces]]
        a = flat[corners].astype(np.float64) - iso  # (r, 4) cyclic, relative to iso
        saddle = (a[:, 0] * a[:, 2] - a[:, 1] * a[:, 3]) / (a[:, 0] + a[:, 2] - a[:, 1] - a[:, 3])
        np.add.at(bits, rows, (saddle > 0).astype(np.int64) << faces)
    return bits


def find_active_cells(field: Field) -> ActiveCells:
    """Sign-changing cells (all corners inside the mask) with their crossings."""
    f = field.values
    shape = f.shape
    flat = f.reshape(-1)
    offsets = CORNERS @ strides(shape)
    words = threshold_words(f, field.iso)
    blocks = shares(-(-(shape[0] - 1) // BLOCK), max(1, min(available_cores(), shape[0] // 64)))
    found = on_threads(lambda b0, b1: _scan_cells(words, shape[2], b0, b1), blocks)
    cell, case = (np.concatenate(a) for a in zip(*found))
    if field.mask is not None:
        keep = field.mask.reshape(-1)[cell[:, None] + offsets[None, :]].all(axis=1)
        cell, case = cell[keep], case[keep]
    key = case * 64 + _face_bits(flat, cell, case, field.iso, offsets)
    start, axis, t, edge_crossing = _crossings(cell, case, case_table().crossed, EDGE_START @ strides(shape),
                                               EDGE_AXIS, flat, field.iso, strides(shape))
    return ActiveCells(cell, key, edge_crossing, start, axis, t)


_LOW = np.uint64(0x0101010101010101)


@njit(inline="always")
def _bits(word):
    """Set bits of a word of 8 bytes that each hold bits 0-2 only."""
    x = (word & _LOW) + (word >> np.uint64(1) & _LOW) + (word >> np.uint64(2) & _LOW)
    return np.int64((x * _LOW) >> np.uint64(56))


@njit(nogil=True, cache=True)
def _crossings(cell, case, crossed, edge_offset, edge_axis, flat, iso, stride):
    """The crossed grid edges of the cells, numbered in (start point, axis) order, and each cell's.

    Every crossed edge of a cell sets bit ``axis`` of a byte per grid point (its start), so the
    edges shared by up to four cells are listed once; a running count per word of 8 points then
    gives any edge's number as that count plus the set bits before it in its word. Replaces a sort
    of the cells' 4-5 edge keys each (``np.unique``): a byte per grid point, of which only the
    runs of 512 points that hold a crossed edge are counted (8 at a time), and O(1) per crossed
    cell edge.

    Returns
    -------
    start, axis : (V,) int64
        Start point (flat index) and axis of each crossed grid edge, in (start, axis) order.
    t : (V,) float64
        Fraction along the edge where the linear interpolant meets ``iso``.
    edge_crossing : (A, 12) int64
        Number of each crossed cube edge of each cell, -1 elsewhere.
    """
    n_words = (flat.shape[0] + 7) >> 3  # the bytes of a word are its points in order (little-endian)
    words = np.zeros(n_words, dtype=np.uint64)  # pages that stay zero are never touched
    marks = words.view(np.uint8)
    busy = np.zeros((n_words >> 6) + 1, dtype=np.bool_)  # runs of 64 words holding a crossed edge
    for c in range(cell.shape[0]):
        row = crossed[case[c]]
        for e in range(12):
            if row[e]:
                p = cell[c] + edge_offset[e]
                marks[p] |= np.uint8(1 << edge_axis[e])
                busy[p >> 9] = True
    base = np.empty(n_words, dtype=np.int64)  # written (and read) in busy runs only
    count = 0
    for r in range(busy.shape[0]):
        if busy[r]:
            for w in range(r << 6, min((r + 1) << 6, n_words)):
                base[w] = count
                count += _bits(words[w])
    start = np.empty(count, dtype=np.int64)
    axis = np.empty(count, dtype=np.int64)
    t = np.empty(count)
    k = 0
    for r in range(busy.shape[0]):
        if not busy[r]:
            continue
        for w in range(r << 6, min((r + 1) << 6, n_words)):
            if words[w] == 0:
                continue
            for p in range(w << 3, (w << 3) + 8):
                m = marks[p]
                for a in range(3):
                    if m >> a & 1:
                        v0 = np.float64(flat[p])
                        start[k], axis[k] = p, a
                        t[k] = (iso - v0) / (np.float64(flat[p + stride[a]]) - v0)
                        k += 1
    edge_crossing = np.full((cell.shape[0], 12), -1, dtype=np.int64)
    for c in range(cell.shape[0]):
        row = crossed[case[c]]
        for e in range(12):
            if row[e]:
                p = cell[c] + edge_offset[e]
                below = (np.uint64(1) << np.uint64(8 * (p & 7) + edge_axis[e])) - np.uint64(1)  # bits before (p, axis)
                edge_crossing[c, e] = base[p >> 3] + _bits(words[p >> 3] & below)
    return start, axis, t, edge_crossing


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
