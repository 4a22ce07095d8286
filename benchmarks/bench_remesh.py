"""Remesher benchmark: ours vs pymeshlab's isotropic explicit remeshing vs pyacvd, side by side.

Run: ``.venv/bin/python -m benchmarks.bench_remesh [--quick] [--only NAME ...] [--seeds N]``. Every method
remeshes the same surface to the same target edge; each run is a spawned child process, so that its
peak memory (VmHWM above the resident size before the call, Linux; per input and per output face) and time (wall, and CPU of all its
threads: on a shared machine the one to compare) are its own. The child first runs the method once on the same surface (imports
and the compiled code its paths reach loaded: code, not state, which a warm-up on a small sphere left to load inside the
measurement, about 1 MiB per kernel) and hands the memory its allocator kept back to the system (``malloc_trim``), so
the measured call finds none of that run's memory resident. Surfaces
(``tests/remesh_shapes.py``; lengths in nm = voxels):

- ``pipeline``: the pipeline's own cleaned surface of a synthetic specimen (``small`` seed 3: a
  6 nm gamma-prime-like cube and a 3 nm sphere; marching cubes, refinement against the ions, clean
  chain), edge 0.5 (the pipeline's default, half a voxel);
- ``thin plate`` (1.6 thick), ``2 nm spheres``, ``tilted sheet`` (an open, curved interface
  across a conical tip), ``gyroid`` (bicontinuous, open on the cube's faces), and the last two
  with the pipeline refinement's bumps (Gaussian, sd 0.25 / 0.1 along the normals, then split in
  four), all at edge 0.5;
- ``box-sphere-plate``: the issue's test mesh, a box minus a sphere with a thin plate, scaled to a
  unit box, at edge 0.04 (sharp edges: feature-edge F1 against the input's);
- ``2M ions``: the pipeline's cleaned surface of the ``gamma-prime`` preset lengthened to 2 million
  ions (two rotated cubes, two 3 nm spheres), edge 0.5: the whole remesh step of such a run;
- ``demo``: the surface ``apt-filters demo`` hands its remesh step (``default`` seed 0: two cubes,
  three spheres, a rod), edge 0.5;
- ``zoo``: the surfaces ``apt-filters run`` with its defaults hands its remesh step on the zoo's first
  dev draws of the cuboid, plate, rod, sphere and open families (:func:`zoo_surface`), at half a voxel.

Measures, against the input: two-sided Hausdorff distance (output -> input and input -> output, as
fractions of the edge; from every vertex, edge midpoint and face centroid of one mesh to the
other), mean output edge length over the target, area change, topology (components, boundary loops, genus as pymeshlab counts them),
feature-edge F1 against the input's creases (dihedral over 40°, samples every edge/10 matched within edge/10: it
counts every crease of the input, a refined cube edge's two or three 40-60° bends as two or three), feature-edge F1
against the true sharp edges where the surface's true shape is known (``truth F1``: the synthetic specimens'
objects from their ``truth.json``, the box-sphere-plate's analytic solid; :func:`apt_filters.truth.metrics.truth_edge_f1`,
at voxel h = 2 edges: edge points are samples 78.5° apart within 0.3 h, matched within 0.3 h = 0.6 edge, so
a bend spread over a few narrow faces is one edge; mean ± standard error over 5 draws of the random samples;
true objects without a sharp edge, spheres and capsules, are left out and the count of objects scored given;
the input's own figure on its row), smallest angle,
% of triangles under 30°; for ours also the components given back unchanged by the check (``--seeds N``: also
counted, untimed, with seeds 0 .. N-1: components near the tolerance pass with one seed and fail
with another). Prints a markdown table, then ours stage by stage (CPU time and numpy bytes held / at the peak per input face).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
import time

import numpy as np

from apt_filters.core.mesh import TriMesh
from apt_filters.remesh import quality, remesh, verify
from apt_filters.truth.metrics import truth_edge_f1
from benchmarks.results import ratio, write_results
from tests import remesh_shapes as shapes


def ours(mesh: TriMesh, edge: float) -> tuple[TriMesh, str]:
    result = remesh(mesh, edge_length=edge)
    return result.mesh, f"{result.kept_input}/{len(result.checks)}"


def given_back(mesh: TriMesh, edge: float, seeds: int) -> list:
    """Components ours gives back with each seed 0 .. ``seeds`` - 1: a component within a few
    hundredths of a nm of the check's tolerance passes with one seed and fails with another, so a
    change of the remesher is measured over seeds, not by one run."""
    return [remesh(mesh, edge_length=edge, seed=seed).kept_input for seed in range(seeds)]


def meshlab(mesh: TriMesh, edge: float) -> tuple[TriMesh, str]:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(mesh.vertices, mesh.faces))
    ms.meshing_isotropic_explicit_remeshing(targetlen=pymeshlab.PureValue(edge))
    m = ms.current_mesh()
    return TriMesh(m.vertex_matrix(), m.face_matrix()), ""


def acvd(mesh: TriMesh, edge: float) -> tuple[TriMesh, str]:
    import pyacvd
    import pyvista

    faces = np.hstack([np.full((mesh.n_faces, 1), 3), mesh.faces]).ravel()
    clus = pyacvd.Clustering(pyvista.PolyData(mesh.vertices, faces))
    clus.subdivide(3)
    clus.cluster(int(round(mesh.area() / (np.sqrt(3) / 2 * edge**2))))
    out = clus.create_mesh()
    return TriMesh(np.asarray(out.points), np.asarray(out.faces).reshape(-1, 4)[:, 1:]), ""


METHODS = {"ours (CVT)": ours, "pymeshlab isotropic": meshlab, "pyacvd": acvd}


def _status(key: str) -> int:
    """A /proc/self/status entry in bytes."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0


def _child(conn, name: str, vertices: np.ndarray, faces: np.ndarray, edge: float) -> None:
    method = METHODS[name]
    # imports and the compiled code this surface runs loaded first (a smaller surface left kernels its paths
    # never reached to load inside the measurement: code, not state, about 1 MiB each); then the memory the
    # allocator kept from that run handed back, so the measured run finds none of it
    method(TriMesh(vertices.copy(), faces.copy()), edge)
    gc.collect()
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    with open("/proc/self/clear_refs", "w") as f:  # reset the peak (VmHWM) to the current size
        f.write("5")
    base = _status("VmRSS")
    t, cpu = time.perf_counter(), time.process_time()
    out, note = method(TriMesh(vertices, faces), edge)
    seconds, cpu = time.perf_counter() - t, time.process_time() - cpu
    conn.send((out.vertices, out.faces, note, seconds, cpu, _status("VmHWM") - base))
    conn.close()


def measured(name: str, mesh: TriMesh, edge: float) -> tuple[TriMesh, str, float, float, int]:
    """Method ``name`` on ``mesh`` in a fresh (spawned) process: its output, note, wall and CPU seconds
    (all its threads) and peak bytes above the resident size before the call (the libraries loaded
    and warmed up first).
    Spawned, not forked: a fork of a process that has run OpenMP code (the pipeline) is unsafe."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, conn = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(conn, name, mesh.vertices, mesh.faces, edge))
    proc.start()
    conn.close()
    try:
        v, f, note, seconds, cpu, peak = parent.recv()
    except EOFError:
        raise RuntimeError(f"{name} died (exit code {proc.join() or proc.exitcode})") from None
    proc.join()
    return TriMesh(v, f), note, seconds, cpu, peak


# The remesher's stages as (module, attribute the remesh looks up, label); the stage table wraps each.
STAGES = (("apt_filters.remesh.features", "detect", "features"), ("apt_filters.remesh.remesh", "refine", "samples"),
          ("apt_filters.remesh.remesh", "curvature_density", "density"),
          ("apt_filters.remesh.cvt", "initialise", "generators"), ("apt_filters.remesh.cvt", "sample_groups", "groups"),
          ("apt_filters.remesh.cvt", "lloyd", "Lloyd"), ("apt_filters.remesh.extract", "dual_faces", "extraction"),
          ("apt_filters.remesh.cvt", "connect_cells", "connect cells"),
          ("apt_filters.remesh.repair", "repair", "repair"),
          ("apt_filters.remesh.remesh", "_optimise", "flips, relaxation"),
          ("apt_filters.remesh.optimize", "centre_on_samples", "centring"),
          ("apt_filters.remesh.optimize", "undo_crossings", "undo crossings"),
          ("apt_filters.remesh.verify", "check_components", "check"))


def _stage_child(conn, vertices: np.ndarray, faces: np.ndarray, edge: float) -> None:
    """Ours with every stage of :data:`STAGES` wrapped: its CPU seconds and the numpy bytes (``tracemalloc``)
    held when it starts and at its peak, above what was held before the call."""
    import importlib
    import tracemalloc

    ours(TriMesh(vertices.copy(), faces.copy()), edge)  # as in _child: the compiled code loaded first
    figures = {}
    base = [0]

    def wrapped(fn, label):
        def call(*args, **kwargs):
            held = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            cpu = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                f = figures.setdefault(label, [0.0, 0, 0])
                f[0] += time.process_time() - cpu
                f[1] = max(f[1], held - base[0])
                f[2] = max(f[2], tracemalloc.get_traced_memory()[1] - base[0])
        return call

    for module, name, label in STAGES:
        module = importlib.import_module(module)
        setattr(module, name, wrapped(getattr(module, name), label))
    tracemalloc.start()
    base[0] = tracemalloc.get_traced_memory()[0]
    ours(TriMesh(vertices, faces), edge)
    # each stage resets the peak: the whole call's is the largest of theirs and of what came after the last
    whole = max([tracemalloc.get_traced_memory()[1] - base[0]] + [f[2] for f in figures.values()])
    conn.send((figures, whole))
    conn.close()


def stages(mesh: TriMesh, edge: float) -> tuple[dict, int]:
    """Per-stage figures of ours on ``mesh`` (:func:`_stage_child`, in a spawned process) and the whole
    call's traced peak (bytes)."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, conn = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_stage_child, args=(conn, mesh.vertices, mesh.faces, edge))
    proc.start()
    conn.close()
    out = parent.recv()
    proc.join()
    return out


def one_way(a: TriMesh, b: TriMesh, edge: float) -> float:
    """Farthest vertex, edge midpoint or face centroid of ``a`` from ``b``."""
    return float(verify.farthest(a, b, np.zeros(a.n_faces, np.int64), 1, edge)[0])


def feature_f1(mesh: TriMesh, out: TriMesh, edge: float) -> float:
    spacing = 0.1 * edge
    reference = quality.sample_edges(mesh.vertices, quality.feature_edges(mesh), spacing)
    ours_ = quality.sample_edges(out.vertices, quality.feature_edges(out), spacing)
    return quality.edge_f1(ours_, reference, spacing)


TRUTH_SEEDS = 5
"""Sampling seeds the truth F1 is averaged over: one draw of the random samples moves it by 0.004-0.015 (sd)."""


def truth_f1(mesh: TriMesh, truth: list | None, edge: float) -> tuple[float | None, str]:
    """:func:`~apt_filters.truth.metrics.truth_edge_f1` of ``mesh`` against the true objects ``truth`` at voxel
    2 ``edge`` (the pipeline's edge is half a voxel), the mean over sampling seeds 0 .. ``TRUTH_SEEDS`` - 1, and
    its table cell (mean ± standard error): blank where the truth is unknown, the count of sharp objects scored,
    or that there is no (sharp) true object."""
    if truth is None:
        return None, ""
    if not truth:  # an open interface: a half-space, no object
        return None, "no true object"
    runs = [truth_edge_f1(mesh, truth, 2 * edge, seed) for seed in range(TRUTH_SEEDS)]
    scored = runs[0][1]
    if not scored:
        return None, f"no sharp edge ({len(truth)} objects)"
    f1 = np.array([f for f, _ in runs])
    return float(f1.mean()), (f"{f1.mean():.3f} ± {f1.std(ddof=1) / np.sqrt(len(f1)):.3f} "
                              f"({len(scored)} of {len(truth)})")


def mean_edge(mesh: TriMesh) -> float:
    """Mean length of ``mesh``'s edges, each counted once (nm)."""
    ends = np.unique(np.sort(mesh.edges(), axis=1), axis=0)
    return float(np.linalg.norm(mesh.vertices[ends[:, 0]] - mesh.vertices[ends[:, 1]], axis=1).mean())


def row(name: str, mesh: TriMesh, edge: float, sharp: bool, truth: list | None) -> tuple[str, dict]:
    """One method on one surface: the table row and its figures."""
    from apt_filters.contour.metrics import face_quality

    out, note, seconds, cpu, peak = measured(name, mesh, edge)
    angles = face_quality(out)[0].min(axis=1)
    before, after = quality.topology(mesh), quality.topology(out)
    same = (after.components, after.boundary_loops, after.genus, after.non_manifold_edges) == \
        (before.components, before.boundary_loops, before.genus, 0)
    topo = f"{after.components}/{after.boundary_loops}/{after.genus}" + ("" if same else " **changed**")
    f1 = f"{feature_f1(mesh, out, edge):.3f}" if sharp else ""
    true_f1, true_cell = truth_f1(out, truth, edge)
    fig = {"seconds": seconds, "cpu": cpu, "bytes": peak / mesh.n_faces, "out_bytes": peak / max(out.n_faces, 1),
           "hausdorff": max(one_way(out, mesh, edge), one_way(mesh, out, edge)) / edge,
           "under30": 100 * np.mean(angles < 30.0), "kept": int(note.split("/")[0]) if note else 0,
           "edge": mean_edge(out) / edge, "truth_f1": true_f1}
    line = (f"|  | {name} | {seconds:.2f} | {cpu:.2f} | {peak / 2**20:.0f} | {peak / mesh.n_faces:.0f} | "
            f"{fig['out_bytes']:.0f} | {out.n_faces} | {fig['edge']:.2f} | "
            f"{one_way(out, mesh, edge) / edge:.3f} | {one_way(mesh, out, edge) / edge:.3f} | "
            f"{100 * (out.area() / mesh.area() - 1):+.2f} | {topo} | {f1} | {true_cell} | {angles.min():.1f} | "
            f"{fig['under30']:.2f} | {note} |")
    return line, fig


ZOO = (("cuboid", 0), ("plate", 0), ("rod", 0), ("sphere", 0), ("open", 0))
"""Zoo draws (:mod:`apt_filters.synth.zoo`, dev split) whose pipeline surfaces are remeshed too."""


def zoo_surface(family: str, seed: int, folder=None) -> tuple[TriMesh, float]:
    """The surface `apt-filters run` hands its remesh step on zoo draw ``family`` ``seed`` (the iso-value a user
    would give, every option at its default; contour, segregants, specks, refinement, clean chain) and the
    step's edge (half a voxel); cached in ``folder``."""
    import tempfile
    from pathlib import Path

    from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
    from apt_filters.pipeline.surface import finished_surface
    from benchmarks.bench_zoo import run_fields, specimen

    cache = Path(folder or tempfile.gettempdir()) / f"remesh_bench_zoo_{family}_{seed}.npz"
    if not cache.exists():
        sp, species, iso, _ = specimen(family, seed)
        config = PipelineConfig()
        config.remesh.method = "none"
        fields, mask, basis = run_fields(sp, config)
        mesh, _ = finished_surface(fields, mask, sp.ions, sp.ranges, SurfaceConfig(species, iso), config=config,
                                   basis=basis)
        np.savez(cache, vertices=mesh.vertices, faces=mesh.faces, edge=fields.grid.voxel / 2)
    with np.load(cache) as f:
        return TriMesh(f["vertices"], f["faces"]), float(f["edge"])


def zoo_truth(family: str, seed: int) -> list:
    """The true objects of zoo draw ``family`` ``seed`` whose surfaces :func:`zoo_surface` contours
    (:func:`~apt_filters.truth.specimen.iso_shapes` of its truth, built without drawing the ions)."""
    from apt_filters.synth.generate import build_truth
    from apt_filters.synth.zoo import zoo_specimen
    from apt_filters.truth.specimen import iso_shapes
    from benchmarks.bench_zoo import iso_surface

    spec = zoo_specimen(family, seed)
    truth = build_truth(spec, seed)[0]
    return iso_shapes(truth, *iso_surface(spec, truth))


def surfaces(quick: bool) -> list:
    """(kind, mesh, edge, sharp, truth) of every benchmark surface: ``sharp`` scores feature F1 against the input's
    creases; ``truth``, the true objects (:mod:`apt_filters.synth.shapes`) where known, against theirs."""
    gyroid = shapes.gyroid(half=8.0) if quick else shapes.gyroid()
    out = [("pipeline: small seed 3 (cube + sphere, refined)", shapes.pipeline_surface(), 0.5, True,
            shapes.pipeline_truth()),
           ("demo: default seed 0 (apt-filters demo)", shapes.pipeline_surface("default", 0), 0.5, True,
            shapes.pipeline_truth("default", 0)),
           ("thin plate 1.6", shapes.thin_plate(), 0.5, False, None),
           ("2 nm spheres x 8", shapes.small_spheres(), 0.5, False, None),
           ("tilted sheet (open)", shapes.tilted_sheet(), 0.5, False, None),
           ("tilted sheet, bumps 0.25", shapes.bumpy(shapes.tilted_sheet(), 0.25), 0.5, False, None),
           ("gyroid (bicontinuous)", gyroid, 0.5, False, None),
           ("gyroid, bumps 0.1", shapes.bumpy(shapes.gyroid(half=8.0), 0.1), 0.5, False, None),
           ("box-sphere-plate", shapes.box_minus_sphere_plate(0.5 if quick else 0.25), 0.04, True,
            [shapes.box_minus_sphere_plate_shape()])]
    for family, seed in ZOO:
        mesh, edge = zoo_surface(family, seed)
        out.append((f"zoo {family} {seed} (pipeline)", mesh, edge, family == "cuboid", zoo_truth(family, seed)))
    if not quick:
        out.append(("2M ions: gamma-prime, 2,000,000 ions (refined)",
                    shapes.pipeline_surface("gamma-prime", 3, ions=2_000_000), 0.5, True,
                    shapes.pipeline_truth("gamma-prime", 3, ions=2_000_000)))
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller gyroid and plate mesh")
    parser.add_argument("--only", nargs="*", default=None, help="surfaces whose kind starts with one of these")
    parser.add_argument("--without", action="append", default=[], choices=list(METHODS)[1:],
                        help="leave a peer out; repeatable")
    parser.add_argument("--seeds", type=int, default=1,
                        help="also count ours' components given back with seeds 0 .. N-1 (untimed)")
    args = parser.parse_args(argv)
    lines = ["| surface | method | time s | CPU s | peak MiB | peak bytes / input face | peak bytes / output face | faces | "
             "mean edge / target | Hausdorff out->in (edge) | in->out (edge) | area % | components/loops/genus | "
             "feature F1 | truth F1 (objects scored) | min angle ° | % < 30° | components kept |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|"]
    load = os.getloadavg()[0]
    print("\n".join(lines), flush=True)
    figures = []  # (kind, input faces, method, figures)
    labels = [label for _, _, label in STAGES]
    stage_lines = ["| surface | whole call | " + " | ".join(labels) + " |", "|---|" + "---:|" * (len(labels) + 1)]
    for kind, mesh, edge, sharp, truth in surfaces(args.quick):
        if args.only and not any(kind.startswith(o) for o in args.only):
            continue
        topo = quality.topology(mesh)
        lines.append(f"| {kind}: {mesh.n_faces} faces, edge {edge} | input | | | | | | {mesh.n_faces} | {mean_edge(mesh) / edge:.2f} | | | | "
                     f"{topo.components}/{topo.boundary_loops}/{topo.genus} | | {truth_f1(mesh, truth, edge)[1]} | | | |")
        print(lines[-1], flush=True)
        for name in METHODS:
            if name not in args.without:
                line, fig = row(name, mesh, edge, sharp, truth)
                if name == "ours (CVT)" and args.seeds > 1:
                    fig["kept_seeds"] = given_back(mesh, edge, args.seeds)
                    line = line[:-2] + f"; seeds 0-{args.seeds - 1}: {','.join(map(str, fig['kept_seeds']))} |"
                lines.append(line)
                figures.append((kind, mesh.n_faces, name, fig))
                print(line, flush=True)
        per_stage, whole = stages(mesh, edge)
        cells = [f"{per_stage[label][0]:.2f} s, {per_stage[label][1] / mesh.n_faces:,.0f} / "
                 f"{per_stage[label][2] / mesh.n_faces:,.0f} B" if label in per_stage else "" for label in labels]
        stage_lines.append(f"| {kind.split(':')[0]} ({mesh.n_faces} faces) | {whole / mesh.n_faces:,.0f} B | "
                           + " | ".join(cells) + " |")
        print(stage_lines[-1], flush=True)
    write(figures, lines, load, stage_lines)


def write(figures: list, lines: list, load: float, stage_lines: list) -> None:
    """results_remesh.md: the summary (ours against pymeshlab) and the table."""
    by = {(kind, n): f for kind, _, n, f in figures}
    kinds = list(dict.fromkeys(kind for kind, _, _, _ in figures))
    pairs = [(by[k, "ours (CVT)"], by[k, "pymeshlab isotropic"]) for k in kinds
             if (k, "ours (CVT)") in by and (k, "pymeshlab isotropic") in by]
    rows = []
    if pairs:
        remeshed = [o for o, _ in pairs if o["kept"] == 0]
        kept = sum(o["kept"] for o, _ in pairs)
        worst = max((o["hausdorff"] for o in remeshed), default=float("nan"))
        peer = max(p["hausdorff"] for _, p in pairs)
        rows.append(("remesh", f"worst two-sided Hausdorff of surfaces remeshed whole (edge; target 0.25); "
                               f"{kept} components given back", f"{worst:.3f}", f"{peer:.3f}", ratio(worst, peer)))
        for key, what in (("cpu", "CPU time (all threads)"), ("seconds", "wall time")):
            times = [o[key] / p[key] for o, p in pairs]
            rows.append(("remesh", f"{what} on the same surface, {len(pairs)} surfaces (target <= pymeshlab); "
                                   f"ours faster on {sum(t <= 1 for t in times)}",
                         f"{sum(o[key] for o, _ in pairs):.1f} s in all",
                         f"{sum(p[key] for _, p in pairs):.1f} s in all", f"{min(times):.2f}-{max(times):.2f}"))
        spread = [o["kept_seeds"] for o, _ in pairs if "kept_seeds" in o]
        if spread:
            rows.append(("remesh", f"components given back over {len(spread[0])} seeds, {len(spread)} surfaces "
                                   "(target 0)", f"{sum(map(sum, spread))}", "-", "-"))
        scored = [(o["truth_f1"], p["truth_f1"]) for o, p in pairs if o["truth_f1"] is not None]
        if scored:
            rows.append(("remesh", f"feature F1 against the true sharp edges (truth F1, mean of {TRUTH_SEEDS} sample "
                                   f"draws), {len(scored)} surfaces in table order (against the input's creases: in "
                                   "the table); last column ours - peer",
                         ", ".join(f"{o:.3f}" for o, _ in scored), ", ".join(f"{p:.3f}" for _, p in scored),
                         f"{min(o - p for o, p in scored):+.3f} to {max(o - p for o, p in scored):+.3f}"))
        ours_e, peer_e = [o["edge"] for o, _ in pairs], [p["edge"] for _, p in pairs]
        rows.append(("remesh", "mean output edge / target edge (ours shrink where the surface bends, to stay "
                               "within the Hausdorff tolerance)", f"{min(ours_e):.2f}-{max(ours_e):.2f}",
                     f"{min(peer_e):.2f}-{max(peer_e):.2f}", "-"))
        for key, what in (("bytes", "input face (target 200 B)"), ("out_bytes", "output face")):
            ours_b, peer_b = [o[key] for o, _ in pairs], [p[key] for _, p in pairs]
            rows.append(("remesh", f"peak memory per {what}", f"{min(ours_b):,.0f}-{max(ours_b):,.0f} B",
                         f"{min(peer_b):,.0f}-{max(peer_b):,.0f} B", "-"))
        big = [k for k in kinds if k.startswith("2M ions") and (k, "pymeshlab isotropic") in by]
        if big:
            o, p = by[big[0], "ours (CVT)"], by[big[0], "pymeshlab isotropic"]
            rows.append(("remesh", "whole remesh step, pipeline surfaces of a 2M-ion specimen (CPU)",
                         f"{o['cpu']:.1f} s", f"{p['cpu']:.1f} s", ratio(o["cpu"], p["cpu"])))
    intro = __doc__.split("\n\n", 1)[1].strip()
    section = (f"## Ours, pymeshlab's isotropic explicit remeshing and pyacvd\n\nOne run, load average {load:.2f} at "
               f"the start (2 shared cores: compare within a surface; on a loaded machine wall time follows the "
               f"load of the moment, CPU time does not).\n\n" + "\n".join(lines))
    staged = ("## Ours stage by stage\n\nEach stage's CPU seconds, then the numpy bytes per input face held when it "
              "starts / at its peak (``tracemalloc``, above what was held before the call; compiled kernels' own "
              "arrays are not traced), in a separate run of ours; the whole call's traced peak first.\n\n"
              + "\n".join(stage_lines))
    print(write_results("remesh", "benchmarks/bench_remesh.py results", rows, [section, staged], intro=intro))

if __name__ == "__main__":
    main()
