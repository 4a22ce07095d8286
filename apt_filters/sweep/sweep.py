"""``apt-filters sweep``: the pipeline over a grid of analysis choices, and how much the answers move.

Every choice (iso-value x voxel x delocalization x kernel) is one pipeline run, a task on a Dask
cluster; each run's objects are matched across the choices by overlap (:mod:`.match`), and for
every matched object and figure the spread over the choices (the systematic part of its
uncertainty) is set beside its counting error (the statistical part).
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_write_text
from apt_filters.pipeline import config as cfg
from apt_filters.pipeline import report as rep
from apt_filters.pipeline.staging import staged_folder
from apt_filters.sweep.choices import CHOICE_COLUMNS, Choice
from apt_filters.sweep.cluster import run_tasks
from apt_filters.sweep.match import match_objects
from apt_filters.sweep.rows import csv_text, run_task

FIGURES = ("volume", "area")
"""Per-object figures besides the compositions (``c_<El>``) and excesses (``excess_<El>``)."""


@dataclass
class SweepResult:
    """What a sweep found.

    Attributes
    ----------
    runs : list of dict
        One per choice: ``tag``, the choice's values, ``status`` (``ok``/``error``), ``error``,
        ``seconds`` (the run's own wall time), ``objects``.
    rows : list of dict
        One per choice and object: the choice's values, ``object`` (the matched track, 1-based,
        per surface), then the run's figures (:func:`~apt_filters.sweep.rows.object_rows`).
    spread : list of dict
        One per surface, matched object and figure: ``found`` (in how many choices), ``mean``,
        ``sd`` (over the choices: systematic), ``min``, ``max``, ``counting_se`` (median of the
        runs' counting errors: statistical) and ``sd_over_se``.
    wall_seconds : float
        The sweep's wall time (its runs side by side on the cluster).
    """

    runs: list[dict]
    rows: list[dict]
    spread: list[dict]
    wall_seconds: float
    columns: list[str] = field(default_factory=list)


def _figure_keys(rows: list[dict]) -> list[str]:
    keys = dict.fromkeys(FIGURES)
    for row in rows:
        keys.update((k, None) for k in row if (k.startswith("c_") or k.startswith("excess_"))
                    and not k.endswith("_se"))
    return list(keys)


def spread_table(rows: list[dict]) -> list[dict]:
    """Per surface, object and figure: the spread over the choices against the counting error."""
    out = []
    keys = _figure_keys(rows)
    for surface, track in sorted({(r["surface"], r["object"]) for r in rows}):
        mine = [r for r in rows if r["surface"] == surface and r["object"] == track]
        for key in keys:
            values = np.array([r[key] for r in mine if r.get(key) is not None], float)
            errors = np.array([r[f"{key}_se"] for r in mine if r.get(f"{key}_se") is not None], float)
            if len(values) == 0:
                continue
            sd = float(values.std(ddof=1)) if len(values) > 1 else math.nan
            se = float(np.median(errors)) if len(errors) else math.nan
            out.append({"surface": surface, "object": track, "figure": key, "found": len(values),
                        "mean": float(values.mean()), "sd": sd, "min": float(values.min()),
                        "max": float(values.max()), "counting_se": se,
                        "sd_over_se": sd / se if se > 0 and math.isfinite(sd) else math.nan})
    return out


def run_sweep(base: cfg.PipelineConfig, choices: Sequence[Choice], out: str | Path, *, client,
              keep_runs: bool = False, force: bool = False, progress: bool = True) -> SweepResult:
    """Run the pipeline for every choice on ``client`` and write the sweep's folder ``out``.

    Parameters
    ----------
    base : PipelineConfig
        The configuration every choice starts from (inputs, surfaces, the other steps' settings).
    choices : sequence of Choice
        See :func:`~apt_filters.sweep.choices.choice_grid`.
    out : path
        Written whole or not at all: ``sweep.csv`` (one row per choice and object), ``sweep.json``
        (runs, rows, spread), ``report.html`` and ``spread.png``; with ``keep_runs`` each choice's
        full output folder under ``runs/<tag>/``.
    client : distributed.Client
        Where the runs go (:func:`~apt_filters.sweep.cluster.dask_client`); workers read the ion
        file themselves, memory-mapped, so no ions travel.
    force : bool
        Replace an existing output folder written by apt-filters.

    Returns
    -------
    SweepResult
        The rows equal those of separate runs of each choice (runs are deterministic).
    """
    configs = [c.apply(base) for c in choices]  # every choice checked before any work
    tags = [c.tag(config) for c, config in zip(choices, configs)]
    with staged_folder(out, force=force) as stage:
        (stage / "runs").mkdir()
        start = time.perf_counter()
        results = run_tasks(client, run_task, [(dataclasses.asdict(config), str(stage / "runs" / tag), keep_runs)
                                               for config, tag in zip(configs, tags)],
                            label="choice", progress=progress)
        wall = time.perf_counter() - start
        runs, per_run = [], []
        for choice, config, tag, result in zip(choices, configs, tags, results):
            values = choice.values(config)
            runs.append({"tag": tag, **values, "status": result["status"], "error": result.get("error"),
                         "seconds": result.get("seconds"), "objects": result.get("objects", 0)})
            per_run.append([dict(values, **row) for row in result.get("rows", [])])
        rows = _matched(per_run)
        result = SweepResult(runs, rows, spread_table(rows), wall)
        _write(stage, result, base)
        if not keep_runs:  # what a run killed with its worker left there goes too
            shutil.rmtree(stage / "runs")
    return result


def _matched(per_run: list[list[dict]]) -> list[dict]:
    """The rows with ``object``: their track across the runs, matched per surface (1-based)."""
    surfaces = sorted({r["surface"] for rows in per_run for r in rows})
    for surface in surfaces:
        mine = [[r for r in rows if r["surface"] == surface] for rows in per_run]
        boxes = [[r["bbox"] or [0.0] * 6 for r in rows] for rows in mine]
        for rows, tracks in zip(mine, match_objects(boxes)):
            for r, t in zip(rows, tracks):
                r["object"] = t + 1
    ordered = []
    for rows in per_run:
        ordered += [{k: r[k] for k in (*CHOICE_COLUMNS, "surface", "label", "object")} |
                    {k: v for k, v in r.items() if k not in (*CHOICE_COLUMNS, "surface", "label", "object")}
                    for r in rows]
    return ordered


def _write(stage: Path, result: SweepResult, base: cfg.PipelineConfig) -> None:
    atomic_write_text(stage / "sweep.csv", csv_text(result.rows))
    busy = sum(r["seconds"] or 0.0 for r in result.runs)
    doc = {"apt-filters": rep.versions(), "base_config": dataclasses.asdict(base), "wall_seconds": result.wall_seconds,
           "run_seconds": busy, "runs": result.runs, "rows": result.rows, "spread": result.spread}
    atomic_write_text(stage / "sweep.json", jsontext.dumps(doc, indent=1) + "\n")
    images = [p for p in [_plot(stage / "spread.png", result.spread)] if p is not None]
    failed = [r for r in result.runs if r["status"] != "ok"]
    summary = (f"{len(result.runs)} choices ({len(failed)} failed), run side by side in {result.wall_seconds:.1f} s "
               f"wall; the runs took {busy:.1f} s in all ({busy / max(result.wall_seconds, 1e-9):.1f} at once on "
               f"average). sd: the spread of a figure over the choices (systematic); counting se: the median of the "
               f"runs' counting errors (statistical). sd / se well above 1: the choice of analysis moves the figure "
               f"more than counting noise does. Objects are matched across choices by overlap (docs/sweep.md).")
    spread = [[s["surface"], s["object"], figure_label(s["figure"]), f"{s['found']} of {len(result.runs)}",
               *(v * figure_scale(s["figure"]) for v in (s["mean"], s["sd"], s["min"], s["max"], s["counting_se"])),
               s["sd_over_se"]] for s in result.spread]
    choices = [[r["tag"], r["iso"], r["voxel"], r["delocalization"], r["kernel"], r["status"], r["objects"],
                r["seconds"], r["error"] or ""] for r in result.runs]
    sections = [("Summary", summary),
                ("Spread over the choices against counting error",
                 (["surface", "object", "figure", "found in", "mean", "sd over choices", "min", "max",
                   "counting se", "sd / se"], spread)),
                ("Choices", (["run", "iso (fraction)", "voxel (nm)", "delocalization (nm, 3σ x y z)", "kernel",
                              "status", "objects", "time (s)", "error"], choices))]
    pictures = [(p, "each object's spread over the choices and its counting error, in % of its mean")
                for p in images]
    rep.write_page(stage / "report.html", "apt-filters sweep", sections, pictures)


def figure_label(key: str) -> str:
    """A figure's name with its unit, for tables: ``volume (nm³)``, ``Al inside (at.%)``."""
    if key.startswith("c_"):
        return f"{key[2:]} inside (at.%)"
    if key.startswith("excess_"):
        return f"{key[7:]} excess (atoms/nm²)"
    return {"volume": "volume (nm³)", "area": "area (nm²)"}.get(key, key)


def figure_scale(key: str) -> float:
    """Factor from the API's unit to the report's (fractions to at.%)."""
    return 100.0 if key.startswith("c_") else 1.0


def _plot(path: Path, spread: list[dict]) -> Path | None:
    """Per figure kind: each object's spread over the choices (sd) and counting error, relative to its mean."""
    kinds = [k for k in ("volume", "area") if any(s["figure"] == k for s in spread)]
    kinds += sorted({s["figure"] for s in spread if s["figure"].startswith("excess_")})
    rows = [[s for s in spread if s["figure"] == k and s["mean"] and math.isfinite(s["sd"])] for k in kinds]
    kinds, rows = [k for k, r in zip(kinds, rows) if r], [r for r in rows if r]
    if not kinds:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(kinds), figsize=(4.2 * len(kinds), 3.4), squeeze=False)
    for ax, kind, mine in zip(axes[0], kinds, rows):
        x = np.arange(len(mine))
        sd = [100 * s["sd"] / abs(s["mean"]) for s in mine]
        se = [100 * s["counting_se"] / abs(s["mean"]) if math.isfinite(s["counting_se"]) else np.nan for s in mine]
        ax.bar(x - 0.2, sd, 0.4, label="spread over choices (sd)")
        ax.bar(x + 0.2, se, 0.4, label="counting error (se)")
        ax.set_xticks(x, [f"{s['surface']}:{s['object']}" for s in mine], rotation=90, fontsize=7)
        unit = {"volume": "volume", "area": "area"}.get(kind, kind.replace("excess_", "excess of "))
        ax.set_title(unit)
        ax.set_ylabel("% of the object's mean")
        ax.set_xlabel("surface:object")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
