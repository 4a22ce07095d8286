"""Cleaning time of each apt-filters chain on a ~1M-triangle mesh, beside the peers.

Run: ``python -m benchmarks.bench_meshlab [--quick]``. The mesh is a noisy icosphere
(subdivision 8: 1,310,720 triangles; ``--quick``: subdivision 6, 81,920) with small holes
punched in it, like an iso-surface open in places. For each chain it times, in one run:

- apt-filters: :func:`apply_chain` (TriMesh -> MeshSet, the chain, back to TriMesh);
- raw pymeshlab: the same filters called on a MeshSet that already holds the mesh
  (the difference is our conversion overhead);
- open3d (0.20) doing the nearest equivalent, where one exists.

Decimation also times :func:`apt_filters.meshlab.decimation.decimate` (fast-simplification).
Best of ``--repeat`` runs; the machine is shared, so compare ratios, not absolute times.
"""

from __future__ import annotations

import argparse
import platform
import time
from typing import Callable

import numpy as np
import pymeshlab

from apt_filters.core.deps import open3d
from apt_filters.core.mesh import TriMesh
from apt_filters.meshlab.bridge import to_meshset
from apt_filters.meshlab.chains import CHAINS, pymeshlab_args, apply_chain, resolve
from apt_filters.meshlab.decimation import decimate
from benchmarks.results import ratio, write_results


def make_mesh(subdiv: int, n_holes: int = 200, seed: int = 0) -> TriMesh:
    ms = pymeshlab.MeshSet()
    ms.create_sphere(subdiv=subdiv)
    m = ms.current_mesh()
    v, f = m.vertex_matrix() * 50.0, m.face_matrix().astype(np.int64)
    rng = np.random.default_rng(seed)
    v = v + rng.normal(0, 0.02, v.shape)
    holes = rng.choice(len(v), n_holes, replace=False)
    f = f[~np.isin(f, holes).any(axis=1)]  # drop the 1-ring of each hole centre
    return TriMesh(v, f, {"value": v[:, 2].copy()})


def best(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def raw_pymeshlab(mesh: TriMesh, name: str) -> Callable[[], None]:
    ms, _ = to_meshset(mesh)

    def run() -> None:
        ms.add_mesh(ms.mesh(0), "copy")  # a fresh copy of the input each time (not timed apart)
        for step in CHAINS[name].steps:
            values = resolve(step.params, ms.current_mesh().bounding_box().diagonal())
            getattr(ms, step.filter)(**pymeshlab_args(values, step))
        ms.delete_current_mesh()
    return run


def open3d_peer(mesh: TriMesh, name: str) -> Callable[[], object] | None:
    o3d = open3d()

    def legacy() -> "o3d.geometry.TriangleMesh":
        return o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                         o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
    if name == "clean":
        def run():
            m = legacy()
            m.remove_duplicated_vertices()
            m.remove_duplicated_triangles()
            m.remove_degenerate_triangles()
            labels, counts, _ = m.cluster_connected_triangles()
            m.remove_triangles_by_mask(np.asarray(counts)[np.asarray(labels)] < 10)
            m.remove_non_manifold_edges()
            m.orient_triangles()
            m.remove_unreferenced_vertices()
        return run
    if name == "close":
        return lambda: o3d.t.geometry.TriangleMesh.from_legacy(legacy()).fill_holes(hole_size=1e9)
    if name == "smooth":
        return lambda: legacy().filter_smooth_taubin(number_of_iterations=10, lambda_filter=0.5, mu=-0.53)
    if name == "decimate":
        return lambda: legacy().simplify_quadric_decimation(mesh.n_faces // 2)
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="82k triangles instead of 1.3M")
    parser.add_argument("--repeat", type=int, default=None, help="runs per timing (best is kept)")
    parser.add_argument("--chains", default=",".join(CHAINS),
                        help="comma-separated chains to time (the full run of all takes ~5 min on a busy machine)")
    args = parser.parse_args(argv)
    chains = args.chains.split(",")
    unknown = set(chains) - set(CHAINS)
    if unknown:
        parser.error(f"unknown chains {sorted(unknown)}; known: {', '.join(CHAINS)}")
    repeat = args.repeat or (3 if args.quick else 1)
    mesh = make_mesh(6 if args.quick else 8)
    head = (f"mesh: {mesh.n_faces:,} triangles, {mesh.n_vertices:,} vertices, "
            f"{len(mesh.boundary_edges()):,} boundary edges; best of {repeat}; "
            f"{platform.processor() or platform.machine()}, shared machine (2 cores, other jobs running)")
    print(head + "\n")
    lines = ["| chain | apt-filters (s) | raw pymeshlab (s) | overhead ratio | open3d (s) | apt-filters / open3d |",
             "|---|---:|---:|---:|---:|---:|"]
    print("\n".join(lines))
    size = f"{mesh.n_faces / 1e6:.2g}M-triangle mesh"
    rows = []
    ours_by_chain, peer_by_chain = {}, {}
    for name in chains:
        ours = ours_by_chain[name] = best(lambda: apply_chain(mesh, name), repeat)
        raw = best(raw_pymeshlab(mesh, name), repeat)
        peer_fn = open3d_peer(mesh, name)
        peer = peer_by_chain[name] = best(peer_fn, repeat) if peer_fn else float("nan")
        peer_txt = f"{peer:.2f}" if peer_fn else "—"
        ratio_txt = f"{ours / peer:.2f}" if peer_fn else "—"
        lines.append(f"| {name} | {ours:.2f} | {raw:.2f} | {ours / raw:.2f} | {peer_txt} | {ratio_txt} |")
        print(lines[-1])
        if name == "clean":
            rows.append(("meshlab", f"wrapper overhead, clean chain, {size}", f"{ours:.2f} s",
                         f"{raw:.2f} s (raw pymeshlab)", ratio(ours, raw)))
        if name in ("clean", "smooth"):
            rows.append(("meshlab", f"{name} chain, {size}", f"{ours:.2f} s", f"{peer:.2f} s (open3d)", ratio(ours, peer)))
    sections = [f"## Chain times, {size}: {', '.join(chains)}\n\n"
                f"`python -m benchmarks.bench_meshlab{' --quick' if args.quick else ''} --chains {','.join(chains)}`; "
                + head + ". Compare the ratios, measured in the same run.\n\n" + "\n".join(lines)]
    if "decimate" in chains:
        fast = best(lambda: decimate(mesh, 0.5), repeat)
        ours = ours_by_chain["decimate"]
        o3d_s = peer_by_chain["decimate"]
        text = (f"Decimation to 50 %: fast-simplification (`decimate()`, boundary kept) {fast:.2f} s, MeshLab quadric "
                f"chain {ours:.2f} s: MeshLab / fast-simplification = {ours / fast:.2f}.")
        print("\n" + text)
        sections[0] += "\n\n" + text
        rows.append(("meshlab", f"decimate to 50 %, {size}", f"{fast:.2f} s (fast-simplification)",
                     f"{o3d_s:.2f} s (open3d quadric)", ratio(fast, o3d_s)))
    # the full run is made in parts (--chains): each part keeps the other parts' rows and tables
    write_results("meshlab", "MeshLab chains: cleaning time on a 1M-triangle mesh", rows, sections, merge=True)
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
