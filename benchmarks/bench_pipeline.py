"""End-to-end time and peak memory of ``apt-filters run`` (issue 8's targets).

    python -m benchmarks.bench_pipeline [--quick] [--ions N]

Cases, each ``apt-filters run`` in a fresh process (peak RSS of that process alone):

- the real Si dataset (945,211 ions), Cr iso-surface at 30 at.%: target <= 20 s;
- the ``many`` synthetic specimen (47 precipitates) resized to ``--ions`` ions (default 10M;
  ``--quick``: the ``default`` specimen, ~3.4M ions, 7 precipitates), Al at 15 at.% with B left
  out of the basis: target for 10M ions <= 25 s on 2 cores (issue 29) and <= 4 GB, for 100M <= 15 min and <= 12 GB.
  The specimen is generated first (timed apart, not counted).

There is no peer that runs this whole chain; the figures are read against the targets. A second
table gives each step's time and peak memory (from the run's report.json: resident high-water
mark during the step), and the load average before and after is printed, as the 2 cores are
shared with other jobs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.results import write_results

ROOT = Path(__file__).resolve().parents[1]
SI = ROOT.parent / "shared" / "data" / "real" / "apav-si"


def timed(cmd: list[str]) -> tuple[float, float, float]:
    """(wall seconds, CPU seconds of all its threads, peak RSS in MiB) of a command run in a child process."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    before, cpu = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
    start = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    # ru_maxrss of children is the largest of any child so far: run the cases smallest first.
    return wall, usage.ru_utime + usage.ru_stime - cpu, max(usage.ru_maxrss, before) / 1024


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the default specimen at its own size (~3.4M ions)")
    parser.add_argument("--ions", type=int, default=10_000_000, help="ions of the large synthetic case")
    args = parser.parse_args(argv)
    cli = [sys.executable, "-m", "apt_filters"]
    rows = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        wall, cpu, peak = timed(cli + ["run", str(SI / "Si.pos"), "-r", str(SI / "Si.RRNG"), "-o", str(tmp / "si"),
                                  "--species", "Cr", "--iso", "0.3", "-q"])
        rows.append(("real Si (Cr 30 at.%)", 945_211, wall, cpu, peak, "<= 20 s"))
        preset = ["--preset", "default"] if args.quick else ["--preset", "many", "--ions", str(args.ions)]
        synth = cli + ["synth", str(tmp / "spec"), *preset]
        gen_wall, _, _ = timed(synth)
        n_ions = (tmp / "spec" / "specimen.pos").stat().st_size // 16
        wall, cpu, peak = timed(cli + ["run", str(tmp / "spec" / "specimen.pos"), "-r", str(tmp / "spec" / "specimen.rrng"),
                                  "-o", str(tmp / "run"), "--species", "Al", "--iso", "0.15", "--exclude", "B", "-q"])
        report = json.loads((tmp / "run" / "report.json").read_text())
        objects = len(report["surfaces"][0]["objects"])
        steps = report["steps"]
        rows.append((f"synthetic {preset[1]} (Al 15 at.%, {objects} objects; generated in {gen_wall:.0f} s)", n_ions,
                     wall, cpu, peak, "<= 25 s and 4 GB at 10M ions; <= 15 min and 12 GB at 100M"))
    lines = ["## `apt-filters run` end to end", "",
             "Each case is one `apt-filters run` process (all steps, default settings: gaussian 3x3x1.5 nm, "
             "marching cubes, refinement, clean chain, CVT remesh, objects, proxigram, excess, exports, report).", "",
             "The machine's 2 cores are shared with other jobs: the CPU seconds (user + system, all threads) are the "
             "figure to read; the wall counts the other jobs' time too.", "",
             "| case | ions | CPU (s) | wall (s) | ions/s (wall) | peak RSS (MiB) | target |",
             "|---|---:|---:|---:|---:|---:|---|"]
    lines += [f"| {name} | {n:,} | {cpu:.1f} | {wall:.1f} | {n / wall:,.0f} | {peak:,.0f} | {target} |"
              for name, n, wall, cpu, peak, target in rows]
    lines += ["", f"Steps of the synthetic case ({n_ions:,} ions; peak = resident high-water mark during the step):", "",
              "| step | time (s) | peak (MiB) | summary |", "|---|---:|---:|---|"]
    lines += [f"| {st['step']} | {st['seconds']:.1f} | {st['peak_mib']:,.0f} | {st['summary']} |" for st in steps]
    lines += [f"| (sum of steps) | {sum(st['seconds'] for st in steps):.1f} | | |", "",
              "Load average (1, 5, 15 min) before: {:.1f} {:.1f} {:.1f}; after: {:.1f} {:.1f} {:.1f}.".format(
                  *load_before, *os.getloadavg())]
    (_, _, si_wall, si_cpu, _, _), (_, n, wall, cpu, peak, _) = rows
    summary = [("pipeline", "`apt-filters run`, real Si, 945,211 ions, CPU (target: <= 20 s)", f"{si_cpu:.1f} s", "-", "-"),
               ("pipeline", f"`apt-filters run`, synthetic, {n / 1e6:.1f}M ions, CPU, 2 cores (target: <= 25 s at 10M)",
                f"{cpu:.1f} s", "-", "-"),
               ("pipeline", f"`apt-filters run`, synthetic, {n / 1e6:.1f}M ions, peak RSS (target: <= 4 GB at 10M)",
                f"{peak:,.0f} MiB", "-", "-")]
    print("\n".join(lines))
    write_results("pipeline", "bench_pipeline: apt-filters run end to end", summary, ["\n".join(lines)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
