"""Remesher benchmark: ours vs pyacvd (ACVD clustering) vs pymeshlab isotropic explicit remeshing.

Run: ``/work/venv/bin/python -m benchmarks.bench_remesh [--quick] [--dc exact|eno]``. All three remesh the same
marching-cubes torus (about 200k triangles; 30k with ``--quick``) to the same target edge
length (1 voxel), side by side in one run; a second, sharp case (a box with a sphere carved
out, exact edges) checks feature survival by edge F1. ``--dc`` runs the issue's own inputs
instead: the analytic shapes contoured by our dual contouring, with edge F1 against the analytic
edges. Prints a markdown table; lengths in voxels.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import quality, remesh
from tests import remesh_shapes as shapes


def ours(mesh: TriMesh, edge: float) -> TriMesh:
    return remesh(mesh, edge_length=edge).mesh


def ours_bridged(mesh: TriMesh, edge: float) -> TriMesh:
    return remesh(mesh, edge_length=edge, bridge_gaps=True).mesh


def meshlab(mesh: TriMesh, edge: float) -> TriMesh:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(mesh.vertices, mesh.faces))
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(edge))
    m = ms.current_mesh()
    return TriMesh(m.vertex_matrix(), m.face_matrix())


def acvd(mesh: TriMesh, edge: float) -> TriMesh:
    import pyacvd
    import pyvista

    faces = np.hstack([np.full((mesh.n_faces, 1), 3), mesh.faces]).ravel()
    clus = pyacvd.Clustering(pyvista.PolyData(mesh.vertices, faces))
    clus.subdivide(3)
    clus.cluster(int(round(mesh.area() / (np.sqrt(3) / 2 * edge**2))))
    out = clus.create_mesh()
    return TriMesh(np.asarray(out.points), np.asarray(out.faces).reshape(-1, 4)[:, 1:])


METHODS = {"ours (CVT)": ours, "pyacvd": acvd, "pymeshlab isotropic": meshlab,
           "ours (CVT, --bridge-gaps)": ours_bridged}
MAX_INTERSECTION_FACES = 50_000  # open3d's self-intersection test is all-pairs: minutes at 200k


def row(name: str, mesh: TriMesh, out: TriMesh, seconds: float, base: float, sharp: bool, truth: str = "") -> str:
    q = quality.assess(out, mesh, 200_000, intersections=mesh.n_faces <= MAX_INTERSECTION_FACES)
    ref = quality.topology(mesh)
    topo_ok = (q.components, q.boundary_loops, q.genus) == (ref.components, ref.boundary_loops, ref.genus)
    f1 = ""
    if sharp:
        reference = quality.sample_edges(mesh.vertices, quality.feature_edges(mesh), 0.1)
        samples = quality.sample_edges(out.vertices, quality.feature_edges(out), 0.1)
        f1 = f"{quality.edge_f1(samples, reference, 0.1):.3f}"
    if truth:  # against the analytic shape: input -> output
        f1 = f"{shapes.truth_edge_f1(mesh, truth):.3f} -> {shapes.truth_edge_f1(out, truth):.3f}"
    return (f"| {name} | {seconds:.2f} | {seconds / base:.2f} | {q.faces} | {100 * (1 - q.frac_ge_30):.2f} | "
            f"{q.min_angle:.1f} | {q.mean_q:.3f} | {q.hausdorff:.3f} | {q.non_manifold_edges}/{q.non_manifold_vertices} | "
            f"{q.self_intersections if q.self_intersections >= 0 else 'not run'} | {'yes' if topo_ok else 'NO'} | {f1} |")


def bench(label: str, mesh: TriMesh, edge: float, sharp: bool, methods: list[str], truth: str = "") -> list[str]:
    lines = [f"\n**{label}**: {mesh.n_faces} input triangles, target edge {edge} voxel, load average "
             f"{os.getloadavg()[0]:.2f} at the start\n",
             "| method | time s | time / ours | triangles | % min angle < 30° | min angle ° | mean Q | "
             "Hausdorff (voxel) | non-manifold e/v | self-intersections | topology kept | edge F1 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    base = None
    for name in methods:
        method = METHODS[name]
        t = time.perf_counter()
        out = method(mesh, edge)
        seconds = time.perf_counter() - t
        base = base or seconds
        lines.append(row(name, mesh, out, seconds, base, sharp, truth))
        print(lines[-1], flush=True)
    return lines


def profile(mesh: TriMesh, edge: float, top: int) -> None:
    """Ours alone: wall time per phase, peak RSS and the ``top`` functions of cProfile by own time."""
    import cProfile
    import pstats
    import resource

    profiler = cProfile.Profile()
    t = time.perf_counter()
    result = profiler.runcall(remesh, mesh, edge_length=edge)
    wall = time.perf_counter() - t
    t = time.perf_counter()
    q = quality.assess(result.mesh, mesh, 200_000, intersections=mesh.n_faces <= MAX_INTERSECTION_FACES)
    phases = {**result.timings, "quality (assess)": time.perf_counter() - t}
    print(f"\n{mesh.n_faces} input triangles -> {result.mesh.n_faces}, {result.iterations} Lloyd steps, "
          f"remesh {wall:.2f} s (under cProfile), load {os.getloadavg()[0]:.2f}, peak RSS "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6:.2f} GB")
    print(f"mean Q {q.mean_q:.4f}, % < 30° {100 * (1 - q.frac_ge_30):.2f}, Hausdorff {q.hausdorff:.3f}\n")
    print("| phase | s |\n|---|---:|")
    for name, seconds in phases.items():
        print(f"| {name} | {seconds:.2f} |")
    pstats.Stats(profiler).sort_stats("tottime").print_stats(top)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 30k-triangle torus instead of 200k")
    parser.add_argument("--profile", action="store_true",
                        help="profile ours alone on the torus (phase wall times, cProfile) instead of the comparison")
    parser.add_argument("--without", action="append", default=[], choices=list(METHODS)[1:3],
                        help="leave a peer out (pyacvd takes minutes at 200k triangles); repeatable")
    parser.add_argument("--dc", choices=["exact", "eno"],
                        help="instead: the issue's dual-contouring meshes of the analytic shapes (1 nm voxels, "
                             "Hermite normals exact or ENO); edge F1 against the analytic edges, input -> output")
    args = parser.parse_args(argv)
    # the bridged variant is meant for dual contouring with estimated normals
    methods = [name for name in METHODS if name not in args.without
               and ("bridge" not in name or args.dc == "eno")]
    # imports first, so that no method's time holds a library's import (open3d alone takes seconds)
    import pyacvd  # noqa: F401
    import pymeshlab  # noqa: F401

    from apt_filters.core.deps import open3d

    open3d()
    if args.dc:
        lines = []
        for name in shapes.DC_SHAPES:
            mesh = shapes.dual_contoured(name, exact_normals=args.dc == "exact")
            lines += bench(f"{name}, dual contouring ({args.dc} normals)", mesh, 1.0, sharp=False, methods=methods,
                           truth=name if name in ("rotated_box", "box_minus_sphere", "cylinder") else "")
        print("\n".join(lines))
        return
    torus = shapes.torus(26.0, 10.0) if args.quick else shapes.torus(66.0, 27.0)
    if args.profile:
        profile(torus, 1.0, 25)
        return
    lines = bench("marching-cubes torus", torus, 1.0, sharp=False, methods=methods)
    lines += bench("box minus sphere (exact sharp edges, boolean slivers)", shapes.box_minus_sphere(), 1.0, sharp=True,
                   methods=methods)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
