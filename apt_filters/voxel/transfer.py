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
from numba.extending import overload
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


# One fused pass per chunk and thread: each ion is checked against the admissible range, its
# footprint's blocks are looked up in a dense slot table over the box's blocks (4 bytes per block:
# no hashing or sorting) and given pool slots on first touch, and its weights are added in place;
# no per-ion arrays. When the pool is full the kernel stops before the ion that needs a slot,
# having written none of its weight, and resumes from it once the pool has grown.
#
# The transfer function reaches the kernel as a tuple whose length selects it (``_KIND``): numba
# specialises the one scatter loop on the tuple's type (and caches each specialisation), so the
# footprint's 1, 2 or 3 taps per axis are compile-time constants that the compiler unrolls (a loop
# over a run-time tap count ran 2-3x slower).
_KIND = {"square": (), "sawtooth": (0,), "gaussian": (0, 0)}
_DONE, _FULL, _OUTSIDE = 0, 1, 2


@njit(inline="always")
def _nearest(f):
    """Square on one axis: the nearest grid point (f >= -0.5 in the admissible range, so int() floors)."""
    return np.int64(f + 0.5), (1.0,)


@njit(inline="always")
def _lever(f):
    """Sawtooth on one axis: the grid point below (f >= 0) and the next, lever-rule weights."""
    i = np.int64(f)
    return i, (1.0 - (f - i), f - i)


@njit(inline="always")
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


def _footprint(kind, f):
    """(first grid index, weights) along one axis of the transfer function ``kind`` (see ``_KIND``)."""


@overload(_footprint, inline="always")
def _footprint_impl(kind, f):
    axis = (_nearest, _lever, _gauss3)[len(kind)]
    return lambda kind, f: axis(f)


@njit(inline="always")
def _touch(table, coords, n_active, ix, iy, iz, taps):
    """Give the absent blocks of a footprint (taps³ points from ix, iy, iz) the next pool slots.

    Returns the new number of active blocks, or -1 (nothing changed) if the pool lacks room.
    """
    bx, by, bz = ix >> 3, iy >> 3, iz >> 3
    ex, ey, ez = (ix + taps - 1) >> 3, (iy + taps - 1) >> 3, (iz + taps - 1) >> 3
    if bx == ex and by == ey and bz == ez and table[bx, by, bz] >= 0:
        return n_active  # most ions: one block, already there
    missing = 0
    for x in range(bx, ex + 1):
        for y in range(by, ey + 1):
            for z in range(bz, ez + 1):
                missing += table[x, y, z] < 0
    if n_active + missing > coords.shape[0]:
        return -1
    for x in range(bx, ex + 1):
        for y in range(by, ey + 1):
            for z in range(bz, ez + 1):
                if table[x, y, z] < 0:
                    table[x, y, z] = n_active
                    coords[n_active, 0], coords[n_active, 1], coords[n_active, 2] = x, y, z
                    n_active += 1
    return n_active


# The pool stores block after block, each as [channel][z][y][x] (the fields as [x, y, z]): a
# footprint's x neighbours share a cache line, and ions come in detection order, z falling, so the
# values written while the scatter sweeps one z plane lie 8 to a cache line (330 kB for 8 fields
# of a 60 x 60 nm plane, in L2) instead of 1 to a line (2.6 MB).


@njit(inline="always")
def _splat(pool, stride, table, ix, iy, iz, wx, wy, wz, p0, p1, row_chan, row_w):
    """Add the weights wx[a] wy[b] wz[d] at grid point (ix, iy, iz) + (a, b, d) for every channel of one ion's row."""
    taps = len(wx)
    if (ix & 7) + taps <= 8 and (iy & 7) + taps <= 8 and (iz & 7) + taps <= 8:  # all in one block: one lookup
        at = np.int64(table[ix >> 3, iy >> 3, iz >> 3]) * stride + ((iz & 7) << 6) + ((iy & 7) << 3) + (ix & 7)
        for p in range(p0, p1):
            c, m = at + (row_chan[p] << 9), row_w[p]
            for a in range(taps):
                for b in range(taps):
                    wab = m * wx[a] * wy[b]
                    for d in range(taps):
                        pool[c + (d << 6) + (b << 3) + a] += wab * wz[d]
        return
    for p in range(p0, p1):
        c, m = row_chan[p] << 9, row_w[p]
        for a in range(taps):
            x = ix + a
            for b in range(taps):
                y = iy + b
                wab = m * wx[a] * wy[b]
                column = c + ((y & 7) << 3) + (x & 7)
                for d in range(taps):
                    z = iz + d
                    pool[np.int64(table[x >> 3, y >> 3, z >> 3]) * stride + column + ((z & 7) << 6)] += wab * wz[d]


@njit(nogil=True, cache=True)
def _scatter(kind, pos, row, start, origin, inv_h, lo, hi, row_ptr, row_chan, row_w, table, coords, n_active,
             pool, stride, counts):
    """Scatter ions [start, N) with transfer function ``kind`` into ``pool`` (flat, ``stride`` values per block).

    Returns (stop, n_active, status): ``_DONE``; ``_FULL``: the pool has no slot for ion ``stop``
    (none of its weight written: grow the pool and resume from it); ``_OUTSIDE``: ion ``stop``
    lies outside the admissible range (or has a NaN coordinate).
    """
    for i in range(start, pos.shape[0]):
        r = row[i]
        p0, p1 = row_ptr[r], row_ptr[r + 1]
        if p0 == p1:  # an ion that counts in no field
            counts[r] += 1
            continue
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        if not (fx >= lo[0] and fx < hi[0] and fy >= lo[1] and fy < hi[1] and fz >= lo[2] and fz < hi[2]):
            return i, n_active, _OUTSIDE
        ix, wx = _footprint(kind, fx)
        iy, wy = _footprint(kind, fy)
        iz, wz = _footprint(kind, fz)
        grown = _touch(table, coords, n_active, ix, iy, iz, len(wx))
        if grown < 0:
            return i, n_active, _FULL
        n_active = grown
        counts[r] += 1
        _splat(pool, stride, table, ix, iy, iz, wx, wy, wz, p0, p1, row_chan, row_w)
    return pos.shape[0], n_active, _DONE


@njit(nogil=True, cache=True)
def _unpool(blocks, order, out):
    """out[c, k, x, y, z] = blocks[order[k], c, z, y, x]: the pool's blocks (z, y, x) as fields (x, y, z)."""
    for k in range(order.shape[0]):
        s = order[k]
        for c in range(out.shape[0]):
            for x in range(BLOCK):
                for y in range(BLOCK):
                    for z in range(BLOCK):
                        out[c, k, x, y, z] = blocks[s, c, z, y, x]


_EXECUTORS: dict[int, ThreadPoolExecutor] = {}


def _on_threads(fn, calls: list[tuple]) -> list:
    """Results of ``fn(*args)`` for each args in ``calls``, one thread each (the kernels release the GIL)."""
    if len(calls) == 1:
        return [fn(*calls[0])]
    executor = _EXECUTORS.get(len(calls))
    if executor is None:
        executor = _EXECUTORS[len(calls)] = ThreadPoolExecutor(len(calls), thread_name_prefix="voxel-scatter")
    return list(executor.map(lambda args: fn(*args), calls))


class _Pool:
    """One thread's blocks: slot table over the box's blocks, block coordinates, values and row counts.

    ``data`` holds ``capacity`` blocks of ``n_channels`` × 512 float64 values, block-major.
    """

    def __init__(self, block_shape: tuple[int, int, int], n_channels: int, n_rows: int):
        self.table = np.full(block_shape, -1, dtype=np.int32)
        self.coords = np.zeros((0, 3), dtype=np.int32)
        self.stride = n_channels * BLOCK**3
        self.data = np.zeros(0)
        self.n_active = 0
        self.counts = np.zeros(n_rows, dtype=np.int64)

    def blocks(self) -> np.ndarray:
        """(capacity, n_channels * 512) view of the values."""
        return self.data.reshape(-1, self.stride)

    def reserve(self, need: int) -> None:
        """Capacity for at least ``need`` blocks (zero-filled; copies the occupied ones once)."""
        cap = len(self.coords)
        if need <= cap:
            return
        data = np.zeros(need * self.stride)
        data[: self.n_active * self.stride] = self.data[: self.n_active * self.stride]
        coords = np.zeros((need, 3), dtype=np.int32)
        coords[: self.n_active] = self.coords[: self.n_active]
        self.data, self.coords = data, coords

    def scatter(self, kind: tuple, positions, rows, origin, inv_h, lo, hi, csr, max_blocks: int) -> int:
        """Scatter all ions, growing the pool (x1.5, at most ``max_blocks``) as needed.

        Returns the index of the first ion outside the admissible range, or -1.
        """
        start = 0
        while True:
            start, self.n_active, status = _scatter(kind, positions, rows, start, origin, inv_h, lo, hi, *csr,
                                                    self.table, self.coords, self.n_active, self.data,
                                                    self.stride, self.counts)
            if status == _DONE:
                return -1
            if status == _OUTSIDE:
                return start
            # +8: a footprint needs at most 8 new blocks
            self.reserve(min(max_blocks, max(len(self.coords) * 3 // 2, self.n_active + 8)))

    def merge(self, other: "_Pool") -> None:
        """Add another thread's blocks into this pool."""
        n = other.n_active
        theirs = other.coords[:n]
        slots = self.table[theirs[:, 0], theirs[:, 1], theirs[:, 2]].astype(np.int64)
        new = slots < 0
        n_new = int(new.sum())
        self.reserve(self.n_active + n_new)
        slots[new] = np.arange(self.n_active, self.n_active + n_new)
        self.coords[slots[new]] = theirs[new]
        self.table[theirs[new, 0], theirs[new, 1], theirs[new, 2]] = slots[new]
        self.n_active += n_new
        self.blocks()[slots] += other.blocks()[:n]
        self.counts += other.counts


def _first_capacity(positions: np.ndarray, grid: Grid, max_blocks: int) -> int:
    """Pool blocks to start with: 1.25 x the distinct blocks of every 64th ion, at most ``max_blocks``.

    Sized from the data so that a dense box gets its pool in one allocation (no growth copies)
    and a sparse one does not get the box's.
    """
    sample = np.floor(grid.fractional_index(positions[::64]) + 0.5)
    sample = np.clip(np.nan_to_num(sample), 0, np.asarray(grid.shape) - 1).astype(np.int64) // BLOCK
    distinct = len(np.unique(np.ravel_multi_index(tuple(sample.T), grid.block_shape)))
    return int(min(max_blocks, distinct * 5 // 4 + 8))


class BlockAccumulator:
    """Scatters chunks of ions into block-sparse count fields (one channel per field).

    Memory: ``n_channels * 4096`` bytes per pool block, the pool holding up to 1.5× the occupied
    blocks (never more than the box's blocks) and 2.5× for a moment while it grows, plus the
    slot table (4 bytes per block of the bounding box). With ``threads`` > 1 every thread has
    its own pool (so up to ``threads`` × that), merged at the end.

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
        (1 by default: see :func:`~apt_filters.voxel.fields.voxelize`).

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
        self.pools = [_Pool(grid.block_shape, n_channels, len(self.rows[0]) - 1) for _ in range(int(threads))]
        self.row_count = np.zeros(len(self.rows[0]) - 1, dtype=np.int64)

    def add(self, positions: np.ndarray, rows: np.ndarray) -> None:
        """Scatter ions: positions (N, 3) nm, rows (N,) int (ion species index + 1)."""
        positions = np.ascontiguousarray(positions)
        rows = np.ascontiguousarray(rows)
        shares = np.linspace(0, len(positions), len(self.pools) + 1).astype(np.int64)
        for pool, a, b in zip(self.pools, shares[:-1], shares[1:]):
            if not len(pool.coords) and b > a:
                pool.reserve(_first_capacity(positions[a:b], self.grid, self.max_blocks))
        args = (_KIND[self.kernel], np.asarray(self.grid.origin), 1.0 / self.grid.voxel, self.lo, self.hi,
                self.rows, self.max_blocks)
        bad = _on_threads(lambda pool, a, b: pool.scatter(args[0], positions[a:b], rows[a:b], *args[1:]),
                          list(zip(self.pools, shares[:-1], shares[1:])))
        for a, i in zip(shares, bad):
            if i >= 0:
                p = positions[a + i]
                raise AptFiltersError(
                    f"ion at ({p[0]:g}, {p[1]:g}, {p[2]:g}) nm lies outside the grid or within the {self.kernel} "
                    f"kernel's reach of its edge; build the grid with Grid.covering(lower, upper, voxel, "
                    f"margin=kernel_reach(...)) from the ions' bounds"
                )
        self.row_count = sum(p.counts for p in self.pools)

    def result(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """(coords (n_blocks, 3) int32, one (n_blocks, 8, 8, 8) array per channel), after pass 2 if gaussian.

        Blocks in x, y, z block order, whatever the order the ions came in.
        """
        pool, others = self.pools[0], self.pools[1:]
        self.pools = []
        while others:
            pool.merge(others.pop())
        n = pool.n_active
        order = np.lexsort(pool.coords[:n].T[::-1])
        coords = pool.coords[order]
        # one array for all channels, holding the occupied blocks only (not the spare capacity)
        fields = np.empty((pool.stride // BLOCK**3, n, BLOCK, BLOCK, BLOCK))
        _unpool(pool.blocks().reshape(len(pool.coords), -1, BLOCK, BLOCK, BLOCK), order, fields)
        channels = list(fields)
        del pool  # released before pass 2
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
