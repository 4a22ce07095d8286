"""Run every benchmark and gather their results into benchmarks/RESULTS.md.

    python -m benchmarks [--quick] [--only NAME ...]

Each ``bench_<name>.py`` runs in its own process (its own peak memory, no shared JIT or
caches) and writes ``results_<name>.md``; this runner prints each one's table and then
writes RESULTS.md: the machine, then every results file in pipeline order.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from apt_filters.core.atomic import atomic_write_text
from benchmarks.results import summary_rows

HERE = Path(__file__).resolve().parent
ORDER = ["cli", "io", "ranges", "fuzz_ranges", "synth", "audit", "voxel", "scale", "core", "distance", "contour",
         "meshlab", "fuzz_replay", "remesh", "proxigram", "maps", "refine", "refine_scale", "zoo", "object_errors",
         "pipeline", "select", "sweep"]


def machine() -> str:
    import numpy

    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return (f"{platform.machine()}, {os.cpu_count()} cores, {mem:.0f} GiB RAM, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}; gathered {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")


def gather() -> str:
    """RESULTS.md: one table of every benchmark's summary rows in pipeline order, the machine, the files."""
    rows, missing, files = [], [], []
    for name in ORDER:
        path = HERE / f"results_{name}.md"
        if path.is_file():
            found = summary_rows(path.read_text())
            rows += found
            files.append(f"[results_{name}.md](results_{name}.md)")
            if not found:
                missing.append(name)
    parts = ["# Benchmark results", "",
             f"Machine: {machine()}. Ours and the peers run side by side in one run of each benchmark "
             "(`python -m benchmarks [--quick]`); the ratios are the figures to read.", "",
             "| step | measure | ours | peer | ours / peer |", "|---|---|---:|---:|---:|", *rows, "",
             "Details, method and every case: " + ", ".join(files) + "."]
    if missing:
        parts += ["", "Not summarised yet (no summary block): " + ", ".join(missing) + "."]
    return "\n".join(parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the smaller size of every benchmark")
    parser.add_argument("--only", nargs="+", choices=ORDER, help="run only these")
    parser.add_argument("--gather", action="store_true", help="only rebuild RESULTS.md from the results files")
    args = parser.parse_args(argv)
    failed = []
    if not args.gather:
        for name in args.only or ORDER:
            if not (HERE / f"bench_{name}.py").is_file():
                continue
            print(f"\n=== bench_{name} ===", flush=True)
            cmd = [sys.executable, "-m", f"benchmarks.bench_{name}"] + (["--quick"] if args.quick else [])
            if subprocess.run(cmd, cwd=HERE.parent).returncode != 0:
                failed.append(name)
    atomic_write_text(HERE / "RESULTS.md", gather() + "\n", overwrite=True)
    print(f"\nwrote {HERE / 'RESULTS.md'}" + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
