"""Proxigram speed: exact narrow-band signed distances vs open3d's signed distance over all ions.

    python -m benchmarks.bench_proxigram            # 10 M ions, ~230k-triangle surface (the target)
    python -m benchmarks.bench_proxigram --quick    # same surface and box, 1 M ions
    python -m benchmarks.bench_proxigram --full     # 100 M ions streamed in chunks; peak memory
    python -m benchmarks.bench_proxigram --ions 30000000 --peer-ions 0   # any count, ours only

The specimen: 180 spheres of radius 2.5 nm (icospheres, 1280 triangles each, 230,400 in all) on
a grid in a cube of (10 M / 40 nm⁻³)^(1/3) = 63 nm, ions uniform in the cube. Ours is the whole
:func:`compute_proxigram` (band, grid search, exact distances, signs, binning) with ±3 nm; the
peer is open3d ``RaycastingScene.compute_signed_distance`` (closest point + ray-parity sign) over
every ion, which is what a tool without a narrow band has to do. Both run in the same process,
one after the other, so that the ratios survive the noise of a shared machine; the load average
is printed before and after, and the process CPU time beside the wall time (on a loaded machine
the wall time is inflated by the other jobs, the CPU time much less).
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time

import numpy as np

from apt_filters.analysis.proxigram import compute_proxigram
from apt_filters.core.deps import open3d
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from benchmarks.results import ratio, write_results

RANGES = RangeTable([Range(26.5, 27.5, (("Al", 1),), "00AA00"), Range(55.0, 57.0, (("Fe", 1),), "FF0000")])
BOX = (10_000_000 / 40.0) ** (1 / 3)
GRID = (6, 6, 5)
RADIUS = 2.5


def sphere_mesh() -> TriMesh:
    """180 icospheres (1280 triangles each) on a grid filling the box; outward normals."""
    o3d = open3d()
    ico = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(3)
    v = np.asarray(ico.vertices)
    v = RADIUS * v / np.linalg.norm(v, axis=1, keepdims=True)
    f = np.asarray(ico.triangles)
    centers = np.stack(np.meshgrid(*[(np.arange(n) + 0.5) * BOX / n for n in GRID], indexing="ij"), -1).reshape(-1, 3)
    return TriMesh(np.concatenate([v + c for c in centers]),
                   np.concatenate([f + k * len(v) for k in range(len(centers))]))


def ion_chunks(n: int, chunk: int = 1 << 22, seed: int = 0):
    """``n`` uniform ions in the box, generated chunk by chunk (never all in memory)."""
    for k, start in enumerate(range(0, n, chunk)):
        rng = np.random.default_rng([seed, k])
        m = min(chunk, n - start)
        yield IonTable((rng.random((m, 3), dtype=np.float32) * np.float32(BOX)),
                       rng.choice(np.array([27.0, 56.0], np.float32), size=m))


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


INTRO = ('Specimen: 180 icospheres of radius 2.5 nm (1280 triangles each, 230,400 in all) on a 6 x 6 x 5 grid '
         'in a 63 nm cube; ions uniform in the cube (40 nm⁻³ at 10M), range ±3 nm, 0.1 nm bins. Ours = the '
         'whole `compute_proxigram` (block band, grid search for the exact closest triangle, pseudo-normal '
         'signs and rim test in one numba kernel, binning), ion generation included. Peer = open3d '
         '`RaycastingScene.compute_signed_distance` over every ion (what a tool without a narrow band must do; '
         'ray-parity signs, wrong on open meshes). Both run in one process, one after the other, on a shared '
         '2-core machine.')
"""What the results file says about the specimen and the peer, above the tables."""

TARGET_S = 15.0
"""Issue 7's target for 10 M ions on 2 cores."""


def timed(f, *args):
    """(wall s, CPU s of this process, result) of ``f(*args)``."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = f(*args)
    return time.perf_counter() - wall, time.process_time() - cpu, result


def run_ours(mesh: TriMesh, n: int):
    return compute_proxigram(ion_chunks(n), RANGES, mesh, max_distance=3.0)


def run_peer(mesh: TriMesh, n: int) -> None:
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)), o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    for part in ion_chunks(n, chunk=1 << 20):
        scene.compute_signed_distance(o3d.core.Tensor(part.positions))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = p.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="1 M ions")
    g.add_argument("--full", action="store_true", help="100 M ions in chunks (ours only; minutes)")
    g.add_argument("--ions", type=int, help="this many ions (the box stays that of 10 M ions)")
    p.add_argument("--peer-ions", type=int, default=None,
                   help="ions given to the peer (default: all; its time is scaled to all when fewer; 0: no peer)")
    args = p.parse_args(argv)
    n = args.ions or (1_000_000 if args.quick else 100_000_000 if args.full else 10_000_000)
    mesh = sphere_mesh()
    run_ours(mesh, 1000)  # compiles (or loads) the numba kernels first
    load = os.getloadavg()[0]
    wall, cpu, prox = timed(run_ours, mesh, n)
    peak = peak_rss_mb()
    band = prox.n_candidates / prox.n_ions
    in_range = int(prox.counts.sum() + prox.unranged.sum() + (0 if prox.rim_kept else prox.n_rim))
    rows = [("ours: whole proxigram (block band + grid search + pseudo-normal sign + binning)", wall, cpu)]
    if not args.full and args.peer_ions != 0:
        n_peer = min(n, args.peer_ions or n)
        w, c, _ = timed(run_peer, mesh, n_peer)
        rows.append((f"open3d compute_signed_distance, all ions{'' if n_peer == n else f' (run on {n_peer:,}, scaled)'}",
                     w * n / n_peer, c * n / n_peer))
    head = (f"{n:,} ions, {mesh.n_faces:,} triangles, ±3 nm; load average {load:.1f} -> {os.getloadavg()[0]:.1f} "
            f"on {os.cpu_count()} cores; {100 * band:.1f} % of ions in the narrow band, {100 * in_range / n:.1f} % "
            f"within ±3 nm; peak RSS after ours {peak:.0f} MB"
            f"; target {TARGET_S * n / 1e7:g} s (15 s per 10 M): ours / target = {wall / (TARGET_S * n / 1e7):.2f}")
    lines = ["| method | wall (s) | CPU (s) | ions/s (wall) | wall ratio to ours |", "|---|---:|---:|---:|---:|"]
    lines += [f"| {name} | {w:.1f} | {c:.1f} | {n / w:,.0f} | {w / wall:.2f} |" for name, w, c in rows]
    print("\n" + head + "\n\n" + "\n".join(lines))
    size = f"{n / 1e6:g}M ions, {mesh.n_faces:,} triangles, ±3 nm"
    summary = [("proxigram", f"{size}, wall (target: {TARGET_S * n / 1e7:g} s)", f"{wall:.1f} s",
                f"{rows[1][1]:.1f} s (open3d signed distance)" if len(rows) > 1 else "-",
                ratio(wall, rows[1][1]) if len(rows) > 1 else "-"),
               ("proxigram", f"{size}, peak RSS", f"{peak:.0f} MB", "-", "-")]
    cmd = " ".join(["python -m benchmarks.bench_proxigram", *(argv if argv is not None else sys.argv[1:])])
    # one section and two rows per ion count: the 10M run (with the peer) and the 100M run (ours only) coexist
    write_results("proxigram", "Proxigram: exact narrow-band signed distances", summary,
                  [f"## {size}\n\n`{cmd.strip()}`: {head}.\n\n" + "\n".join(lines)], intro=INTRO, merge=True)

if __name__ == "__main__":
    main()
