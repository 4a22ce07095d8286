"""A one-off fuzz campaign over generated range files of every dialect, through the command line.

    python -m benchmarks.fuzz_ranges [--files 1000] [--subprocess-every 25]

Generates ``--files`` range files with tests/rangefile_gen.py (RRNG, RNG, ENV and GPM ENV; decimal
commas, header lines, duplicate indices, near-duplicate overlaps, placeholder names, line damage,
five encodings; up to 300 ranges each), derandomized so that a rerun makes the same files. Each
file goes through ``apt-filters info IONS --range FILE`` in this process (the CLI's own error
handling: exit 0, or 2 with one line on stderr; anything else is a traceback); every
``--subprocess-every``-th file also runs in a fresh ``python -m apt_filters`` process, which
shows signal deaths and tracebacks as the user would see them. Reports the outcomes, the
slowest read and the files that broke a promise, to stdout and benchmarks/results_fuzz_ranges.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings

from apt_filters.cli.main import main as cli
from apt_filters.io import IonTable
from apt_filters.io.writers import write_pos
from benchmarks.results import write_results

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from rangefile_gen import range_files  # noqa: E402

LIMIT_S = 10.0


def run_campaign(n_files: int, every: int, folder: Path) -> dict:
    ions = folder / "ions.pos"
    rng = np.random.default_rng(0)
    write_pos(ions, IonTable(rng.uniform(-5, 5, (1000, 3)).astype(np.float32),
                             rng.uniform(0.5, 300, 1000).astype(np.float32)))
    stats = {"outcomes": Counter(), "slowest": (0.0, ""), "broken": [], "subprocess": Counter(), "files": 0}

    @settings(max_examples=n_files, deadline=None, derandomize=True, database=None,
              suppress_health_check=list(HealthCheck))
    @given(case=range_files(max_ranges=300))
    def one(case):
        suffix, data = case
        k = stats["files"]
        stats["files"] += 1
        path = folder / f"f{k}{suffix}"
        path.write_bytes(data)
        err = io.StringIO()
        start = time.perf_counter()
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                rc = cli(["info", str(ions), "--range", str(path)])
        except Exception as exc:  # a traceback: a broken promise
            rc = f"traceback {type(exc).__name__}: {str(exc)[:120]}"
        took = time.perf_counter() - start
        lines = err.getvalue().strip().splitlines()
        if rc not in (0, 2) or (rc == 2 and len(lines) != 1) or took > LIMIT_S:
            stats["broken"].append(f"{path.name}: rc {rc}, {len(lines)} stderr lines, {took:.2f} s")
        stats["outcomes"]["read" if rc == 0 else "refused in one line" if rc == 2 else "broken"] += 1
        if took > stats["slowest"][0]:
            stats["slowest"] = (took, path.name)
        if every and k % every == 0:
            proc = subprocess.run([sys.executable, "-m", "apt_filters", "info", str(ions), "--range", str(path)],
                                  capture_output=True, text=True, timeout=60)
            ok = proc.returncode in (0, 2) and "Traceback" not in proc.stderr
            stats["subprocess"]["ok" if ok else f"rc {proc.returncode}"] += 1
            if not ok:
                stats["broken"].append(f"{path.name}: subprocess rc {proc.returncode}")
        path.unlink()

    one()
    return stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=1000)
    parser.add_argument("--subprocess-every", type=int, default=25)
    args = parser.parse_args()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        stats = run_campaign(args.files, args.subprocess_every, Path(tmp))
    total = time.perf_counter() - start
    slow, slow_name = stats["slowest"]
    rows = [("ranges", f"fuzz: {stats['files']:,} generated range files through the CLI (target: no traceback, "
             f"none over {LIMIT_S:g} s)", f"{len(stats['broken'])} broken, slowest {slow:.1f} s", "-", "-")]
    lines = [f"## Fuzz campaign: {stats['files']:,} generated range files through `apt-filters info`", "",
             "RRNG, RNG, ENV and GPM ENV files from tests/rangefile_gen.py (up to 300 ranges, quirks, line damage, "
             f"five encodings), derandomized; {total:.0f} s in all on a shared 2-core machine", "",
             "| outcome | files |", "|---|---:|"]
    lines += [f"| {k} | {v:,} |" for k, v in sorted(stats["outcomes"].items())]
    lines += ["", f"- slowest file: {slow:.3f} s ({slow_name}); limit {LIMIT_S:g} s",
              f"- in a fresh process (every {args.subprocess_every}th file): "
              + ", ".join(f"{v} {k}" for k, v in stats["subprocess"].items()),
              f"- broken promises (traceback, several error lines, signal death, over {LIMIT_S:g} s): "
              f"{len(stats['broken'])}"]
    lines += [f"  - {b}" for b in stats["broken"][:20]]
    text = "\n".join(lines)
    print(text)
    write_results("fuzz_ranges", "benchmarks/fuzz_ranges.py results", rows, [text])


if __name__ == "__main__":
    main()
