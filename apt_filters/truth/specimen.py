"""Comparison of a run's objects and excess with a synthetic specimen's ground truth.

Each bounded feature of ``truth.json`` is matched to the run's object that shares the most volume with its shape
rebuilt from the file (:func:`~apt_filters.truth.match_objects`, as the benchmarks pair them); volume, area and
excess are compared.
With the ions, each segregant's excess is also counted from them against the feature's true
surface and true plateaus (:func:`~apt_filters.truth.counted_truth`): the specimen's ions
are one draw of its model, and that count is what they hold, which no method can know better.
"""

from __future__ import annotations

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.composition import ion_atoms
from apt_filters.refine.levels import PLATEAU_WINDOW
from apt_filters.synth import shape_from_params
from apt_filters.truth.counting import CountedTruth, counted_truth
from apt_filters.voxel import ConcentrationBasis


def _paired(result, truth: dict) -> list[tuple[dict, dict | None]]:
    """(feature, object) for each bounded feature of ``truth`` whose shape truth.json can rebuild: the object of
    ``result`` (a pipeline ``SurfaceResult``) that shares the most volume with it, or None (none within reach)."""
    from apt_filters.analysis.objects import object_surfaces
    from apt_filters.truth.surface import match_objects

    features, sdfs = [], []
    for feature in truth["features"]:
        try:
            shape = shape_from_params(feature["shape"]) if feature.get("bounded") else None
        except AptFiltersError:  # a custom shape: nothing to pair it by
            shape = None
        if shape is not None:
            features.append(feature)
            sdfs.append(shape.sdf)
    listed = {obj["object_id"]: obj for obj in result.objects}
    surfaces = object_surfaces(result.mesh) if listed and result.mesh.n_faces else {}
    ids = [i for i in surfaces if i in listed]  # an object dropped for holding no ion is not paired
    match = match_objects([surfaces[i] for i in ids], sdfs)
    return [(f, None if m is None else listed[ids[m]]) for f, m in zip(features, match)]


def _ratio(measured, true) -> float | None:
    if measured is None or true in (None, 0) or not np.isfinite(measured):
        return None
    return float(measured) / float(true)


def true_plateaus(feature: dict, elements: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """A truth.json feature's inside and outside compositions as (k,) fractions of ``elements`` (absent ones 0)."""
    inside, outside = (np.array([feature[side].get(e, 0.0) for e in elements])
                       for side in ("composition_inside", "composition_outside"))
    return inside, outside


def iso_shapes(truth: dict, species: str, iso: float) -> list:
    """The true objects (:mod:`apt_filters.synth.shapes`, nm) whose surfaces make a specimen's iso-surface of
    ``species`` at ``iso`` (fraction): the bounded features of ``truth.json`` whose inside and outside fractions of
    ``species`` lie on either side of ``iso`` (a Cr-rich plate has no Al 15 at.% surface)."""
    def crosses(f) -> bool:
        inside, outside = (f[side].get(species, 0.0) for side in ("composition_inside", "composition_outside"))
        return (inside - iso) * (outside - iso) < 0

    return [shape_from_params(f["shape"]) for f in truth["features"] if f["bounded"] and crosses(f)]


def counted_truths(truth: dict, ions: IonTable, ranges: RangeTable) -> tuple[list[str], dict[int, CountedTruth]]:
    """The elements, and (feature index) -> what its ions hold (:func:`~apt_filters.truth.counted_truth`)
    for every bounded feature.

    Counted in the band |d| <= 1.5 nm of the true surface against the true plateaus (0.75-3 nm), every ranged
    element in the denominator, from the ions within 3.5 nm of each feature's bounding box. Features whose
    shape truth.json cannot rebuild (custom SDFs) have none. Peak memory: the atoms per ion (``ion_atoms``) and
    the box test, about 30 bytes per ion; only the ions inside a feature's box go through its SDF.
    """
    atoms = ion_atoms(ions, ranges, ConcentrationBasis())
    positions = ions.positions
    reach = PLATEAU_WINDOW[1] + 0.5
    out = {}
    for feature in truth["features"]:
        if not feature.get("bounded"):
            continue
        try:
            shape = shape_from_params(feature["shape"])
        except AptFiltersError:
            continue
        lo, hi = shape.bounds()
        near = np.flatnonzero(np.all((positions >= lo - reach) & (positions <= hi + reach), axis=1))
        out[feature["index"]] = counted_truth(shape.sdf, positions[near], atoms.atoms[near],
                                              *true_plateaus(feature, atoms.elements))
    return atoms.elements, out


def counted_excess(truth: dict, ions: IonTable, ranges: RangeTable) -> dict[tuple[int, str], float]:
    """(feature index, segregant) -> the excess its ions hold over the model's (ratio), for the bounded features
    (:func:`counted_truths`)."""
    elements, counts = counted_truths(truth, ions, ranges)
    out = {}
    for feature in truth["features"]:
        for seg in feature.get("segregation", []):
            solute = seg["species"]
            if feature["index"] in counts and solute in elements:
                out[(feature["index"], solute)] = _ratio(counts[feature["index"]].excess_ions[elements.index(solute)],
                                                         feature["excess"][solute]["excess_ions"])
    return out


def compare_with_truth(results: list, truth: dict, counted: dict | None = None) -> list[dict]:
    """One row per (surface, bounded feature): measured / true volume, area and excess of each segregant, and
    with ``counted`` (:func:`counted_excess`) what the ions hold of that excess."""
    rows = []
    for res in results:
        excess = {(e["solute"], e["object_id"]): e for e in res.excess}
        for feature, obj in _paired(res, truth):
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
                if counted is not None:
                    row[f"counted_excess_{solute}_ratio"] = counted.get((feature["index"], solute))
                measured = None if obj is None else excess.get((solute, obj["object_id"]))
                if measured is not None:
                    gamma = measured["cumulative"]["gamma_atoms"]
                    row[f"excess_{solute}_atoms_nm2"] = gamma
                    row[f"excess_{solute}_ratio"] = _ratio(gamma, true_gamma)
            rows.append(row)
    return rows
