"""Refinement time on the end-to-end scale case: the ``many`` specimen (47 precipitates) at 10^7 ions.

    python -m benchmarks.bench_refine_scale [--ions 1e7] [--preset many] [--baseline PATH] [--together] [--work DIR]
                                            [--quick]

The specimen of :mod:`benchmarks.bench_pipeline` (``apt-filters synth --preset many --ions N``) is
generated once, voxelized and contoured as ``apt-filters run ... --species Al --iso 0.15 --exclude B``
does (gaussian 3 x 3 x 1.5 nm, 1 nm voxels, marching cubes, specks removed), and the contoured mesh is
saved. :func:`~apt_filters.refine.refine_surface` with its defaults is then timed in a fresh child
process, once with this tree's code and, with ``--baseline PATH`` (a checkout of another revision), once
with that code, in the same run: on a shared machine the process CPU time (all threads, user + system)
is the figure to compare; the wall time and the child's peak resident memory (the ion table read whole
included) are printed beside it. With ``--together`` the two processes run at the same time, so that both see
the same load from the machine's other jobs (one after the other, the second often runs under another).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import resource
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENVIRONMENT = dict(os.environ)
"""The environment each child gets (before importing ``apt_filters`` here changed any of it)."""


def prepare(work: Path, ions: int | None, name: str = "many") -> None:
    """Write the specimen (POS, RRNG) and the contoured, speck-free mesh (``mesh.npz``) into ``work``."""
    from apt_filters.io import read_ions, read_ranges
    from apt_filters.pipeline.surface import contour_surface
    from apt_filters.refine import remove_specks
    from apt_filters.synth import preset, write_specimen
    from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

    if (work / "mesh.npz").exists():
        return
    work.mkdir(parents=True, exist_ok=True)
    write_specimen(work / "spec", preset(name, ions), seed=1, keep_ions=False)
    table = read_ions(work / "spec" / "specimen.pos")
    ranges = read_ranges(work / "spec" / "specimen.rrng")
    basis = ConcentrationBasis(("B",))
    fields = voxelize(table, ranges, kernel="gaussian", delocalization=(3.0, 3.0, 1.5), voxel=1.0, basis=basis)
    mask = inside_mask(fields).dense()
    mesh = contour_surface(fields, mask, "Al", 0.15)
    mesh, _ = remove_specks(mesh, fields=fields, mask=mask, ions=table, ranges=ranges, species="Al", iso=0.15,
                            basis=basis)
    np.savez(work / "mesh.npz", vertices=mesh.vertices, faces=mesh.faces)


def child(work: Path) -> dict:
    """Refine the saved mesh with the code on ``sys.path``; CPU and wall seconds of the call."""
    from apt_filters import refine
    from apt_filters.core.mesh import TriMesh
    from apt_filters.io import read_ions, read_ranges
    from apt_filters.voxel import ConcentrationBasis

    table = read_ions(work / "spec" / "specimen.pos")
    ranges = read_ranges(work / "spec" / "specimen.rrng")
    saved = np.load(work / "mesh.npz")
    mesh = TriMesh(saved["vertices"], saved["faces"])
    basis = ConcentrationBasis(("B",))
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu, wall = usage.ru_utime + usage.ru_stime, time.perf_counter()
    result = refine.refine_surface(mesh, table, ranges, "Al", basis)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    out = result.mesh
    # what must not change with the code's speed: the refined vertices, widths, offset errors and levels; the
    # surface alone has its own hash, so that a change to what is reported beside it shows the surface unmoved
    surface = hashlib.sha1()
    for part in (out.vertices, out.faces):
        surface.update(np.ascontiguousarray(part).tobytes())
    digest = surface.copy()
    for part in (np.asarray(result.widths), np.asarray(result.offset_errors)):
        digest.update(np.ascontiguousarray(part).tobytes())
    digest.update(pickle.dumps(result.levels))
    # and the rest of the report (mode selection, blur, facets, shape errors, stages' notes), times left out
    report = replace(result, mesh=None, stages=[replace(s, seconds=0.0) for s in result.stages])
    digest.update(pickle.dumps(report))
    return {"outputs": digest.hexdigest()[:16], "surface": surface.hexdigest()[:16],
            "cpu_s": usage.ru_utime + usage.ru_stime - cpu,
            "wall_s": time.perf_counter() - wall, "peak_mib": usage.ru_maxrss / 1024,
            "ions": len(table), "faces": int(out.n_faces), "objects": len(result.levels),
            "area_nm2": float(out.area()),
            "mean_displacement_nm": float(result.displacement["mean"])}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ions", type=float, default=1e7, help="0: the preset's own size")
    parser.add_argument("--preset", default="many", help="synth preset ('default': 7 objects, ~3.4M ions, to develop on)")
    parser.add_argument("--work", type=Path, help="folder for the specimen and mesh (kept; default /tmp/...)")
    parser.add_argument("--baseline", type=Path, help="checkout of the revision to compare against")
    parser.add_argument("--together", action="store_true",
                        help="run this tree and the baseline at the same time (the same load on a shared machine)")
    parser.add_argument("--quick", action="store_true", help="the default preset at its own size (~3.4M ions)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.quick:
        args.preset, args.ions = "default", 0
    work = args.work or Path(f"/tmp/bench_refine_scale_{args.preset}_{int(args.ions)}")
    if args.child:
        print(json.dumps(child(work)))
        return 0
    from benchmarks.results import child_result

    start = time.perf_counter()
    prepare(work, int(args.ions) or None, args.preset)
    print(f"specimen and contour ready in {time.perf_counter() - start:.0f} s ({work})", flush=True)
    runs = [("this tree", ROOT)] + ([(f"baseline ({args.baseline})", args.baseline.resolve())] if args.baseline else [])
    lines = [f"## Refinement of the `{args.preset}` specimen ({'own size' if not args.ions else f'{args.ions:.0e} ions'})",
             "", "Default settings, Al at 15 at.% with B out of the basis; each row a fresh process; CPU = user + "
             "system of all threads during `refine_surface`.", "",
             "| code | ions | objects | faces | CPU (s) | wall (s) | peak RSS (MiB) | mean displacement (nm) | "
             "outputs (SHA-1) | surface (SHA-1) |", "|---|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    print("\n".join(lines), flush=True)
    def measure(code: Path) -> dict:
        return child_result(__file__, work, code, ENVIRONMENT, "refinement")

    together = None
    if args.together:
        with ThreadPoolExecutor(len(runs)) as pool:  # each row's child is its own process: the threads only wait
            together = list(pool.map(measure, [code for _, code in runs]))
    results = []
    for i, (name, code) in enumerate(runs):
        r = together[i] if together else measure(code)
        results.append(r)
        lines.append(f"| {name} | {r['ions']:,} | {r['objects']} | {r['faces']:,} | {r['cpu_s']:.1f} | "
                     f"{r['wall_s']:.1f} | {r['peak_mib']:,.0f} | {r['mean_displacement_nm']:+.4f} | "
                     f"`{r['outputs']}` | `{r['surface']}` |")
        print(lines[-1], flush=True)
    lines += ["", "Load average (1, 5, 15 min) after: {:.1f} {:.1f} {:.1f}{}.".format(
        *os.getloadavg(), "; the rows ran at the same time" if args.together else "")]
    if len(results) > 1:
        same, surfaces = (len({r[key] for r in results}) == 1 for key in ("outputs", "surface"))
        lines += ["", f"Outputs (refined vertices and faces, widths, offset errors, levels, the rest of the report): "
                      f"{'identical bit for bit' if same else 'DIFFERENT'} across the rows; the refined surface "
                      f"alone: {'identical' if surfaces else 'DIFFERENT'}."]
    if not args.child:
        from benchmarks.results import ratio, write_results

        ours = results[0]
        peer = results[1] if len(results) > 1 else None
        rows = [("refine", f"refinement CPU, {ours['ions'] / 1e6:.1f}M ions, {ours['objects']} objects, 2 cores "
                           "(target: <= 15 s at 10M)", f"{ours['cpu_s']:.1f} s",
                 f"{peer['cpu_s']:.1f} s (baseline)" if peer else "-", ratio(ours["cpu_s"], peer["cpu_s"]) if peer else "-")]
        write_results("refine_scale", "bench_refine_scale: refinement time at scale", rows, ["\n".join(lines)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
