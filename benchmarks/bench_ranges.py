"""Range-file reading time against the number of ranges (linear: the time per range stays flat).

    python -m benchmarks.bench_ranges [--quick]

For 10^3, 10^4 and 10^5 ranges (``--quick``: up to 10^4) writes an RRNG, an RNG and an ENV
file (alternating Fe, O and FeO ranges, 0.005 Da wide) and times, least of 3 in this process:
``read_ranges`` (parse, overlap check, table), then ranging 10^6 ions with ``summarize``
(range edges, one compiled pass, element matrix). Results go to stdout and
benchmarks/results_ranges.md.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from apt_filters.io import IonTable, read_ranges
from apt_filters.io.summary import summarize
from benchmarks.results import write_results

SPECIES = [("Fe", "Fe:1"), ("O", "O:1"), ("FeO", "Fe:1 O:1")]


def _windows(n: int) -> np.ndarray:
    lower = 1.0 + 0.01 * np.arange(n)
    return np.column_stack([lower, lower + 0.005])


def write_file(folder: Path, dialect: str, n: int) -> Path:
    w = _windows(n)
    if dialect == "rrng":
        rows = [f"Range{k + 1}={lo:.4f} {hi:.4f} Vol:0.01 {SPECIES[k % 3][1]} Color:FF0000" for k, (lo, hi) in
                enumerate(w)]
        text = "[Ions]\nNumber=2\nIon1=Fe\nIon2=O\n[Ranges]\n" + f"Number={n}\n" + "\n".join(rows)
    elif dialect == "rng":
        counts = ["1 0", "0 1", "1 1"]
        rows = [f". {lo:.4f} {hi:.4f} {counts[k % 3]}" for k, (lo, hi) in enumerate(w)]
        text = f"2 {n}\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n" + "\n".join(rows)
    else:
        rows = [f"{SPECIES[k % 3][0]} {lo:.4f} {hi:.4f}" for k, (lo, hi) in enumerate(w)]
        text = f"3 {n}\nFe 1 0 0\nO 0 0 1\nFeO 0 1 0\n" + "\n".join(rows)
    path = folder / f"r{n}.{'env' if dialect == 'env' else dialect}"
    path.write_text(text + "\n")
    return path


def best_of(fn, repeat: int = 3) -> tuple[float, float]:
    """Least wall and least CPU (process) time over ``repeat`` calls, s."""
    wall, cpu = [], []
    for _ in range(repeat):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return min(wall), min(cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    sizes = [1_000, 10_000] if args.quick else [1_000, 10_000, 100_000]
    rng = np.random.default_rng(0)
    ions = IonTable(rng.uniform(-20, 20, (1_000_000, 3)).astype(np.float32),
                    rng.uniform(1, 1 + 0.01 * sizes[-1], 1_000_000).astype(np.float32))
    summarize(ions, read_ranges(write_file(Path(tempfile.mkdtemp()), "rrng", 10)))  # compile the pass
    lines = ["## Range-file reading and ranging time against the number of ranges", "",
             "least of 3 wall and CPU times in one process on a shared 2-core machine (CPU time is the figure "
             "other jobs disturb least); ranging: `summarize` of 10^6 ions (range edges, one compiled pass, "
             "element matrix)", "",
             "| dialect | ranges | file (MB) | read_ranges wall (s) | read_ranges CPU (s) | CPU µs per range "
             "| summarize 10^6 ions CPU (s) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    cpu_read: dict[tuple[str, int], float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for dialect in ("rrng", "rng", "env"):
            for n in sizes:
                path = write_file(Path(tmp), dialect, n)
                table = read_ranges(path)
                assert len(table) == n
                wall, cpu = best_of(lambda: read_ranges(path))
                cpu_read[dialect, n] = cpu
                _, cpu_sum = best_of(lambda: summarize(ions, table))
                row = (f"| {dialect} | {n:,} | {path.stat().st_size / 1e6:.2f} | {wall:.3f} | {cpu:.3f} | "
                       f"{1e6 * cpu / n:.1f} | {cpu_sum:.3f} |")
                print(row, flush=True)
                lines.append(row)
    big, small = sizes[-1], sizes[0]
    per = {n: 1e6 * max(cpu_read[d, n] for d in ("rrng", "rng", "env")) / n for n in (small, big)}
    rows = [("ranges", f"read {big:,} ranges, CPU (RRNG / RNG / ENV; target: seconds)",
             " / ".join(f"{cpu_read[d, big]:.1f}" for d in ("rrng", "rng", "env")) + " s", "-", "-"),
            ("ranges", f"CPU per range, slowest dialect, {small:,} and {big:,} ranges (linear: flat)",
             f"{per[small]:.0f} and {per[big]:.0f} µs", "-", "-")]
    write_results("ranges", "benchmarks/bench_ranges.py results", rows, ["\n".join(lines)])

if __name__ == "__main__":
    main()
