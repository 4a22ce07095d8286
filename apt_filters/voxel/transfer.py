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


# The scatter loops below are written out per kernel, with scalar locals, because the footprint
# size is then a constant that the compiler unrolls (a generic loop ran 2-3x slower).
# Each returns (stop, n_active, status): status 0 = all ions done, 1 = the pool may run out of
# blocks at ion ``stop`` (grow it and call again from ``stop``), 2 = ion ``stop`` lies outside
# the admissible range. An ion is only started with room for the 8 blocks its footprint can touch.


@njit
def _slot(table, coords, n_active, ix, iy, iz):
    """Slot of the block holding voxel (ix, iy, iz), activating it if absent: (slot, n_active)."""
    bx, by, bz = ix >> 3, iy >> 3, iz >> 3
    s = np.int64(table[bx, by, bz])
    if s < 0:
        s = n_active
        table[bx, by, bz] = s
        coords[s, 0] = bx
        coords[s, 1] = by
        coords[s, 2] = bz
        n_active += 1
    return s, n_active


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


@njit(cache=True)
def _scatter_square(pos, row, origin, inv_h, lo, hi, row_ptr, row_chan, row_w, table, pool, coords, n_active, start):
    for i in range(start, pos.shape[0]):
        p0, p1 = row_ptr[row[i]], row_ptr[row[i] + 1]
        if p0 == p1:
            continue  # an ion that counts in no field
        if n_active + 1 > coords.shape[0]:
            return i, n_active, 1
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h  # written out: numba helpers here ran 1.5x slower
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        if not (fx >= lo[0] and fx < hi[0] and fy >= lo[1] and fy < hi[1] and fz >= lo[2] and fz < hi[2]):
            return i, n_active, 2
        ix, iy, iz = np.int64(np.floor(fx + 0.5)), np.int64(np.floor(fy + 0.5)), np.int64(np.floor(fz + 0.5))
        s, n_active = _slot(table, coords, n_active, ix, iy, iz)
        for p in range(p0, p1):
            pool[row_chan[p], s, ix & 7, iy & 7, iz & 7] += row_w[p]
    return pos.shape[0], n_active, 0


@njit(cache=True)
def _scatter_sawtooth(pos, row, origin, inv_h, lo, hi, row_ptr, row_chan, row_w, table, pool, coords, n_active, start):
    for i in range(start, pos.shape[0]):
        p0, p1 = row_ptr[row[i]], row_ptr[row[i] + 1]
        if p0 == p1:
            continue
        if n_active + 8 > coords.shape[0]:
            return i, n_active, 1
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h  # written out: numba helpers here ran 1.5x slower
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        if not (fx >= lo[0] and fx < hi[0] and fy >= lo[1] and fy < hi[1] and fz >= lo[2] and fz < hi[2]):
            return i, n_active, 2
        x0, y0, z0 = np.floor(fx), np.floor(fy), np.floor(fz)
        wx = (1.0 - (fx - x0), fx - x0)  # lever rule
        wy = (1.0 - (fy - y0), fy - y0)
        wz = (1.0 - (fz - z0), fz - z0)
        ix, iy, iz = np.int64(x0), np.int64(y0), np.int64(z0)
        for p in range(p0, p1):
            c, m = row_chan[p], row_w[p]
            for a in range(2):
                for b in range(2):
                    wab = m * wx[a] * wy[b]
                    s, n_active = _slot(table, coords, n_active, ix + a, iy + b, iz)
                    for d in range(2):
                        if d and (iz + d) & 7 == 0:  # the z column enters the next block
                            s, n_active = _slot(table, coords, n_active, ix + a, iy + b, iz + d)
                        pool[c, s, (ix + a) & 7, (iy + b) & 7, (iz + d) & 7] += wab * wz[d]
    return pos.shape[0], n_active, 0


@njit(cache=True)
def _scatter_gaussian(pos, row, origin, inv_h, lo, hi, row_ptr, row_chan, row_w, table, pool, coords, n_active, start):
    for i in range(start, pos.shape[0]):
        p0, p1 = row_ptr[row[i]], row_ptr[row[i] + 1]
        if p0 == p1:
            continue
        if n_active + 8 > coords.shape[0]:
            return i, n_active, 1
        fx = (np.float64(pos[i, 0]) - origin[0]) * inv_h  # written out: numba helpers here ran 1.5x slower
        fy = (np.float64(pos[i, 1]) - origin[1]) * inv_h
        fz = (np.float64(pos[i, 2]) - origin[2]) * inv_h
        if not (fx >= lo[0] and fx < hi[0] and fy >= lo[1] and fy < hi[1] and fz >= lo[2] and fz < hi[2]):
            return i, n_active, 2
        ix, wx = _gauss3(fx)
        iy, wy = _gauss3(fy)
        iz, wz = _gauss3(fz)
        for p in range(p0, p1):
            c, m = row_chan[p], row_w[p]
            for a in range(3):
                for b in range(3):
                    wab = m * wx[a] * wy[b]
                    s, n_active = _slot(table, coords, n_active, ix + a, iy + b, iz)
                    for d in range(3):
                        if d and (iz + d) & 7 == 0:  # the z column enters the next block
                            s, n_active = _slot(table, coords, n_active, ix + a, iy + b, iz + d)
                        pool[c, s, (ix + a) & 7, (iy + b) & 7, (iz + d) & 7] += wab * wz[d]
    return pos.shape[0], n_active, 0


_SCATTER = {"square": _scatter_square, "sawtooth": _scatter_sawtooth, "gaussian": _scatter_gaussian}


class BlockAccumulator:
    """Scatters chunks of ions into block-sparse count fields (one channel per field).

    Memory: ``n_channels * capacity * 512 * 8`` bytes of pool (capacity grows by doubling, so up
    to twice the occupied blocks while scattering) plus the block table (4 bytes per block of
    the bounding box).

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
    """

    def __init__(self, grid: Grid, kernel: str, rows, n_channels: int, delocalization=(3.0, 3.0, 1.5)):
        check_kernel(kernel)
        self.grid = grid
        self.kernel = kernel
        self.delocalization = delocalization
        self.rows = tuple(np.ascontiguousarray(a) for a in rows)
        self.lo, self.hi = admissible_range(kernel, grid, delocalization)
        self.table = np.full(grid.block_shape, -1, dtype=np.int32)
        self.pool = np.zeros((n_channels, 64, BLOCK, BLOCK, BLOCK))
        self.coords = np.zeros((64, 3), dtype=np.int32)
        self.n_active = 0

    def add(self, positions: np.ndarray, rows: np.ndarray) -> None:
        """Scatter ions: positions (N, 3) nm, rows (N,) int (ion species index + 1)."""
        positions = np.ascontiguousarray(positions)
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        scatter = _SCATTER[self.kernel]
        origin = np.asarray(self.grid.origin)
        start = 0
        while True:
            start, self.n_active, status = scatter(
                positions, rows, origin, 1.0 / self.grid.voxel, self.lo, self.hi,
                *self.rows, self.table, self.pool, self.coords, self.n_active, start,
            )
            if status == 0:
                return
            if status == 2:
                p = positions[start]
                raise AptFiltersError(
                    f"ion at ({p[0]:g}, {p[1]:g}, {p[2]:g}) nm lies outside the grid or within the {self.kernel} "
                    f"kernel's reach of its edge; build the grid with Grid.covering(lower, upper, voxel, "
                    f"margin=kernel_reach(...)) from the ions' bounds"
                )
            self._grow()

    def _grow(self) -> None:
        cap = self.pool.shape[1]
        pool = np.zeros((self.pool.shape[0], 2 * cap, BLOCK, BLOCK, BLOCK))
        pool[:, :cap] = self.pool
        coords = np.zeros((2 * cap, 3), dtype=np.int32)
        coords[:cap] = self.coords
        self.pool, self.coords = pool, coords

    def result(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """(coords (n_blocks, 3) int32, one (n_blocks, 8, 8, 8) array per channel), after pass 2 if gaussian."""
        coords = self.coords[: self.n_active].copy()
        channels = [np.ascontiguousarray(self.pool[c, : self.n_active]) for c in range(self.pool.shape[0])]
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
