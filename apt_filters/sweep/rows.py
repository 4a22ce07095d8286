"""One pipeline run as a cluster task, and its figures as flat rows: one per object, with errors."""

from __future__ import annotations

import csv
import io
import math
import shutil
import time
from pathlib import Path

import numpy as np

from apt_filters.core.errors import AptFiltersError


def _number(value) -> float | None:
    """A finite float, or None (JSON has no NaN)."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def object_boxes(mesh_path: Path) -> dict[int, list[float]]:
    """Axis-aligned bounding box ``[x0, y0, z0, x1, y1, z1]`` (nm) of each object of a written surface."""
    from apt_filters.meshlab.exports import read_ply

    mesh = read_ply(mesh_path)
    ids = np.asarray(mesh.face_scalars.get("object_id", np.zeros(mesh.n_faces)), dtype=np.int64)
    boxes = {}
    for oid in np.unique(ids):
        corners = mesh.vertices[mesh.faces[ids == oid].ravel()]
        boxes[int(oid)] = corners.min(axis=0).tolist() + corners.max(axis=0).tolist()
    return boxes


def object_rows(report: dict, run_dir: Path) -> list[dict]:
    """Per surface and object of a finished run: its figures and their counting errors.

    Columns: ``surface`` (index in the configuration), ``label``, ``object_id`` (the run's own
    numbering), ``status``, ``volume`` / ``volume_se`` (nm³), ``area`` / ``area_se`` (nm²) where the
    run states them, ``n_ions``, ``c_<El>`` / ``c_<El>_se`` (fraction of the atoms inside, binomial
    error), ``excess_<El>`` / ``excess_<El>_se`` (detected atoms/nm², proxigram integration) and
    ``bbox`` (for matching objects across runs).
    """
    rows = []
    for index, surface in enumerate(report["surfaces"]):
        boxes = object_boxes(run_dir / "meshes" / f"{surface['label']}.ply")
        excess = {(e["solute"], e["object_id"]): e["integration"] for e in surface["excess"]}
        solutes = sorted({solute for solute, _ in excess})
        for o in surface["objects"]:
            oid, n = int(o["object_id"]), int(o.get("n_ions", -1))
            row = {"surface": index, "label": surface["label"], "object_id": oid, "status": o["status"],
                   "volume": _number(o.get("volume")), "volume_se": _number(o.get("volume_se")),
                   "area": _number(o.get("area")), "area_se": _number(o.get("area_se")), "n_ions": n}
            for key, value in o.items():
                if key.startswith("frac_"):
                    c = _number(value)
                    row[f"c_{key[5:]}"] = c
                    row[f"c_{key[5:]}_se"] = math.sqrt(c * (1 - c) / n) if c is not None and n > 0 else None
            for solute in solutes:
                e = excess.get((solute, oid))
                row[f"excess_{solute}"] = None if e is None else _number(e["gamma_detected"])
                row[f"excess_{solute}_se"] = None if e is None else _number(e["gamma_detected_error"])
            row["bbox"] = boxes.get(oid)
            rows.append(row)
    return rows


def run_task(config_data: dict, out: str, keep: bool) -> dict:
    """Run the pipeline on one configuration (as a dict) into ``out``; its rows, or its error.

    Runs on a cluster worker: errors come back as a row (``status`` ``error`` and the one-line
    message), so that one bad input or choice does not stop the others. ``out`` is deleted after
    the rows are read unless ``keep``.
    """
    from apt_filters.pipeline import config as cfg
    from apt_filters.pipeline.run import run_pipeline

    start = time.perf_counter()
    out_path = Path(out)
    try:
        config = cfg.from_dict(config_data, source="task")
        report = run_pipeline(config, out_path, quiet=True)
        rows = object_rows(report, out_path)
        result = {"status": "ok", "rows": rows, "objects": len(rows),
                  "warnings": report.get("warnings", [])}
    except AptFiltersError as exc:
        result = {"status": "error", "error": str(exc)}
    except Exception as exc:  # noqa: BLE001 - a bug in one run must not cost the others; it is reported
        result = {"status": "error", "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:500]}
    finally:
        if not keep and out_path.exists():
            shutil.rmtree(out_path, ignore_errors=True)
    result["seconds"] = time.perf_counter() - start
    return result


def csv_text(rows: list[dict]) -> str:
    """CSV of rows (columns in order of first appearance; None as empty; ``bbox`` left out)."""
    columns = list(dict.fromkeys(k for r in rows for k in r if k != "bbox"))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in columns})
    return buf.getvalue()

