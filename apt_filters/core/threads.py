"""Running compiled kernels on threads: nogil numba loops and numpy's large copies release the GIL,
so Python threads run them in parallel without copies of their inputs."""

from __future__ import annotations

import functools
import importlib
import os
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np

def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # no affinity masks on this OS
        return os.cpu_count() or 1


def kernels_share_threads() -> bool:
    """Whether compiled parallel kernels may run from several Python threads at once.

    numba's OpenMP and TBB threading layers allow it; the workqueue layer it falls back to where neither
    library loads (no ``libgomp1``, no ``tbb``) aborts the process on a second concurrent launch, so there
    the callers below run their items one after the other (same results, one core's time). Told from the
    setting and from which layer's library loads, as numba chooses, without launching a kernel; before
    numba is loaded no compiled kernel can run, and reading a file need not load it.
    """
    numba = sys.modules.get("numba")
    return numba is None or _layer_shares_threads(numba.config.THREADING_LAYER)


@functools.cache
def _layer_shares_threads(layer: str) -> bool:
    if layer != "default":
        return layer != "workqueue"
    for pool in ("numba.np.ufunc.tbbpool", "numba.np.ufunc.omppool"):
        try:
            importlib.import_module(pool)
            return True
        except ImportError:  # that layer's library is not installed
            continue
    return False


def on_threads(fn, calls: list[tuple]) -> list:
    """Results of ``fn(*args)`` for each args in ``calls``, one thread each (the caller's thread for a single call)."""
    if len(calls) == 1 or not kernels_share_threads():
        return [fn(*args) for args in calls]
    return _mapped(lambda args: fn(*args), calls, len(calls))


def per_item(fn, items: list) -> list:
    """``[fn(item) for item in items]``, the items taken in turn by as many threads as this process has cores.

    For independent pieces of work (a surface's objects) that run in GIL-free code (nogil numba kernels,
    numpy's and LAPACK's loops): each result is what ``fn(item)`` alone gives, in the order of ``items``."""
    workers = min(available_cores(), len(items))
    if workers <= 1 or not kernels_share_threads():
        return [fn(item) for item in items]
    return _mapped(fn, items, workers)


def _mapped(fn, items: list, workers: int) -> list:
    """``list(map(fn, items))`` on a pool of ``workers`` threads of its own, let go whatever happens.

    A pool per call (its threads cost tens of microseconds; the calls are whole shares of a pass) keeps
    nested calls apart and is shut down on every way out. An interrupt (Ctrl-C, SIGTERM) can arrive while
    the pool starts a thread, before the pool has registered it; nothing at exit would then wake that
    thread, and the interpreter would wait for it forever. The shutdown's wake-up reaches every thread
    of the pool, registered or not; the items already running finish, the others are cancelled.
    """
    executor = ThreadPoolExecutor(workers, thread_name_prefix="apt-filters")
    try:
        return list(executor.map(fn, items))
    finally:
        executor.shutdown(wait=False, cancel_futures=True)


def shares(n: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous (start, stop) shares of ``range(n)``, as equal as can be."""
    bounds = np.linspace(0, n, parts + 1).astype(np.int64)
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))


def serial_blas(fn):
    """``fn`` with BLAS and LAPACK (numpy's and scipy's OpenBLAS) on one thread while it runs.

    For code whose parallel work is in numba loops and whose BLAS calls are small (eigensolves of a few
    hundred unknowns, 3-column least squares): OpenBLAS's threads spin while they wait for work, and on a
    busy machine the spinning costs more CPU than the calls (the manifold harmonics of 47 objects: 17.4 s
    of CPU on 2 threads, 0.8 s on one, the same eigenvectors bit for bit).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
