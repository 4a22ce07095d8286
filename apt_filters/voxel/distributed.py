"""Voxelization of one ion file over a Dask cluster: map over shares of the file, reduce by adding.

Each worker memory-maps the file itself and scatters only its share of the ions (nothing but
the share's bounds travels), into the first pass of the transfer function; the partial block
fields are added pairwise in a fixed tree order, and the gaussian's second pass, which is
linear, runs once on the sum. So a file that outgrows one machine's cores is voxelized by many,
and the result equals :func:`~apt_filters.voxel.fields.voxelize`'s up to the rounding of the
additions (relative 1e-12; tested).
"""

from __future__ import annotations

import operator
import os

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.io import count_ions, iter_ion_chunks
from apt_filters.io.ranges import RangeTable
from apt_filters.voxel.fields import Fields, VoxelPlan, chunk_bounds, plan_voxelization
from apt_filters.voxel.grid import Grid, check_budget
from apt_filters.voxel.transfer import BlockPartial, finish_partial

SHARE = 1 << 24
"""Ions per map task (16.8 M: ~270 MB of POS, a few seconds of scatter on one core)."""


def _bounds(path: str, start: int, stop: int, chunk_size: int) -> tuple[np.ndarray, np.ndarray]:
    return chunk_bounds(iter_ion_chunks(path, chunk_size, start=start, stop=stop))


def _scatter_share(path: str, start: int, stop: int, plan: VoxelPlan, chunk_size: int) -> BlockPartial:
    acc = plan.accumulator(threads=1)  # one core per task: the cluster runs tasks side by side
    for chunk in iter_ion_chunks(path, chunk_size, start=start, stop=stop):
        plan.scatter(acc, chunk)
    return acc.partial()


def tree_sum(client, futures: list):
    """The sum of ``futures`` on the cluster, added pairwise in a fixed order (deterministic)."""
    while len(futures) > 1:
        pairs = [futures[i:i + 2] for i in range(0, len(futures), 2)]
        futures = [client.submit(operator.add, *p, retries=2) if len(p) == 2 else p[0] for p in pairs]
    return futures[0]


def voxelize_distributed(
    path: str | os.PathLike,
    ranges: RangeTable,
    *,
    client,
    grid: Grid | None = None,
    memory_budget: int | None = None,
    share: int = SHARE,
    chunk_size: int = 1 << 22,
    threads: int = 1,
    **options,
) -> Fields:
    """Voxelize an ion file on a ``dask.distributed`` cluster; same fields as :func:`voxelize`.

    Parameters
    ----------
    path : path-like
        The ion file; every worker must see it at this path (a shared file system).
    ranges : RangeTable
    **options
        ``kernel``, ``delocalization``, ``species``, ``voxel``, ``basis``, ``keep_unranged``,
        ``efficiency``: as :func:`~apt_filters.voxel.fields.voxelize`, with its defaults.
    client : distributed.Client
        The cluster (see :func:`apt_filters.sweep.cluster.dask_client`).
    grid : Grid, optional
        Default: the covering grid of the file's bounds, found in a first map over the shares.
    memory_budget : int, optional
        Bytes for the fields on this machine (and on each worker); an absurd grid is refused up front.
    share : int
        Ions per map task.
    chunk_size : int
        Ions a task converts at a time (its peak beyond its partial fields: one chunk).
    threads : int
        Threads of the gaussian second pass, run here on the sum.

    Returns
    -------
    Fields

    Notes
    -----
    Each task holds one partial: at most the occupied blocks of its share times the fields
    (4 kB per block and field). The additions hold two partials and their sum. The client holds
    the sum and, for the gaussian, its second-pass copy.
    """
    path = os.fspath(path)
    n = count_ions(path)
    if int(share) < 1:
        raise AptFiltersError(f"share must be at least 1 ion, got {share}")
    spans = [(a, min(a + int(share), n)) for a in range(0, n, int(share))] or [(0, 0)]
    starts, stops = [a for a, _ in spans], [b for _, b in spans]
    bounds = None
    if grid is None:
        found = client.gather(client.map(_bounds, [path] * len(spans), starts, stops, [chunk_size] * len(spans),
                                         retries=2))
        bounds = (np.min([lo for lo, _ in found], axis=0), np.max([hi for _, hi in found], axis=0))
    plan = plan_voxelization(None, ranges, grid=grid, bounds=bounds, **options)
    grid = plan.grid
    check_budget(grid, len(plan.names), memory_budget, copies=3)
    [shared_plan] = client.scatter([plan], broadcast=True)
    parts = client.map(_scatter_share, [path] * len(spans), starts, stops, [shared_plan] * len(spans),
                       [chunk_size] * len(spans), retries=2)
    total = tree_sum(client, parts).result()
    coords, channels = finish_partial(grid, plan.kernel, plan.delocalization, total, threads)
    return plan.fields(coords, channels, total.row_count)
