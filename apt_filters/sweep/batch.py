"""``apt-filters batch``: one analysis over many datasets, listed in a TOML manifest.

The manifest::

    [defaults]                 # optional: run options for every dataset
    species = "Cr"
    iso = 0.3

    [[dataset]]
    name = "Si-cap"            # optional: default the ion file's stem (names must be unique)
    input = "data/Si.pos"      # paths relative to the manifest
    range = "data/Si.RRNG"
    iso = 0.25                 # any run option: species, iso, density, exclude, voxel, kernel,
                               # delocalization, method, remesh, efficiency, blur, relabel,
                               # unknown_species; config = a base TOML

Each dataset is one pipeline run, a task on a Dask cluster, into ``OUT/runs/<name>/``; a dataset
that fails (a bad file, a wrong option) fails its own row with the one-line error, and the
others finish.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_write_text
from apt_filters.core.errors import AptFiltersError
from apt_filters.pipeline import config as cfg
from apt_filters.pipeline import report as rep
from apt_filters.pipeline.staging import staged_folder
from apt_filters.sweep.cluster import run_tasks
from apt_filters.sweep.rows import csv_text, run_task

MAX_DATASETS = 100_000
"""More datasets than this in one manifest is a mistake, not a batch."""


@dataclass(frozen=True)
class Dataset:
    """One manifest entry: its name and its configuration (or why it has none)."""

    name: str
    config: dict | None
    error: str | None = None


def read_manifest(path: str | Path) -> list[Dataset]:
    """The datasets of a batch manifest, each with its resolved configuration.

    Raises
    ------
    AptFiltersError
        The manifest itself is unreadable, has no ``[[dataset]]``, unknown top-level tables or
        repeated names. A single dataset's bad option does not raise: it becomes that
        dataset's error.
    """
    path = Path(path)
    data = cfg.read_toml(path, "manifest")
    unknown = sorted(set(data) - {"defaults", "dataset"})
    if unknown:
        raise AptFiltersError(f"unknown table(s) {', '.join(unknown)}: a manifest has [defaults] and [[dataset]]", path)
    entries, defaults = data.get("dataset"), data.get("defaults", {})
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise AptFiltersError("no [[dataset]] tables", path)
    if len(entries) > MAX_DATASETS or not isinstance(defaults, dict):
        raise AptFiltersError(f"[defaults] must be a table and at most {MAX_DATASETS:,} datasets", path)
    out, names = [], set()
    for i, entry in enumerate(entries, start=1):
        options = {**defaults, **entry}
        raw_name = options.pop("name", None) or Path(str(options.get("input", f"dataset{i}"))).stem
        name = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in str(raw_name))[:100]
        if name in names:
            raise AptFiltersError(f"dataset name {name!r} is used twice (set name = ...)", path)
        names.add(name)
        try:
            base = options.pop("config", None)
            config = cfg.load(path.parent / base) if base else cfg.PipelineConfig()
            for key in ("input", "range"):
                if key in options:
                    options[key] = str((path.parent / str(options[key])).resolve())
            resolved = cfg.with_options(config, options, source=f"{path} dataset {name}")
            cfg.check_config(resolved)
            out.append(Dataset(name, dataclasses.asdict(resolved)))
        except AptFiltersError as exc:
            out.append(Dataset(name, None, str(exc)))
    return out


def summary_row(name: str, result: dict) -> dict:
    """One dataset's line of the batch summary."""
    row = {"dataset": name, "status": result["status"], "error": result.get("error") or "",
           "seconds": result.get("seconds")}
    rows = result.get("rows", [])
    for label in dict.fromkeys(r["label"] for r in rows):
        mine = [r for r in rows if r["label"] == label]
        volumes = [r["volume"] for r in mine if r["volume"] is not None]
        row[f"{label} objects"] = len(mine)
        row[f"{label} closed volume nm3"] = sum(volumes) if volumes else None
        row[f"{label} area nm2"] = sum(r["area"] or 0.0 for r in mine)
    return row


def run_batch(manifest: str | Path, out: str | Path, *, client, force: bool = False,
              progress: bool = True) -> list[dict]:
    """Run every dataset of ``manifest`` on ``client``; write ``out`` and return the summary rows.

    ``out`` (whole or not at all) holds ``runs/<name>/`` (each dataset's full output),
    ``batch.csv`` (one summary row per dataset), ``objects.csv`` (every object of every
    dataset), ``batch.json`` and ``report.html``.
    """
    datasets = read_manifest(manifest)
    with staged_folder(out, force=force) as stage:
        (stage / "runs").mkdir()
        todo = [d for d in datasets if d.config is not None]
        start = time.perf_counter()
        results = run_tasks(client, run_task, [(d.config, str(stage / "runs" / d.name), True) for d in todo],
                            label="dataset", progress=progress)
        wall = time.perf_counter() - start
        done = dict(zip((d.name for d in todo), results))
        rows, objects = [], []
        for d in datasets:
            result = done.get(d.name) or {"status": "error", "error": d.error}
            rows.append(summary_row(d.name, result))
            objects += [{"dataset": d.name, **{k: v for k, v in r.items() if k != "bbox"}}
                        for r in result.get("rows", [])]
        atomic_write_text(stage / "batch.csv", csv_text(rows))
        atomic_write_text(stage / "objects.csv", csv_text(objects) if objects else "dataset\n")
        doc = {"apt-filters": rep.versions(), "manifest": str(Path(manifest).resolve()), "wall_seconds": wall,
               "datasets": rows, "objects": objects}
        atomic_write_text(stage / "batch.json", jsontext.dumps(doc, indent=1) + "\n")
        failed = sum(r["status"] != "ok" for r in rows)
        text = (f"{len(rows)} datasets, {failed} failed; {wall:.1f} s wall. Each dataset's full report: "
                f"runs/<dataset>/report.html.")
        header = list(dict.fromkeys(k for r in rows for k in r))
        table = (header, [[r.get(k) if r.get(k) is not None else "" for k in header] for r in rows])
        rep.write_page(stage / "report.html", "apt-filters batch", [("Summary", text), ("Datasets", table)])
    return rows

