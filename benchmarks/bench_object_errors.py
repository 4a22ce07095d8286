"""Objects' significance and counting errors on the specimen zoo (issue 25): the speck test and sigma_V, sigma_A.

    python -m benchmarks.bench_object_errors [--split heldout] [--count 8] [--out benchmarks/results_object_errors.md]

Each zoo draw (:mod:`apt_filters.synth.zoo`) is contoured as ``apt-filters run`` does with every option at its
default (segregants found and left out, the speck test of :mod:`apt_filters.refine.specks`, refinement), and
its components are matched to the true objects (:func:`~apt_filters.truth.match_objects`). Reported: true
objects of >= 30 nm³ found, spurious components kept, components removed as specks; per found object its
family-wise p-value and z, and the volume and area errors against the truth divided by the counting errors
the run states (``sigma_V = A sigma_offset``, ``sigma_A = |dA/dd| sigma_offset``, ``RefineResult.offset_errors``,
raised for faceted objects to the spread of the two cross-fit halves, ``RefineResult.shape_errors``:
:func:`~apt_filters.analysis.objects.size_errors`):
their spread over objects is ~1 where the stated errors cover the counting noise and the method adds no bias.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from apt_filters.core.mesh import split_components
from apt_filters.pipeline.config import PipelineConfig
from apt_filters.pipeline.surface import contour_surface, segregant_basis
from apt_filters.refine import refine_surface, remove_specks
from apt_filters.refine.specks import REACH
from apt_filters.analysis.objects import size_errors
from apt_filters.synth import generate
from apt_filters.synth.zoo import SPLITS, draws, zoo_specimen
from apt_filters.truth import match_objects
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize


def run_draw(family: str, seed: int, ion_seed: int | None = None, refine: bool = True) -> tuple[str, list[dict], int, int]:
    """(header line, rows per true object, spurious components kept, specks removed) of one draw (its ions drawn
    with ``ion_seed``, default ``seed``); without ``refine``, the objects are the contour's components the speck
    test kept (no sizes)."""
    spec = zoo_specimen(family, seed)
    sp = generate(spec, seed if ion_seed is None else ion_seed)
    inside = sp.truth["features"][0]["composition_inside"]
    species = max(inside, key=lambda e: inside[e] - spec.matrix.get(e, 0.0))
    iso = 0.5 * (spec.features[0].composition.get(species, 0.0) + spec.matrix.get(species, 0.0))
    config = PipelineConfig()
    v, r = config.voxel, config.refine
    basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
    fields = voxelize(sp.ions, sp.ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size, basis=basis)
    mask = inside_mask(fields).dense()
    mesh = contour_surface(fields, mask, species, iso)
    surface_basis, _ = segregant_basis(mesh, sp.ions, sp.ranges, species, basis, v.include)
    if surface_basis is not basis:
        mesh = contour_surface(fields, mask, species, iso, basis=surface_basis)
    t = time.perf_counter()
    mesh, specks = remove_specks(mesh, fields=fields, mask=mask, ions=sp.ions, ranges=sp.ranges, species=species,
                                 iso=iso, basis=surface_basis, alpha=r.speck_alpha)
    speck_seconds = time.perf_counter() - t
    refined = refine_surface(mesh, sp.ions, sp.ranges, species, surface_basis) if mesh.n_faces and refine else None
    final = refined.mesh if refined is not None else mesh
    parts = split_components(final) if final.n_faces else []
    feats = range(len(sp.truth["features"]))
    match = match_objects(parts, [sp.feature_sdf(i) for i in feats])
    rows = []
    kept_p, kept_z = specks.of(final, REACH) if parts else (np.zeros(0), np.zeros(0))
    for i, m in zip(feats, match):
        tf = sp.truth["features"][i]
        row = {"name": tf["name"], "bounded": tf["bounded"], "true_volume": tf["volume_nm3"], "found": m is not None}
        if m is not None:
            row |= {"p": float(kept_p[m]), "z": float(kept_z[m])}
            if refined is not None and tf["bounded"] and len(parts[m].boundary_edges()) == 0:
                part = parts[m]
                sigma_v, sigma_a = size_errors(part, float(refined.offset_errors[m]), refined.shape_errors[m])
                row |= {"volume": part.signed_volume(), "area": part.area(), "sigma_v": sigma_v,
                        "sigma_a": sigma_a, "true_area": tf["area_nm2"]}
        rows.append(row)
    spurious = sum(1 for j in range(len(parts)) if j not in set(match))
    f0 = spec.features[0]
    ions = "" if ion_seed is None else f" ions {ion_seed}"
    head = (f"{family} seed {seed}{ions}: {len(sp.ions):,} ions, {species} {100 * spec.matrix[species]:.1f} -> "
            f"{100 * f0.composition[species]:.1f} at.%, efficiency {spec.efficiency:.2f}; {specks.tested} components, "
            f"{specks.count} specks removed ({speck_seconds:.1f} s; null {specks.null[0]:+.2f} ± {specks.null[1]:.2f} "
            f"from {specks.null[2]} noise components), {spurious} spurious kept")
    return head, rows, spurious, specks.count


def fmt(r: dict) -> str:
    if not r["found"]:
        return "not found"
    text = f"p {r['p']:.1e} (z {r['z']:.1f})"
    if "volume" in r:
        dv, da = r["volume"] - r["true_volume"], r["area"] - r["true_area"]
        text += (f"; V {r['volume']:.0f} ± {r['sigma_v']:.0f} nm³ (true {r['true_volume']:.0f}, "
                 f"z {dv / r['sigma_v']:+.1f}); A {r['area']:.0f} ± {r['sigma_a']:.0f} nm² (true "
                 f"{r['true_area']:.0f}, z {da / r['sigma_a']:+.1f})")
    return text


def summary(rows: list[dict], spurious: list[int], removed: list[int]) -> list[str]:
    big = [r for r in rows if r["bounded"] and (r["true_volume"] or 0) >= 30]
    sized = [r for r in rows if "volume" in r]
    zv = np.array([(r["volume"] - r["true_volume"]) / r["sigma_v"] for r in sized])
    za = np.array([(r["area"] - r["true_area"]) / r["sigma_a"] for r in sized])

    def spread(z):
        return (f"mean {z.mean():+.2f}, sd {z.std(ddof=1):.2f}, |z| <= 2: {np.sum(np.abs(z) <= 2)} of {len(z)}"
                if len(z) > 1 else "-")
    return [f"- objects >= 30 nm³ found: {sum(r['found'] for r in big)} of {len(big)}",
            f"- spurious components kept: {sum(spurious)} over {len(spurious)} draws; specks removed: {sum(removed)}",
            f"- volume z = (V - V_true) / sigma_V over {len(zv)} objects: {spread(zv)}",
            f"- area z = (A - A_true) / sigma_A over {len(za)} objects: {spread(za)}"]


def repeats(args) -> int:
    """Per object: sd of volume and area over ion draws of one geometry, against the rms stated error."""
    lines = []
    ratios = {"volume": [], "area": []}
    for family, seed in draws(args.split, args.count)[args.skip:]:
        per = []
        for k in range(args.repeats):
            head, rows, _, _ = run_draw(family, seed, ion_seed=seed * 100 + k)
            print(head, flush=True)
            per.append(rows)
        for i, row in enumerate(per[0]):
            found = [r[i] for r in per if "volume" in r[i]]
            if len(found) < 3:
                continue
            text = f"{family} seed {seed} {row['name']} ({row['true_volume']:.0f} nm³, {len(found)} draws):"
            for key, sig in (("volume", "sigma_v"), ("area", "sigma_a")):
                values = np.array([r[key] for r in found])
                stated = np.sqrt(np.mean([r[sig] ** 2 for r in found]))
                ratio = values.std(ddof=1) / stated
                ratios[key].append((ratio, len(found) - 1))
                text += f" {key} sd {values.std(ddof=1):.2f} vs stated {stated:.2f} (x{ratio:.2f});"
            lines.append(text)
            print(text, flush=True)
    for key, rs in ratios.items():
        if rs:  # pooled over objects, weighted by degrees of freedom
            dof = sum(d for _, d in rs)
            pooled = np.sqrt(sum(r ** 2 * d for r, d in rs) / dof)
            lines.append(f"- {key}: observed sd / stated error, pooled over {len(rs)} objects ({dof} dof): "
                         f"{pooled:.2f} (a ratio of 1 lies within +-{1.96 / np.sqrt(2 * dof):.2f} at 95 %)")
            print(lines[-1], flush=True)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(f"# bench_object_errors --repeats {args.repeats} ({args.split})\n\n" + "\n".join(lines) + "\n")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="heldout", choices=list(SPLITS))
    ap.add_argument("--count", type=int, default=8)
    ap.add_argument("--skip", type=int, default=0, help="leave out the first draws")
    ap.add_argument("--specks-only", action="store_true", help="no refinement: the speck test's figures alone")
    ap.add_argument("--repeats", type=int, default=0,
                    help="instead: each draw's objects with their ions drawn this many times (the spread of the "
                         "volumes and areas over the repeats against the stated errors)")
    ap.add_argument("--out", help="also write the results file")
    ap.add_argument("--quick", action="store_true", help="the speck test alone on the first two draws")
    args = ap.parse_args(argv)
    if args.quick:
        args.count, args.specks_only = min(args.count, 2), True
    if args.repeats:
        return repeats(args)
    lines, rows, spurious, removed = [], [], [], []

    def say(text=""):
        lines.append(text)
        print(text, flush=True)

    for family, seed in draws(args.split, args.count)[args.skip:]:
        head, r, n_spurious, n_removed = run_draw(family, seed, refine=not args.specks_only)
        say(f"## {head}")
        for row in r:
            say(f"    {row['name']} ({row['true_volume'] or 0:.0f} nm³): {fmt(row)}")
        rows += r
        spurious.append(n_spurious)
        removed.append(n_removed)
    say()
    say(f"## summary: {args.split}, draws {args.skip}-{args.count - 1}")
    for line in summary(rows, spurious, removed):
        say(line)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(f"# bench_object_errors ({args.split})\n\nmachine: 2 cores shared with other jobs\n\n"
                     + "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
