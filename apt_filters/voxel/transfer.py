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

_FOOTPRINT = {"square": (0, 1), "sawtooth": (1, 2), "gaussian": (2, 3)}  # kernel id, points per axis


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


@njit(cache=True)
def _scatter(kind, pos, row, origin, inv_h, lo, hi, row_ptr, row_chan, row_w, table, pool, coords, n_active, start):
    """Add ions ``start..`` to the block pool.

    Returns (stop, n_active, status): status 0 = all done, 1 = pool full at ion ``stop``
    (grow it and call again from ``stop``), 2 = ion ``stop`` lies outside the admissible range.
    """
    n_pts = kind + 1
    cap = pool.shape[1]
    base = np.empty(3, np.int64)
    w = np.zeros((3, 3))
    for i in range(start, pos.shape[0]):
        r = row[i]
        if row_ptr[r] == row_ptr[r + 1]:
            continue  # an ion that counts in no field
        for a in range(3):
            f = (np.float64(pos[i, a]) - origin[a]) * inv_h
            if not (f >= lo[a] and f < hi[a]):
                return i, n_active, 2
            if kind == 1:
                b = np.floor(f)
                t = f - b
                w[a, 0] = 1.0 - t
                w[a, 1] = t
            else:
                b = np.floor(f + 0.5)
                if kind == 0:
                    w[a, 0] = 1.0
                else:
                    b -= 1.0
                    s = 0.0
                    for k in range(3):
                        d = b + k - f
                        w[a, k] = np.exp(-18.0 * d * d)  # sigma = voxel / 6: 1 / (2 sigma²) = 18
                        s += w[a, k]
                    for k in range(3):
                        w[a, k] /= s
            base[a] = np.int64(b)
        # activate the (at most 2 per axis) blocks this footprint touches
        need = 0
        for bx in range(base[0] >> 3, ((base[0] + n_pts - 1) >> 3) + 1):
            for by in range(base[1] >> 3, ((base[1] + n_pts - 1) >> 3) + 1):
                for bz in range(base[2] >> 3, ((base[2] + n_pts - 1) >> 3) + 1):
                    if table[bx, by, bz] < 0:
                        need += 1
        if n_active + need > cap:
            return i, n_active, 1
        if need:
            for bx in range(base[0] >> 3, ((base[0] + n_pts - 1) >> 3) + 1):
                for by in range(base[1] >> 3, ((base[1] + n_pts - 1) >> 3) + 1):
                    for bz in range(base[2] >> 3, ((base[2] + n_pts - 1) >> 3) + 1):
                        if table[bx, by, bz] < 0:
                            table[bx, by, bz] = n_active
                            coords[n_active, 0] = bx
                            coords[n_active, 1] = by
                            coords[n_active, 2] = bz
                            n_active += 1
        for p in range(row_ptr[r], row_ptr[r + 1]):
            c = row_chan[p]
            m = row_w[p]
            for a in range(n_pts):
                vx = base[0] + a
                wa = m * w[0, a]
                for b2 in range(n_pts):
                    vy = base[1] + b2
                    wab = wa * w[1, b2]
                    for d in range(n_pts):
                        vz = base[2] + d
                        slot = table[vx >> 3, vy >> 3, vz >> 3]
                        pool[c, slot, vx & 7, vy & 7, vz & 7] += wab * w[2, d]
    return pos.shape[0], n_active, 0


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
        kind = _FOOTPRINT[self.kernel][0]
        origin = np.asarray(self.grid.origin)
        start = 0
        while True:
            start, self.n_active, status = _scatter(
                kind, positions, rows, origin, 1.0 / self.grid.voxel, self.lo, self.hi,
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
