"""Sweeps on Dask: how near to linear the cluster runs them, and how much the answers move.

    python -m benchmarks.bench_sweep [--quick] [--workers N]

1. **Scaling** on the real Si data (Cr at 30 at.%): a sweep of 3 voxels x 3 delocalizations x 3
   iso-values (``--quick``: 2 x 2 x 2) on a local cluster of one worker per core, against one
   ``apt-filters run`` of the middle choice alone in a fresh process. The ideal sweep takes
   (one run) x (choices) / (cores); the target is <= 3x that.
2. **Refined against unrefined** on the ``gamma-prime`` synthetic specimen: the same grid of choices
   (iso 12/14/16 at.%, voxel 1/0.8 nm, delocalization 3x3x1.5 / 2x2x1 nm; ``--quick``: 2 x 1 x 2)
   with the refinement on and off; per precipitate, the spread of its volume over the choices (sd
   over its mean) and its counting error, and the true volume.

There is no peer that sweeps (AP Suite users repeat runs by hand; paraprobe-toolbox sweeps on
its own workflow): the figures are read against the ideal and the counting error.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.results import ratio, write_results

ROOT = Path(__file__).resolve().parents[1]
SUMMARY: list[tuple[str, str, str, str, str]] = []
"""Rows of the summary block that RESULTS.md gathers."""
SI = ROOT.parent / "shared" / "data" / "real" / "apav-si"


def one_run(args: list[str]) -> float:
    """Wall seconds of one ``apt-filters run`` in a fresh process."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "apt_filters", "run", *args, "-q"], check=True, cwd=ROOT,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def scaling(tmp: Path, quick: bool, workers: int) -> list[str]:
    from apt_filters.pipeline import config as cfg
    from apt_filters.sweep import choice_grid, dask_client, run_sweep

    voxels = [1.0, 0.8] if quick else [1.0, 0.8, 1.2]
    delocs = [(3, 3, 1.5), (2, 2, 1)] if quick else [(3, 3, 1.5), (2, 2, 1), (4, 4, 2)]
    isos = [0.3, 0.25] if quick else [0.3, 0.25, 0.35]
    base = cfg.with_options(cfg.PipelineConfig(), {"input": str(SI / "Si.pos"), "range": str(SI / "Si.RRNG"),
                                                  "species": "Cr", "iso": 0.3}, source="benchmark")
    alone = one_run([str(SI / "Si.pos"), "-r", str(SI / "Si.RRNG"), "-o", str(tmp / "alone"), "--species", "Cr",
                     "--iso", "0.3"])
    choices = choice_grid(isos=isos, voxels=voxels, delocalizations=delocs)
    with dask_client(workers=workers) as client:
        result = run_sweep(base, choices, tmp / "sweep", client=client, progress=False)
    ideal = alone * len(choices) / workers
    ok = sum(r["status"] == "ok" for r in result.runs)
    SUMMARY.append(("sweep", f"{len(choices)}-choice sweep on real Si, {workers} workers: wall / ideal (target <= 3)",
                    f"{result.wall_seconds:.0f} s", f"{ideal:.0f} s (one run alone x choices / workers)",
                    ratio(result.wall_seconds, ideal)))
    return ["## Scaling: the real Si data (945,211 ions, Cr 30 at.%)", "",
            "| choices | workers | one run alone (s) | ideal sweep (s) | sweep wall (s) | wall / ideal | target |",
            "|---:|---:|---:|---:|---:|---:|---|",
            f"| {len(choices)} ({ok} ok) | {workers} | {alone:.1f} | {ideal:.1f} | {result.wall_seconds:.1f} | "
            f"{result.wall_seconds / ideal:.2f} | <= 3 |", ""]


def refined_spread(tmp: Path, quick: bool, workers: int) -> list[str]:
    from apt_filters.pipeline import config as cfg
    from apt_filters.synth import preset, write_specimen
    from apt_filters.sweep import choice_grid, dask_client, run_sweep

    truth = write_specimen(tmp / "gp", preset("gamma-prime"), seed=1, keep_ions=False).truth
    base = cfg.with_options(cfg.PipelineConfig(), {"input": str(tmp / "gp" / "specimen.pos"),
                                                  "range": str(tmp / "gp" / "specimen.rrng"), "species": "Al",
                                                  "iso": 0.15, "exclude": ["B"]}, source="benchmark")
    choices = choice_grid(isos=[0.12, 0.15] if quick else [0.12, 0.14, 0.16], voxels=[1.0] if quick else [1.0, 0.8],
                          delocalizations=[(3, 3, 1.5), (2, 2, 1)])
    spreads = {}
    with dask_client(workers=workers) as client:
        for refined in (False, True):
            base.refine.enabled = refined
            result = run_sweep(base, choices, tmp / f"sweep{refined}", client=client, progress=False)
            spreads[refined] = {s["object"]: s for s in result.spread if s["figure"] == "volume"}
            centroids = {r["object"]: r["bbox"] for r in result.rows}
    lines = [f"## Refined against unrefined: gamma-prime seed 1, {len(choices)} choices "
             "(iso 12/14/16 at.% x voxel 1/0.8 nm x delocalization 3x3x1.5 / 2x2x1 nm)", "",
             "| object | true volume (nm³) | unrefined: mean (nm³) | sd over choices | refined: mean (nm³) | "
             "sd over choices | refined counting se |", "|---|---:|---:|---:|---:|---:|---:|"]
    features = [f for f in truth["features"] if "volume_nm3" in f]
    for track, s in sorted(spreads[True].items()):
        box = centroids.get(track)
        centre = [(box[i] + box[i + 3]) / 2 for i in range(3)] if box else None
        near = min(features, key=lambda f: sum((a - b) ** 2 for a, b in zip(f["shape"]["center"], centre)),
                   default=None) if centre else None
        raw = spreads[False].get(track)
        lines.append(f"| {track} ({near['name'] if near else '?'}) | {near['volume_nm3'] if near else float('nan'):.0f} | "
                     f"{raw['mean'] if raw else float('nan'):.0f} | "
                     f"{100 * raw['sd'] / raw['mean'] if raw else float('nan'):.1f} % | {s['mean']:.0f} | "
                     f"{100 * s['sd'] / s['mean']:.1f} % | {100 * s['counting_se'] / s['mean']:.1f} % |")
    cv = {k: statistics.median(100 * s["sd"] / s["mean"] for s in v.values()) for k, v in spreads.items() if v}
    SUMMARY.append(("sweep", f"median spread of precipitate volumes over {len(choices)} choices (gamma-prime)",
                    f"{cv.get(True, float('nan')):.1f} % refined", f"{cv.get(False, float('nan')):.1f} % AP Suite-style",
                    ratio(cv.get(True, float("nan")), cv.get(False, float("nan")))))
    lines += ["", f"Median spread of the volumes over the choices: unrefined {cv.get(False, float('nan')):.1f} %, "
                  f"refined {cv.get(True, float('nan')):.1f} %.", ""]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 x 2 x 2 choices on Si, 4 on the synthetic specimen")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="local cluster workers")
    args = parser.parse_args(argv)
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        sections = ["\n".join(scaling(Path(tmp), args.quick, args.workers)),
                    "\n".join(refined_spread(Path(tmp), args.quick, args.workers))]
    path = write_results("sweep", "bench_sweep: sweeps on a local Dask cluster", SUMMARY, sections,
                         intro=f"Load average before: {load[0]:.1f} (the cluster shares the machine's cores with it).")
    print(path.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
