"""Fuzz campaign of ``apt-filters replay``: N hostile ``.mlx`` scripts, none may crash, hang or trace back.

Scripts come from the hypothesis strategy ``tests/mlx_scripts.py`` (MeshLab's vocabulary mixed
with junk, NaN, huge counts, repeats, deep nesting, DTDs, byte damage). Each is replayed on a
1,280-face sphere by a worker process that imports apt-filters once; a worker killed by a
signal (MeshLab crashing) is counted, named and replaced. Every ``--cli`` th script also goes
through the real command line in its own process (exit status 0 or 2, one stderr line, no
traceback).

    PYTHONPATH=. python benchmarks/fuzz_replay.py --scripts 200 --cli 10

Writes the figures to benchmarks/results_fuzz_replay.md (summary block first): scripts replayed /
refused, exceptions other than AptFiltersError, signal deaths, the slowest script (limit 10 s).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIMIT_S = 10.0

REASONS = ("larger than", "not UTF-8", "DTD", "processing instruction", "malformed filter script",
           "not a MeshLab filter script", "replays at most", "unknown filter", "nested elements", "attribute",
           "has no parameter", "given twice", "has type", "not a whole number", "not a number", "not true or false",
           "is outside", "face visits")
"""Kinds of refusal, as the messages of apt_filters.meshlab.mlx word them (first match counts)."""

WORKER = r"""
import json, sys, time, traceback
from apt_filters.core.errors import AptFiltersError
from apt_filters.meshlab.mlx import replay_file
mesh, out = sys.argv[1], sys.argv[2]
for line in sys.stdin:
    script = line.strip()
    print(json.dumps({"start": script}), flush=True)
    t = time.perf_counter()
    try:
        replay_file(script, mesh, out, overwrite=True)
        result = {"ok": True}
    except AptFiltersError as exc:
        result = {"refused": str(exc), "multiline": "\n" in str(exc), "chars": len(str(exc))}
    except Exception:
        result = {"exception": traceback.format_exc(limit=3)}
    result.update(script=script, seconds=time.perf_counter() - t)
    print(json.dumps(result), flush=True)
"""


BATCH = 50
"""Scripts drawn per generating process (hypothesis' memory grows with the examples of one run)."""


def generate(n: int, folder: Path, first: int = 0) -> list[Path]:
    """Write ``n`` scripts drawn from the strategy as ``folder/sNNNN.mlx`` from number ``first``
    (the seed follows ``first``: the same campaign every time)."""
    from hypothesis import HealthCheck, Phase, given, seed, settings

    sys.path.insert(0, str(ROOT))
    from tests.mlx_scripts import scripts

    paths: list[Path] = []

    @seed(20261204 + first)
    @settings(max_examples=n, phases=[Phase.generate], database=None, deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(scripts())
    def draw(data: bytes) -> None:
        path = folder / f"s{first + len(paths):04d}.mlx"
        path.write_bytes(data)
        paths.append(path)

    draw()
    return paths


def generate_in_batches(n: int, folder: Path) -> list[Path]:
    """:func:`generate` in processes of :data:`BATCH` scripts each."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    for first in range(0, n, BATCH):
        subprocess.run([sys.executable, __file__, "--generate", str(folder), str(first), str(min(BATCH, n - first))],
                       check=True, env=env)
    return sorted(folder.glob("s*.mlx"))


def campaign(paths: list[Path], mesh: Path, out: Path) -> list[dict]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    results: list[dict] = []
    pending = list(paths)
    while pending:
        worker = subprocess.Popen([sys.executable, "-c", WORKER, str(mesh), str(out)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True, env=env)
        worker.stdin.write("".join(f"{p}\n" for p in pending))
        worker.stdin.close()
        started = None
        for line in worker.stdout:
            record = json.loads(line)
            if "start" in record:
                started = record["start"]
                continue
            results.append(record)
            pending.remove(Path(record["script"]))
            started = None
        worker.wait()
        if started is not None:  # died inside a script
            results.append({"script": started, "signal": -worker.returncode, "seconds": None})
            pending.remove(Path(started))
    return results


def through_cli(paths: list[Path], mesh: Path, out: Path) -> Counter:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    tally: Counter = Counter()
    for path in paths:
        proc = subprocess.run([sys.executable, "-m", "apt_filters", "replay", str(path), str(mesh), "-o", str(out),
                               "--force"], capture_output=True, text=True, env=env, timeout=120)
        good = proc.returncode in (0, 2) and "Traceback" not in proc.stderr and proc.stderr.count("\n") <= 1
        tally["cli ok" if good else f"cli BAD exit {proc.returncode}: {proc.stderr[-200:]}"] += 1
    return tally


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scripts", type=int, default=200)
    parser.add_argument("--cli", type=int, default=10, help="every N-th script also through the command line")
    parser.add_argument("--generate", nargs=3, metavar=("FOLDER", "FIRST", "N"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.generate:
        generate(int(args.generate[2]), Path(args.generate[0]), int(args.generate[1]))
        return
    sys.path.insert(0, str(ROOT))
    from apt_filters.meshlab.exports import write_ply
    from tests.meshlab_shapes import sphere

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        mesh = folder / "in.ply"
        write_ply(sphere(5.0, subdiv=3), mesh)
        start = time.perf_counter()
        paths = generate_in_batches(args.scripts, folder)
        results = campaign(paths, mesh, folder / "out.ply")
        cli = through_cli(paths[:: args.cli], mesh, folder / "cli.ply") if args.cli else Counter()
        sizes = [p.stat().st_size for p in paths]
    elapsed = time.perf_counter() - start
    timed = [r["seconds"] for r in results if r["seconds"] is not None]
    broken = [r for r in results if "exception" in r or "signal" in r or r.get("multiline")
              or r.get("chars", 0) > 2500 or (r["seconds"] or 0) > LIMIT_S]
    broken_cli = sum(n for k, n in cli.items() if k != "cli ok")
    reasons = Counter(next((k for k in REASONS if k in r["refused"]), "other") for r in results if "refused" in r)
    from benchmarks.results import write_results

    row = ("meshlab", f"fuzz: {len(results):,} generated .mlx scripts replayed (target: no traceback, no signal "
           f"death, none over {LIMIT_S:g} s)", f"{len(broken) + broken_cli} broken, slowest {max(timed):.2f} s", "-", "-")
    section = f"""## Fuzz campaign: {len(results):,} generated `.mlx` scripts through `replay_file`

Scripts from tests/mlx_scripts.py ({min(sizes):,}-{max(sizes):,} bytes; fixed seeds), replayed on a 1,280-face
sphere by a worker process; {elapsed:.0f} s in all on a shared 2-core machine.

| outcome | scripts |
|---|---:|
| replayed | {sum("ok" in r for r in results)} |
| refused in one line | {sum("refused" in r for r in results)} |
| exception other than AptFiltersError | {sum("exception" in r for r in results)} |
| worker killed by a signal | {sum("signal" in r for r in results)} |

- refusals by kind: {", ".join(f"{k} {n}" for k, n in reasons.most_common())}
- slowest script: {max(timed):.2f} s; limit {LIMIT_S:g} s
- through the command line in a fresh process (every {args.cli}th script): \
{", ".join(f"{n} {k}" for k, n in cli.items()) or "none"}
- broken promises (traceback, several error lines, signal death, over {LIMIT_S:g} s): {len(broken) + broken_cli}
"""
    print(write_results("fuzz_replay", "benchmarks/fuzz_replay.py results", [row], [section]).read_text())
    for r in broken:
        print("FAILURE", r)

if __name__ == "__main__":
    main()
