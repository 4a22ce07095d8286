"""Small closed objects under wide interfaces: the defaults against ``RefineParams(curved_levels=False)``, per object.

    .venv/bin/python -m benchmarks.bench_curved_levels sphere:7 sphere:10009 rod:10011 ...

On each zoo draw (:func:`benchmarks.bench_zoo.specimen`) the surface ``apt-filters run`` draws
(:func:`~apt_filters.pipeline.surface.finished_surface`, every option at its default) is drawn twice on the same
ions, once with every object's plateau windows as they are (``curved_levels=False``) and once as it is, each closed
object's windows unmixed by its blurred ball where the held-out ions choose it
(:func:`apt_filters.refine.surface._curved_levels`). Per true closed object: volume and area
error with their counting sigma (:func:`~apt_filters.truth.counting_floor`), and whether both are within
max(5 %, 2 sigma); the last line counts the objects within per split (dev seeds < 10000, held-out from 10000) and
lists those that went from within to beyond.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

from apt_filters.core.mesh import split_components
from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
from apt_filters.pipeline.surface import finished_surface, refine_params
from apt_filters.truth import match_objects, surface_error
from benchmarks.bench_zoo import run_fields, specimen, truths

RUNS = ("windows", "defaults")


def _within(e, floor) -> bool:
    return (abs(e.volume_error) <= max(0.05, 2 * floor.volume)) and (abs(e.area_error) <= max(0.05, 2 * floor.area))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("draws", nargs="+", help="family:seed")
    args = ap.parse_args(argv)
    config = PipelineConfig()
    params = refine_params(config.refine)
    counts = {split: {run: 0 for run in ("objects",) + RUNS} for split in ("dev", "heldout")}
    worse = []
    print("| draw | object (nm³) | " + " | ".join(f"{r} V / A (σ)" for r in RUNS) + " |")
    print("|---|---|" + "---|" * len(RUNS))
    for item in args.draws:
        family, seed = item.split(":")
        sp, species, iso, _ = specimen(family, int(seed))
        truth = truths(sp, species)
        fields, mask, basis = run_fields(sp, config)
        feats = list(range(len(sp.truth["features"])))
        cells = {i: [] for i in feats}
        within = {i: [] for i in feats}
        for run in RUNS:
            mesh, _ = finished_surface(fields, mask, sp.ions, sp.ranges, SurfaceConfig(species, iso), config=config,
                                       basis=basis, params=replace(params, curved_levels=run == "defaults"))
            parts = split_components(mesh) if mesh.n_faces else []
            for i, m in zip(feats, match_objects(parts, [sp.feature_sdf(j) for j in feats])):
                tf, floor = sp.truth["features"][i], truth[i]["floor"]
                if not tf["bounded"] or sp.spec.features[i].shape.cut or not floor:
                    continue
                if m is None:
                    cells[i].append("not found")
                    within[i].append(False)
                    continue
                e = surface_error(parts[m], sp.feature_sdf(i), sp.meshes[i], tf["volume_nm3"], tf["area_nm2"],
                                  seed=int(seed))
                within[i].append(_within(e, floor))
                cells[i].append(f"{100 * e.volume_error:+.1f} / {100 * e.area_error:+.1f} ({100 * floor.volume:.1f} / "
                                f"{100 * floor.area:.1f}){' ✓' if within[i][-1] else ''}")
        split = "heldout" if int(seed) >= 10000 else "dev"
        for i in feats:
            if not cells[i]:
                continue
            tf = sp.truth["features"][i]
            print(f"| {family} {seed} | {tf['name']} ({tf['volume_nm3']:.0f}) | " + " | ".join(cells[i]) + " |",
                  flush=True)
            counts[split]["objects"] += 1
            for run, ok in zip(RUNS, within[i]):
                counts[split][run] += ok
            if within[i][0] and not within[i][1]:
                worse.append(f"{family} {seed} {tf['name']}")
    for split, c in counts.items():
        print(f"{split}: " + ", ".join(f"{run} {c[run]} of {c['objects']}" for run in RUNS))
    print("within -> beyond: " + (", ".join(worse) or "none"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
