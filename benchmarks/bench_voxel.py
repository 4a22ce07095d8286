"""Voxelization speed and agreement: ours (square / sawtooth / gaussian) against np.bincount and APAV.

Run: ``python -m benchmarks.bench_voxel [--quick | --full]``.

Synthetic ions fill a 60 × 60 × 200 nm box (8 single-atom species, 1 nm voxels): 10 M by
default, 1 M with ``--quick``; ``--full`` writes 100 M ions (in detection order) to a temporary
POS file and streams it memory-mapped in chunks of 5 M (peak memory = fields + one chunk),
skipping APAV, which needs every ion in memory.

Rows (each timed as the best of ``--repeat`` rounds, a round running every in-memory row in turn,
all side by side in one process):
- ``numpy bincount square``: the plain numpy square kernel (nearest voxel, one bincount over
  species × voxels), given the species index, as the peer for the scatter;
- ``ours ranging (MzLookup)``: our bin-table ranging (what ``voxelize`` uses) beside ``RangeTable.ion_index``;
- ``ours <kernel> scatter``: our block-sparse scatter given the same species index, on 1 thread
  (the default) and on 2 threads;
- ``ours <kernel> voxelize``: the whole ``voxelize`` call (ranging, scatter, second pass, fields)
  with its default thread count (one per available core, within the memory budget), and on 1 thread;
- ``apav RangedGrid``: APAV 1.4's IVAS-scheme gaussian on the same ions (ranging included),
  compared with ``ours gaussian voxelize``; agreement checked where APAV's grid is not affected
  by its reflecting edges.
Peak memory is measured separately with tracemalloc (numpy allocations), excluding the input.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import sys
import tempfile
import time
import tracemalloc
import warnings

import numpy as np

from apt_filters.io import IonTable, Range, RangeTable, iter_ion_chunks
from apt_filters.voxel import Grid, kernel_reach, voxelize
from apt_filters.voxel.fields import decomposition
from apt_filters.voxel.grid import available_cores, scatter_threads
from apt_filters.voxel.ranging import MzLookup
from apt_filters.voxel.transfer import BlockAccumulator, second_pass_radius, second_pass_sigma
from benchmarks.results import ratio, write_results

BOX = np.array([60.0, 60.0, 200.0])
ELEMENTS = ("Fe", "Cr", "Ni", "Al", "Ti", "Mo", "Si", "C")
VOXEL, DELOC = 1.0, (3.0, 3.0, 1.5)

INTRO = ('Data: uniform synthetic ions in a 60 × 60 × 200 nm box in detection order (z falling), 8 single-atom '
         "species, 1 nm voxels, grid 71 × 71 × 207 with the gaussian kernel's padding; gaussian delocalization "
         '(3, 3, 1.5) nm. "scatter" rows: the transfer-function loop given the species index (like the '
         'bincount peer); "voxelize" rows: the whole call (ranging with `MzLookup`, scatter, gaussian second '
         'pass, fields). Peak memory: tracemalloc peak of numpy allocations during the call (input excluded). '
         'The 2 cores are shared with other jobs: compare ratios taken in the same run.')
"""What the results file says about the data and rows, above the tables."""


def bench_ranges() -> RangeTable:
    return RangeTable([Range(10.0 * k + 9.5, 10.0 * k + 10.5, ((el, 1),)) for k, el in enumerate(ELEMENTS)])


def synthetic(n: int, seed: int, slab: tuple[int, int] = (0, 1)) -> IonTable:
    """Uniform ions strictly inside the box (a non-integer lower corner, see APAV's grid quirk).

    In detection order, as reconstructions store them: z falls from the top of the box down.
    ``slab = (k, n_slabs)``: only the k-th of n_slabs equal z slabs, counted from the top (the
    k-th chunk of a file in detection order).
    """
    rng = np.random.default_rng(seed)
    k, n_slabs = slab
    unit = rng.random((n, 3), dtype=np.float32)
    unit[:, 2] = (unit[:, 2] + (n_slabs - 1 - k)) / n_slabs
    pos = (unit * (BOX - 0.5) + 0.25).astype(np.float32)
    pos = pos[np.argsort(-pos[:, 2], kind="stable")]
    mz = (10.0 * rng.integers(1, len(ELEMENTS) + 1, n) + rng.uniform(-0.4, 0.4, n)).astype(np.float32)
    return IonTable(pos, mz)


def bincount_square(positions: np.ndarray, species: np.ndarray, grid: Grid, n_species: int) -> np.ndarray:
    """The plain numpy square kernel: nearest voxel, one bincount over (species, voxel)."""
    idx = np.rint((positions - np.asarray(grid.origin, np.float32)) / np.float32(grid.voxel)).astype(np.int64)
    flat = (species * grid.shape[0] + idx[:, 0]) * grid.shape[1] + idx[:, 1]
    flat = flat * grid.shape[2] + idx[:, 2]
    return np.bincount(flat, minlength=n_species * grid.n_voxels).reshape((n_species,) + grid.shape)


def best_time(fn, repeat: int) -> tuple[float, float]:
    """Best (wall, CPU) seconds of ``repeat`` runs; CPU time is less disturbed by other jobs
    for our single-threaded loops, wall time is what counts for APAV's two OpenMP threads."""
    return best_times([fn], repeat)[0]


def best_times(fns: list, repeat: int) -> list[tuple[float, float]]:
    """Best (wall, CPU) seconds of each function over ``repeat`` rounds that run them all in turn,
    so that a change of the machine's load during the run falls on every row alike."""
    wall = np.full(len(fns), np.inf)
    cpu = np.full(len(fns), np.inf)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            gc.collect()
            t, c = time.perf_counter(), time.process_time()
            fn()
            wall[k] = min(wall[k], time.perf_counter() - t)
            cpu[k] = min(cpu[k], time.process_time() - c)
    return list(zip(wall.tolist(), cpu.tolist()))


def timed_peak(fn) -> tuple[np.ndarray, int]:
    """(wall, CPU) seconds and tracemalloc peak of one run (tracing adds little to runs of a few large arrays)."""
    gc.collect()
    tracemalloc.start()
    t, c = time.perf_counter(), time.process_time()
    fn()
    times = np.array([time.perf_counter() - t, time.process_time() - c])
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return times, peak


def peak_bytes(fn) -> int:
    gc.collect()
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


def apav_run(ions: IonTable, rt: RangeTable):
    import apav
    from apav.analysis.spatial import RangedGrid

    coll = apav.RangeCollection([apav.Range(r.ion, (r.lower, r.upper)) for r in rt.ranges])
    roi = apav.Roi(ions.positions, ions.mz)  # float32 arrays: APAV converts per range
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        return RangedGrid(roi, coll, bin_width=VOXEL, delocalization=np.asarray(DELOC))


def apav_agreement(ions: IonTable, rt: RangeTable, ref) -> float:
    """Max relative difference of element counts over APAV's interior (beyond its edge effects)."""
    reach = 1 + second_pass_radius(second_pass_sigma(VOXEL, DELOC))
    x, y, z = ref.centers[0][:, 0, 0], ref.centers[1][0, :, 0], ref.centers[2][0, 0, :]
    n = np.array([len(x), len(y), len(z)])
    grid = Grid(tuple(np.array([x[0], y[0], z[0]]) - reach * VOXEL), VOXEL, tuple(n + 2 * reach + 1))
    ours = voxelize(ions, rt, grid=grid, kernel="gaussian", delocalization=DELOC)
    core = tuple(slice(r + 1, m - r - 1) for r, m in zip(reach, n))
    shifted = tuple(slice(s.start + r, s.stop + r) for s, r in zip(core, reach))
    worst = 0.0
    for el, counts in ref._elem_counts.items():
        a = counts[core]
        b = ours.counts[el.symbol].dense()[shifted]
        worst = max(worst, float(np.max(np.abs(b - a) / a)))
    return worst


def write_stream(path: str, n: int, chunk: int, seed: int) -> None:
    """A POS file (big-endian float32 x, y, z, m/z) of ``n`` ions in detection order, written chunk by chunk."""
    n_chunks = -(-n // chunk)
    with open(path, "wb") as fh:
        for k in range(n_chunks):
            c = synthetic(min(chunk, n - k * chunk), seed + k, (k, n_chunks))
            fh.write(np.column_stack([c.positions, c.mz]).astype(">f4").tobytes())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    size = ap.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="1 M ions")
    size.add_argument("--full", action="store_true", help="100 M ions streamed in chunks (no APAV)")
    ap.add_argument("--repeat", type=int, default=3, help="timing repeats (best is reported)")
    ap.add_argument("--no-apav", action="store_true", help="skip APAV")
    args = ap.parse_args(argv)
    rt = bench_ranges()
    names, rows = decomposition(rt, "elements", keep_unranged=False)
    grid = Grid.covering(np.zeros(3), BOX, VOXEL, kernel_reach("gaussian", VOXEL, DELOC))

    # warm the JIT (cached on disk after the first run) outside every timing
    warm = synthetic(1000, 1)
    for kernel in ("square", "sawtooth", "gaussian"):
        voxelize(warm, rt, grid=grid, kernel=kernel)

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores "
          f"({available_cores()} available), load average {os.getloadavg()[0]:.1f} at the start "
          "(shared with other jobs: compare ratios, not absolute times)")
    print(f"voxelize's default scatter threads here: {scatter_threads(grid, len(names), None)}")
    results = []
    if args.full:
        n, chunk = 100_000_000, 5_000_000
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "full.pos")
            write_stream(path, n, chunk, 100)
            print(f"{n / 1e6:.0f} M ions in a memory-mapped POS file, streamed in chunks of {chunk / 1e6:.0f} M, "
                  f"grid {grid.shape}, 8 species; peak memory traced in the timed run")

            def run_bincount():
                acc = np.zeros((len(ELEMENTS),) + grid.shape, dtype=np.int64)
                for c in iter_ion_chunks(path, chunk):
                    acc += bincount_square(c.positions, rt.ion_index(c.mz).astype(np.int64), grid, len(ELEMENTS))

            def read_only():
                for _ in iter_ion_chunks(path, chunk):
                    pass

            t_read = np.array(best_time(read_only, 1))
            results.append(("numpy bincount square (incl. ranging)", np.array(best_time(run_bincount, 1)) - t_read,
                            None))
            for kernel in ("square", "sawtooth", "gaussian"):
                fn = lambda k=kernel: voxelize(iter_ion_chunks(path, chunk), rt, grid=grid, kernel=k)  # noqa: E731
                t, peak = timed_peak(fn)
                results.append((f"ours {kernel} voxelize (streamed)", t - t_read, peak))
        print(f"(reading the chunks, {t_read[0]:.1f} s wall, subtracted from each time)")
    else:
        n = 1_000_000 if args.quick else 10_000_000
        ions = synthetic(n, 7)
        print(f"{n / 1e6:.0f} M ions, box {BOX.tolist()} nm, grid {grid.shape}, 8 species")
        species = rt.ion_index(ions.mz).astype(np.int64)
        row = rt.ion_index(ions.mz) + 1  # int32, as voxelize passes it

        def scatter(kernel, threads=1):
            acc = BlockAccumulator(grid, kernel, rows, len(names), DELOC, threads)
            acc.add(ions.positions, row)
            return acc.result()

        lookup = MzLookup.from_ranges(rt)
        rows_timed = [  # (name, function, trace its peak memory)
            ("numpy bincount square", lambda: bincount_square(ions.positions, species, grid, len(ELEMENTS)), True),
            ("ranging (RangeTable.ion_index)", lambda: rt.ion_index(ions.mz), False),
            ("ours ranging (MzLookup)", lambda: lookup.rows_of(ions.mz), False),
        ]
        for kernel in ("square", "sawtooth", "gaussian"):
            rows_timed.append((f"ours {kernel} scatter", lambda k=kernel: scatter(k), True))
            rows_timed.append((f"ours {kernel} scatter, 2 threads", lambda k=kernel: scatter(k, 2), False))
        for kernel in ("square", "sawtooth", "gaussian"):
            rows_timed.append((f"ours {kernel} voxelize", lambda k=kernel: voxelize(ions, rt, grid=grid, kernel=k),
                               True))
            rows_timed.append((f"ours {kernel} voxelize, 1 thread",
                               lambda k=kernel: voxelize(ions, rt, grid=grid, kernel=k, threads=1), False))
        times = best_times([fn for _, fn, _ in rows_timed], args.repeat)
        for (name, fn, traced), t in zip(rows_timed, times):
            results.append((name, t, peak_bytes(fn) if traced else None))
        if not args.no_apav:
            try:
                import apav  # noqa: F401
            except ImportError:
                print("apav not installed: its row is skipped")
            else:
                holder = {}
                t = best_time(lambda: holder.update(ref=apav_run(ions, rt)), 1)
                peak = peak_bytes(lambda: apav_run(ions, rt))
                results.append(("apav RangedGrid (gaussian)", t, peak))
                agreement = apav_agreement(ions, rt, holder["ref"])
                print(f"agreement with APAV (max relative difference, interior voxels): {agreement:.2e}")

    load_end = os.getloadavg()[0]
    print(f"load average {load_end:.1f} at the end")
    base_wall, base_cpu = results[0][1]
    times = {name: t for name, t, _ in results}
    peaks = {name: p for name, _, p in results}
    lines = ["| method | wall (s) | CPU (s) | M ions/s (wall) | speed vs bincount (wall) | (CPU) | peak memory (MB) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, (wall, cpu), peak in results:
        mem = f"{peak / 1e6:.0f}" if peak is not None else "-"
        lines.append(f"| {name} | {wall:.3f} | {cpu:.3f} | {n / wall / 1e6:.1f} | {base_wall / wall:.2f} | "
                     f"{base_cpu / cpu:.2f} | {mem} |")
    notes = []
    if "apav RangedGrid (gaussian)" in times:
        faster = times["apav RangedGrid (gaussian)"][0] / times["ours gaussian voxelize"][0]
        notes.append(f"ours gaussian voxelize is {faster:.1f}x faster than APAV RangedGrid (wall); agreement with "
                     f"APAV (max relative difference, interior voxels): {agreement:.2e}")
    key = "voxelize (streamed)" if args.full else "voxelize"
    for col, label in ((0, "wall"), (1, "CPU")):
        notes.append(f"gaussian / sawtooth time ({label}): "
                     f"{times[f'ours gaussian {key}'][col] / times[f'ours sawtooth {key}'][col]:.2f}")
    print("\n" + "\n".join(lines) + "\n\n" + "\n".join(notes))
    size = f"{n / 1e6:g}M ions"
    gauss, square, peer = times[f"ours gaussian {key}"][0], times[f"ours square {key}"][0], base_wall
    summary = [("voxel", f"square voxelization, {size}, wall", f"{square:.3f} s", f"{peer:.3f} s (numpy bincount)",
                ratio(square, peer))]
    if "apav RangedGrid (gaussian)" in times:
        apav_s = times["apav RangedGrid (gaussian)"][0]
        summary.append(("voxel", f"gaussian voxelization, {size}, wall", f"{gauss:.3f} s",
                        f"{apav_s:.3f} s (APAV RangedGrid)", ratio(gauss, apav_s)))
    else:
        summary.append(("voxel", f"gaussian voxelization, {size}, wall", f"{gauss:.3f} s",
                        f"{peer:.3f} s (numpy bincount, square)", ratio(gauss, peer)))
    if args.full:
        summary.append(("voxel", f"gaussian voxelization, {size} streamed, peak memory beyond the mapped file",
                        f"{peaks[f'ours gaussian {key}'] / 1e6:.0f} MB", "-", "-"))
    cmd = "python -m benchmarks.bench_voxel " + " ".join(argv if argv is not None else sys.argv[1:])
    # one section per ion count: the in-memory 10M run (with APAV) and the streamed 100M run coexist
    write_results("voxel", "Voxelization (`apt_filters.voxel`)", summary,
                  [f"## {size}\n\n`{cmd.strip()}`, best of {args.repeat}; load average {load_end:.1f} at the end "
                   "on a shared 2-core machine: compare ratios taken in the same run.\n\n"
                   + "\n".join(lines) + "\n\n" + "\n".join(f"- {x}" for x in notes)], intro=INTRO, merge=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
