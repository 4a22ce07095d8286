"""Block-sparse scalar fields, as OpenVDB stores them: 8³ leaf blocks keyed by block coordinate.

Memory model: a field holds ``n_blocks * 512 * itemsize`` bytes of values plus
``n_blocks * 3 * 4`` bytes of block coordinates (shared between the fields of one
:class:`~apt_filters.voxel.fields.Fields`). Absent blocks read as the field's ``background``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apt_filters.voxel.grid import BLOCK, Grid


@dataclass
class SparseField:
    """A scalar field on ``grid`` stored as occupied 8³ leaf blocks.

    Attributes
    ----------
    grid : Grid
    coords : (n_blocks, 3) int32
        Block coordinates (voxel index // 8) of the stored blocks, x, y, z.
    data : (n_blocks, 8, 8, 8)
        Values; ``data[b, i, j, k]`` is voxel ``coords[b] * 8 + (i, j, k)``.
    background : float
        Value of every voxel outside the stored blocks (0 for counts, NaN for concentrations).
    """

    grid: Grid
    coords: np.ndarray
    data: np.ndarray
    background: float = 0.0

    @property
    def nbytes(self) -> int:
        """Bytes held by the values and block coordinates."""
        return int(self.data.nbytes + self.coords.nbytes)

    @property
    def n_blocks(self) -> int:
        return len(self.coords)

    def dense(self) -> np.ndarray:
        """The field as a dense ``grid.shape`` array (allocates the whole box: small grids only)."""
        return blocks_to_dense(self.grid, self.coords, self.data, self.background)[
            : self.grid.shape[0], : self.grid.shape[1], : self.grid.shape[2]
        ]

    def sum(self) -> float:
        """Sum of the stored values (the total count for a count field), float64."""
        return float(self.data.sum(dtype=np.float64))

    def values_at(self, index: np.ndarray) -> np.ndarray:
        """Values at integer voxel indices, (n, 3) -> (n,); background where no block is stored."""
        index = np.asarray(index, dtype=np.int64)
        table = block_table(self.grid, self.coords)
        block = index // BLOCK
        inside = np.all((index >= 0) & (index < np.asarray(self.grid.shape)), axis=1)
        slot = np.full(len(index), -1, dtype=np.int64)
        b = block[inside]
        slot[inside] = table[b[:, 0], b[:, 1], b[:, 2]]
        out = np.full(len(index), self.background, dtype=self.data.dtype)
        ok = slot >= 0
        local = index[ok] % BLOCK
        out[ok] = self.data[slot[ok], local[:, 0], local[:, 1], local[:, 2]]
        return out

    @classmethod
    def from_dense(cls, grid: Grid, values: np.ndarray, background: float = 0.0) -> "SparseField":
        """Store a dense ``grid.shape`` array, keeping the blocks that hold a value other than ``background``."""
        if values.shape != grid.shape:
            raise ValueError(f"values have shape {values.shape}, the grid {grid.shape}")
        padded = np.full(tuple(n * BLOCK for n in grid.block_shape), background, dtype=values.dtype)
        padded[: grid.shape[0], : grid.shape[1], : grid.shape[2]] = values
        differs = padded != background
        if np.isnan(background):
            differs &= ~np.isnan(padded)
        occupied = block_view(differs).any(axis=(1, 3, 5))
        coords = np.argwhere(occupied).astype(np.int32)
        return cls(grid, coords, dense_to_blocks(padded, coords), background)


def block_view(dense: np.ndarray) -> np.ndarray:
    """(8·bx, 8·by, 8·bz) -> (bx, 8, by, 8, bz, 8) view."""
    bx, by, bz = (n // BLOCK for n in dense.shape)
    return dense.reshape(bx, BLOCK, by, BLOCK, bz, BLOCK)


def blocks_to_dense(grid: Grid, coords: np.ndarray, data: np.ndarray, background: float = 0.0) -> np.ndarray:
    """Blocks -> dense array of the block-rounded shape ``8 * grid.block_shape``."""
    dense = np.full(tuple(n * BLOCK for n in grid.block_shape), background, dtype=data.dtype)
    if len(coords):
        block_view(dense)[coords[:, 0], :, coords[:, 1], :, coords[:, 2], :] = data
    return dense


def dense_to_blocks(dense: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """The blocks at ``coords`` of a block-rounded dense array, (n_blocks, 8, 8, 8) copy."""
    return np.ascontiguousarray(block_view(dense)[coords[:, 0], :, coords[:, 1], :, coords[:, 2], :])


def block_table(grid: Grid, coords: np.ndarray) -> np.ndarray:
    """Top-level lookup: (bx, by, bz) int32 array, slot of each block in ``coords`` or -1.

    Costs 4 bytes per block of the bounding box, 1/1024 of a dense float64 field.
    """
    table = np.full(grid.block_shape, -1, dtype=np.int32)
    if len(coords):
        table[coords[:, 0], coords[:, 1], coords[:, 2]] = np.arange(len(coords), dtype=np.int32)
    return table
