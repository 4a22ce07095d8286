"""Comparison of a run's objects and excess with a synthetic specimen's ground truth.

Each bounded feature of ``truth.json`` is matched to the object whose centroid lies
nearest its centre (within the feature's depth); volume, area and excess are compared.
"""

from __future__ import annotations

import numpy as np


def _match(objects: list[dict], center: np.ndarray, radius: float) -> dict | None:
    best, best_d = None, radius
    for obj in objects:
        c = np.array([obj["centroid_x"], obj["centroid_y"], obj["centroid_z"]], dtype=float)
        d = float(np.linalg.norm(c - center))
        if d < best_d:
            best, best_d = obj, d
    return best


def _ratio(measured, true) -> float | None:
    if measured is None or true in (None, 0) or not np.isfinite(measured):
        return None
    return float(measured) / float(true)


def compare_with_truth(results: list, truth: dict) -> list[dict]:
    """One row per (surface, bounded feature): measured / true volume, area and excess of each segregant."""
    rows = []
    for res in results:
        excess = {(e["solute"], e["object_id"]): e for e in res.excess}
        for feature in truth["features"]:
            shape = feature["shape"]
            if not feature.get("bounded") or "center" not in shape:
                continue
            obj = _match(res.objects, np.asarray(shape["center"], float), float(feature["depth_nm"]))
            row = {"surface": res.label, "feature": feature["name"],
                   "true_volume_nm3": feature["volume_nm3"], "true_area_nm2": feature["area_nm2"],
                   "object_id": None if obj is None else obj["object_id"]}
            if obj is not None:
                row["volume_ratio"] = _ratio(obj["volume"], feature["volume_nm3"])
                row["area_ratio"] = _ratio(obj["area"], feature["area_nm2"])
            for seg in feature.get("segregation", []):
                solute = seg["species"]
                true_gamma = feature["excess"][solute]["atoms_per_nm2"]
                row[f"true_excess_{solute}_atoms_nm2"] = true_gamma
                measured = None if obj is None else excess.get((solute, obj["object_id"]))
                if measured is not None:
                    gamma = measured["cumulative"]["gamma_atoms"]
                    row[f"excess_{solute}_atoms_nm2"] = gamma
                    row[f"excess_{solute}_ratio"] = _ratio(gamma, true_gamma)
            rows.append(row)
    return rows
