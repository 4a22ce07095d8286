"""What each stage of the refinement buys (issue 25): the default surface with one stage or knob off at a time.

    .venv/bin/python -m benchmarks.bench_ablation [--split dev] [--count 6] [--variants "no facets" ...]
                                                  [--save rows.json] [--load rows.json] [--write]

On each zoo draw (:func:`apt_filters.synth.zoo.draws`) the surface ``apt-filters run`` draws with every
option at its default (:func:`~apt_filters.pipeline.surface.finished_surface`: contour, segregants, specks,
refinement, clean chain, remesh) is drawn once per variant of the refinement's settings
(:class:`~apt_filters.refine.RefineParams`): the defaults, then one stage switched off or one knob at a
simpler value at a time (``VARIANTS``; ``EXTRA`` holds further knobs for ``--variants``). The specimen,
its truth and the voxelization are made once per draw and shared by the variants; only the steps from
the contour on run again (the contour and the speck test are deterministic, so every variant refines the
same input). Each surface is scored per true object as :mod:`benchmarks.bench_zoo` scores it (volume and
area errors with their counting sigma, mean and Hausdorff distance, excess and inside plateau against
the counted truth); the refinement's CPU seconds are the ``refine`` step's process time (speck test and
``refine_surface``, all threads).

Against the defaults, each variant's effect on a figure is the mean over the objects found by both of the
per-object difference (variant minus defaults) of that figure's size, with its standard error over the
objects: an effect within 2 standard errors of zero is "no measurable effect". A stage *helps* on a
figure when switching it off makes that figure measurably worse, and *harms* when measurably better.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time
from types import SimpleNamespace

import numpy as np

from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
from apt_filters.pipeline.surface import finished_surface
from apt_filters.refine import RefineParams
from apt_filters.synth.zoo import SPLITS, draws
from benchmarks.bench_zoo import _within, evaluate, run_fields, specimen, truths
from benchmarks.results import write_results

VARIANTS = {
    "defaults": {},
    "no cross_fit": {"cross_fit": False, "select_modes": False},  # select_modes needs cross_fit's halves
    "no select_modes": {"select_modes": False},
    "blur None": {"blur": None},
    "no facets": {"facets": False},
    "no marker": {"marker": False},
    "subdivisions 0": {"subdivisions": 0},
    "smoothing halved": {"smoothing": 5, "crease_smoothing": 3},
}
"""Variant name: the settings it changes from :class:`RefineParams`'s defaults (one stage or knob each)."""

EXTRA = {
    "full steps throughout": {"full_steps": 1000},
    "no start relaxation": {"relax_start": 0},
    "no pooling": {"pool_radius": 0.0},
    "pooling across edges": {"normal_power": 0.0},
    "no far iterations": {"far_iterations": 0},
    "tangent distance": {"distance": "tangent"},
    "species score": {"score": "species"},
    "no crease smoothing": {"crease_angle": 180.0},
}
"""Further one-knob variants, run only when named in ``--variants``."""

FIGURES = {  # key: (label, size of a row's figure (smaller is better), unit of a difference)
    "volume": ("|V| %", lambda r: 100 * abs(r["volume"]) if "volume" in r else None, "pts"),
    "area": ("|A| %", lambda r: 100 * abs(r["area"]), "pts"),
    "mean": ("mean d", lambda r: r["mean"], "nm"),
    "hausdorff": ("Hausdorff", lambda r: r["hausdorff"], "nm"),
    "excess": ("|excess|/σ", lambda r: abs(r["excess"]) / r["excess_sigma"] if "excess" in r else None, ""),
    "plateau": ("|plateau|/σ", lambda r: abs(r["plateau_in"]) / max(r["plateau_sigma"], 1e-9), ""),
}


class _StepClock:
    """``step`` for :func:`finished_surface`: each step's process (CPU, all threads) seconds."""

    def __init__(self):
        self.cpu: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, name: str):
        t = time.process_time()
        yield SimpleNamespace(summary="")
        self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - t


def _plain(value):
    """JSON for numpy scalars."""
    return value.item() if hasattr(value, "item") else str(value)


def run(split: str, count: int, names: list[str], say, save: str | None = None, families=None) -> list[dict]:
    """One record per (draw, variant): its rows (bench_zoo.evaluate), spurious objects and refine seconds; of the
    first ``count`` draws of ``split``, those of ``families`` (default all)."""
    settings = VARIANTS | EXTRA
    config = PipelineConfig()
    records = []
    for family, seed in draws(split, count):
        if families and family not in families:
            continue
        sp, species, iso, header = specimen(family, seed)
        header = "#" + header  # a heading below the results file's sections
        say(header)
        truth = truths(sp, species)
        fields, mask, basis = run_fields(sp, config)
        for name in names:
            params = dataclasses.replace(RefineParams(), **settings[name])
            clock, t = _StepClock(), time.perf_counter()
            mesh, _ = finished_surface(fields, mask, sp.ions, sp.ranges, SurfaceConfig(species, iso), config=config,
                                       basis=basis, params=params, step=clock)
            wall = time.perf_counter() - t
            rows, spurious = evaluate(sp, mesh, species, truth, seed, family)
            steps = ", ".join(f"{k} {v:.1f}" for k, v in clock.cpu.items())
            line = (f"  {name}: CPU s {steps}; {wall:.1f} s wall, {spurious} spurious; "
                    + "; ".join(_brief(r) for r in rows))
            records.append({"split": split, "family": family, "seed": seed, "variant": name, "rows": rows,
                            "spurious": spurious, "refine_cpu": clock.cpu.get("refine", 0.0), "wall": wall,
                            "header": header, "line": line})
            say(line)
            if save:
                with open(save, "w", encoding="utf-8") as f:
                    json.dump(records, f, default=_plain)
    return records


def sections(records: list[dict]) -> list[str]:
    """The results file's sections of one split's records: effects, totals, families, the draws."""
    split, variants = records[0]["split"], _by_variant(records)
    seeds = list(dict.fromkeys((r["family"], r["seed"]) for r in records))
    what = f"{split}, {len(seeds)} draws ({', '.join(f'{f} {s}' for f, s in seeds)})"
    draws_text = []
    for rec in records:
        if rec["variant"] == "defaults":
            draws_text += ["", rec["header"]]
        draws_text.append(rec["line"])
    return [f"## {split}: what each stage buys\n\n{what}; Δ = variant minus defaults of each object's figure, "
            f"mean ± standard error over the objects found by both\n\n{effects_table(variants)}",
            f"## {split}: per variant\n\n{totals_table(variants)}",
            f"## {split}: per family\n\n{family_table(variants)}",
            f"## {split}: draws\n\nmachine: 2 cores shared with other jobs; CPU s per pipeline step"
            + "\n".join(draws_text)]


def _brief(r: dict) -> str:
    if not r["found"]:
        return f"{r['name']} not found"
    size = f"V {100 * r['volume']:+.1f}% A {100 * r['area']:+.1f}%" if "volume" in r else f"A/V {100 * r['area']:+.1f}%"
    return f"{r['name']} {size} d {r['mean']:.3f} H {r['hausdorff']:.2f}"


def _by_variant(records: list[dict]) -> dict:
    out: dict[str, dict] = {}
    for rec in records:
        v = out.setdefault(rec["variant"], {"rows": [], "spurious": 0, "cpu": {}, "families": []})
        v["rows"] += [r | {"seed": rec["seed"]} for r in rec["rows"]]
        v["spurious"] += rec["spurious"]
        v["cpu"][rec["seed"]] = rec["refine_cpu"]
    return out


def _area_within(r: dict) -> bool:
    return _within(r, "area") if "volume" in r else abs(r["area"]) <= 0.05


def totals_table(variants: dict) -> str:
    """Per variant: the figures over all objects, and the refinement's CPU time against the defaults'."""
    base = variants["defaults"]
    lines = ["| variant | found | spurious | mean \\|V\\| % (mean σ) | V within max(5 %, 2σ) | mean \\|A\\| % (mean σ) | "
             "A within (interfaces 5 %) | mean d nm | mean Hausdorff nm | excess within 2σ | plateau within 2σ | "
             "refine CPU s | CPU / defaults |", "|---|" + "---:|" * 12]
    for name, v in variants.items():
        found = [r for r in v["rows"] if r["found"]]
        closed = [r for r in found if "volume" in r]
        ex = [r for r in found if "excess" in r]
        seeds = [s for s in v["cpu"] if s in base["cpu"]]
        cpu, cpu0 = sum(v["cpu"][s] for s in seeds), sum(base["cpu"][s] for s in seeds)

        def mean(values):
            return float(np.mean(values)) if values else np.nan

        lines.append(
            f"| {name} | {len(found)} / {len(v['rows'])} | {v['spurious']} | "
            f"{mean([100 * abs(r['volume']) for r in closed]):.2f} ({mean([100 * r['volume_sigma'] for r in closed]):.2f}) | "
            f"{sum(_within(r, 'volume') for r in closed)} of {len(closed)} | "
            f"{mean([100 * abs(r['area']) for r in found]):.2f} ({mean([100 * r['area_sigma'] for r in closed]):.2f}) | "
            f"{sum(_area_within(r) for r in found)} of {len(found)} | {mean([r['mean'] for r in found]):.3f} | "
            f"{mean([r['hausdorff'] for r in found]):.2f} | "
            f"{sum(abs(r['excess']) <= 2 * r['excess_sigma'] for r in ex)} of {len(ex)} | "
            f"{sum(abs(r['plateau_in']) <= 2 * r['plateau_sigma'] for r in found)} of {len(found)} | "
            f"{cpu:.0f} | {cpu / cpu0 if cpu0 else np.nan:.2f} |")
    return "\n".join(lines)


def _changed(variants: dict, name: str) -> int:
    """Objects whose surface the variant changed (any figure, or found/not found; the pipeline is deterministic)."""
    base = {(r["seed"], r["name"]): r for r in variants["defaults"]["rows"]}
    keys = ("found", "volume", "area", "mean", "hausdorff", "excess", "plateau_in")
    return sum(any(r.get(k) != base[(r["seed"], r["name"])].get(k) for k in keys) for r in variants[name]["rows"])


def effects(variants: dict) -> dict:
    """Per variant and figure: (mean difference from the defaults, its standard error, objects compared)."""
    base = {(r["seed"], r["name"]): r for r in variants["defaults"]["rows"] if r["found"]}
    out = {}
    for name, v in variants.items():
        if name == "defaults":
            continue
        out[name] = {}
        for key, (_, size, _) in FIGURES.items():
            d = [size(r) - size(base[(r["seed"], r["name"])]) for r in v["rows"]
                 if r["found"] and (r["seed"], r["name"]) in base and size(r) is not None
                 and size(base[(r["seed"], r["name"])]) is not None]
            se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else np.nan
            out[name][key] = (float(np.mean(d)) if d else np.nan, se, len(d))
    return out


def _reading(effect: dict) -> str:
    """What the stage does on the figures where switching it off changes them beyond 2 standard errors."""
    helps = [FIGURES[k][0] for k, (m, se, _) in effect.items() if np.isfinite(se) and m > 2 * se]
    harms = [FIGURES[k][0] for k, (m, se, _) in effect.items() if np.isfinite(se) and m < -2 * se]
    words = ([f"helps: {', '.join(helps)}"] if helps else []) + ([f"harms: {', '.join(harms)}"] if harms else [])
    return "; ".join(words) or "no measurable effect"


def effects_table(variants: dict) -> str:
    """What each stage buys: the mean change of each figure when it is switched off, ± its standard error."""
    eff = effects(variants)
    base = variants["defaults"]
    lines = ["| switched off | " + " | ".join(f"Δ {label}" + (f" ({unit})" if unit else "")
                                             for label, _, unit in FIGURES.values())
             + " | Δ found | objects changed | CPU / defaults | what the stage does (beyond 2 SE) |",
             "|---|" + "---:|" * (len(FIGURES) + 3) + "---|"]
    n_found = sum(r["found"] for r in base["rows"])
    for name, effect in eff.items():
        v = variants[name]
        seeds = [s for s in v["cpu"] if s in base["cpu"]]
        cpu = sum(v["cpu"][s] for s in seeds) / max(sum(base["cpu"][s] for s in seeds), 1e-9)
        cells = [f"{m:+.3f} ± {se:.3f}" if key in ("mean", "hausdorff") else f"{m:+.2f} ± {se:.2f}"
                 for key, (m, se, _) in effect.items()]
        lines.append(f"| {name} | " + " | ".join(cells)
                     + f" | {sum(r['found'] for r in v['rows']) - n_found:+d} | {_changed(variants, name)} of "
                       f"{len(v['rows'])} | {cpu:.2f} | {_reading(effect)} |")
    return "\n".join(lines)


def family_table(variants: dict) -> str:
    """Per family and variant: mean |V| and |A| % of the closed objects (area per volume of interfaces), mean d."""
    families = list(dict.fromkeys(r["family"] for r in variants["defaults"]["rows"]))
    lines = ["| variant | " + " | ".join(families) + " |", "|---|" + "---|" * len(families)]
    for name, v in variants.items():
        cells = []
        for fam in families:
            found = [r for r in v["rows"] if r["family"] == fam and r["found"]]
            closed = [r for r in found if "volume" in r]
            size = (f"V {np.mean([100 * abs(r['volume']) for r in closed]):.1f} A "
                    f"{np.mean([100 * abs(r['area']) for r in closed]):.1f}" if closed else
                    f"A/V {np.mean([100 * abs(r['area']) for r in found]):.1f}" if found else "none found")
            cells.append(f"{size}, d {np.mean([r['mean'] for r in found]):.3f}" if found else size)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary_rows(variants: dict, split: str) -> list[tuple[str, str, str, str, str]]:
    """The results file's summary rows: which stages measurably help on this split, and which do not."""
    eff = effects(variants)
    n = sum(r["found"] for r in variants["defaults"]["rows"])
    helps = [k for k, e in eff.items() if _reading(e).startswith("helps") and "harms" not in _reading(e)]
    rest = [k for k in eff if k not in helps]
    return [("refine", f"ablation, {split} zoo ({n} objects): switching off measurably worse, never better",
             ", ".join(helps) or "none", "-", "-"),
            ("refine", f"ablation, {split} zoo: no measurable effect or some harm", ", ".join(rest) or "none", "-", "-")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="dev", choices=list(SPLITS))
    ap.add_argument("--count", type=int, default=6, help="draws, families in turn")
    ap.add_argument("--families", nargs="+", help="only these families (of the split's first --count draws)")
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS | EXTRA),
                    help="variants to run (the defaults are always run first)")
    ap.add_argument("--save", help="JSON file the records are written to after every variant")
    ap.add_argument("--load", nargs="+", help="tabulate the records of earlier --save files instead of running")
    ap.add_argument("--write", action="store_true", help="write benchmarks/results_ablation.md (the splits run "
                    "or loaded: `--load dev.json heldout.json --write` gathers two runs)")
    ap.add_argument("--intro", help="a file whose text goes between the summary block and the sections")
    args = ap.parse_args(argv)
    if args.load:
        records = []
        for path in args.load:
            with open(path, encoding="utf-8") as f:
                records += json.load(f)
    else:
        names = ["defaults"] + [n for n in args.variants if n != "defaults"]
        records = run(args.split, args.count, names, print, args.save, args.families)
    splits = {}
    for rec in records:
        splits.setdefault(rec["split"], []).append(rec)
    text, rows = [], []
    for split, mine in splits.items():
        text += sections(mine)
        rows += summary_rows(_by_variant(mine), split)
        print("\n\n".join(text[-4:-1]))
    if args.write:
        intro = open(args.intro, encoding="utf-8").read() if args.intro else ""
        write_results("ablation", "bench_ablation: what each stage of the refinement buys", rows, text, intro=intro)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
