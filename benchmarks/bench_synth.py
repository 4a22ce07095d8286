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
        start = time.perf_counter()
        if name == "floor":
            n = int(round(spec.expected_ions()))
            _floor(n, Path(tmp))
        elif name == "truth":
            build_truth(spec, 0)
            n = 0
        else:
            n = write_specimen(tmp, spec, seed=0, keep_ions=keep).truth["ions"]["total"]
        seconds = time.perf_counter() - start
    return {"seconds": seconds, "ions": n, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


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
    print("| specimen | ions | ours: write_specimen (s) | of which truth (s) | Mions/s | peak RSS (MB) "
          "| floor: random POS (s) | floor RSS (MB) | ours / floor |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for preset, n, ours, truth, floor in rows:
        label = preset + ("" if n is None else " (streamed, ions not kept)")
        print(f"| {label} | {ours['ions']:,} | {ours['seconds']:.2f} | {truth['seconds']:.2f} | "
              f"{ours['ions'] / ours['seconds'] / 1e6:.2f} | {ours['peak_rss_mb']:.0f} | {floor['seconds']:.2f} | "
              f"{floor['peak_rss_mb']:.0f} | {ours['seconds'] / floor['seconds']:.1f} |")


if __name__ == "__main__":
    main()
