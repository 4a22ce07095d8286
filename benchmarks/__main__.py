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

HERE = Path(__file__).resolve().parent
ORDER = ["io", "ranges", "synth", "audit", "voxel", "contour", "meshlab", "remesh", "proxigram", "refine", "pipeline",
         "sweep"]


def machine() -> str:
    import numpy

    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return (f"{platform.machine()}, {os.cpu_count()} cores, {mem:.0f} GiB RAM, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}; gathered {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")


def gather() -> str:
    """RESULTS.md: the machine, then each results_<name>.md in pipeline order."""
    parts = ["# Benchmark results", "", f"Machine: {machine()}.", "",
             "Each section below is written by its benchmark (`python -m benchmarks.bench_<name>`); "
             "peers run side by side with ours in the same run, so the ratios are the figures to read.", ""]
    for name in ORDER:
        path = HERE / f"results_{name}.md"
        if path.is_file():
            text = path.read_text().strip()
            parts += [text.replace("\n# ", "\n## ").replace("# ", "## ", 1) if text.startswith("# ") else text, ""]
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
