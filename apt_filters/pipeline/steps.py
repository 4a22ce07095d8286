"""Timing and peak memory of each pipeline step, and its one-line summary.

Peak memory is the process's resident high-water mark during the step: Linux lets a
process reset it (``/proc/self/clear_refs`` with 5) and read it back (``VmHWM``), which
also counts memory-mapped pages and allocations made by C++ libraries (open3d, MeshLab)
that ``tracemalloc`` cannot see.
"""

from __future__ import annotations

import contextlib
import resource
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Iterator

from apt_filters.core.atomic import raise_if_interrupted


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_bytes() -> int:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # lifetime peak, KiB on Linux


@dataclass
class StepRecord:
    """One step: wall seconds, CPU seconds of this process (every thread; on a loaded machine the
    wall time says more about the others than about the step), peak resident bytes, summary."""

    name: str
    seconds: float
    peak_bytes: int
    summary: str = ""
    cpu_seconds: float = 0.0


@dataclass
class StepLog:
    """Records steps; prints one line per step unless ``quiet``, under a progress bar over
    ``total`` steps when it is given (tqdm, on stderr, only on a terminal: logs and pipes get
    the plain lines). On a terminal the bar shows the running step and its elapsed seconds,
    refreshed every second."""

    quiet: bool = False
    total: int | None = None
    records: list[StepRecord] = field(default_factory=list)
    _bar: object = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.total and not self.quiet:
            from tqdm import tqdm

            # disable=None: a bar only on a terminal, plain lines in logs and pipes
            self._bar = tqdm(total=self.total, unit="step", file=sys.stderr, leave=False, dynamic_ncols=True,
                             disable=None)

    @contextlib.contextmanager
    def step(self, name: str) -> Iterator[StepRecord]:
        """Time a step; the body may set ``record.summary`` to what it found."""
        raise_if_interrupted()
        _reset_peak()
        if self._bar is not None:
            self._bar.set_description(name)
        record = StepRecord(name, 0.0, 0)
        start, cpu = time.perf_counter(), time.process_time()
        done = threading.Event()
        if self._bar is not None and not self._bar.disable:
            threading.Thread(target=self._tick, args=(name, start, done), daemon=True).start()
        try:
            yield record
        finally:
            done.set()
        raise_if_interrupted()
        record.seconds = time.perf_counter() - start
        record.cpu_seconds = time.process_time() - cpu
        record.peak_bytes = _peak_bytes()
        self.records.append(record)
        if not self.quiet:
            line = f"[{name:>10}] {record.seconds:7.2f} s  peak {record.peak_bytes / 2**20:8.0f} MiB  {record.summary}"
            if self._bar is None or self._bar.disable:
                print(line, file=sys.stderr, flush=True)
            else:
                self._bar.write(line, file=sys.stderr)
                self._bar.update(1)
                if self._bar.n >= self._bar.total:
                    self._bar.close()

    def _tick(self, name: str, start: float, done: threading.Event) -> None:
        """Show the running step's elapsed time once a second, so a long step visibly moves."""
        while not done.wait(1.0):
            self._bar.set_description(f"{name} {time.perf_counter() - start:4.0f} s", refresh=True)

    def as_dicts(self) -> list[dict]:
        return [{"step": r.name, "seconds": round(r.seconds, 3), "cpu_seconds": round(r.cpu_seconds, 3),
                 "peak_mib": round(r.peak_bytes / 2**20, 1), "summary": r.summary} for r in self.records]
