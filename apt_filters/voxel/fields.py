"""Ions -> count, concentration and density fields on a block-sparse grid, streamed from chunks."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.voxel.grid import Grid, check_budget, scatter_threads
from apt_filters.voxel.ranging import MzLookup
from apt_filters.voxel.sparse import SparseField
from apt_filters.voxel.transfer import BlockAccumulator, check_kernel, kernel_reach

UNRANGED_FIELD = "unranged"
"""Name of the field of unranged ions (kept only when asked for)."""


@dataclass(frozen=True)
class ConcentrationBasis:
    """Which fields count in the denominator of a concentration.

    Default: every ranged species (element or ion). ``exclude`` leaves out named species (e.g.
    a segregant, so that it does not dilute the matrix fractions); ``include_unranged`` adds the
    unranged ions (background, unidentified peaks), each counted as one atom.
    """

    exclude: tuple[str, ...] = ()
    include_unranged: bool = False

    def fields(self, names: list[str]) -> list[str]:
        """The names out of ``names`` that form the denominator."""
        unknown = [s for s in self.exclude if s not in names or s == UNRANGED_FIELD]
        if unknown:
            raise AptFiltersError(f"concentration basis excludes unknown species {', '.join(unknown)}")
        if self.include_unranged and UNRANGED_FIELD not in names:
            raise AptFiltersError("concentration basis includes unranged ions, but they were not voxelized")
        return [n for n in names if n not in self.exclude and (n != UNRANGED_FIELD or self.include_unranged)]

    def describe(self) -> str:
        """One line for reports, e.g. 'all ranged species except B, unranged ions excluded'."""
        text = "all ranged species"
        if self.exclude:
            text += " except " + ", ".join(self.exclude)
        return text + (", unranged ions included" if self.include_unranged else ", unranged ions excluded")


@dataclass
class Fields:
    """The fields of one voxelization.

    Attributes
    ----------
    grid : Grid
    counts : dict[str, SparseField]
        Delocalised counts per species (elements or ions, see ``kind``), plus ``"unranged"`` if kept.
        All share one set of block coordinates.
    total : SparseField
        Sum of the counts in ``basis``: the denominator of :meth:`concentration`.
    kind : {"elements", "ions"}
    kernel : str
    delocalization : (3,) nm (gaussian only)
    basis : ConcentrationBasis
    efficiency : float
        Detection efficiency, for :meth:`density`.
    n_counted : dict[str, float]
        Atoms (or ions) of each field scattered: what each field must sum to.
    """

    grid: Grid
    counts: dict[str, SparseField]
    total: SparseField
    kind: str
    kernel: str
    delocalization: tuple[float, float, float]
    basis: ConcentrationBasis
    efficiency: float
    n_counted: dict[str, float] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return list(self.counts)

    @property
    def nbytes(self) -> int:
        """Bytes held by all count fields and the total (block coordinates counted once)."""
        return sum(f.data.nbytes for f in self.counts.values()) + self.total.data.nbytes + self.total.coords.nbytes

    def basis_total(self, basis: ConcentrationBasis | None = None) -> SparseField:
        """The denominator for ``basis`` (default: the one voxelized with)."""
        if basis is None or basis == self.basis:
            return self.total
        return _sum_fields(self.grid, [self.counts[n] for n in basis.fields(self.names)])

    def concentration(self, name: str, basis: ConcentrationBasis | None = None) -> SparseField:
        """Fraction ``counts[name] / total`` where total > 0, NaN elsewhere (background NaN)."""
        if name not in self.counts:
            raise AptFiltersError(f"no field {name!r}; fields are {', '.join(self.names)}")
        total = self.basis_total(basis)
        num = self.counts[name].data
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(total.data > 0, num / np.where(total.data > 0, total.data, 1.0), np.nan)
        return SparseField(self.grid, total.coords, frac, background=np.nan)

    def density(self) -> SparseField:
        """Atomic density (atoms/nm³): total / (voxel volume × efficiency)."""
        return SparseField(
            self.grid, self.total.coords, self.total.data / (self.grid.voxel_volume * self.efficiency)
        )

    def all_counts(self) -> SparseField:
        """Sum of every count field (all species, unranged too if kept): how many atoms each voxel holds."""
        return _sum_fields(self.grid, list(self.counts.values()))


def _sum_fields(grid: Grid, fields: list[SparseField]) -> SparseField:
    data = np.zeros_like(fields[0].data)
    for f in fields:
        data += f.data
    return SparseField(grid, fields[0].coords, data)


def decomposition(ranges: RangeTable, kind: str, keep_unranged: bool) -> tuple[list[str], tuple[np.ndarray, ...]]:
    """Field names and the CSR map (row_ptr, row_chan, row_w) from ion row to fields.

    Row 0 is the unranged ions, row ``k + 1`` ion species ``ranges.ions[k]``. For elements a
    molecular ion adds its atoms: CrO2 adds 1 to Cr and 2 to O.
    """
    if kind == "elements":
        names, matrix = list(ranges.elements), ranges.element_matrix().astype(np.float64)
    elif kind == "ions":
        names, matrix = list(ranges.ions), np.eye(len(ranges.ions))
    else:
        raise AptFiltersError(f"species must be 'elements' or 'ions', got {kind!r}")
    if UNRANGED_FIELD in names:
        raise AptFiltersError(f"a species named {UNRANGED_FIELD!r} clashes with the unranged-ion field")
    unranged_row = np.zeros((1, matrix.shape[1]))
    if keep_unranged:
        names.append(UNRANGED_FIELD)
        matrix = np.pad(matrix, ((0, 0), (0, 1)))
        unranged_row = np.pad(unranged_row, ((0, 0), (0, 1)))
        unranged_row[0, -1] = 1.0
    matrix = np.vstack([unranged_row, matrix])
    row_ptr = np.concatenate([[0], np.cumsum(np.count_nonzero(matrix, axis=1))]).astype(np.int64)
    r, c = np.nonzero(matrix)
    return names, (row_ptr, c.astype(np.int64), matrix[r, c])


SCATTER_CHUNK = 1 << 22
"""Ions of a table ranged and scattered per step (their rows: 16 MiB of int32)."""


def as_chunks(ions_or_chunks: IonTable | Iterable[IonTable]) -> Iterable[IonTable]:
    """An IonTable as a list of views of :data:`SCATTER_CHUNK` ions each (a memory-mapped table is
    then read slice by slice); an iterable of chunks as it is."""
    if not isinstance(ions_or_chunks, IonTable):
        return ions_or_chunks
    ions = ions_or_chunks
    return [IonTable(np.asarray(ions.positions[i: i + SCATTER_CHUNK]), np.asarray(ions.mz[i: i + SCATTER_CHUNK]),
                     source=ions.source) for i in range(0, max(len(ions), 1), SCATTER_CHUNK)]


def voxelize(
    ions_or_chunks: IonTable | Iterable[IonTable],
    ranges: RangeTable,
    grid: Grid | None = None,
    kernel: str = "gaussian",
    delocalization=(3.0, 3.0, 1.5),
    species: str = "elements",
    voxel: float = 1.0,
    basis: ConcentrationBasis = ConcentrationBasis(),
    keep_unranged: bool | None = None,
    efficiency: float = 1.0,
    memory_budget: int | None = None,
    threads: int | None = None,
) -> Fields:
    """Voxelize ions into block-sparse count fields with a contribution transfer function.

    Parameters
    ----------
    ions_or_chunks : IonTable or iterable of IonTable
        The ions, or chunks of them (e.g. ``apt_filters.io.iter_ion_chunks(path, chunk_size)``);
        each chunk is ranged, scattered and dropped, so peak memory is the fields plus one chunk.
    ranges : RangeTable
    grid : Grid, optional
        Needed for a one-shot iterator of chunks (build it from the file's bounds with
        ``Grid.covering(lower, upper, voxel, margin=kernel_reach(kernel, voxel, delocalization))``).
        Default: that covering grid of the ions' bounds (takes an extra pass over a list of chunks).
        Ions whose kernel would leave the grid raise AptFiltersError: no mass is ever lost or reflected.
    kernel : {"gaussian", "sawtooth", "square"}
        See :mod:`apt_filters.voxel.transfer`.
    delocalization : float or (3,) float
        Gaussian delocalization as 3 sigma per axis in nm (AP Suite default (3, 3, 1.5)).
    species : {"elements", "ions"}
        Element fields (molecular ions decomposed) or ion-species fields.
    voxel : float
        Voxel edge in nm when ``grid`` is not given.
    basis : ConcentrationBasis
        Denominator of concentrations (default: all ranged species).
    keep_unranged : bool, optional
        Also voxelize unranged ions into a field ``"unranged"``; default: when ``basis`` includes them.
    efficiency : float
        Detection efficiency in (0, 1], for :meth:`Fields.density`.
    memory_budget : int, optional
        Bytes; default half the physical RAM. A grid whose fields could exceed it is refused up front.
    threads : int, optional
        Threads that scatter each chunk, each a contiguous share of its ions into its own pool
        (merged at the end: ``threads`` pools of memory). Default: one per core this process
        may use, fewer if the memory budget cannot hold a pool for each
        (:func:`~apt_filters.voxel.grid.scatter_threads`). The fields are the same bit for bit on
        any thread count (the pools' sums are exact: :data:`~apt_filters.voxel.transfer.QUANTUM`).

    Returns
    -------
    Fields

    Notes
    -----
    Peak memory: the pool of occupied blocks (up to 1.5× the occupied blocks × fields × 4 kB,
    2.5× for a moment while it grows, never more than the box's blocks; one pool per thread), its
    copy into the fields at the end, one chunk with its ranging (≈ 30 bytes per ion), and for the
    gaussian second pass (after the pools are released) two dense float64 copies of one field's
    bounding box per thread, one field per thread at a time;
    :func:`~apt_filters.voxel.grid.check_budget` bounds it (measured: 10 M ions in a
    60 × 60 × 200 nm box, 8 species, see benchmarks/results_voxel.md).
    """
    plan = plan_voxelization(ions_or_chunks, ranges, grid=grid, kernel=kernel, delocalization=delocalization,
                             species=species, voxel=voxel, basis=basis, keep_unranged=keep_unranged,
                             efficiency=efficiency)
    if threads is None:
        threads = scatter_threads(plan.grid, len(plan.names), memory_budget)
    check_budget(plan.grid, len(plan.names), memory_budget, copies=int(threads) + 1)
    acc = plan.accumulator(threads)
    for chunk in as_chunks(ions_or_chunks):
        plan.scatter(acc, chunk, threads)
    coords, channels = acc.result()
    return plan.fields(coords, channels, acc.row_count)


@dataclass(frozen=True)
class VoxelPlan:
    """Everything a voxelization needs besides the ions: the grid, the transfer function, the
    fields and the map from m/z to fields. Built by :func:`plan_voxelization`; small and picklable,
    so that workers of a cluster can scatter their share of the ions with it
    (:mod:`apt_filters.voxel.distributed`).
    """

    grid: Grid
    kernel: str
    delocalization: tuple[float, float, float]
    species: str
    names: tuple[str, ...]
    rows: tuple[np.ndarray, ...]
    lookup: MzLookup
    basis: ConcentrationBasis
    efficiency: float

    def accumulator(self, threads: int = 1) -> BlockAccumulator:
        return BlockAccumulator(self.grid, self.kernel, self.rows, len(self.names), self.delocalization, threads)

    def scatter(self, acc: BlockAccumulator, chunk: IonTable, threads: int = 1) -> None:
        """Range one chunk and scatter it into ``acc`` (its rows int32: 4 bytes per ion)."""
        acc.add(chunk.positions, self.lookup.rows_of(chunk.mz, threads))

    def fields(self, coords: np.ndarray, channels: list[np.ndarray], row_count: np.ndarray) -> Fields:
        """The :class:`Fields` of the finished blocks (``row_count``: ions scattered per ion row)."""
        counts = {n: SparseField(self.grid, coords, d) for n, d in zip(self.names, channels)}
        total_names = self.basis.fields(list(self.names))
        total = _sum_fields(self.grid, [counts[n] for n in total_names]) if total_names else SparseField(
            self.grid, coords, np.zeros_like(channels[0]))
        return Fields(grid=self.grid, counts=counts, total=total, kind=self.species, kernel=self.kernel,
                      delocalization=self.delocalization, basis=self.basis, efficiency=self.efficiency,
                      n_counted=_counted(list(self.names), self.rows, row_count.astype(np.float64)))


def plan_voxelization(
    ions_or_chunks: IonTable | Iterable[IonTable] | None,
    ranges: RangeTable,
    *,
    grid: Grid | None = None,
    kernel: str = "gaussian",
    delocalization=(3.0, 3.0, 1.5),
    species: str = "elements",
    voxel: float = 1.0,
    basis: ConcentrationBasis = ConcentrationBasis(),
    keep_unranged: bool | None = None,
    efficiency: float = 1.0,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> VoxelPlan:
    """The :class:`VoxelPlan` of :func:`voxelize`'s arguments (same meanings).

    Without ``grid``, the grid covers ``bounds`` (lower, upper corners in nm) or, without those,
    the ions' bounds, read from ``ions_or_chunks`` (not a one-shot stream)."""
    check_kernel(kernel)
    if not (0 < efficiency <= 1):
        raise AptFiltersError(f"detection efficiency must be in (0, 1], got {efficiency!r}")
    keep_unranged = basis.include_unranged if keep_unranged is None else keep_unranged
    names, rows = decomposition(ranges, species, keep_unranged)
    basis.fields(names)  # refuses an unknown species in the basis up front
    if grid is None:
        if bounds is None:
            chunks = as_chunks(ions_or_chunks) if ions_or_chunks is not None else None
            if chunks is None or iter(chunks) is chunks:
                raise AptFiltersError("voxelizing a one-shot stream of chunks needs a grid (Grid.covering of the bounds)")
            bounds = chunk_bounds(chunks)
        if not np.all(np.isfinite(bounds)):
            raise AptFiltersError("no ions to voxelize (or non-finite positions)")
        grid = Grid.covering(*bounds, voxel, kernel_reach(kernel, voxel, delocalization))
    return VoxelPlan(grid=grid, kernel=kernel,
                     delocalization=tuple(float(v) for v in np.broadcast_to(delocalization, (3,))),
                     species=species, names=tuple(names), rows=rows, lookup=MzLookup.from_ranges(ranges),
                     basis=basis, efficiency=float(efficiency))


def _counted(names: list[str], rows: tuple[np.ndarray, ...], per_row: np.ndarray) -> dict[str, float]:
    """Atoms scattered into each field, from the ion count of each row."""
    row_ptr, row_chan, row_w = rows
    out = np.zeros(len(names))
    for r in range(len(per_row)):
        np.add.at(out, row_chan[row_ptr[r]: row_ptr[r + 1]], per_row[r] * row_w[row_ptr[r]: row_ptr[r + 1]])
    return dict(zip(names, out.tolist()))


def chunk_bounds(chunks: Iterable[IonTable]) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) corners (nm) of the ions of some chunks; infinite where there are none."""
    lower, upper = np.full(3, np.inf), np.full(3, -np.inf)
    for chunk in chunks:
        if len(chunk):
            lo, hi = chunk.bounds()
            lower, upper = np.minimum(lower, lo), np.maximum(upper, hi)
    return lower, upper
