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
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

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
    features = [f for f in truth["features"] if f.get("bounded") and "volume_nm3" in f]
    volumes = {}  # (pipeline, feature index) -> volumes over the choices
    with dask_client(workers=workers) as client:
        for refined in (False, True):
            base.refine.enabled = refined
            result = run_sweep(base, choices, tmp / f"sweep{refined}", client=client, progress=False)
            for f_index, f in enumerate(features):
                for choice in choices:
                    config = choice.apply(base)
                    values = choice.values(config)
                    mine = [r for r in result.rows if all(r[k] == values[k] for k in values) and r["bbox"]
                            and r["volume"] is not None and _contains(r["bbox"], f["shape"]["center"])]
                    # the object around the precipitate's centre; a precipitate not found counts as missing
                    best = max(mine, key=lambda r: r["volume"], default=None)
                    volumes.setdefault((refined, f_index), []).append(None if best is None else best["volume"])
    lines = [f"## Refined against unrefined: gamma-prime seed 1, {len(choices)} choices "
             f"(iso {'/'.join(f'{c:g}' for c in sorted({c.iso for c in choices}))} x voxel "
             f"{'/'.join(f'{c:g}' for c in sorted({c.voxel for c in choices}))} nm x delocalization 3x3x1.5 / 2x2x1 nm)",
             "", "Each precipitate is the object of each choice whose bounding box holds its true centre.", "",
             "| precipitate | true volume (nm³) | AP Suite-style: mean (nm³) | sd over choices | refined: mean (nm³) | "
             "sd over choices |", "|---|---:|---:|---:|---:|---:|"]
    spread = {False: [], True: []}
    for f_index, f in enumerate(features):
        cells = []
        for refined in (False, True):
            found = [v for v in volumes[(refined, f_index)] if v is not None]
            missing = len(choices) - len(found)
            mean = float(np.mean(found)) if found else float("nan")
            sd = 100 * float(np.std(found, ddof=1)) / mean if len(found) > 1 else float("nan")
            if np.isfinite(sd):
                spread[refined].append(sd)
            cells += [f"{mean:.0f}" + (f" ({missing} missed)" if missing else ""), f"{sd:.1f} %"]
        lines.append(f"| {f['name']} | {f['volume_nm3']:.0f} | " + " | ".join(cells) + " |")
    cv = {k: statistics.median(v) if v else float("nan") for k, v in spread.items()}
    SUMMARY.append(("sweep", f"median spread of precipitate volumes over {len(choices)} choices (gamma-prime)",
                    f"{cv[True]:.1f} % refined", f"{cv[False]:.1f} % AP Suite-style", ratio(cv[True], cv[False])))
    lines += ["", f"Median spread of the volumes over the choices: AP Suite-style {cv[False]:.1f} %, "
                  f"refined {cv[True]:.1f} %.", ""]
    return lines


def _contains(box, point) -> bool:
    return all(box[i] <= point[i] <= box[i + 3] for i in range(3))


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
