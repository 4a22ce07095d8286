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
import time
from dataclasses import dataclass, field
from typing import Iterator


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
    name: str
    seconds: float
    peak_bytes: int
    summary: str = ""


@dataclass
class StepLog:
    """Records steps; prints one line per step unless ``quiet``."""

    quiet: bool = False
    records: list[StepRecord] = field(default_factory=list)

    @contextlib.contextmanager
    def step(self, name: str) -> Iterator[StepRecord]:
        """Time a step; the body may set ``record.summary`` to what it found."""
        _reset_peak()
        record = StepRecord(name, 0.0, 0)
        start = time.perf_counter()
        yield record
        record.seconds = time.perf_counter() - start
        record.peak_bytes = _peak_bytes()
        self.records.append(record)
        if not self.quiet:
            print(f"[{name:>10}] {record.seconds:7.2f} s  peak {record.peak_bytes / 2**20:8.0f} MiB  {record.summary}",
                  file=sys.stderr, flush=True)

    def as_dicts(self) -> list[dict]:
        return [{"step": r.name, "seconds": round(r.seconds, 3), "peak_mib": round(r.peak_bytes / 2**20, 1),
                 "summary": r.summary} for r in self.records]
