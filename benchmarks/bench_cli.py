"""How fast the command line reports a mistake: the time from start to the one-line error.

    python -m benchmarks.bench_cli [--quick] [--repeat R]

Each case runs ``python -m apt_filters ...`` in a fresh process (``--repeat`` times, 7 by
default, 3 with ``--quick``) and keeps the least and the median wall time, beside a bare
``python -c pass`` and ``python -c "import numpy"`` (the floor any Python command pays). The
mistakes are caught before numba, scipy, pymeshlab, open3d or matplotlib are imported; the
table says which of those each case loaded (``-X importtime``). Target: well under a second.
Results go to stdout and benchmarks/results_cli.md.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).with_name("results_cli.md")
HEAVY = ("numba", "scipy", "pymeshlab", "open3d", "matplotlib")


def _cases(folder: Path) -> list[tuple[str, list[str]]]:
    rrng = folder / "tiny.rrng"
    rrng.write_text("[Ions]\nNumber=2\nIon1=Al\nIon2=Ni\n[Ranges]\nNumber=2\n"
                    "Range1=26.5000 27.5000 Vol:0.01661 Al:1 Color:33FFFF\n"
                    "Range2=57.5000 58.5000 Vol:0.01094 Ni:1 Color:00FF00\n")
    pos = folder / "tiny.pos"
    pos.write_bytes(b"\x00" * 16 * 10)
    m = [sys.executable, "-m", "apt_filters"]
    return [
        ("python -c pass", [sys.executable, "-c", "pass"]),
        ("python -c 'import numpy'", [sys.executable, "-c", "import numpy"]),
        ("apt-filters --help", [*m, "--help"]),
        ("run: missing ion file", [*m, "run", str(folder / "missing.pos"), "-r", str(rrng), "-o", str(folder / "o"),
                                   "--species", "Al", "--iso", "0.1"]),
        ("run: unknown species", [*m, "run", str(pos), "-r", str(rrng), "-o", str(folder / "o"),
                                  "--species", "Xe", "--iso", "0.1"]),
        ("proxigram: missing mesh", [*m, "proxigram", str(pos), "-r", str(rrng), "-m", str(folder / "none.ply"),
                                     "-o", str(folder / "p")]),
        ("info: unknown extension", [*m, "info", str(folder / "ions.xyz")]),
    ]


def _heavy(cmd: list[str]) -> str:
    err = subprocess.run([cmd[0], "-X", "importtime", *cmd[1:]], capture_output=True, text=True).stderr
    loaded = {line.split("|")[-1].strip().split(".")[0] for line in err.splitlines() if line.startswith("import time")}
    return ", ".join(sorted(loaded & set(HEAVY))) or "none"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="3 repeats")
    parser.add_argument("--repeat", type=int, default=None)
    args = parser.parse_args(argv)
    repeat = args.repeat or (3 if args.quick else 7)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-cli-") as tmp:
        for name, cmd in _cases(Path(tmp)):
            times = []
            for _ in range(repeat):
                start = time.perf_counter()
                proc = subprocess.run(cmd, capture_output=True, text=True)
                times.append(time.perf_counter() - start)
            last = (proc.stderr.strip().splitlines() or [""])[-1] if proc.returncode else ""
            rows.append((name, min(times), statistics.median(times), proc.returncode,
                         _heavy(cmd) if cmd[1] == "-m" else "-", last[:70]))
    lines = ["# Command line: time to report a mistake", "",
             f"Fresh process per run, {repeat} runs; wall time in seconds (least, median); load average "
             f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores during the run (compare with the bare "
             "Python and numpy rows, which pay the same load).", "",
             "| case | least (s) | median (s) | exit | heavy libraries loaded | message |",
             "|---|---:|---:|---:|---|---|"]
    lines += [f"| {n} | {lo:.3f} | {med:.3f} | {rc} | {heavy} | {msg.replace('|', '/')} |"
              for n, lo, med, rc, heavy, msg in rows]
    median = {n: med for n, _, med, *_ in rows}
    floor = median["python -c 'import numpy'"]
    lines += ["", "<!-- summary -->", "| step | measure | ours | peer | ours / peer |", "|---|---|---:|---:|---:|"]
    lines += [f"| cli | {case}, median s (peer: python -c 'import numpy') | {median[case]:.2f} | {floor:.2f} | "
              f"{median[case] / floor:.2f} |" for case in ("run: missing ion file", "run: unknown species")]
    lines += ["<!-- /summary -->"]
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
