"""The analysis steps of a finished surface: each reading the whole ion table, or one selection shared by all.

    python -m benchmarks.bench_select [--ions 2e6] [--seed 1] [--quick]

A ``gamma-prime`` specimen of about N ions is written as POS and memory-mapped (``io.map_ions``, as
``apt-filters run`` maps a table that does not fit its memory budget); its finished Al 15 at.% surface
(``pipeline.surface.finished_surface``, the command line's defaults) is computed once. Then, each in a
fresh child process (so that each peak is its own), the analysis steps of ``apt-filters run``:

``whole``   the object table, the proxigram (±3 nm), the B excess map and the scene's local composition,
            each streaming the whole mapped table (the specimen's hull, for the object table, too);
``select``  the hull, then the ions within 3 nm of the surface or inside its objects selected in one
            streamed pass (``pipeline.surface.analysis_ions``), and the same four steps on them.

Per step: wall and CPU seconds, and the peak resident memory (``VmHWM`` reset before each step, as
``apt-filters run`` reports it: it counts the mapped table's pages a step touches). The figures of both
arms are compared (object table rows, proxigram counts, maps) and must be equal.
"""

from __future__ import annotations

import argparse
import json
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.results import ratio, write_results

ROOT = Path(__file__).resolve().parents[1]
REACH = 3.0
STEPS = ("select", "objects", "proxigram", "maps", "composition")


def _prepare(work: Path, ions: int, seed: int) -> None:
    from apt_filters.pipeline.config import SurfaceConfig
    from apt_filters.pipeline.surface import finished_surface
    from apt_filters.synth import preset, write_specimen
    from apt_filters.voxel import inside_mask, voxelize

    sp = write_specimen(work / "specimen", preset("gamma-prime", ions=ions), seed=seed)
    fields = voxelize(sp.ions, sp.ranges)
    mesh, _ = finished_surface(fields, inside_mask(fields).dense(), sp.ions, sp.ranges, SurfaceConfig("Al", 0.15))
    np.savez(work / "mesh.npz", vertices=mesh.vertices, faces=mesh.faces, object_id=mesh.face_scalars["object_id"])
    (work / "ranges.pkl").write_bytes(pickle.dumps(sp.ranges))


def _child(work: Path, arm: str) -> dict:
    """One arm's steps in this process; returns per step (seconds, cpu, peak bytes) and the figures."""
    from apt_filters.analysis.maps import excess_maps
    from apt_filters.analysis.objects import object_table
    from apt_filters.analysis.proxigram import compute_proxigram
    from apt_filters.core.hull import SpecimenHull
    from apt_filters.core.mesh import TriMesh
    from apt_filters.io import map_ions
    from apt_filters.pipeline.scene import vertex_composition
    from apt_filters.pipeline.steps import StepLog
    from apt_filters.pipeline.surface import analysis_ions

    saved = np.load(work / "mesh.npz")
    mesh = TriMesh(saved["vertices"], saved["faces"])
    mesh.face_scalars["object_id"] = saved["object_id"]
    ranges = pickle.loads((work / "ranges.pkl").read_bytes())
    scratch = work / f"scratch_{arm}"
    scratch.mkdir()
    table = map_ions(work / "specimen" / "specimen.pos", scratch)
    log, cpu = StepLog(quiet=True), {}

    def step(name):
        cpu[name] = time.process_time()
        return log.step(name)

    with step("hull"):
        hull = SpecimenHull.from_points(table.positions)
    cpu["hull"] = time.process_time() - cpu["hull"]
    ions = table
    if arm == "select":
        with step("select"):
            ions = analysis_ions(table, mesh, reach=REACH)
        cpu["select"] = time.process_time() - cpu["select"]
    with step("objects"):
        rows = object_table(mesh, ions, ranges, specimen=hull).rows()
    cpu["objects"] = time.process_time() - cpu["objects"]
    with step("proxigram"):
        prox = compute_proxigram(ions, ranges, mesh, max_distance=REACH)
    cpu["proxigram"] = time.process_time() - cpu["proxigram"]
    with step("maps"):
        maps = excess_maps(mesh=mesh, ions=ions, ranges=ranges, solutes=["B"], max_distance=REACH)
    cpu["maps"] = time.process_time() - cpu["maps"]
    with step("composition"):
        comp = vertex_composition(vertices=mesh.vertices, ions=ions, ranges=ranges, elements=["Al", "B"])
    cpu["composition"] = time.process_time() - cpu["composition"]
    return {"n_ions": len(table), "n_selected": len(ions),
            "steps": {r.name: (r.seconds, cpu[r.name], r.peak_bytes) for r in log.records},
            "figures": {"objects": rows, "proxigram": prox.counts.tolist(),
                        "maps": {k: np.nan_to_num(v, nan=-1e300).tolist() for k, v in maps.vertex_scalars().items()},
                        "composition": {k: np.nan_to_num(v, nan=-1e300).tolist() for k, v in comp.items()}}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ions", type=float, default=2e6)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="the preset's own size (about 1.2M ions)")
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(_child(Path(args.child[0]), args.child[1]), default=float))
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        t = time.perf_counter()
        _prepare(work, None if args.quick else int(args.ions), args.seed)
        print(f"specimen and finished surface in {time.perf_counter() - t:.0f} s", flush=True)
        runs = {}
        for arm in ("whole", "select"):
            done = subprocess.run([sys.executable, "-m", "benchmarks.bench_select", "--child", str(work), arm],
                                  cwd=ROOT, capture_output=True, text=True, check=True)
            runs[arm] = json.loads(done.stdout.strip().splitlines()[-1])
    whole, select = runs["whole"], runs["select"]
    same = {k: whole["figures"][k] == select["figures"][k] for k in whole["figures"]}
    n, k = whole["n_ions"], select["n_selected"]
    lines = [f"## Analysis steps, {n:,} ions memory-mapped", "",
             f"gamma-prime seed {args.seed}, finished Al 15 at.% surface; {k:,} ions ({k / n:.1%}) within "
             f"{REACH:g} nm of it or inside its objects. Figures equal in both arms: "
             + ", ".join(f"{name} {'yes' if ok else 'NO'}" for name, ok in same.items()) + ".", "",
             "| step | whole table: wall (s) | CPU (s) | peak (MiB) | one selection: wall (s) | CPU (s) | peak (MiB) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    totals = {"whole": [0.0, 0.0, 0], "select": [0.0, 0.0, 0]}
    for name in ("hull",) + STEPS:
        cells = []
        for arm in ("whole", "select"):
            if name in runs[arm]["steps"]:
                wall, cpu, peak = runs[arm]["steps"][name]
                cells.append(f"{wall:.2f} | {cpu:.2f} | {peak / 2**20:,.0f}")
                totals[arm] = [totals[arm][0] + wall, totals[arm][1] + cpu, max(totals[arm][2], peak)]
            else:
                cells.append("– | – | –")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("| all | " + " | ".join(f"{w:.2f} | {c:.2f} | {p / 2**20:,.0f}" for w, c, p in totals.values()) + " |")
    print("\n".join(lines), flush=True)
    w, s = totals["whole"], totals["select"]
    summary = [("pipeline", f"analysis steps of a finished surface, {n / 1e6:.1f}M ions mapped, CPU "
                "(peer: each step reading the whole table)", f"{s[1]:.1f} s", f"{w[1]:.1f} s", ratio(s[1], w[1])),
               ("pipeline", "same, peak RSS of the steps", f"{s[2] / 2**20:,.0f} MiB", f"{w[2] / 2**20:,.0f} MiB",
                ratio(s[2], w[2]))]
    write_results("select", "One ion selection per surface (`benchmarks/bench_select.py`)", summary, ["\n".join(lines)],
                  intro=__doc__.split("\n\n", 2)[2].split("\n\n")[0])
    return 0 if all(same.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
