"""The Dask cluster that sweeps and batches run on, and running a list of tasks on it with progress.

``dask.distributed`` is imported here only, and only when a sweep or batch starts: the rest of
apt-filters does not need it.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from apt_filters.core.errors import AptFiltersError

RETRIES = 2
"""Times a task is resubmitted when its worker dies (a task that raises is not retried: it
reports its error in its row)."""


def _distributed():
    try:
        import distributed
    except ImportError:  # pragma: no cover - a declared dependency
        raise AptFiltersError("sweeps and batches need dask.distributed (pip install 'dask[distributed]')") from None
    return distributed


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, *, workers: int | None = None,
                memory_budget: int | None = None) -> Iterator[object]:
    """A ``distributed.Client``, closed (with its local cluster) on exit.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``) or the path of its scheduler file
        (``.json``, as SLURM and Kubernetes deployments write): then any Dask cluster runs the work.
        Its workers must see the input and output paths (a shared file system).
    workers : int, optional
        Local cluster only: worker processes, one thread each; default one per core this process
        may use.
    memory_budget : int, optional
        Local cluster only: bytes shared by all workers (each gets its share as Dask's memory
        limit, past which the nanny restarts it and its task is retried); default half the
        physical memory, as for voxelization.
    """
    distributed = _distributed()
    cluster = None
    if scheduler:
        try:
            if scheduler.endswith(".json") and Path(scheduler).is_file():
                client = distributed.Client(scheduler_file=scheduler, timeout="20s")
            else:
                client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise AptFiltersError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from None
    else:
        from apt_filters.voxel.grid import available_cores, default_budget

        n = max(1, int(workers or available_cores()))
        budget = default_budget() if memory_budget is None else int(memory_budget)
        # One thread per worker: the pipeline's own kernels are single runs per task, and the
        # cluster's parallelism is across tasks. Workers are separate processes (the GIL, numba).
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           memory_limit=max(budget // n, 1 << 28), dashboard_address=None,
                                           silence_logs=50)
        client = distributed.Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_tasks(client, fn: Callable, calls: Sequence[tuple], *, label: str = "task",
              progress: bool = True) -> list:
    """``[fn(*args) for args in calls]`` on the cluster, in order; a line on stderr as each finishes.

    Tasks whose worker dies are retried (:data:`RETRIES`); ``fn`` is expected to catch its own
    errors and return them (so one bad input fails its row, not the whole run).
    """
    distributed = _distributed()
    futures = [client.submit(fn, *args, retries=RETRIES, pure=False) for args in calls]
    index = {f.key: i for i, f in enumerate(futures)}
    results: list = [None] * len(futures)
    for done, future in enumerate(distributed.as_completed(futures), start=1):
        try:
            results[index[future.key]] = future.result()
        except distributed.KilledWorker as exc:
            results[index[future.key]] = {"status": "error", "error": f"its worker died {RETRIES + 1} times: {exc}"}
        if progress:
            print(f"  {label} {done}/{len(futures)} done", file=sys.stderr, flush=True)
    return results
