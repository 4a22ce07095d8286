"""The voxel grid: origin, voxel size and shape (x, y, z), and the memory budget that guards it."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.threads import available_cores

BLOCK = 8
"""Edge of a leaf block in voxels (OpenVDB's leaf size): a block holds 8³ = 512 values."""

DEFAULT_BUDGET_FRACTION = 0.5
"""Default memory budget as a fraction of the machine's physical RAM."""


@dataclass(frozen=True)
class Grid:
    """A regular grid of points ``origin + index * voxel`` (nm), ``index`` in ``[0, shape)``, x, y, z order.

    Each grid point is the centre of its voxel: voxel ``i`` spans
    ``origin + (i - 0.5) * voxel .. origin + (i + 0.5) * voxel``.

    Attributes
    ----------
    origin : (3,) tuple of float
        Position of grid point (0, 0, 0) in nm.
    voxel : float
        Voxel edge in nm (cubic voxels).
    shape : (3,) tuple of int
        Number of grid points along x, y, z.
    """

    origin: tuple[float, float, float]
    voxel: float
    shape: tuple[int, int, int]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel) and self.voxel > 0):
            raise AptFiltersError(f"voxel size must be a positive number of nm, got {self.voxel!r}")
        if len(self.shape) != 3 or any(int(n) < 1 for n in self.shape):
            raise AptFiltersError(f"grid shape must be three positive integers, got {self.shape!r}")
        if len(self.origin) != 3 or not np.all(np.isfinite(self.origin)):
            raise AptFiltersError(f"grid origin must be three finite numbers, got {self.origin!r}")
        object.__setattr__(self, "origin", tuple(float(v) for v in self.origin))
        object.__setattr__(self, "voxel", float(self.voxel))
        object.__setattr__(self, "shape", tuple(int(n) for n in self.shape))

    @property
    def n_voxels(self) -> int:
        return math.prod(self.shape)  # Python ints: a huge grid's size must not wrap

    @property
    def block_shape(self) -> tuple[int, int, int]:
        """Number of 8³ leaf blocks along x, y, z (the last ones may be partly outside the grid)."""
        return tuple(-(-n // BLOCK) for n in self.shape)

    @property
    def voxel_volume(self) -> float:
        """nm³."""
        return self.voxel**3

    def axis(self, axis: int) -> np.ndarray:
        """(shape[axis],) float64 coordinates (nm) of the grid points along one axis."""
        return self.origin[axis] + self.voxel * np.arange(self.shape[axis], dtype=np.float64)

    def points(self, index: np.ndarray) -> np.ndarray:
        """Positions (nm) of (possibly fractional) grid indices, (..., 3) -> (..., 3) float64."""
        return np.asarray(self.origin) + self.voxel * np.asarray(index, dtype=np.float64)

    def fractional_index(self, positions: np.ndarray) -> np.ndarray:
        """Fractional grid index of positions in nm, (..., 3) -> (..., 3) float64."""
        return (np.asarray(positions, dtype=np.float64) - np.asarray(self.origin)) / self.voxel

    @classmethod
    def covering(
        cls,
        lower: np.ndarray,
        upper: np.ndarray,
        voxel: float,
        margin: np.ndarray | int = 0,
        align: bool = True,
    ) -> "Grid":
        """The smallest grid whose points cover the box ``[lower, upper]`` (nm) plus ``margin`` voxels each side.

        Parameters
        ----------
        lower, upper : (3,) array_like
            Box corners in nm (e.g. ``IonTable.bounds()``).
        voxel : float
            Voxel edge in nm.
        margin : int or (3,) int
            Extra grid points on each side per axis; :func:`kernel_reach` gives what a transfer
            function needs so that no ion's weight falls off the grid.
        align : bool
            If True (default) grid points sit on integer multiples of ``voxel``, so that grids of
            different datasets or chunks coincide; otherwise point 0 is at ``lower - margin * voxel``.
        """
        lower = np.asarray(lower, dtype=np.float64)
        upper = np.asarray(upper, dtype=np.float64)
        if lower.shape != (3,) or upper.shape != (3,) or not np.all(np.isfinite([lower, upper])):
            raise AptFiltersError("grid bounds must be two finite (3,) corners")
        if np.any(upper < lower):
            raise AptFiltersError(f"grid bounds upper {upper.tolist()} below lower {lower.tolist()}")
        margin = np.broadcast_to(np.asarray(margin, dtype=np.int64), (3,))
        start = np.floor(lower / voxel) * voxel if align else lower.copy()
        origin = start - margin * voxel
        # +1: the top grid point must lie at or above the upper corner; an overflow is refused just below,
        # in one line, so numpy need not warn of it too
        with np.errstate(over="ignore"):
            steps = np.ceil((upper - origin) / voxel - 1e-9)
        if not np.all(np.isfinite(steps)):
            raise AptFiltersError(f"a grid of {voxel:g} nm voxels over {lower.tolist()} .. {upper.tolist()} nm "
                                  "has too many voxels to count")
        # Python ints, not int64: a far-away ion makes a grid whose voxel count would wrap int64
        return cls(tuple(origin), voxel, tuple(int(n) + int(m) + 1 for n, m in zip(steps, margin)))


def physical_memory() -> int:
    """Bytes of physical RAM of this machine."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def default_budget() -> int:
    """Default memory budget in bytes: :data:`DEFAULT_BUDGET_FRACTION` of physical RAM."""
    return int(DEFAULT_BUDGET_FRACTION * physical_memory())


def field_bytes(grid: Grid, n_fields: int, itemsize: int = 8) -> int:
    """Upper bound (bytes) of ``n_fields`` fields on ``grid`` if every leaf block were occupied."""
    return math.prod(grid.block_shape) * BLOCK**3 * itemsize * n_fields  # Python ints: never wraps


def check_budget(grid: Grid, n_fields: int, budget: int | None, itemsize: int = 8, copies: int = 2) -> int:
    """Refuse up front a request whose fields could exceed ``budget`` bytes; return the bound.

    The bound counts every block of the bounding box as occupied (what a dense grid would
    need) for ``copies`` times the ``n_fields`` species fields plus two working fields: the
    scatter pool and the fields copied off it exist together for a moment (2 copies; a scatter
    on t threads holds t pools and merges them: t + 1), and the total or the gaussian second
    pass's dense copies come on top. Block-sparse storage usually needs much less, but
    the check stays conservative so that a run never dies half-way.

    Raises
    ------
    AptFiltersError
        With the voxel size and the number of species that would fit.
    """
    budget = default_budget() if budget is None else int(budget)
    need = field_bytes(grid, copies * n_fields + 2, itemsize)
    if need <= budget:
        return need
    per_field = field_bytes(grid, 1, itemsize)
    fit_fields = (budget // per_field - 2) // copies
    fit_voxel = np.ceil(_fitting_voxel(grid, copies * n_fields + 2, budget, itemsize) * 100) / 100  # nm, rounded up
    fields_hint = f"at most {fit_fields} species" if fit_fields >= 1 else "no species at this voxel size"
    raise AptFiltersError(
        f"voxelizing {n_fields} species on {grid.shape[0]}x{grid.shape[1]}x{grid.shape[2]} voxels of "
        f"{grid.voxel:g} nm may need {need / 1e9:.3g} GB, over the memory budget of {budget / 1e9:.2f} GB; "
        f"would fit: voxel >= {fit_voxel:g} nm, or {fields_hint}, or a smaller region "
        f"(sparse storage only helps when the ions fill a small part of the box)"
    )


def scatter_threads(grid: Grid, n_fields: int, budget: int | None, itemsize: int = 8) -> int:
    """Default scatter threads: one per available core, as many as :func:`check_budget` allows
    with one pool per thread (``copies = threads + 1``), at least 1."""
    budget = default_budget() if budget is None else int(budget)
    threads = available_cores()
    while threads > 1 and field_bytes(grid, (threads + 1) * n_fields + 2, itemsize) > budget:
        threads -= 1
    return threads


def _fitting_voxel(grid: Grid, n_fields: int, budget: int, itemsize: int) -> float:
    """Smallest voxel (to 2%) at which a grid over the same extent (+2 points a side for the
    re-aligned padding) holds ``n_fields`` fields within ``budget``."""
    extent = np.asarray(grid.shape) * grid.voxel
    voxel = grid.voxel * (field_bytes(grid, n_fields, itemsize) / budget) ** (1 / 3)
    while True:
        shape = tuple(int(n) for n in np.ceil(extent / voxel) + 4)
        if field_bytes(Grid(grid.origin, voxel, shape), n_fields, itemsize) <= budget:
            return voxel
        voxel *= 1.02
