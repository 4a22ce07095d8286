"""Benchmark of the range audit on the real Si dataset (945,211 ions) and a 10x tiling of it.

Peer: no other tool audits range files, so the reference is the floor any audit pays, one
``numpy.histogram`` pass over the same m/z at the same 0.005 Da bins; the ratio says how much the
isotope fits and the candidate search add on top of reading the spectrum.

Run: ``/work/venv/bin/python -m benchmarks.bench_audit [--quick]`` (quick: no 10x tiling, 1 repeat).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from apt_filters.audit import audit_ranges
from apt_filters.io import read_ions, read_ranges
from benchmarks.results import ratio, write_results

SI = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "apav-si"


def _best_of(repeats: int, func) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        func()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    repeats = 1 if args.quick else 3
    mz = read_ions(SI / "Si.pos").mz
    ranges = read_ranges(SI / "Si.RRNG")
    audit_ranges(mz[:1000], ranges)  # build the candidate isotope patterns once (cached per process)
    cases = [("Si.pos", mz)] + ([] if args.quick else [("Si.pos x10", np.tile(mz, 10))])
    lines = ["| data | ions | audit (s) | numpy.histogram 0.005 Da (s) | ratio |", "|---|---:|---:|---:|---:|"]
    rows = []
    for name, data in cases:
        ours = _best_of(repeats, lambda: audit_ranges(data, ranges))
        peer = _best_of(repeats, lambda: np.histogram(data, bins=int(np.ceil(data.max() / 0.005)) + 1,
                                                      range=(0.0, (int(np.ceil(data.max() / 0.005)) + 1) * 0.005)))
        lines.append(f"| {name} | {len(data):,} | {ours:.2f} | {peer:.2f} | {ours / peer:.1f} |")
        rows.append(("audit", f"audit {name} ({len(data):,} ions), patterns cached", f"{ours:.2f} s",
                     f"{peer:.2f} s (numpy.histogram, 0.005 Da)", ratio(ours, peer)))
    t = time.perf_counter()
    audit_ranges(mz[:1000], ranges)
    small = time.perf_counter() - t
    print("\n".join(lines) + f"\n\nsmall audit (1,000 ions, patterns cached): {small:.2f} s")
    write_results("audit", "Range audit (`apt_filters.audit`)", rows, [
        "## Audit time against one histogram pass\n\n"
        f"`python -m benchmarks.bench_audit{' --quick' if args.quick else ''}`: best of {repeats}, candidate isotope "
        "patterns already built (as after the first audit in a process). No other tool audits range files; the "
        "floor any spectrum-based check pays is one `numpy.histogram` pass over the same m/z at the same 0.005 Da "
        "bins, so the ratio is what the isotope fits and the candidate search add.\n\n" + "\n".join(lines)
        + f"\n\nSmall audit (1,000 ions, patterns cached): {small:.2f} s."])

if __name__ == "__main__":
    main()
