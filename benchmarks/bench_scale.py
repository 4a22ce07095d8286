"""Scale: the streaming steps on 10^7-10^9 ions, their thread scaling and peak memory, and ``apt-filters run``.

Run: ``python -m benchmarks.bench_scale --ions 1e7 [--threads 1,2] [--run] [--big 1e9]``; writes
``benchmarks/results_scale.md`` (:func:`benchmarks.results.write_results`, merged with the previous file:
the summary rows and sections of sizes not measured again are kept) after every section.

1. A synthetic POS file of N ions is written chunk by chunk (any N; 16 bytes per ion on disk,
   one chunk in memory): an Al matrix (96 % Al, 1 % Cu, 3 % unranged background) in a box
   D × D × 4D nm at 40 ions/nm³, with Cu-rich spheres (radius 3 nm, 40 % Cu) on a 15 nm
   lattice, in detection order (z falling, as reconstructions store them), and a range file.
2. Streaming steps, each in a fresh child process (so that its peak RSS is its own), once per
   thread count:

   - ``read``: one pass of :func:`~apt_filters.io.iter_ion_chunks` over the memory-mapped file
     (byte-swapping conversion and finiteness check);
   - ``read + ranging``: the same with every chunk ranged (:class:`~apt_filters.voxel.ranging.MzLookup`);
   - ``voxelize square`` / ``voxelize gaussian``: :func:`~apt_filters.voxel.voxelize` from the
     file's chunks on the covering grid (1 nm voxels, gaussian 3 × 3 × 1.5 nm), elements Al and Cu.

   Each row prints the wall time, M ions/s, the speed-up over one thread, the CPU time over the
   wall time (how many cores the step kept busy: on a shared machine the wall-clock speed-up
   also depends on the cores the others leave free), M ions per CPU second (what the step costs,
   whatever the load) and the child's peak RSS, also per ion.
   ``--big N`` repeats the steps on a second file of N ions at the largest thread count only.
3. Marching cubes on dense 128³ and 256³ fields (smoothed noise: active cells everywhere; the
   contouring benchmark's box minus sphere) beside scikit-image's Lewiner marching cubes and VTK's
   flying edges, same process, round-robin, best of 5 wall and CPU times (``--no-mc`` skips it).
4. ``--run``: ``apt-filters run`` on the N-ion file (Cu at 20 at.%, ``--memory-budget`` passed on; ``--run-only``:
   this section alone),
   wall and CPU time, and each step's wall and CPU time and peak RSS (from its report); then the
   same run with a budget nothing fits, which must be refused up front (exit 2, one line).
   ``--baseline DIR``: the same run with the code of another commit too (``DIR`` holds its source,
   e.g. ``git archive main | tar -x -C DIR``), first, each after an untimed run on a 200,000-ion file
   (numba's caches warm); its times beside this tree's, and whether every output file is the same
   byte for byte (``report.json`` without its steps' times and peaks, ``report.html`` left out: both
   hold the times).

Pure numpy / numba / scipy except the optional skimage peer and ``--run`` (pymeshlab, open3d).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.results import ratio, write_results

ROOT = Path(__file__).resolve().parents[1]
DENSITY = 40.0  # ions / nm³
SPACING, RADIUS = 15.0, 3.0  # Cu-rich spheres: lattice spacing and radius, nm
FRACTIONS = {"matrix": (0.96, 0.01), "sphere": (0.57, 0.40)}  # (Al, Cu); the rest unranged
GEN_CHUNK = 1 << 22
TITLE = "Scale: streaming steps, thread scaling, marching cubes (`benchmarks/bench_scale.py`)"
STEPS = ("read", "read + ranging", "voxelize square", "voxelize gaussian", "voxelize gaussian, chunks in memory")
RRNG = """[Ions]
Number=2
Ion1=Al
Ion2=Cu
[Ranges]
Number=2
Range1=26.5000 27.5000 Vol:0.01661 Al:1 Color:33FFFF
Range2=62.5000 63.5000 Vol:0.01181 Cu:1 Color:FF7700
"""


def box_of(n: int) -> np.ndarray:
    """(3,) box edges (nm) of the N-ion specimen: D × D × 4D at DENSITY."""
    d = (n / DENSITY / 4.0) ** (1.0 / 3.0)
    return np.array([d, d, 4.0 * d])


def _chunk_ions(n: int, box: np.ndarray, z_hi: float, z_lo: float, seed: int) -> np.ndarray:
    """(n, 4) big-endian float32 POS records of ``n`` ions with z in (z_lo, z_hi], z falling."""
    rng = np.random.default_rng(seed)
    rec = np.empty((n, 4), dtype=">f4")
    pos = rng.random((n, 3))
    pos[:, 2] = np.sort(pos[:, 2])[::-1]
    pos *= [box[0], box[1], z_hi - z_lo]
    pos[:, 2] += z_lo
    centre = (np.floor(pos / SPACING) + 0.5) * SPACING
    inside = np.sum((pos - centre) ** 2, axis=1) < RADIUS**2
    u = rng.random(n)
    al = np.where(inside, FRACTIONS["sphere"][0], FRACTIONS["matrix"][0])
    cu = al + np.where(inside, FRACTIONS["sphere"][1], FRACTIONS["matrix"][1])
    mz = np.where(u < al, 27.0, np.where(u < cu, 63.0, 0.0)) + rng.uniform(-0.3, 0.3, n)
    background = u >= cu
    mz[background] = rng.uniform(1.0, 100.0, int(background.sum()))
    rec[:, :3] = pos
    rec[:, 3] = mz
    return rec


def generate(path: Path, n: int, threads: int) -> float:
    """Write the N-ion POS (chunks in detection order) and its RRNG; returns seconds."""
    from concurrent.futures import ThreadPoolExecutor

    start = time.perf_counter()
    box = box_of(n)
    n_chunks = -(-n // GEN_CHUNK)
    counts = [min(GEN_CHUNK, n - k * GEN_CHUNK) for k in range(n_chunks)]
    tops = box[2] * (1 - np.concatenate([[0], np.cumsum(counts)]) / n)
    with open(path, "wb") as fh, ThreadPoolExecutor(threads) as pool:
        jobs = [pool.submit(_chunk_ions, counts[k], box, tops[k], tops[k + 1], k) for k in range(min(threads, n_chunks))]
        for k in range(n_chunks):
            rec = jobs[k].result()
            if k + threads < n_chunks:
                jobs.append(pool.submit(_chunk_ions, counts[k + threads], box, tops[k + threads],
                                        tops[k + threads + 1], k + threads))
            fh.write(rec.tobytes())
            jobs[k] = None
    path.with_suffix(".rrng").write_text(RRNG)
    return time.perf_counter() - start


def step(name: str, pos: str, threads: int) -> dict:
    """Run one streaming step in this process; returns its wall time and this process's peak RSS."""
    from apt_filters.io import iter_ion_chunks, read_ranges
    from apt_filters.io.mapped import PAGE  # noqa: F401  (imported here so that compile time is not timed)
    from apt_filters.voxel import Grid, kernel_reach, voxelize
    from apt_filters.voxel.ranging import MzLookup

    ranges = read_ranges(str(Path(pos).with_suffix(".rrng")))
    n = os.path.getsize(pos) // 16
    box = box_of(n)
    lookup = MzLookup.from_ranges(ranges)
    lookup.rows_of(np.zeros(4, np.float32))  # compile outside the timing
    kernel = "square" if "square" in name else "gaussian"
    if name.startswith("voxelize"):  # compile and fill the page cache outside the timing
        small = Grid.covering(np.zeros(3), np.ones(3), 1.0, kernel_reach(kernel))
        from apt_filters.io import IonTable
        voxelize(IonTable(np.full((2, 3), 0.5, np.float32), np.float32([27, 63])), ranges, grid=small,
                 kernel=kernel, threads=1)
    held = list(iter_ion_chunks(pos)) if name.endswith("in memory") else None  # read before the timing
    cpu, start = time.process_time(), time.perf_counter()
    if name == "read":
        total = sum(len(c) for c in iter_ion_chunks(pos, threads=threads))
        assert total == n
    elif name == "read + ranging":
        total = sum(int(np.count_nonzero(lookup.rows_of(c.mz, threads))) for c in iter_ion_chunks(pos, threads=threads))
    else:
        grid = Grid.covering(np.zeros(3), box, 1.0, kernel_reach(kernel))
        chunks = held if held is not None else iter_ion_chunks(pos, threads=threads)
        voxelize(chunks, ranges, grid=grid, kernel=kernel, threads=threads)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    return {"wall": wall, "cpu": cpu, "rss_mib": peak_rss_mib()}


def peak_rss_mib() -> float:
    """This process's resident high-water mark (VmHWM: unlike ru_maxrss it does not carry the forking
    parent's over the exec)."""
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmHWM")) / 1024


def in_child(name: str, pos: Path, threads: int) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.bench_scale", "--child", name, str(pos), str(threads)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode:
        return {"error": (done.stderr.strip().splitlines() or ["exit %d" % done.returncode])[-1]}
    return json.loads(done.stdout.strip().splitlines()[-1])


def streaming_table(pos: Path, n: int, thread_counts: list[int]) -> tuple[list[str], list[tuple]]:
    """The streaming steps' table and its summary rows: gaussian voxelization at the most threads against
    reading the file alone, and its peak RSS."""
    rows = [f"## Streaming steps, {n:,} ions", "", f"{n:,} ions ({os.path.getsize(pos) / 1e9:.1f} GB POS), box {' × '.join(f'{v:.0f}' for v in box_of(n))} nm:",
            "", "| step | threads | wall (s) | M ions/s | × 1 thread | CPU / wall | M ions per CPU s | peak RSS (MiB) | "
            "bytes per ion at the peak |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    last = {}
    for name in STEPS if n * 16 <= 4e9 else STEPS[:-1]:  # holding the chunks: only while they fit easily
        base = None
        for t in thread_counts if not name.endswith("in memory") else thread_counts[-1:]:
            r = in_child(name, pos, t)
            if "error" in r:
                rows.append(f"| {name} | {t} | failed: {r['error']} | | | | | | |")
                print(rows[-1], flush=True)
                continue
            base = r["wall"] if t == 1 else base
            speedup = f"{base / r['wall']:.2f}" if base else "–"
            rows.append(f"| {name} | {t} | {r['wall']:.2f} | {n / r['wall'] / 1e6:.1f} | {speedup} | "
                        f"{r['cpu'] / r['wall']:.2f} | {n / r['cpu'] / 1e6:.1f} | {r['rss_mib']:,.0f} | "
                        f"{r['rss_mib'] * 2**20 / n:.1f} |")
            print(rows[-1], flush=True)
            last[name] = (t, r)
    summary = []
    if "voxelize gaussian" in last and "read" in last:
        (t, g), (_, read) = last["voxelize gaussian"], last["read"]
        summary = [("scale", f"gaussian voxelization streamed from a {n / 1e6:g}M-ion POS, {t} threads, CPU",
                    f"{g['cpu']:.2f} s ({n / g['cpu'] / 1e6:.1f} M ions per CPU s)", f"{read['cpu']:.2f} s (reading alone)",
                    ratio(g["cpu"], read["cpu"])),
                   ("scale", f"gaussian voxelization streamed from a {n / 1e6:g}M-ion POS, peak RSS",
                    f"{g['rss_mib']:,.0f} MiB", "-", "-")]
    return rows, summary


def dense_fields(n: int) -> dict[str, tuple[np.ndarray, float]]:
    from scipy.ndimage import gaussian_filter

    from apt_filters.truth.shapes import benchmark_shapes, grid

    noise = gaussian_filter(np.random.default_rng(0).standard_normal((n, n, n)), 1.5)
    return {"smoothed noise": (noise, 0.0), "box minus sphere": (grid(benchmark_shapes()["box_minus_sphere"], n)[0], 0.0)}


def mc_table(sizes=(128, 256), repeats: int = 5) -> tuple[list[str], list[tuple]]:
    """Ours, scikit-image (Lewiner) and VTK's flying edges on the same fields, round-robin over the
    repeats (each sees the same spells of load), best wall and best CPU time of each; the table and
    its summary rows (the largest dense noise field against scikit-image, CPU and wall)."""
    from apt_filters.contour import marching_cubes
    from apt_filters.contour.cells import find_active_cells, prepare_field
    from apt_filters.core.mesh import Topology
    from benchmarks.bench_contour import vtk_flying_edges

    peers = {}
    try:
        from skimage.measure import marching_cubes as sk
        peers["skimage"] = lambda v, iso: sk(v, iso, method="lewiner")
    except ImportError:
        pass
    try:
        import vtk  # noqa: F401
        peers["VTK"] = lambda v, iso: vtk_flying_edges(v, iso, np.ones(3), np.zeros(3))
    except ImportError:
        pass
    marching_cubes(np.random.default_rng(1).random((8, 8, 8)), 0.5)  # compile outside the timing
    rows = [f"## Marching cubes on dense fields, ours beside scikit-image (Lewiner) and VTK (flying edges), "
            f"same process, round-robin, best of {repeats}", "",
            "\"ours\" is the whole `marching_cubes` call (component labels included, which the peers do not "
            "compute); \"scan\" is `find_active_cells`, \"labels\" `Topology.components` (CPU seconds). "
            "CPU counts every thread of the process: on a loaded machine it is the figure to read.", "",
            "| field | size | active cells | faces | ours MC wall (s) | ours CPU (s) | of it: scan | of it: labels | "
            "skimage wall (s) | skimage CPU (s) | VTK wall (s) | ours / skimage wall | ours / skimage CPU | ours / VTK wall |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    summary = []
    for n in sizes:
        for name, (values, iso) in dense_fields(n).items():
            field = prepare_field(values, iso, 1.0, 0.0, None, False)
            mesh = marching_cubes(values, iso)
            runs = {"ours": lambda: marching_cubes(values, iso), "scan": lambda: find_active_cells(field),
                    "labels": lambda: Topology.of(mesh.faces, mesh.n_vertices).components}
            runs |= {peer: (lambda fn=fn: fn(values, iso)) for peer, fn in peers.items()}
            best = {k: (np.inf, np.inf) for k in runs}
            for _ in range(repeats):
                for k, fn in runs.items():
                    wall, cpu = _timed(fn)
                    best[k] = (min(best[k][0], wall), min(best[k][1], cpu))
            sk_w, sk_c = best.get("skimage", (np.nan, np.nan))
            vtk_w = best.get("VTK", (np.nan, np.nan))[0]
            (o_w, o_c), active = best["ours"], len(find_active_cells(field).cell)
            rows.append(f"| {name} | {n}³ | {active:,} | {mesh.n_faces:,} | {o_w:.3f} | {o_c:.3f} | {best['scan'][1]:.3f} | "
                        f"{best['labels'][1]:.3f} | {sk_w:.3f} | {sk_c:.3f} | {vtk_w:.3f} | {o_w / sk_w:.2f} | "
                        f"{o_c / sk_c:.2f} | {o_w / vtk_w:.2f} |")
            print(rows[-1], flush=True)
            if name == "smoothed noise" and n == max(sizes):
                what = f"marching cubes, smoothed noise {n}³ (every cell active; target <= 1.0x)"
                summary = [("scale", f"{what}, CPU", f"{o_c:.2f} s", f"{sk_c:.2f} s (skimage Lewiner)", ratio(o_c, sk_c)),
                           ("scale", f"{what}, wall", f"{o_w:.2f} s", f"{sk_w:.2f} s (skimage Lewiner)", ratio(o_w, sk_w))]
    return rows, summary


def _timed(fn) -> tuple[float, float]:
    """(wall, CPU) seconds of one call; CPU counts every thread of this process."""
    cpu, wall = time.process_time(), time.perf_counter()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def _run(pos: Path, out: Path, budget: float | None, root: Path = ROOT) -> tuple[float, float, dict]:
    """``apt-filters run`` of the code in ``root`` on ``pos`` into ``out``: wall and CPU seconds (the process and its
    children, every thread) and its report."""
    cmd = [sys.executable, "-m", "apt_filters", "run", str(pos), "-r", str(pos.with_suffix(".rrng")),
           "-o", str(out), "--species", "Cu", "--iso", "0.2", "-q", "--force"]
    cmd += ["--memory-budget", str(budget)] if budget else []
    t, before = time.perf_counter(), os.times()
    subprocess.run(cmd, cwd=root, check=True, env={**os.environ, "PYTHONPATH": str(root)})
    wall, after = time.perf_counter() - t, os.times()
    cpu = after.children_user + after.children_system - before.children_user - before.children_system
    return wall, cpu, json.loads((out / "report.json").read_text())


def _same_outputs(a: Path, b: Path) -> list[str]:
    """Files of two run folders that differ (or exist in one only), comparing every file byte for byte but
    ``report.json`` without its steps (times, peaks) and ``report.html`` (which shows them)."""
    names = {p.relative_to(a) for p in a.rglob("*") if p.is_file()} | {p.relative_to(b) for p in b.rglob("*")
                                                                       if p.is_file()}
    differ = []
    for name in sorted(names - {Path("report.html")}):
        x, y = a / name, b / name
        if not (x.is_file() and y.is_file()):
            differ.append(str(name))
        elif name == Path("report.json"):
            if ({k: v for k, v in json.loads(x.read_text()).items() if k != "steps"}
                    != {k: v for k, v in json.loads(y.read_text()).items() if k != "steps"}):
                differ.append(str(name))
        elif x.read_bytes() != y.read_bytes():
            differ.append(str(name))
    return differ


def run_table(pos: Path, n: int, work: Path, budget: float | None,
              baseline: Path | None = None) -> tuple[list[str], list[tuple]]:
    """``apt-filters run``'s table (each step's time and peak RSS) and its summary row; with ``baseline``, the run
    of that source tree too (first), its times beside these and the files whose outputs differ."""
    times = {}
    if baseline is not None:
        small = work / "warm.pos"
        generate(small, 200_000, 1)
        for root in (baseline, ROOT):
            _run(small, work / "warm", budget, root)  # compiles what numba has not cached: untimed
        times["baseline"] = _run(pos, work / "baseline", budget, baseline.resolve())
    wall, cpu, report = times["this"] = _run(pos, work / "run", budget)
    peak = max(s["peak_mib"] for s in report["steps"])
    rows = [f"## `apt-filters run`, {n:,} ions", "",
            f"`apt-filters run` (Cu 20 at.%{f', memory budget {budget:g} GB' if budget else ''}), {n:,} ions: "
            f"{wall:.1f} s wall, {cpu:.1f} s CPU (the process and its children, every thread), "
            f"peak RSS {peak:,.0f} MiB.", ""]
    if baseline is None:
        rows += ["| step | wall (s) | CPU (s) | peak (MiB) | bytes per ion at the peak |", "|---|---:|---:|---:|---:|"]
        rows += [f"| {s['step']} | {s['seconds']:.1f} | {s.get('cpu_seconds', float('nan')):.1f} | "
                 f"{s['peak_mib']:,.0f} | {s['peak_mib'] * 2**20 / n:.0f} |" for s in report["steps"]]
    else:
        b_wall, b_cpu, b_report = times["baseline"]
        differ = _same_outputs(work / "baseline", work / "run")
        rows += [f"Baseline (`{baseline}`), same file, run just before: {b_wall:.1f} s wall, {b_cpu:.1f} s CPU, "
                 f"peak RSS {max(s['peak_mib'] for s in b_report['steps']):,.0f} MiB. Outputs: "
                 + ("every file the same byte for byte (report.json without its times)" if not differ
                    else "differ in " + ", ".join(differ)) + ".", "",
                 "| step | wall (s) | CPU (s) | baseline CPU (s) | peak (MiB) | baseline peak (MiB) |",
                 "|---|---:|---:|---:|---:|---:|"]
        base = {s["step"]: s for s in b_report["steps"]}
        for s in report["steps"]:
            b = base.get(s["step"], {})
            rows.append(f"| {s['step']} | {s['seconds']:.1f} | {s.get('cpu_seconds', float('nan')):.1f} | "
                        f"{b.get('cpu_seconds', float('nan')):.1f} | {s['peak_mib']:,.0f} | "
                        f"{b.get('peak_mib', float('nan')):,.0f} |")
    print("\n".join(rows), flush=True)
    refusal = refused(pos, work)
    rows += ["", f"Refusal: the same run with a {REFUSED_BUDGET:g} GB budget (not even the fields fit) {refusal}."]
    print(rows[-1], flush=True)
    mapped = " (ions memory-mapped)" if "memory-mapped" in report["steps"][0]["summary"] else ""
    return rows, [("scale", f"`apt-filters run`, {n / 1e6:g}M ions{mapped}, wall / CPU / peak RSS (target: 25 s for 10M)",
                   f"{wall:.0f} s / {cpu:.0f} s / {peak:,.0f} MiB", "-", "-")]


REFUSED_BUDGET = 0.001
"""GB: a budget no run fits, for the refusal check."""


def refused(pos: Path, work: Path) -> str:
    """Words on how ``apt-filters run`` with :data:`REFUSED_BUDGET` ends: it must refuse up front, exit 2 with
    one line on stderr and no output folder (raises AssertionError otherwise)."""
    out = work / "refused"
    cmd = [sys.executable, "-m", "apt_filters", "run", str(pos), "-r", str(pos.with_suffix(".rrng")), "-o", str(out),
           "--species", "Cu", "--iso", "0.2", "-q", "--memory-budget", str(REFUSED_BUDGET)]
    t = time.perf_counter()
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and not out.exists(), (done.returncode, done.stderr)
    return f"exits 2 after {time.perf_counter() - t:.1f} s with one line: `{lines[0]}`"


def machine() -> str:
    from apt_filters.core.threads import available_cores

    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return (f"{platform.machine()}, {available_cores()} cores available, {mem:.0f} GiB, "
            f"load average {os.getloadavg()[0]:.1f} at the start, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ions", type=float, default=1e7, help="ions of the main file (default 1e7)")
    parser.add_argument("--threads", default=None, help="comma-separated thread counts (default 1, 2, 4, ... cores)")
    parser.add_argument("--big", type=float, default=0, help="also a file of this many ions, largest thread count only")
    parser.add_argument("--no-mc", action="store_true", help="skip the marching-cubes table")
    parser.add_argument("--run", action="store_true", help="also time `apt-filters run` on the main file")
    parser.add_argument("--run-only", action="store_true",
                        help="time `apt-filters run` on the main file and nothing else (implies --run and --no-mc)")
    parser.add_argument("--memory-budget", type=float, help="GB, for --run (default: the run's own)")
    parser.add_argument("--baseline", type=Path, help="with --run: the source tree of another commit, run too")
    parser.add_argument("--work", help="folder for the generated files (default: a temporary one, removed)")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        name, pos, threads = args.child
        print(json.dumps(step(name, pos, int(threads))))
        return 0
    from apt_filters.core.threads import available_cores

    cores = available_cores()
    counts = ([int(t) for t in args.threads.split(",")] if args.threads else
              sorted({1 << k for k in range(cores.bit_length()) if 1 << k <= cores} | {cores}))
    intro = f"Machine: {machine()}."
    print(intro, flush=True)
    sections, summary = [], []

    def section(table: tuple[list[str], list[tuple]]) -> None:
        sections.append("\n".join(table[0]))
        summary.extend(table[1])
        # after every section: a run stopped part-way keeps what it measured
        write_results("scale", TITLE, summary, sections, intro=intro, merge=True)

    if args.run_only:
        args.run, args.no_mc, args.big = True, True, 0
    if not args.no_mc:
        section(mc_table())
    with tempfile.TemporaryDirectory(dir=args.work) as tmp:
        work = Path(tmp)
        for n, counts_n in ((int(args.ions), counts), (int(args.big), counts[-1:])):
            if not n:
                continue
            pos = work / "scale.pos"
            gen = generate(pos, n, cores)
            print(f"generated {n:,} ions in {gen:.1f} s", flush=True)
            if not args.run_only:
                section(streaming_table(pos, n, counts_n))
            if args.run and n == int(args.ions):
                section(run_table(pos, n, work, args.memory_budget, args.baseline))
            pos.unlink()
    return 0


if __name__ == "__main__":
    sys.exit(main())
