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

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit
from scipy.ndimage import binary_dilation, gaussian_filter1d

from apt_filters.core.errors import AptFiltersError
from apt_filters.voxel.grid import BLOCK, Grid
from apt_filters.voxel.sparse import blocks_to_dense, dense_to_blocks

KERNELS = ("square", "sawtooth", "gaussian")
TRUNCATE = 4.0
"""Second-pass Gaussian truncation in sigmas (IVAS/APAV)."""
_E18 = float(np.exp(-18.0))


def second_pass_sigma(voxel: float, delocalization) -> np.ndarray:
    """(3,) second-pass sigma in voxels: sqrt((deloc/3)² − (voxel/6)²) / voxel.

    Raises AptFiltersError where the delocalization does not exceed the first pass (deloc <= voxel/2).
    """
    deloc = np.broadcast_to(np.asarray(delocalization, dtype=np.float64), (3,))
    var = (deloc / 3) ** 2 - (voxel / 6) ** 2
    if not np.all(np.isfinite(deloc)) or np.any(var <= 0):
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


# Each chunk is scattered in three passes, on ``threads`` Python threads running
# nogil kernels (compiled like serial code: numba's parallel=True took 4x the first-call JIT
# time). ``_mark`` (each thread on a contiguous share of the ions) checks every ion against the
# admissible range, counts the ions per row and flags the absent blocks its footprint touches;
# ``_assign`` (serial, over the flags: one byte per block of the box) gives them pool slots in
# block order; the scatter (threads) then only reads the block table. Scatter threads write
# disjoint blocks: an ion belongs to the z layer of blocks holding the lowest z index of its
# footprint (which spans at most that layer and the next), and in phase p the threads take the
# layers L with L % 2 == p, task (L // 2) % n_tasks, so two layers scattered at once are >= 2
# apart. Every thread reads the whole chunk and skips the ions of other tasks (cheap next to the
# writes; in detection order the layer changes rarely).
#
# Footprint along one axis: first grid index floor(f + shift) + offset, then ``width`` more.
FOOTPRINT = {"square": (0.5, 0, 0), "sawtooth": (0.0, 0, 1), "gaussian": (0.5, -1, 2)}


@njit(nogil=True, cache=True)
def _mark(pos, row, origin, inv_h, lo, hi, shift, offset, width, row_ptr, table, fresh, counts, i0, i1):
    """Flag (``fresh`` = 1) the absent blocks of the footprints of ions [i0, i1); count them per row.

    Returns the first ion outside the admissible range (or NaN), else -1. Threads on other
    shares may flag one block together: they all store the same byte.
    """
    for i in range(i0, i1):
        r = row[i]
        counts[r] += 1
        if row_ptr[r] == row_ptr[r + 1]:
            continue  # an ion that counts in no field
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        if not (fx >= lo[0] and fx < hi[0] and fy >= lo[1] and fy < hi[1] and fz >= lo[2] and fz < hi[2]):
            return i
        x0 = np.int64(np.floor(fx + shift)) + offset
        y0 = np.int64(np.floor(fy + shift)) + offset
        z0 = np.int64(np.floor(fz + shift)) + offset
        if (x0 & 7) + width < 8 and (y0 & 7) + width < 8 and (z0 & 7) + width < 8:  # most ions: one block
            if table[x0 >> 3, y0 >> 3, z0 >> 3] < 0:
                fresh[x0 >> 3, y0 >> 3, z0 >> 3] = 1
            continue
        for bx in range(x0 >> 3, ((x0 + width) >> 3) + 1):
            for by in range(y0 >> 3, ((y0 + width) >> 3) + 1):
                for bz in range(z0 >> 3, ((z0 + width) >> 3) + 1):
                    if table[bx, by, bz] < 0:
                        fresh[bx, by, bz] = 1
    return -1


@njit(cache=True)
def _assign(fresh, table, coords, n_active):
    """Give the flagged blocks the next pool slots (x, y, z block order), clear the flags; new n_active."""
    for bx in range(fresh.shape[0]):
        for by in range(fresh.shape[1]):
            for bz in range(fresh.shape[2]):
                if fresh[bx, by, bz]:
                    fresh[bx, by, bz] = 0
                    table[bx, by, bz] = n_active
                    coords[n_active, 0] = bx
                    coords[n_active, 1] = by
                    coords[n_active, 2] = bz
                    n_active += 1
    return n_active


@njit(inline="always")
def _owns(layer, last_layer, owned, phase, task, n_tasks):
    """Whether this task scatters ions of block layer ``layer`` (memoised on the previous layer)."""
    if layer != last_layer:
        owned = n_tasks == 1 or ((layer & 1) == phase and (layer >> 1) % n_tasks == task)
    return owned


@njit
def _gauss3(f):
    """Pass 1 on one axis: first of the 3 grid points around the nearest one, and their weights.

    Weights exp(-d² / (2 sigma²)) with sigma = voxel / 6, i.e. exp(-18 d²) in voxels, normalised.
    With d the offset of the nearest point, exp(-18 (d ± 1)²) = exp(-18 d²) e^-18 exp(±36 d), so
    one exp per axis gives all three.
    """
    c = np.floor(f + 0.5)
    b = np.exp(36.0 * (c - f))
    w1 = 1.0 / (1.0 + _E18 * (b + 1.0 / b))
    return np.int64(c) - 1, (_E18 * b * w1, w1, _E18 / b * w1)


# The pool stores each block as [z, y, x] (the fields as [x, y, z]): ions come in detection order,
# z falling, so the values written while the scatter sweeps one z plane lie 8 to a cache line
# (330 kB for 8 fields of a 60 x 60 nm plane, in L2) instead of 1 to a line (2.6 MB); this
# halved the scatter time of a dense test loop.
#
# The scatter loops are written out per kernel, with scalar locals, because the footprint size is
# then a constant that the compiler unrolls (a generic loop ran 2-3x slower). They index the pool
# flat (``chan`` values per channel, 512 per block): shifts instead of numba's 5-d stride arithmetic.


@njit(nogil=True, cache=True)
def _scatter_square(pos, row, origin, inv_h, row_ptr, row_chan, row_w, table, pool, chan, phase, task, n_tasks):
    last, owned = np.int64(-1), False
    for i in range(pos.shape[0]):
        p0, p1 = row_ptr[row[i]], row_ptr[row[i] + 1]
        if p0 == p1:
            continue
        iz = np.int64(np.floor((np.float64(pos[i, 2]) - origin[2]) * inv_h + 0.5))
        owned = _owns(iz >> 3, last, owned, phase, task, n_tasks)
        last = iz >> 3
        if not owned:
            continue
        ix = np.int64(np.floor((np.float64(pos[i, 0]) - origin[0]) * inv_h + 0.5))
        iy = np.int64(np.floor((np.float64(pos[i, 1]) - origin[1]) * inv_h + 0.5))
        voxel = ((iz & 7) << 6) + ((iy & 7) << 3) + (ix & 7) + (np.int64(table[ix >> 3, iy >> 3, iz >> 3]) << 9)
        for p in range(p0, p1):
            pool[row_chan[p] * chan + voxel] += row_w[p]


@njit(nogil=True, cache=True, inline="always")
def _splat(pool, chan, table, ix, iy, iz, wx, wy, wz, taps, p0, p1, row_chan, row_w):
    """Add the taps x taps x taps weights wx[a] wy[b] wz[d] at grid point (ix, iy, iz) + (a, b, d)
    for every channel of one ion's row, in the pool's z-first block layout."""
    last = 8 - taps
    if (ix & 7) <= last and (iy & 7) <= last and (iz & 7) <= last:  # all in one block: one lookup
        at = (np.int64(table[ix >> 3, iy >> 3, iz >> 3]) << 9) + ((iz & 7) << 6) + ((iy & 7) << 3) + (ix & 7)
        for p in range(p0, p1):
            c, m = row_chan[p], row_w[p]
            for a in range(taps):
                for b in range(taps):
                    wab = m * wx[a] * wy[b]
                    for d in range(taps):
                        pool[c * chan + at + (d << 6) + (b << 3) + a] += wab * wz[d]
        return
    for p in range(p0, p1):
        c, m = row_chan[p], row_w[p]
        for a in range(taps):
            for b in range(taps):
                wab = m * wx[a] * wy[b]
                column = c * chan + (((iy + b) & 7) << 3) + ((ix + a) & 7)
                at = column + (np.int64(table[(ix + a) >> 3, (iy + b) >> 3, iz >> 3]) << 9)
                for d in range(taps):
                    if d and (iz + d) & 7 == 0:  # the z column enters the next block
                        at = column + (np.int64(table[(ix + a) >> 3, (iy + b) >> 3, (iz + d) >> 3]) << 9)
                    pool[at + (((iz + d) & 7) << 6)] += wab * wz[d]


@njit(nogil=True, cache=True)
def _scatter_sawtooth(pos, row, origin, inv_h, row_ptr, row_chan, row_w, table, pool, chan, phase, task, n_tasks):
    last, owned = np.int64(-1), False
    for i in range(pos.shape[0]):
        p0, p1 = row_ptr[row[i]], row_ptr[row[i] + 1]
        if p0 == p1:
            continue
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        z0 = np.floor(fz)
        iz = np.int64(z0)
        owned = _owns(iz >> 3, last, owned, phase, task, n_tasks)
        last = iz >> 3
        if not owned:
            continue
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        x0, y0 = np.floor(fx), np.floor(fy)
        wx = (1.0 - (fx - x0), fx - x0)  # lever rule
        wy = (1.0 - (fy - y0), fy - y0)
        wz = (1.0 - (fz - z0), fz - z0)
        ix, iy = np.int64(x0), np.int64(y0)
        _splat(pool, chan, table, ix, iy, iz, wx, wy, wz, 2, p0, p1, row_chan, row_w)


@njit(nogil=True, cache=True)
def _scatter_gaussian(pos, row, origin, inv_h, row_ptr, row_chan, row_w, table, pool, chan, phase, task, n_tasks):
    last, owned = np.int64(-1), False
    for i in range(pos.shape[0]):
        p0, p1 = row_ptr[row[i]], row_ptr[row[i] + 1]
        if p0 == p1:
            continue
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        layer = (np.int64(np.floor(fz + 0.5)) - 1) >> 3  # as _gauss3 places it, without its exp
        owned = _owns(layer, last, owned, phase, task, n_tasks)
        last = layer
        if not owned:
            continue
        iz, wz = _gauss3(fz)
        ix, wx = _gauss3((np.float64(pos[i, 0]) - origin[0]) * inv_h)
        iy, wy = _gauss3((np.float64(pos[i, 1]) - origin[1]) * inv_h)
        _splat(pool, chan, table, ix, iy, iz, wx, wy, wz, 3, p0, p1, row_chan, row_w)


_EXECUTORS: dict[int, ThreadPoolExecutor] = {}


def _on_threads(fn, calls: list[tuple]) -> list:
    """Results of ``fn(*args)`` for each args in ``calls``, one thread each (the kernels release the GIL)."""
    if len(calls) == 1:
        return [fn(*calls[0])]
    executor = _EXECUTORS.get(len(calls))
    if executor is None:
        executor = _EXECUTORS[len(calls)] = ThreadPoolExecutor(len(calls), thread_name_prefix="voxel-scatter")
    return list(executor.map(lambda args: fn(*args), calls))


_SCATTER = {"square": _scatter_square, "sawtooth": _scatter_sawtooth, "gaussian": _scatter_gaussian}


class BlockAccumulator:
    """Scatters chunks of ions into block-sparse count fields (one channel per field).

    Memory: ``n_channels * capacity * 512 * 8`` bytes of pool (capacity grows by doubling, so up
    to twice the occupied blocks while scattering, capped at the box's blocks) plus the block
    table and its flags (5 bytes per block of the bounding box). With ``threads`` > 1 the
    threads share the one pool (they write disjoint blocks) and add ``threads × n_rows`` counters.

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
        Threads that scatter each chunk (1 by default: see :func:`~apt_filters.voxel.fields.voxelize`).

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
        self.threads = int(threads)
        self.grid = grid
        self.kernel = kernel
        self.delocalization = delocalization
        self.rows = tuple(np.ascontiguousarray(a) for a in rows)
        self.lo, self.hi = admissible_range(kernel, grid, delocalization)
        self.table = np.full(grid.block_shape, -1, dtype=np.int32)
        self.fresh = np.zeros(grid.block_shape, dtype=np.uint8)
        # empty until the first chunk says how many blocks it needs (no growth copy for one chunk)
        self.pool = np.zeros((n_channels, 0, BLOCK, BLOCK, BLOCK))
        self.coords = np.zeros((0, 3), dtype=np.int32)
        self.n_active = 0
        self.row_count = np.zeros(len(self.rows[0]) - 1, dtype=np.int64)

    def add(self, positions: np.ndarray, rows: np.ndarray) -> None:
        """Scatter ions: positions (N, 3) nm, rows (N,) int (ion species index + 1)."""
        positions = np.ascontiguousarray(positions)
        rows = np.ascontiguousarray(rows)
        origin = np.asarray(self.grid.origin)
        inv_h = 1.0 / self.grid.voxel
        n_tasks = self.threads
        counts = np.zeros((n_tasks, len(self.row_count)), dtype=np.int64)
        shares = np.linspace(0, len(positions), n_tasks + 1).astype(np.int64)
        mark_args = (positions, rows, origin, inv_h, self.lo, self.hi, *FOOTPRINT[self.kernel], self.rows[0],
                     self.table, self.fresh)
        bad = [i for i in _on_threads(_mark, [mark_args + (counts[t], shares[t], shares[t + 1])
                                              for t in range(n_tasks)]) if i >= 0]
        if bad:
            self.fresh[:] = 0
            p = positions[bad[0]]
            raise AptFiltersError(
                f"ion at ({p[0]:g}, {p[1]:g}, {p[2]:g}) nm lies outside the grid or within the {self.kernel} "
                f"kernel's reach of its edge; build the grid with Grid.covering(lower, upper, voxel, "
                f"margin=kernel_reach(...)) from the ions' bounds"
            )
        self._grow(self.n_active + int(np.count_nonzero(self.fresh)))
        self.n_active = _assign(self.fresh, self.table, self.coords, self.n_active)
        self.row_count += counts.sum(axis=0)
        scatter_args = (positions, rows, origin, inv_h, *self.rows, self.table, self.pool.reshape(-1),
                        self.pool[0].size)
        for phase in range(2 if n_tasks > 1 else 1):  # the layers of one phase are >= 2 apart
            _on_threads(_SCATTER[self.kernel], [scatter_args + (phase, t, n_tasks) for t in range(n_tasks)])

    def _grow(self, need: int) -> None:
        """Make room for ``need`` blocks: double the pool (at least to ``need``, never beyond the box's blocks)."""
        cap = self.pool.shape[1]
        if need <= cap:
            return
        new_cap = int(min(max(2 * cap, need), np.prod(self.grid.block_shape)))
        pool = np.zeros((self.pool.shape[0], new_cap, BLOCK, BLOCK, BLOCK))
        pool[:, :cap] = self.pool
        coords = np.zeros((new_cap, 3), dtype=np.int32)
        coords[:cap] = self.coords
        self.pool, self.coords = pool, coords

    def result(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """(coords (n_blocks, 3) int32, one (n_blocks, 8, 8, 8) array per channel), after pass 2 if gaussian."""
        coords = self.coords[: self.n_active].copy()
        # copies, so that the fields hold their occupied blocks only, not the spare capacity; the
        # pool stores a block z, y, x (see POOL_ORDER), the fields x, y, z
        channels = [np.ascontiguousarray(self.pool[c, : self.n_active].transpose(0, 3, 2, 1))
                    for c in range(self.pool.shape[0])]
        self.pool = self.coords = None  # release the over-allocated pool before pass 2
        if self.kernel == "gaussian":
            return second_pass(self.grid, coords, channels, second_pass_sigma(self.grid.voxel, self.delocalization))
        return coords, channels


def second_pass(grid: Grid, coords: np.ndarray, channels: list[np.ndarray], sigma_vox: np.ndarray):
    """Separable Gaussian (truncated at 4 sigma, zero outside) of each block-sparse channel.

    The result lives on the blocks within the kernel radius of the input blocks. Works one
    channel at a time through a dense copy of the block-rounded box: transient memory is two
    dense float64 fields.
    """
    reach = -(-second_pass_radius(sigma_vox) // BLOCK)
    occupied = np.zeros(grid.block_shape, dtype=bool)
    occupied[coords[:, 0], coords[:, 1], coords[:, 2]] = True
    footprint = np.ones(tuple(2 * reach + 1), dtype=bool)
    new_coords = np.argwhere(binary_dilation(occupied, structure=footprint)).astype(np.int32)
    out = []
    for data in channels:
        dense = blocks_to_dense(grid, coords, data)
        for axis in range(3):
            dense = gaussian_filter1d(dense, sigma_vox[axis], axis=axis, mode="constant", truncate=TRUNCATE)
        out.append(dense_to_blocks(dense, new_coords))
    return new_coords, out
