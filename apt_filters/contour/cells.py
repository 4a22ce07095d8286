"""Active cells and edge crossings shared by marching cubes and dual contouring.

Work beyond one cheap pass over the box is proportional to the number of *active* cells
(cells whose corners straddle the iso-value): the field is thresholded and a compiled scan
lists the active cells with their cases (a few ns per cell). Peak memory beyond the input
is three bytes per voxel (threshold, edge bits, running counts) plus O(active cells) index arrays.

All geometry here is in *index space* (voxel units, point ``(i, j, k)`` at ``(i, j, k)``);
the public functions map to world coordinates at the end.
"""

from __future__ import annotations

import functools
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
    shape : (3,) int
        Grid points per axis of the field the cells come from.
    cell : (A,) int64
        Flat point index of each active cell's corner 0.
    key : (A,) int64
        Table key ``case * 64 + face_bits``.
    crossing_start : (V,) int64
        Flat point index where each crossed grid edge starts.
    crossing_axis : (V,) int64
    crossing_t : (V,) float64
        Fraction along the edge (linear interpolation).
    edge_marks : (ceil(N / 8),) uint64
        Bit ``8 * (p % 8) + axis`` of word ``p // 8`` is set where grid edge (point ``p``, ``axis``)
        is crossed (N grid points).
    edge_rank : (ceil(N / 8),) int64
        Crossings numbered before each word; valid in the runs of 64 words that hold a crossing.
        With ``edge_marks`` it numbers any crossed edge in O(1).
    """

    shape: tuple[int, int, int]
    cell: np.ndarray
    key: np.ndarray
    crossing_start: np.ndarray
    crossing_axis: np.ndarray
    crossing_t: np.ndarray
    edge_marks: np.ndarray
    edge_rank: np.ndarray

    @functools.cached_property
    def edge_crossing(self) -> np.ndarray:
        """(A, 12) int64 crossing id of each crossed cube edge of each cell, -1 elsewhere (built on
        first use: 96 bytes per active cell, which marching cubes does without)."""
        return _edge_crossing(self.cell, self.key >> 6, crossed_bits(), EDGE_START @ strides(self.shape), EDGE_AXIS,
                              self.edge_marks, self.edge_rank)

    def crossing_points(self, shape: tuple[int, int, int]) -> np.ndarray:
        """(V, 3) crossing positions in index space."""
        out = np.empty((len(self.crossing_start), 3))
        world_points(self.crossing_start, self.crossing_axis, self.crossing_t, strides(shape), np.ones(3),
                     np.zeros(3), out)
        return out


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
                        if n + 8 > len(cells):
                            cells = np.concatenate((cells, np.empty_like(cells)))
                            cases = np.concatenate((cases, np.empty_like(cases)))
                        for k in range(8):  # without branches: every byte written, the count kept for cases 1-254
                            case = np.int64(word >> np.uint64(8 * k) & np.uint64(255))
                            cells[n] = row + k
                            cases[n] = case
                            n += np.int64(np.uint64(case - 1) < np.uint64(254))
    return cells[:n].copy(), cases[:n].copy()


@functools.lru_cache(maxsize=1)
def crossed_bits() -> np.ndarray:
    """(256,) int64: bit e set where cube edge e is crossed in each case."""
    return case_table().crossed.astype(np.int64) @ (1 << np.arange(12))


@functools.lru_cache(maxsize=1)
def _ambiguous_bits() -> np.ndarray:
    """(256,) int64: bit f set where face f is ambiguous in each case."""
    return case_table().ambiguous.astype(np.int64) @ (1 << np.arange(6))


def find_active_cells(field: Field) -> ActiveCells:
    """Sign-changing cells (all corners inside the mask) with their crossings."""
    f = field.values
    shape = f.shape
    flat = f.reshape(-1)
    offsets = CORNERS @ strides(shape)
    words = threshold_words(f, field.iso)
    blocks = shares(-(-(shape[0] - 1) // BLOCK), max(1, min(available_cores(), shape[0] // 64)))
    found = on_threads(lambda b0, b1: _scan_cells(words, shape[2], b0, b1), blocks)
    del words
    cell, case = (np.concatenate(a) for a in zip(*found))
    if field.mask is not None:
        keep = field.mask.reshape(-1)[cell[:, None] + offsets[None, :]].all(axis=1)
        cell, case = cell[keep], case[keep]
    key, marks, busy = _mark_edges(cell, case, flat, field.iso, offsets, _ambiguous_bits(), FACE_CORNERS,
                                   crossed_bits(), EDGE_START @ strides(shape), EDGE_AXIS)
    start, axis, t, rank = _number_crossings(marks, busy, flat, field.iso, strides(shape))
    return ActiveCells(shape, cell, key, start, axis, t, marks, rank)


_LOW = np.uint64(0x0101010101010101)


@njit(inline="always")
def _bits(word):
    """Set bits of a word of 8 bytes that each hold bits 0-2 only."""
    x = (word & _LOW) + (word >> np.uint64(1) & _LOW) + (word >> np.uint64(2) & _LOW)
    return np.int64((x * _LOW) >> np.uint64(56))


@njit(inline="always")
def crossing_id(p, axis, marks, rank):
    """Number of crossed grid edge (point ``p``, ``axis``): the crossings before its word plus the set
    bits before it in the word (see :class:`ActiveCells`)."""
    below = (np.uint64(1) << np.uint64(8 * (p & 7) + axis)) - np.uint64(1)
    return rank[p >> 3] + _bits(marks[p >> 3] & below)


@njit(nogil=True, cache=True, error_model="numpy")
def _mark_edges(cell, case, flat, iso, corner_offset, ambiguous, face_corners, crossed, edge_offset, edge_axis):
    """Table keys (asymptotic decider on ambiguous faces) and the crossed grid edges of the cells.

    A face bit is set when the saddle value ``(a0 a2 - a1 a3) / (a0 + a2 - a1 - a3)`` of the face's
    four values relative to ``iso`` (cyclic order) is positive: the inside corners connect. Every
    crossed edge of a cell sets bit ``axis`` of a byte per grid point (its start), so the edges
    shared by up to four cells are marked once; ``busy`` flags the runs of 512 points (64 words)
    holding a mark, the only ones :func:`_number_crossings` counts (pages that stay zero are never
    touched).

    Returns
    -------
    key : (A,) int64
    marks : (ceil(N / 8),) uint64
        The mark bytes, 8 points to a word (little-endian: the bytes of a word are its points in order).
    busy : (ceil(N / 512) + 1,) bool
    """
    n_words = (flat.shape[0] + 7) >> 3
    words = np.zeros(n_words, dtype=np.uint64)
    marks = words.view(np.uint8)
    busy = np.zeros((n_words >> 6) + 1, dtype=np.bool_)
    key = np.empty(cell.shape[0], dtype=np.int64)
    for c in range(cell.shape[0]):
        base, k = cell[c], case[c]
        bits = 0
        if ambiguous[k]:
            for f in range(6):
                if ambiguous[k] >> f & 1:
                    a0 = np.float64(flat[base + corner_offset[face_corners[f, 0]]]) - iso
                    a1 = np.float64(flat[base + corner_offset[face_corners[f, 1]]]) - iso
                    a2 = np.float64(flat[base + corner_offset[face_corners[f, 2]]]) - iso
                    a3 = np.float64(flat[base + corner_offset[face_corners[f, 3]]]) - iso
                    if (a0 * a2 - a1 * a3) / (a0 + a2 - a1 - a3) > 0:
                        bits |= 1 << f
        key[c] = k * 64 + bits
        row = crossed[k]
        for e in range(12):
            if row >> e & 1:
                p = base + edge_offset[e]
                marks[p] |= np.uint8(1 << edge_axis[e])
                busy[p >> 9] = True
    return key, words, busy


@njit(nogil=True, cache=True)
def _number_crossings(words, busy, flat, iso, stride):
    """The marked grid edges numbered in (start point, axis) order, without sorting.

    A running count over the busy runs gives each word's first number (``rank``); the edges are
    then listed word by word. O(1) per crossed edge plus a count per 8 points of the busy runs.

    Returns
    -------
    start, axis : (V,) int64
        Start point (flat index) and axis of each crossed grid edge, in (start, axis) order.
    t : (V,) float64
        Fraction along the edge where the linear interpolant meets ``iso``.
    rank : (ceil(N / 8),) int64
        Crossings before each word (written in the busy runs only).
    """
    n_words = words.shape[0]
    marks = words.view(np.uint8)
    rank = np.empty(n_words, dtype=np.int64)
    count = 0
    for r in range(busy.shape[0]):
        if busy[r]:
            for w in range(r << 6, min((r + 1) << 6, n_words)):
                rank[w] = count
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
    return start, axis, t, rank


@njit(nogil=True, cache=True)
def _edge_crossing(cell, case, crossed, edge_offset, edge_axis, marks, rank):
    """(A, 12) crossing id of each crossed cube edge, -1 elsewhere."""
    out = np.full((cell.shape[0], 12), -1, dtype=np.int64)
    for c in range(cell.shape[0]):
        row = crossed[case[c]]
        for e in range(12):
            if row >> e & 1:
                out[c, e] = crossing_id(cell[c] + edge_offset[e], edge_axis[e], marks, rank)
    return out


@njit(nogil=True, cache=True)
def world_points(start, axis, t, stride, spacing, origin, out):
    """Write ``origin + position * spacing`` of the crossings into ``out`` (V, 3): their index-space
    position is the start point's ``(i, j, k)`` with ``t`` added along ``axis``."""
    for v in range(start.shape[0]):
        p = start[v]
        ijk = (p // stride[0], p % stride[0] // stride[1], p % stride[1])
        for a in range(3):
            x = np.float64(ijk[a]) + (t[v] if a == axis[v] else 0.0)
            out[v, a] = origin[a] + x * spacing[a]


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
