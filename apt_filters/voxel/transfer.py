"""Contribution transfer functions: how one ion's count is fitted onto the grid points.

- ``square``: the whole ion to its nearest grid point;
- ``sawtooth``: cloud-in-cell, lever-rule weights on the 8 surrounding grid points;
- ``gaussian``: AP Suite / IVAS / APAV two-pass delocalization. Pass 1 spreads each ion over
  the 3×3×3 grid points around its nearest one with a Gaussian of sigma = voxel/6,
  renormalised per ion; pass 2 convolves the grid with a separable Gaussian of
  sigma² = (deloc/3)² − (voxel/6)² per axis, truncated at 4 sigma (scipy's discrete kernel,
  as APAV uses). Counts are delocalised, never concentrations.

Every ion's weights sum to 1 and the grid is padded so that no weight falls off it, so the
sum of a field equals its count exactly (to rounding): mass is never reflected at edges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numba.extending import overload
from scipy.ndimage import binary_dilation

from apt_filters.core.errors import AptFiltersError
from apt_filters.voxel.grid import BLOCK, Grid
from apt_filters.core.threads import on_threads, shares

QUANTUM = 2.0**-40
"""Resolution of the first pass's pools (an ion's weight at a grid point is held as a whole number of
these): integer sums are exact, so the fields are the same bit for bit whatever the thread count, the
shares of the ions or their order (float sums rounded in the order each pool saw its ions: one core
against two moved held-out rounded 10008's surface by 0.08 nm). 2**-40 keeps ~12 digits of a weight; an
int64 holds 2**23 whole weights, so a block of a pool that may reach :data:`POOL_LIMIT` spills (see ``_Pool``)."""
_PER_QUANTUM = 1.0 / QUANTUM
POOL_LIMIT = 2.0**22
"""Weight (in ions × |field weight|) that one grid point and channel of the pools may hold, all threads'
pools together, between spills: half of what an int64 of quanta holds, the other half margin for the
rounding of each weight to a quantum. Numba's int64 sums wrap silently beyond it."""
_HIGH = 40
"""Spills keep the low ``_HIGH`` bits (below one whole weight) in the pool and move the rest to ``_Pool.high``."""

KERNELS = ("square", "sawtooth", "gaussian")
TRUNCATE = 4.0
"""Second-pass Gaussian truncation in sigmas (IVAS/APAV)."""
_E18 = float(np.exp(-18.0))


def second_pass_sigma(voxel: float, delocalization) -> np.ndarray:
    """(3,) second-pass sigma in voxels: sqrt((deloc/3)² − (voxel/6)²) / voxel.

    Raises AptFiltersError where the delocalization does not exceed the first pass (deloc <= voxel/2).
    """
    deloc = np.broadcast_to(np.asarray(delocalization, dtype=np.float64), (3,))
    with np.errstate(over="ignore", invalid="ignore"):  # float64: a 1e300 nm voxel gives inf, not OverflowError
        var = (deloc / 3) ** 2 - (np.float64(voxel) / 6) ** 2
    if not (np.all(np.isfinite(deloc)) and np.all(np.isfinite(var))) or np.any(var <= 0):
        raise AptFiltersError(
            f"gaussian delocalization {deloc.tolist()} nm must exceed half the voxel ({voxel / 2:g} nm) on every axis"
        )
    return np.sqrt(var) / voxel


def second_pass_radius(sigma_vox: np.ndarray) -> np.ndarray:
    """(3,) int kernel radius in voxels, as scipy.ndimage.gaussian_filter rounds it."""
    return (TRUNCATE * np.asarray(sigma_vox) + 0.5).astype(np.int64)


def kernel_reach(kernel: str, voxel: float = 1.0, delocalization=(3.0, 3.0, 1.5)) -> np.ndarray:
    """(3,) int: grid points needed beyond the ions' box on each side so that no weight falls off.

    Use as ``Grid.covering(lower, upper, voxel, margin=kernel_reach(...))``.
    """
    check_kernel(kernel)
    if kernel == "square":
        return np.zeros(3, dtype=np.int64)
    if kernel == "sawtooth":
        return np.ones(3, dtype=np.int64)
    return 1 + second_pass_radius(second_pass_sigma(voxel, delocalization))


def check_kernel(kernel: str) -> None:
    if kernel not in KERNELS:
        raise AptFiltersError(f"unknown transfer function {kernel!r}; choose one of {', '.join(KERNELS)}")


def admissible_range(kernel: str, grid: Grid, delocalization) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) float64: fractional grid indices an ion may have without weight leaving the grid."""
    n = np.asarray(grid.shape, dtype=np.float64)
    if kernel == "square":
        return np.full(3, -0.5), n - 0.5
    if kernel == "sawtooth":
        return np.zeros(3), n - 1.0
    r = second_pass_radius(second_pass_sigma(grid.voxel, delocalization))
    return r + 0.5, n - 1.5 - r


# Two passes per chunk and thread. ``_mark`` checks each ion against the admissible range, counts
# it and flags the blocks its footprint touches in a dense uint8 table over the box's blocks;
# the flagged blocks without a slot get the next pool slots in block order (``_Pool.assign``, one
# pass over the box's blocks); ``_scatter`` then adds the weights through the slot table
# with no checks, no allocation and no early exit (cheaper per ion than one fused pass that gives
# slots on first touch and must stop when the pool is full).
# The slot table is read flat and holds each block's offset in the pool (slot × values per block,
# int64: no multiplication per tap), and every subscript goes through ``_u`` (unsigned), which spares
# numba's negative-index handling on each of the up to 27 writes per ion.
#
# The transfer function reaches the kernels as a tuple whose length selects it (``_KIND``): numba
# specialises each loop on the tuple's type (and caches each specialisation), so the
# footprint's 1, 2 or 3 taps per axis are compile-time constants that the compiler unrolls (a loop
# over a run-time tap count ran 2-3x slower).
_KIND = {"square": (), "sawtooth": (0,), "gaussian": (0, 0)}


# Each transfer function on one axis: the first of its 1, 2 or 3 grid points (``_*_start``; the
# marking pass needs no more), and that point with the weights and their sum: the scatter divides
# once per ion by the product of the three sums (1.0 and folded away for square and sawtooth),
# not once per axis.


@njit(inline="always")
def _nearest_start(f):
    """Square: the nearest grid point (f >= -0.5 in the admissible range, so int() floors)."""
    return np.int64(f + 0.5)


@njit(inline="always")
def _nearest(f, e):
    return _nearest_start(f), (1.0,), 1.0


@njit(inline="always")
def _lever_start(f):
    """Sawtooth: the grid point below (f >= 0)."""
    return np.int64(f)


@njit(inline="always")
def _lever(f, e):
    """Sawtooth: the grid point below and the next, lever-rule weights."""
    i = _lever_start(f)
    return i, (1.0 - (f - i), f - i), 1.0


@njit(inline="always")
def _gauss3_start(f):
    """Pass 1: the grid point before the nearest one (f >= 0.5 in the admissible range, so int() floors)."""
    return np.int64(f + 0.5) - 1


@njit(inline="always")
def _gauss3(f, e):
    """Pass 1: first of the 3 grid points around the nearest one, their weights relative to the
    nearest one's, and the sum of the three; ``e`` = exp(36 d) (``_exponentials``).

    Weights exp(-d² / (2 sigma²)) with sigma = voxel / 6, i.e. exp(-18 d²) in voxels. With d the
    offset of the nearest point, exp(-18 (d ± 1)²) / exp(-18 d²) = e^-18 exp(±36 d), so one exp
    per axis gives all three.
    """
    before, after = _E18 * e, _E18 / e
    return _gauss3_start(f), (before, 1.0, after), 1.0 + before + after


# Pass 1's exponentials are computed ahead of the scatter, ``_BATCH`` ions at a time, by two loops
# that the compiler vectorizes (8 ns per ion for the three; libm's exp does not vectorize, and as
# one loop the two did not either): with libm's exp called inside the scatter loop, pass 1 took
# 61-63 ns per ion, with the batches 53 (one process, 4 M ions).
_BATCH = 512
"""Ions per batch of pass-1 exponentials (12 kB of float64, in L1)."""
_TAYLOR = tuple(1.0 / math.factorial(k) for k in range(16))


@njit(inline="always")
def _exp36(y):
    """exp(y) for |y| <= 18, vectorizable: the degree-15 Taylor polynomial of y / 32 (|y / 32| <= 0.57,
    truncation below 5e-18) squared 5 times: relative error below 1e-14 (8.4e-15 at most over 4 M
    points of the range). Each ion's weights are still renormalised, so conservation is untouched;
    pass-1 fields moved by 6e-16 of their maximum against libm's exp."""
    r = y * (1.0 / 32.0)
    p = _TAYLOR[15]
    for k in range(14, -1, -1):
        p = p * r + _TAYLOR[k]
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    return p * p


@njit(nogil=True, cache=True)
def _pass1_exponents(pos, origin, inv_h, out):
    """out[3 j + a] = 36 d on axis a of ion j, d = its nearest grid point's offset (|d| <= 1/2)."""
    ox, oy, oz = origin[0], origin[1], origin[2]
    for j in range(pos.shape[0]):
        fx, fy, fz = (np.float64(pos[j, 0]) - ox) * inv_h, (np.float64(pos[j, 1]) - oy) * inv_h, \
            (np.float64(pos[j, 2]) - oz) * inv_h
        out[3 * j] = 36.0 * (_nearest_start(fx) - fx)
        out[3 * j + 1] = 36.0 * (_nearest_start(fy) - fy)
        out[3 * j + 2] = 36.0 * (_nearest_start(fz) - fz)


@njit(nogil=True, cache=True)
def _exp36_in_place(y):
    for j in range(y.shape[0]):
        y[j] = _exp36(y[j])


def _exponentials(kind, pos, origin, inv_h, out):
    """Gaussian: out[3 j + a] = exp(36 d) on axis a of ion j of ``pos`` (a batch); other kinds: nothing."""


@overload(_exponentials, inline="always")
def _exponentials_impl(kind, pos, origin, inv_h, out):
    if len(kind) < 2:
        return lambda kind, pos, origin, inv_h, out: None

    def impl(kind, pos, origin, inv_h, out):
        _pass1_exponents(pos, origin, inv_h, out)
        _exp36_in_place(out[: 3 * pos.shape[0]])
    return impl


def _batch_starts(kind, i, start):
    """Whether ion ``i`` starts a new batch of ``_exponentials`` (the last began at ``start``):
    gaussian only."""


@overload(_batch_starts, inline="always")
def _batch_starts_impl(kind, i, start):
    if len(kind) < 2:
        return lambda kind, i, start: False
    return lambda kind, i, start: i - start == _BATCH or i == 0


def _footprint(kind, f, e):
    """(first grid index, weights, their sum) along one axis of the transfer function ``kind`` (see
    ``_KIND``); ``e``: the axis's exponential from ``_exponentials`` (gaussian only)."""


def _start(kind, f):
    """First grid index along one axis of the transfer function ``kind`` (see ``_KIND``)."""


@overload(_footprint, inline="always")
def _footprint_impl(kind, f, e):
    axis = (_nearest, _lever, _gauss3)[len(kind)]
    return lambda kind, f, e: axis(f, e)


@overload(_start, inline="always")
def _start_impl(kind, f):
    axis = (_nearest_start, _lever_start, _gauss3_start)[len(kind)]
    return lambda kind, f: axis(f)


def _taps(kind):
    """Grid points per axis of the transfer function ``kind``: 1, 2 or 3."""


@overload(_taps, inline="always")
def _taps_impl(kind):
    taps = len(kind) + 1
    return lambda kind: taps


@njit(inline="always")
def _u(i):
    """An index known to be >= 0, as unsigned: numba then leaves out its negative-index wraparound
    (a compare and add per subscript that made the scatter 1.3-1.5x slower)."""
    return np.uint64(i)


@njit(nogil=True, cache=True)
def _mark(kind, pos, row, origin, inv_h, lo, hi, row_ptr, row_bound, marks, load, sx, sy, counts):
    """Count the ions per row, set ``marks`` to 1 on every block their footprints touch and add each
    ion's ``row_bound`` (the most it adds to one grid point and channel) to ``load`` at its first grid
    point's block (the footprint reaches that block and the next one per axis at most).

    ``marks`` and ``load`` are flat over the box's blocks: block (x, y, z) at ``x * sx + y * sy + z``.

    Returns the index of the first ion that counts in a field and lies outside the admissible
    range (or has a NaN coordinate), or -1.
    """
    for i in range(pos.shape[0]):
        r = row[i]
        counts[_u(r)] += 1
        if row_ptr[_u(r)] == row_ptr[_u(r + 1)]:  # an ion that counts in no field
            continue
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        if not (fx >= lo[0] and fx < hi[0] and fy >= lo[1] and fy < hi[1] and fz >= lo[2] and fz < hi[2]):
            return i
        ix, iy, iz = _start(kind, fx), _start(kind, fy), _start(kind, fz)
        last = _taps(kind) - 1
        # the blocks of the footprint's 8 corners, repeats included: no branch on whether it crosses a face
        x0, x1 = (ix >> 3) * sx, ((ix + last) >> 3) * sx
        y0, y1 = (iy >> 3) * sy, ((iy + last) >> 3) * sy
        z0, z1 = iz >> 3, (iz + last) >> 3
        marks[_u(x0 + y0 + z0)] = 1
        load[_u(x0 + y0 + z0)] += row_bound[_u(r)]
        if last:
            marks[_u(x1 + y0 + z0)] = 1
            marks[_u(x0 + y1 + z0)] = 1
            marks[_u(x1 + y1 + z0)] = 1
            marks[_u(x0 + y0 + z1)] = 1
            marks[_u(x1 + y0 + z1)] = 1
            marks[_u(x0 + y1 + z1)] = 1
            marks[_u(x1 + y1 + z1)] = 1
    return -1


# The pool stores block after block, each as [channel][z][y][x] (the fields as [x, y, z]): a
# footprint's x neighbours share a cache line, and ions come in detection order, z falling, so the
# values written while the scatter sweeps one z plane lie 8 to a cache line (330 kB for 8 fields
# of a 60 x 60 nm plane, in L2) instead of 1 to a line (2.6 MB).


def _axis_taps(w, i, sb, sv):
    """Per grid point ``i + t`` of a footprint with weights ``w`` on one axis: (its block × sb,
    its index in the block × sv), two tuples of len(w)."""


@overload(_axis_taps, inline="always")
def _axis_taps_impl(w, i, sb, sv):
    if len(w) == 1:
        return lambda w, i, sb, sv: (((i >> 3) * sb,), ((i & 7) * sv,))
    if len(w) == 2:
        return lambda w, i, sb, sv: (((i >> 3) * sb, ((i + 1) >> 3) * sb), ((i & 7) * sv, ((i + 1) & 7) * sv))
    return lambda w, i, sb, sv: (((i >> 3) * sb, ((i + 1) >> 3) * sb, ((i + 2) >> 3) * sb),
                                 ((i & 7) * sv, ((i + 1) & 7) * sv, ((i + 2) & 7) * sv))


# fastmath "contract" alone (here and in pass 2): a * b + c as one fused multiply-add, one rounding
# instead of two, no other licence (no reassociation, NaN and inf kept): pass 1 4-6 % faster, pass 2 18 %.
@njit(nogil=True, cache=True, fastmath={"contract"})
def _scatter(kind, pos, row, origin, inv_h, row_ptr, row_chan, row_w, table, sx, sy, pool):
    """Add every ion's weights into ``pool`` (flat, block after block, int64 in :data:`QUANTUM` units) through
    the slot table.

    ``table`` is flat over the box's blocks (block (x, y, z) at ``x * sx + y * sy + z``) and holds
    each block's offset in ``pool`` (its slot × the values per block). Every
    ion must lie in the admissible range and every block it touches have a slot (``_mark`` and
    ``_Pool.assign`` see to both). Ion ``i`` of row ``r`` adds ``row_w[p]`` times its normalised
    weights ``wx[a] wy[b] wz[d] / (nx ny nz)`` at grid point (ix + a, iy + b, iz + d) of channel
    ``row_chan[p]`` for each ``p`` in ``row_ptr[r]:row_ptr[r + 1]``.
    """
    expo = np.empty(3 * _BATCH)
    start = 0
    for i in range(pos.shape[0]):
        if _batch_starts(kind, i, start):
            start = i
            _exponentials(kind, pos[i: i + _BATCH], origin, inv_h, expo)
        e = 3 * (i - start)
        r = row[i]
        p0, p1 = row_ptr[_u(r)], row_ptr[_u(r + 1)]
        if p0 == p1:
            continue
        ix, wx, nx = _footprint(kind, (np.float64(pos[i, 0]) - origin[0]) * inv_h, expo[_u(e)])
        iy, wy, ny = _footprint(kind, (np.float64(pos[i, 1]) - origin[1]) * inv_h, expo[_u(e + 1)])
        iz, wz, nz = _footprint(kind, (np.float64(pos[i, 2]) - origin[2]) * inv_h, expo[_u(e + 2)])
        norm = 1.0 / (nx * ny * nz)  # the ion's weights sum to 1
        taps = len(wx)
        if (ix & 7) + taps <= 8 and (iy & 7) + taps <= 8 and (iz & 7) + taps <= 8:  # all in one block: one lookup
            at = (table[_u((ix >> 3) * sx + (iy >> 3) * sy + (iz >> 3))]
                  + ((iz & 7) << 6) + ((iy & 7) << 3) + (ix & 7))
            for p in range(p0, p1):
                c, m = at + (row_chan[_u(p)] << 9), row_w[_u(p)] * norm
                for a in range(taps):
                    for b in range(taps):
                        wab = m * wx[a] * wy[b]
                        for d in range(taps):
                            pool[_u(c + (d << 6) + (b << 3) + a)] += np.int64(wab * wz[d] * _PER_QUANTUM + 0.5)
            continue
        # across block faces: per axis and grid point its block's share of the table index and
        # its offset in the block, added up per point (the table is read per point, but in L1)
        tx, ox = _axis_taps(wx, ix, sx, 1)
        ty, oy = _axis_taps(wy, iy, sy, 8)
        tz, oz = _axis_taps(wz, iz, 1, 64)
        for p in range(p0, p1):
            c, m = row_chan[_u(p)] << 9, row_w[_u(p)] * norm
            for a in range(taps):
                for b in range(taps):
                    wab = m * wx[a] * wy[b]
                    column, offset = tx[a] + ty[b], c + ox[a] + oy[b]
                    for d in range(taps):
                        pool[_u(table[_u(column + tz[d])] + offset + oz[d])] += np.int64(wab * wz[d] * _PER_QUANTUM
                                                                                         + 0.5)


@njit(nogil=True, cache=True)
def _unpool(blocks, where, lo, hi, out):
    """out[c, where[s], x, y, z] += blocks[s, c, z, y, x] for the slots s with lo <= where[s] < hi: a
    pool's blocks (z, y, x) added into the fields (x, y, z), one thread's share of the blocks."""
    for s in range(where.shape[0]):
        k = where[s]
        if k < lo or k >= hi:
            continue
        for c in range(out.shape[0]):
            for x in range(BLOCK):
                for y in range(BLOCK):
                    for z in range(BLOCK):
                        out[c, k, x, y, z] += blocks[s, c, z, y, x]


class _Pool:
    """One thread's blocks: slot table over the box's blocks, block coordinates, values and row counts.

    ``data`` holds ``capacity`` blocks of ``n_channels`` × 512 int64 values (quanta), block-major.

    Overflow guard: an int64 of quanta holds 2**23 whole weights, so a grid point of a dense block
    could wrap silently after ~8 M ions. Each ion adds its row's bound to ``load`` at its first
    grid point's block; ``held`` bounds each block's values (in weights) up to the last check. Before
    each scatter, once ``held``'s maximum plus the weight marked since could pass ``limit``, a block
    whose bound (its held plus the load of the blocks whose ions reach it) passes ``limit`` is
    spilled: its whole weights (bits ``_HIGH`` and up) move to ``high`` (int64 in weights, by block
    offset) and the rest stays in ``data``. The sums stay exact, so the fields still do not depend on
    the thread count; blocks of ordinary specimens never spill.
    """

    def __init__(self, block_shape: tuple[int, int, int], n_channels: int, n_rows: int, limit: float):
        self.table = np.full(block_shape, -1, dtype=np.int64)  # each block's offset in data, -1: none
        self.marks = np.zeros(block_shape, dtype=np.uint8)
        self.coords = np.zeros((0, 3), dtype=np.int32)
        self.stride = n_channels * BLOCK**3
        self.data = np.zeros(0, dtype=np.int64)  # in units of QUANTUM: exact sums
        self.n_active = 0
        self.counts = np.zeros(n_rows, dtype=np.int64)
        self.limit = float(limit)
        self.load = np.zeros(block_shape)  # weight marked per first-point block since the last check
        self.pending = 0.0  # its sum
        self.held = np.zeros(block_shape)  # bound on each block's values at the last check, weights
        self.held_max = 0.0
        self.high: dict[int, np.ndarray] = {}  # block offset in data -> (stride,) int64 spilled weights

    def blocks(self) -> np.ndarray:
        """(capacity, n_channels * 512) view of the values."""
        return self.data.reshape(-1, self.stride)

    def reserve(self, need: int, max_blocks: int) -> None:
        """Capacity for at least ``need`` blocks: 1.5x the current one if more, at most ``max_blocks``
        (zero-filled; copies the occupied ones once)."""
        cap = len(self.coords)
        if need <= cap:
            return
        if cap:
            need = min(max_blocks, max(need, cap * 3 // 2))
        data = np.zeros(need * self.stride, dtype=np.int64)
        data[: self.n_active * self.stride] = self.data[: self.n_active * self.stride]
        coords = np.zeros((need, 3), dtype=np.int32)
        coords[: self.n_active] = self.coords[: self.n_active]
        self.data, self.coords = data, coords

    def assign(self, max_blocks: int) -> None:
        """Give the marked blocks that have none the next slots, in block order, and clear the marks."""
        new = np.flatnonzero((self.marks.ravel() != 0) & (self.table.ravel() < 0))
        self.marks[...] = 0
        self.reserve(self.n_active + len(new), max_blocks)
        slots = np.arange(self.n_active, self.n_active + len(new))
        self.table.ravel()[new] = slots * self.stride
        self.coords[slots] = np.column_stack(np.unravel_index(new, self.table.shape))
        self.n_active += len(new)

    def guard(self, kind: tuple) -> None:
        """Spill the blocks whose values could pass ``limit`` with the ions marked since the last
        check (see the class docstring); a no-op while ``held_max`` + ``pending`` stays within it."""
        if self.held_max + self.pending <= self.limit:
            return
        add = self.load.copy()
        if kind:  # sawtooth and gaussian reach the next block on each axis: add the lower neighbours' load
            for axis in range(3):
                add[(slice(None),) * axis + (slice(1, None),)] += add[(slice(None),) * axis + (slice(None, -1),)]
        bound = self.held + add
        bound[self.table < 0] = 0.0  # no slot after ``assign``: no ion reaches it
        over = bound > self.limit
        mask = (1 << _HIGH) - 1
        for offset in self.table[over]:
            values = self.data[offset: offset + self.stride]
            high = self.high.setdefault(int(offset), np.zeros(self.stride, dtype=np.int64))
            high += values >> _HIGH  # floor: exact for negative weights too
            values &= mask
        bound[over] = 1.0 + add[over]  # what stays is below one weight
        self.held, self.held_max = bound, float(bound.max())
        self.load[...] = 0.0
        self.pending = 0.0

    def scatter(self, kind: tuple, positions, rows, origin, inv_h, lo, hi, csr, max_blocks: int,
                row_bound: np.ndarray) -> int:
        """Scatter all ions; returns the index of the first ion outside the admissible range (the
        ions of the pieces before it scattered, none after), or -1.

        The ions go in pieces of less than ``limit`` weight, so that one piece never overfills a
        block that the guard has just spilled (below one weight left); ordinary chunks are one piece.
        """
        strides = self.table.shape[1] * self.table.shape[2], self.table.shape[2]
        piece = max(1, int((self.limit - 1.0) / max(float(row_bound.max()), 1e-300)))
        for a in range(0, len(positions), piece):
            pos, row = positions[a: a + piece], rows[a: a + piece]
            bad = _mark(kind, pos, row, origin, inv_h, lo, hi, csr[0], row_bound, self.marks.ravel(),
                        self.load.ravel(), *strides, self.counts)
            if bad >= 0:
                return a + bad
            self.pending += float(row_bound.max()) * len(pos)
            self.assign(max_blocks)
            self.guard(kind)
            _scatter(kind, pos, row, origin, inv_h, *csr, self.table.ravel(), *strides, self.data)
        return -1


class BlockAccumulator:
    """Scatters chunks of ions into block-sparse count fields (one channel per field).

    Memory: ``n_channels * 4096`` bytes per pool block. The first chunk sizes the pool to its
    occupied blocks exactly; later chunks that add blocks grow it by at least 1.5× (never beyond
    the box's blocks), so it holds up to 1.5× the occupied blocks, 2.5× for a moment while it
    grows; plus the slot table, the marks and the guard's load and bound (25 bytes per block of the bounding box). With
    ``threads`` > 1 every thread has its own pool (so up to ``threads`` × that), added one after
    the other into the fields at the end.

    Parameters
    ----------
    grid : Grid
    kernel : {"square", "sawtooth", "gaussian"}
    rows : (row_ptr, row_chan, row_w)
        CSR map from ion row (ion species index + 1; row 0 = unranged) to (channel, weight):
        an ion of row r adds ``weight`` times its kernel to each listed channel.
    n_channels : int
    delocalization : (3,) nm
        Gaussian only.
    threads : int
        Threads that scatter each chunk, each a contiguous share of its ions into its own pool
        (1 here; :func:`~apt_filters.voxel.fields.voxelize` uses one per available core).

    Attributes
    ----------
    row_count : (n_rows,) int64
        Ions scattered so far per row.
    """

    def __init__(self, grid: Grid, kernel: str, rows, n_channels: int, delocalization=(3.0, 3.0, 1.5),
                 threads: int = 1):
        check_kernel(kernel)
        if int(threads) < 1:
            raise AptFiltersError(f"scatter threads must be at least 1, got {threads!r}")
        self.grid = grid
        self.kernel = kernel
        self.delocalization = delocalization
        self.rows = tuple(np.ascontiguousarray(a) for a in rows)
        self.lo, self.hi = admissible_range(kernel, grid, delocalization)
        self.max_blocks = int(np.prod(grid.block_shape))
        # the pools' values are added up as int64 at the end: each pool holds its share of the limit
        self.pools = [_Pool(grid.block_shape, n_channels, len(self.rows[0]) - 1, POOL_LIMIT / int(threads))
                      for _ in range(int(threads))]
        row_ptr, _, row_w = self.rows
        # the most an ion of each row adds to one grid point and channel: its |weights| (a kernel gives a point <= 1)
        self.row_bound = np.zeros(len(row_ptr) - 1)
        np.add.at(self.row_bound, np.repeat(np.arange(len(row_ptr) - 1), np.diff(row_ptr)), np.abs(row_w))
        self.row_count = np.zeros(len(self.rows[0]) - 1, dtype=np.int64)

    def add(self, positions: np.ndarray, rows: np.ndarray) -> None:
        """Scatter ions: positions (N, 3) nm, rows (N,) int (ion species index + 1)."""
        positions = np.ascontiguousarray(positions)
        rows = np.ascontiguousarray(rows)
        parts = shares(len(positions), len(self.pools))
        args = (_KIND[self.kernel], np.asarray(self.grid.origin), 1.0 / self.grid.voxel, self.lo, self.hi,
                self.rows, self.max_blocks, self.row_bound)
        bad = on_threads(lambda pool, a, b: pool.scatter(args[0], positions[a:b], rows[a:b], *args[1:]),
                         [(pool, a, b) for pool, (a, b) in zip(self.pools, parts)])
        for (a, _), i in zip(parts, bad):
            if i >= 0:
                p = positions[a + i]
                raise AptFiltersError(
                    f"ion at ({p[0]:g}, {p[1]:g}, {p[2]:g}) nm lies outside the grid or within the {self.kernel} "
                    f"kernel's reach of its edge; build the grid with Grid.covering(lower, upper, voxel, "
                    f"margin=kernel_reach(...)) from the ions' bounds"
                )
        self.row_count = sum(p.counts for p in self.pools)

    def _merged(self, extend: bool) -> tuple[np.ndarray, np.ndarray]:
        """Every pool's blocks added into one array, and the pools released.

        Returns ``(keys, fields)``: sorted flat block indices (x, y, z block order, whatever the
        order the ions came in) and (n_channels, len(keys), 8, 8, 8) float64 values, x, y, z.
        ``extend`` adds the blocks pass 2 will reach (gaussian), so that the second pass can work
        in place without a second copy of the fields.
        """
        pools, self.pools = self.pools, []
        threads = len(pools)
        keys = [np.ravel_multi_index(tuple(p.coords[: p.n_active].T), self.grid.block_shape) for p in pools]
        union = np.unique(np.concatenate(keys))
        if extend and self.kernel == "gaussian":
            coords = block_coords(self.grid, union)
            coords = second_pass_blocks(self.grid, coords, second_pass_sigma(self.grid.voxel, self.delocalization))
            union = np.ravel_multi_index(tuple(coords.T), self.grid.block_shape)
        # each thread adds every pool's share of its range of blocks (disjoint writes), in whole quanta (exact)
        fields = np.zeros((pools[0].stride // BLOCK**3, len(union), BLOCK, BLOCK, BLOCK), dtype=np.int64)
        blocks = [p.blocks()[: p.n_active].reshape(p.n_active, fields.shape[0], BLOCK, BLOCK, BLOCK) for p in pools]
        wheres = [np.searchsorted(union, key) for key in keys]
        on_threads(lambda lo, hi: [_unpool(b, w, lo, hi, fields) for b, w in zip(blocks, wheres)],
                   shares(len(union), threads))
        spilled = self._spilled(pools, union, wheres, fields)
        values = fields.view(np.float64)  # in place: no second copy of the fields
        np.multiply(fields, QUANTUM, out=values)
        if spilled is not None:
            values[:, spilled[0]] = spilled[1]
        return union, values

    @staticmethod
    def _spilled(pools, union, wheres, fields):
        """None, or (indices into ``union``, (n_channels, k, 8, 8, 8) float64 values) of the blocks that
        some pool spilled (``_Pool.guard``): whole weights plus the quanta below one, each an exact
        int64, added with one rounding, as ``fields × QUANTUM`` rounds the blocks that none spilled (so
        a value does not depend on which pools spilled)."""
        if not any(p.high for p in pools):
            return None
        n_channels = fields.shape[0]
        high = {}
        for pool, where in zip(pools, wheres):
            for offset, weights in pool.high.items():
                k = int(where[offset // pool.stride])
                blocks = weights.reshape(n_channels, BLOCK, BLOCK, BLOCK).transpose(0, 3, 2, 1)  # z, y, x -> x, y, z
                high[k] = high[k] + blocks if k in high else blocks.copy()
        ks = np.array(sorted(high))
        quanta = fields[:, ks]
        whole = np.stack([high[k] for k in ks], axis=1) + (quanta >> _HIGH)
        return ks, whole.astype(np.float64) + (quanta & ((1 << _HIGH) - 1)) * QUANTUM

    def partial(self) -> BlockPartial:
        """The first pass so far, as a :class:`BlockPartial` to add to others' (releases the pools).

        Partials of disjoint sets of ions, added and finished with :func:`finish_partial`, give the
        fields of all the ions (map-reduce voxelization over many processes or machines).
        """
        counts = self.row_count.copy()
        keys, fields = self._merged(extend=False)
        return BlockPartial(keys, fields, counts)

    def result(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """(coords (n_blocks, 3) int32, one (n_blocks, 8, 8, 8) array per channel), after pass 2 if gaussian.

        Blocks in x, y, z block order, whatever the order the ions came in.
        """
        threads = len(self.pools)
        keys, fields = self._merged(extend=True)
        coords = block_coords(self.grid, keys)
        channels = list(fields)
        if self.kernel == "gaussian":
            second_pass(self.grid, coords, channels, second_pass_sigma(self.grid.voxel, self.delocalization), threads)
        return coords, channels


@dataclass
class BlockPartial:
    """The first-pass scatter of a set of ions, before the gaussian's second pass (which is linear,
    so it runs once on the sum).

    Attributes
    ----------
    keys : (n,) int64
        Sorted flat indices of the occupied blocks on the grid's block shape.
    fields : (n_channels, n, 8, 8, 8) float64
        Values per channel and block, x, y, z.
    row_count : (n_rows,) int64
        Ions scattered per ion row.
    """

    keys: np.ndarray
    fields: np.ndarray
    row_count: np.ndarray

    def __add__(self, other: BlockPartial) -> BlockPartial:
        """The partial of both sets of ions (the blocks' union, values added)."""
        keys = np.union1d(self.keys, other.keys)
        fields = np.zeros((self.fields.shape[0], len(keys)) + self.fields.shape[2:])
        fields[:, np.searchsorted(keys, self.keys)] += self.fields  # keys are unique: no lost additions
        fields[:, np.searchsorted(keys, other.keys)] += other.fields
        return BlockPartial(keys, fields, self.row_count + other.row_count)


def block_coords(grid: Grid, keys: np.ndarray) -> np.ndarray:
    """(n, 3) int32 block coordinates of flat block indices."""
    return np.column_stack(np.unravel_index(keys, grid.block_shape)).astype(np.int32).reshape(-1, 3)


def finish_partial(grid: Grid, kernel: str, delocalization, partial: BlockPartial,
                   threads: int = 1) -> tuple[np.ndarray, list[np.ndarray]]:
    """What :meth:`BlockAccumulator.result` returns, from the sum of partials: (coords, channels)."""
    coords = block_coords(grid, partial.keys)
    if kernel != "gaussian":
        return coords, list(partial.fields)
    sigma = second_pass_sigma(grid.voxel, delocalization)
    coords = second_pass_blocks(grid, coords, sigma)
    keys = np.ravel_multi_index(tuple(coords.T), grid.block_shape)
    fields = np.zeros((partial.fields.shape[0], len(keys)) + partial.fields.shape[2:])
    fields[:, np.searchsorted(keys, partial.keys)] = partial.fields
    channels = list(fields)
    second_pass(grid, coords, channels, sigma, threads)
    return coords, channels


def second_pass_weights(sigma_vox: float) -> tuple[float, ...]:
    """Taps of the pass-2 Gaussian on one axis (2 radius + 1, summing to 1), as scipy's
    ``gaussian_filter1d`` builds them (truncated at :data:`TRUNCATE` sigma): a tuple, so that the
    compiled filter is specialised (and unrolled) on the number of taps."""
    r = int(second_pass_radius(sigma_vox))
    x = np.arange(-r, r + 1)
    phi = np.exp(-0.5 / sigma_vox**2 * x**2)
    return tuple((phi / phi.sum()).tolist())


@njit(nogil=True, cache=True, fastmath={"contract"})
def _correlate_row(src, i, dst, w):
    """dst[:] = sum_k w[k] src[i + k - r, :] for an (n, m) ``src`` and (m,) ``dst``, zero beyond the
    first axis's ends (r = len(w) // 2).

    A row whose taps all lie inside takes the unrolled loop (a branch per tap made the pass 1.5x slower).
    """
    n, m = src.shape
    r = len(w) // 2
    if i >= r and i + r < n:
        for j in range(m):
            s = 0.0
            for k in range(len(w)):
                s += w[k] * src[_u(i + k - r), _u(j)]
            dst[_u(j)] = s
    else:
        for j in range(m):
            s = 0.0
            for k in range(len(w)):
                if 0 <= i + k - r < n:
                    s += w[k] * src[_u(i + k - r), _u(j)]
            dst[_u(j)] = s


@njit(nogil=True, cache=True, fastmath={"contract"})
def _correlate_last(src, dst, w):
    """dst[i, j] = sum_k w[k] src[i, j + k - r] on (n, m) arrays, zero beyond the last axis's ends."""
    n, m = src.shape
    r = len(w) // 2
    for i in range(n):
        for j in range(m):
            if j >= r and j + r < m:
                s = 0.0
                for k in range(len(w)):
                    s += w[k] * src[_u(i), _u(j + k - r)]
            else:
                s = 0.0
                for k in range(len(w)):
                    if 0 <= j + k - r < m:
                        s += w[k] * src[_u(i), _u(j + k - r)]
            dst[_u(i), _u(j)] = s


@njit(nogil=True, cache=True)
def _densify(coords, data, bx0, bx1, a):
    """Rows ``bx0 * 8 : bx1 * 8`` (x) of the dense block-rounded box ``a``: zero, then the values of the
    blocks ``data`` at ``coords`` whose x block lies in ``bx0:bx1`` (one thread's slab)."""
    a[bx0 * BLOCK: bx1 * BLOCK] = 0.0
    for s in range(coords.shape[0]):
        if coords[s, 0] < bx0 or coords[s, 0] >= bx1:
            continue
        x0, y0, z0 = coords[s, 0] * BLOCK, coords[s, 1] * BLOCK, coords[s, 2] * BLOCK
        for i in range(BLOCK):
            for j in range(BLOCK):
                for k in range(BLOCK):
                    a[_u(x0 + i), _u(y0 + j), _u(z0 + k)] = data[s, i, j, k]


@njit(nogil=True, cache=True)
def _smooth(a, data, slots, wx, wy, wz, x0, x1, plane, plane2):
    """Planes ``x0:x1`` of one channel's pass 2: the dense box ``a`` filtered plane by plane along x
    (into ``plane``), y (into ``plane2``) and z (into ``plane``), and written back into the blocks
    ``data`` (``slots``: each block's slot, or -1). One plane (120 kB here) is filtered along y and z
    while it is in cache: one pass over the box instead of three. Threads filtering disjoint ranges
    of planes read the same ``a`` and write disjoint values of ``data``."""
    nx, ny, nz = a.shape
    flat = a.reshape(nx, ny * nz)
    for x in range(x0, x1):
        _correlate_row(flat, x, plane.reshape(ny * nz), wx)
        for y in range(ny):
            _correlate_row(plane, y, plane2[y], wy)
        _correlate_last(plane2, plane, wz)
        bx, i = x // BLOCK, x % BLOCK
        for by in range(slots.shape[1]):
            for bz in range(slots.shape[2]):
                slot = slots[bx, by, bz]
                if slot >= 0:
                    for j in range(BLOCK):
                        for k in range(BLOCK):
                            data[slot, i, j, k] = plane[_u(by * BLOCK + j), _u(bz * BLOCK + k)]


def second_pass_blocks(grid: Grid, coords: np.ndarray, sigma_vox: np.ndarray) -> np.ndarray:
    """(n, 3) int32 block coordinates, x, y, z block order: ``coords`` and every block within pass 2's
    kernel radius of one of them (where pass 2 puts weight)."""
    reach = -(-second_pass_radius(sigma_vox) // BLOCK)
    occupied = np.zeros(grid.block_shape, dtype=bool)
    occupied[coords[:, 0], coords[:, 1], coords[:, 2]] = True
    footprint = np.ones(tuple(2 * reach + 1), dtype=bool)
    return np.argwhere(binary_dilation(occupied, structure=footprint)).astype(np.int32)


def second_pass(grid: Grid, coords: np.ndarray, channels: list[np.ndarray], sigma_vox: np.ndarray,
                threads: int = 1) -> None:
    """Separable Gaussian (truncated at 4 sigma, zero outside) of each block-sparse channel, in place.

    ``coords`` must hold every block within the kernel radius of a block with weight
    (:func:`second_pass_blocks`). Works one channel at a time through a dense copy of the
    block-rounded box (a nogil compiled filter, the same taps as scipy's ``gaussian_filter1d``),
    each of ``threads`` threads on its own slab of x planes (whole blocks): copied in, then
    filtered once every slab is in. The result does not depend on ``threads``. Transient memory:
    one dense float64 field, and two of its x planes per thread.
    """
    taps = [second_pass_weights(s) for s in sigma_vox]
    box = tuple(n * BLOCK for n in grid.block_shape)
    slots = np.full(grid.block_shape, -1, dtype=np.int32)
    slots[coords[:, 0], coords[:, 1], coords[:, 2]] = np.arange(len(coords), dtype=np.int32)
    slabs = shares(grid.block_shape[0], max(1, min(int(threads), grid.block_shape[0])))
    planes = [(np.empty(box[1:]), np.empty(box[1:])) for _ in slabs]
    a = np.empty(box)
    for data in channels:
        on_threads(lambda b0, b1: _densify(coords, data, b0, b1, a), slabs)
        on_threads(lambda b0, b1, p: _smooth(a, data, slots, *taps, b0 * BLOCK, b1 * BLOCK, *p),
                   [(b0, b1, p) for (b0, b1), p in zip(slabs, planes)])
