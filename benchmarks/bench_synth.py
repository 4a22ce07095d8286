"""Speed and memory of the synthetic specimen generator.

    /work/venv/bin/python -m benchmarks.bench_synth [--quick] [--large N]

There is no peer generator to race; the reference ("floor") is the least any generator of the
same number of ions must do: draw uniform positions and m/z with numpy and write them as POS.
Our generator does that plus the composition field, species, blur, spectrum, truth and meshes.
Each case runs in a fresh process so that its peak RSS is its own.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.results import ratio, write_results


def _floor(n: int, out: Path) -> None:
    rng = np.random.default_rng(0)
    with open(out / "floor.pos", "wb") as fh:
        for start in range(0, n, 1 << 20):
            m = min(1 << 20, n - start)
            block = np.empty((m, 4), dtype=">f4")
            block[:, :3] = rng.random((m, 3)) * 40
            block[:, 3] = rng.random(m) * 60
            fh.write(block.tobytes())


def _case(name: str, preset: str, ions: int | None, keep: bool) -> dict:
    """Run one case here (called in a child process); return its figures."""
    from apt_filters.synth import build_truth, preset as get_preset, write_specimen

    spec = get_preset(preset, ions)
    with tempfile.TemporaryDirectory() as tmp:
        start, cpu = time.perf_counter(), time.process_time()
        if name == "floor":
            n = int(round(spec.expected_ions()))
            _floor(n, Path(tmp))
        elif name == "truth":
            build_truth(spec, 0)
            n = 0
        else:
            n = write_specimen(tmp, spec, seed=0, keep_ions=keep).truth["ions"]["total"]
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    return {"seconds": seconds, "cpu_seconds": cpu, "ions": n, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _run_child(name: str, preset: str, ions: int | None, keep: bool) -> dict:
    code = (f"import json, benchmarks.bench_synth as b; "
            f"print(json.dumps(b._case({name!r}, {preset!r}, {ions!r}, {keep!r})))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small preset only")
    parser.add_argument("--large", type=float, default=None, metavar="N",
                        help="also stream a default-preset specimen of N ions without keeping them (memory bound)")
    args = parser.parse_args()
    presets = ["small"] if args.quick else ["small", "gamma-prime", "default"]
    rows = []
    for preset in presets:
        floor = _run_child("floor", preset, None, False)
        truth = _run_child("truth", preset, None, False)
        ours = _run_child("write", preset, None, True)
        rows.append((preset, None, ours, truth, floor))
    if args.large:
        n = int(args.large)
        rows.append(("default", n, _run_child("write", "default", n, False), _run_child("truth", "default", n, False),
                     _run_child("floor", "default", n, False)))
    lines = ["| specimen | ions | ours: write_specimen wall (s) | CPU (s) | of which truth, CPU (s) | Mions/s (CPU) "
             "| peak RSS (MB) | floor: random POS, CPU (s) | floor RSS (MB) | ours / floor (CPU) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    summary = []
    for preset, n, ours, truth, floor in rows:
        label = preset + ("" if n is None else " (streamed, ions not kept)")
        lines.append(f"| {label} | {ours['ions']:,} | {ours['seconds']:.2f} | {ours['cpu_seconds']:.2f} | "
                     f"{truth['cpu_seconds']:.2f} | {ours['ions'] / ours['cpu_seconds'] / 1e6:.2f} | "
                     f"{ours['peak_rss_mb']:.0f} | {floor['cpu_seconds']:.2f} | {floor['peak_rss_mb']:.0f} | "
                     f"{ours['cpu_seconds'] / floor['cpu_seconds']:.1f} |")
        if preset == presets[-1] or n is not None:
            what = f"{label} specimen, {ours['ions'] / 1e6:.1f}M ions"
            summary.append(("synth", f"write the {what}, CPU (target: < 20 s)", f"{ours['cpu_seconds']:.2f} s",
                            f"{floor['cpu_seconds']:.2f} s (random POS floor)",
                            ratio(ours["cpu_seconds"], floor["cpu_seconds"])))
    print("\n".join(lines))
    write_results("synth", "Synthetic specimens (`apt_filters.synth`)", summary[:2], [
        "## Generator time and memory against the floor\n\n"
        "CPU seconds (`time.process_time`, numpy single-threaded) are the figure to compare on a shared machine; "
        "each case runs in its own process, so peak RSS includes the interpreter with numpy/scipy (see the floor). "
        "The floor is the least any generator of as many ions must do: draw uniform positions and m/z with numpy "
        "and write them as POS. \"truth\" is everything computed before the ions (layout checks, exact volumes "
        "and areas, excess integrals, ranges, fine true-surface meshes).\n\n" + "\n".join(lines)])

if __name__ == "__main__":
    main()
