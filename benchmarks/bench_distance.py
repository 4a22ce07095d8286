"""The distance engine's hot paths at scale: the selections and signed distances the run asks of one surface.

    python -m benchmarks.bench_distance [--ions 1e7] [--preset many] [--baseline PATH] [--work DIR] [--quick]

The specimen and contoured mesh of :mod:`benchmarks.bench_refine_scale` (``prepare``: the ``many`` preset,
47 precipitates, Al iso-surface at 15 at.%), subdivided once as the refinement starts. In a fresh child
process, with this tree's code and, with ``--baseline PATH`` (a checkout of another revision), with that
code, in the same run:

- ``select 5.5 nm``: :func:`~apt_filters.core.nearby.select_near` of every ion within 5.5 nm with exact
  signed distances (the refinement's first selection, :meth:`~apt_filters.refine.band.NearIons.select`);
- ``select 3 nm, no distances``: the same within 3 nm with ``distances=False`` (the analyses' ions,
  :func:`~apt_filters.pipeline.surface.analysis_ions`);
- ``query 3 nm``: :meth:`~apt_filters.core.distance.SurfaceDistance.query` of the ions within 5.5 nm with
  ``max_distance=3`` (the proxigram's and :meth:`~apt_filters.core.nearby.NearSurface.within`'s distances);
- ``nearest``: :meth:`~apt_filters.core.distance.SurfaceDistance.query` without a limit of every 20th ion
  (the truth metrics' and remesher's unbounded queries).

Each is timed once after a warm-up on 1,000 ions (numba's caches), CPU = user + system of all threads; its
outputs (rows, distances, faces, rim flags) are hashed, so that the rows of the two codes show whether
they are the same bit for bit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENVIRONMENT = dict(os.environ)

STEPS = ("select 5.5 nm", "select 3 nm, no distances", "query 3 nm", "nearest")


def _cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def child(work: Path) -> dict:
    """Time each step with the code on ``sys.path``; CPU and wall seconds and an output digest per step."""
    from apt_filters.core.distance import SurfaceDistance
    from apt_filters.core.mesh import TriMesh
    from apt_filters.core.nearby import select_near
    from apt_filters.io import read_ions
    from apt_filters.refine.subdivide import subdivide

    positions = read_ions(work / "spec" / "specimen.pos").positions
    saved = np.load(work / "mesh.npz")
    mesh = subdivide(TriMesh(saved["vertices"], saved["faces"]))
    every = positions[::20]

    def digest(*parts) -> str:
        h = hashlib.sha1()
        for part in parts:
            h.update(np.ascontiguousarray(part).tobytes())
        return h.hexdigest()[:16]

    held = {}

    def select_exact(points):
        near = select_near(points, mesh, 5.5)
        held["near"] = near.positions
        return digest(near.rows, near.distance, near.face, near.on_boundary)

    def select_rows(points):
        near = select_near(points, mesh, 3.0, distances=False)
        return digest(near.rows, near.distance, near.face, near.on_boundary)

    def query(points):
        sd = SurfaceDistance(mesh, reach=3.0).query(points, max_distance=3.0)
        return digest(sd.distance, sd.face, sd.feature, sd.on_boundary)

    def nearest(points):
        sd = SurfaceDistance(mesh).query(points)
        return digest(sd.distance, sd.face, sd.feature, sd.on_boundary)

    steps = [(STEPS[0], select_exact, lambda: positions), (STEPS[1], select_rows, lambda: positions),
             (STEPS[2], query, lambda: held["near"]), (STEPS[3], nearest, lambda: every)]
    out = {"ions": len(positions), "faces": int(mesh.n_faces), "steps": {}}
    for name, run, points in steps:
        run(np.ascontiguousarray(points()[:1000]))  # compile / load numba's caches
        data = points()
        cpu, wall = _cpu(), time.perf_counter()
        h = run(data)
        out["steps"][name] = {"cpu_s": _cpu() - cpu, "wall_s": time.perf_counter() - wall, "points": len(data),
                              "outputs": h}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ions", type=float, default=1e7, help="0: the preset's own size")
    parser.add_argument("--preset", default="many")
    parser.add_argument("--work", type=Path, help="folder for the specimen and mesh (kept; default /tmp/...)")
    parser.add_argument("--baseline", type=Path, help="checkout of the revision to compare against")
    parser.add_argument("--quick", action="store_true", help="the default preset at its own size (~3.4M ions)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.quick:
        args.preset, args.ions = "default", 0
    work = args.work or Path(f"/tmp/bench_refine_scale_{args.preset}_{int(args.ions)}")
    if args.child:
        print(json.dumps(child(work)))
        return 0
    from benchmarks.bench_refine_scale import prepare
    from benchmarks.results import child_result

    prepare(work, int(args.ions) or None, args.preset)
    runs = [("this tree", ROOT)] + ([(f"baseline ({args.baseline})", args.baseline.resolve())] if args.baseline else [])
    results = [(name, child_result(__file__, work, code, ENVIRONMENT, "distance steps")) for name, code in runs]
    first = results[0][1]
    lines = [f"## Distance steps on the `{args.preset}` specimen ({first['ions']:,} ions, "
             f"{first['faces']:,}-face surface)", "",
             "Each code in a fresh process, one after the other; CPU = user + system of all threads.", "",
             "| step | points | code | CPU (s) | wall (s) | outputs (SHA-1) |", "|---|---:|---|---:|---:|---|"]
    for step in STEPS:
        for name, r in results:
            s = r["steps"][step]
            lines.append(f"| {step} | {s['points']:,} | {name} | {s['cpu_s']:.2f} | {s['wall_s']:.2f} | "
                         f"`{s['outputs']}` |")
    lines += ["", "Load average (1, 5, 15 min) after: {:.1f} {:.1f} {:.1f}.".format(*os.getloadavg())]
    if len(results) > 1:
        same = all(len({r["steps"][s]["outputs"] for _, r in results}) == 1 for s in STEPS)
        lines += ["", f"Outputs: {'identical bit for bit' if same else 'DIFFERENT'} across the codes."]
    text = "\n".join(lines)
    print(text, flush=True)
    from benchmarks.results import ratio, write_results

    rows = []
    for step in STEPS:
        ours = first["steps"][step]
        peer = results[1][1]["steps"][step] if len(results) > 1 else None
        rows.append(("distance", f"{step}, {ours['points']:,} points ({first['ions'] / 1e6:.1f}M-ion specimen), CPU",
                     f"{ours['cpu_s']:.2f} s", f"{peer['cpu_s']:.2f} s (baseline)" if peer else "-",
                     ratio(ours["cpu_s"], peer["cpu_s"]) if peer else "-"))
    write_results("distance", "bench_distance: the distance engine's hot paths", rows, [text])
    return 0


if __name__ == "__main__":
    sys.exit(main())
