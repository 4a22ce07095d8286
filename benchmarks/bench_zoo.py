"""The surface estimator's defaults on specimens it was not tuned on (issue 25): the specimen zoo.

    .venv/bin/python -m benchmarks.bench_zoo [--split heldout] [--count 8] [--families rod plate] [--write]

Each draw of :mod:`apt_filters.synth.zoo` (randomised shapes, sizes, contrasts, interface widths,
segregants, efficiencies, blurs; ``dev`` and ``heldout`` splits by seed and by family) is generated and
two surfaces are drawn on the same ions at the iso-value a user would give, the midpoint of the iso
species' two phases (all ranged species in the denominator):

``AP``        AP Suite-style: 1 nm voxels, Gaussian 3 x 3 x 1.5 nm delocalization, all ranged species in the
              denominator, marching cubes; specks removed by the pipeline's rule.
``defaults``  What ``apt-filters run INPUT -r R -o OUT --species EL --iso C`` draws, every option at its
              default (:func:`~apt_filters.pipeline.surface.finished_surface`: contour, segregants, specks,
              refinement, clean chain, remesh).

Per true object: volume and area errors with their counting sigma (the Cramér-Rao floor of
:func:`~apt_filters.refine.evaluate.counting_floor`, segregant as marker where there is one; for an object cut by
the edge, of its part compared, from the ions there), mean and
Hausdorff distance to the true surface (for an interface, beside its mean distance the counting floor of it,
:func:`~apt_filters.truth.distance_floor`), and the chemistry ``apt-filters run`` reports (:func:`run_chemistry`:
the proxigram over the range its fitted width asks for, :func:`~apt_filters.analysis.width.fitted_proxigram`, and
per object the segregant's Krakauer-Seidman excess, :func:`~apt_filters.analysis.excess.interfacial_excess`, and
the iso species' inside plateau, the window composition of the report's summary) against what the object's
own ions hold in its true frame (:func:`~apt_filters.refine.evaluate.counted_truth`) with that count's Poisson
and binomial sigma. The truth's inside window is the one the run's rule
(:func:`~apt_filters.analysis.width.inside_windows`) gives the true object from its ions' true depths, not the
run's window: a thin object's deeper half, the same as the run's where the run has its depth right. Surfaces
that end at the specimen edge (open, curved and bicontinuous interfaces, objects cut by the edge) are compared
inside the box shrunk by ``MARGIN`` nm (:func:`~apt_filters.truth.surface_error_within`): area (for an
interface, its area per volume of that region), distances and, for a cut object, volume; an interface's pieces
are all the components near it. Their chemistry is measured on the faces and ions inside that region (the ions beyond
the clipped surface's rim left out, as the run leaves out those beyond the specimen edge) and compared with
the count of its ions. Per specimen: objects not found and spurious objects (components that match no true
object). The summary checks the issue's targets per family.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from typing import Callable

import numpy as np

from apt_filters.analysis.excess import POOLED, interfacial_excess
from apt_filters.analysis.width import fitted_proxigram, inside_windows
from apt_filters.contour import marching_cubes
from apt_filters.contour.metrics import sample_mesh
from apt_filters.core.mesh import TriMesh, split_components
from apt_filters.io.ions import IonTable
from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
from apt_filters.pipeline.surface import finished_surface
from apt_filters.pipeline.summary import window_composition
from apt_filters.refine import remove_specks
from apt_filters.refine.composition import ion_atoms
from apt_filters.synth import generate
from apt_filters.synth.zoo import SPLITS, draws, zoo_specimen
from apt_filters.truth import (counted_truth, counting_floor, distance_floor, match_objects, surface_error,
                               surface_error_within)
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize
from benchmarks.results import ratio, write_results

PIPELINES = ("AP", "defaults")
MARGIN = 2.0
"""nm: surfaces ending at the specimen edge are compared this far inside it (the measured surface stops at
the voxel mask, about a voxel short of the edge)."""


def user_iso(spec, species: str) -> float:
    """The iso-value a user would give: midway between the matrix and the objects (all species counted)."""
    inside = spec.features[0].composition.get(species, 0.0)
    return 0.5 * (inside + spec.matrix.get(species, 0.0))


def iso_surface(spec, truth: dict) -> tuple[str, float]:
    """(species, iso-value) of a draw's surface: the species its first object gains most over the matrix, at
    :func:`user_iso`; ``truth`` the draw's ``truth.json``."""
    inside = truth["features"][0]["composition_inside"]
    species = max(inside, key=lambda e: inside[e] - spec.matrix.get(e, 0.0))
    return species, user_iso(spec, species)


def run_fields(sp, config: PipelineConfig):
    """(fields, mask, basis) as `apt-filters run` builds them from ``config``: the input of its surface."""
    v = config.voxel
    basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
    fields = voxelize(sp.ions, sp.ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size, basis=basis,
                      efficiency=config.analysis.efficiency)
    return fields, inside_mask(fields).dense(), basis


def surfaces(sp, species: str, iso: float) -> dict:
    """(mesh, seconds, note) of each pipeline."""
    t = time.perf_counter()
    fields = voxelize(sp.ions, sp.ranges)
    c = fields.concentration(species).dense()
    mask = inside_mask(fields).dense()
    ap, _ = remove_specks(marching_cubes(c, iso, spacing=fields.grid.voxel, origin=fields.grid.origin, mask=mask),
                          fields=fields, mask=mask, ions=sp.ions, ranges=sp.ranges, species=species, iso=iso)
    out = {"AP": (ap, time.perf_counter() - t, "")}
    t = time.perf_counter()
    config = PipelineConfig()
    fields, mask, basis = run_fields(sp, config)
    mesh, record = finished_surface(fields, mask, sp.ions, sp.ranges, SurfaceConfig(species, iso), config=config,
                                    basis=basis)
    note = f"basis: {record.refine['basis']}" if record.refine else "; ".join(record.warnings)
    out["defaults"] = (mesh, time.perf_counter() - t, note)
    return out


def truths(sp, species: str) -> dict:
    """Per feature: counting floor (volume and area sigma), counted truth and its sigmas."""
    spec = sp.spec
    seg = spec.features[0].segregation[0].species if spec.features[0].segregation else None
    everything = ion_atoms(sp.ions, sp.ranges, ConcentrationBasis())
    basis = ConcentrationBasis(exclude=(seg,) if seg else ())
    atoms = ion_atoms(sp.ions, sp.ranges, basis).atoms
    k_seg = everything.elements.index(seg) if seg else None
    k_iso = everything.elements.index(species)
    pos = sp.ions.positions
    bounded = [i for i, f in enumerate(sp.truth["features"]) if f["bounded"]]
    marker = None if seg is None else everything.atoms[:, k_seg]
    floors = {}
    whole = [i for i in bounded if not spec.features[i].shape.cut]
    if whole:
        fl = counting_floor([sp.feature_sdf(i) for i in whole], [spec.features[i].shape.level_area for i in whole],
                            [sp.truth["features"][i]["volume_nm3"] for i in whole], pos, atoms, marker=marker)
        floors |= dict(zip(whole, fl))
    # an object cut by the edge is compared inside the box shrunk by MARGIN (_edge_error): its floor is that part's,
    # from the ions there (the whole object's stated a 6.8 nm³ lens's volume error as a 76 nm³ object's, 1.1 %
    # for 12.7 %)
    cut = [i for i in bounded if spec.features[i].shape.cut]
    if cut:
        inner = [spec.features[i].shape.moved_in(MARGIN) for i in cut]
        there = _interior(sp, cut[0], pos)
        fl = counting_floor([sp.feature_sdf(i) for i in cut], [s.level_area for s in inner],
                            [s.volume() for s in inner], pos[there], atoms[there],
                            marker=None if marker is None else marker[there])
        floors |= dict(zip(cut, fl))
    # an interface's mean distance has a floor of its own: the ideal estimate low-passed as the refinement's
    # (distance_floor), from the offset floor of its part inside the compared region
    for i in (i for i, f in enumerate(sp.truth["features"]) if not f["bounded"]):
        there, region = _interior(sp, i, pos), _region(sp)
        pts, _ = sample_mesh(sp.meshes[i], 200.0, np.random.default_rng(0))
        area = sp.meshes[i].area() * float(np.mean(region(pts) < 0))
        [fl] = counting_floor([sp.feature_sdf(i)], [lambda d, a=area: np.full(len(d), a)], [area], pos[there],
                              atoms[there])
        floors[i] = distance_floor(true_mesh=sp.meshes[i], sdf=sp.feature_sdf(i), offset=fl.offset, area=area,
                                   region=region)
    out = {}
    for i, tf in enumerate(sp.truth["features"]):
        inside = np.array([tf["composition_inside"].get(e, 0.0) for e in everything.elements])
        outside = np.array([tf["composition_outside"].get(e, 0.0) for e in everything.elements])
        d = sp.feature_sdf(i)(pos.astype(np.float64))
        near = (np.abs(d) < 3.5) & _interior(sp, i, pos)
        ct = counted_truth(lambda p, d=d[near]: d, pos[near], everything.atoms[near], inside, outside)
        band = np.abs(d[near]) <= 1.5
        n_seg = float(everything.atoms[near][band, k_seg].sum()) if seg else 0.0
        out[i] = {"floor": floors.get(i), "counted": ct, "seg": seg, "k_seg": k_seg, "k_iso": k_iso,
                  "excess_sigma": np.sqrt(max(n_seg, 1.0)), "distance": d, "region": _interior(sp, i, pos),
                  "atoms": everything.atoms}
    return out


def _reaches_edge(sp, i: int) -> bool:
    """Whether feature ``i``'s surface ends at the specimen edge (an interface, or an object cut by the edge)."""
    shape = sp.spec.features[i].shape
    return shape.bounds() is None or shape.cut


def _region(sp) -> Callable[[np.ndarray], np.ndarray]:
    """The box shrunk by ``MARGIN`` (negative inside), where surfaces that reach the edge are compared."""
    return lambda points: sp.spec.geometry.sdf(np.asarray(points, dtype=np.float64)) + MARGIN


def _interior(sp, i: int, points: np.ndarray) -> np.ndarray:
    """Where feature ``i`` is compared: everywhere for a whole object, else inside the box shrunk by ``MARGIN``."""
    if not _reaches_edge(sp, i):
        return np.ones(len(points), dtype=bool)
    return _region(sp)(points) < 0


def _clipped(sp, i: int, mesh: TriMesh) -> TriMesh:
    """The faces of ``mesh`` whose centroids lie where feature ``i`` is compared."""
    keep = _interior(sp, i, mesh.vertices[mesh.faces].mean(axis=1))
    used, faces = np.unique(mesh.faces[keep], return_inverse=True)
    return TriMesh(mesh.vertices[used], faces.reshape(-1, 3))


def _joined(parts: list[TriMesh]) -> TriMesh:
    """One mesh of several components."""
    offsets = np.cumsum([0] + [p.n_vertices for p in parts[:-1]])
    return TriMesh(np.vstack([p.vertices for p in parts]), np.vstack([p.faces + o for p, o in zip(parts, offsets)]))


def _edge_error(sp, i: int, part: TriMesh, seed: int):
    """An open interface or a cut object against its truth inside the box shrunk by ``MARGIN``."""
    shape, box, region = sp.spec.features[i].shape, sp.spec.geometry, _region(sp)
    if shape.cut:  # the same sphere cut by the face moved in: exact volume and area inside the region
        inner = shape.moved_in(MARGIN)
        lo, hi = shape.bounds()
        blo, bhi = box.bounds()
        bounds = (np.maximum(lo - 1.0, blo + MARGIN), np.minimum(hi + 1.0, bhi - MARGIN))
        return surface_error_within(part, shape.sdf, sp.meshes[i], region, inner.area(), inner.volume(), bounds,
                                    seed=seed)
    true = sp.meshes[i]  # the true interface's area inside the region, by the same estimator as the measured one
    pts, _ = sample_mesh(true, 200.0, np.random.default_rng(seed + 1))
    return surface_error_within(part, shape.sdf, true, region, true.area() * float(np.mean(region(pts) < 0)),
                                seed=seed)


def run_chemistry(mesh: TriMesh, ions: IonTable, ranges, species: str, solute: str | None) -> dict:
    """What ``apt-filters run`` reports of each object of ``mesh`` (default options): object id (or ``POOLED``,
    the pieces together) -> (the solute's Krakauer-Seidman excess in detected atoms per nm² or NaN, the iso
    species' fraction in the inside plateau window, where that window starts in nm: the fitted inner edge, or
    nearer for an object thinner than twice it, :func:`~apt_filters.analysis.width.inside_windows`), as the run's
    proxigram step computes them (:func:`apt_filters.pipeline.run`); and the plateau windows (inner, outer nm) it
    fitted."""
    config = PipelineConfig()
    p = config.proxigram
    solutes = [solute] if solute else []
    prox, windows = fitted_proxigram(ions=ions, ranges=ranges, mesh=mesh, species=species, solutes=solutes,
                                     bin_width=p.bin, inner=p.inner or None, outer=p.extent or None,
                                     keep_edge=not p.exclude_edge)
    gamma = {}
    if solute:
        for e in interfacial_excess(prox, solute, config.analysis.efficiency, windows.inner, windows.outer,
                                    skip_unmeasurable=True, fit=windows.fit_of(solute)):
            gamma[e.object_id] = e.cumulative.gamma_detected
    out = {}
    for k, obj in enumerate(list(prox.object_ids) + ([POOLED] if len(prox.object_ids) > 1 else [])):
        profile = prox if obj == POOLED else replace(prox, object_ids=prox.object_ids[k:k + 1], counts=prox.counts[k:k + 1],
                                                     unranged=prox.unranged[k:k + 1], areas=prox.areas[k:k + 1],
                                                     shell_volumes=prox.shell_volumes[k:k + 1])
        window = window_composition(profile, windows.inner, windows.outer)["inside"]
        inside = window["fraction"].get(species)
        start = min([c["from_nm"] for c in window["nearer"]], default=windows.inner)
        out[int(obj)] = (gamma.get(int(obj), np.nan), np.nan if inside is None else inside, start)
    return out, (windows.inner, windows.outer)


def evaluate(sp, mesh, species: str, truth: dict, seed: int, family: str) -> tuple[list[dict], int]:
    """Rows per true feature, and the number of spurious objects."""
    parts = split_components(mesh) if mesh.n_faces else []
    feats = list(range(len(sp.truth["features"])))
    match = match_objects(parts, [sp.feature_sdf(i) for i in feats])
    seg = truth[0]["seg"]
    chemistry, windows = run_chemistry(mesh, sp.ions, sp.ranges, species, seg) if parts else ({}, None)
    rows, used = [], set()
    for i, m in zip(feats, match):
        tf, tr = sp.truth["features"][i], truth[i]
        shape = sp.spec.features[i].shape
        row = {"family": family, "name": tf["name"], "bounded": tf["bounded"], "cut": shape.cut, "found": m is not None,
               "true_volume": tf["volume_nm3"] if tf["bounded"] else None, "d_target": 0.15 if tf["bounded"] else 0.1}
        if m is None:
            rows.append(row)
            continue
        part = parts[m]
        used.add(m)
        ct = tr["counted"]
        if tf["bounded"] and not shape.cut:
            err = surface_error(part, sp.feature_sdf(i), sp.meshes[i], tf["volume_nm3"], tf["area_nm2"], seed=seed)
        else:
            if not tf["bounded"]:  # an interface may reach the edge in pieces: all components near it are it
                near = [j for j, p in enumerate(parts)
                        if np.abs(sp.feature_sdf(i)(p.vertices[np.unique(p.faces)])).mean() < 1.5]
                used.update(near)
                part = _joined([parts[j] for j in near])
            inner = _clipped(sp, i, part)
            if not inner.n_faces:  # the run's surface lies only outside the compared region: not found there
                rows.append(row | {"found": False})
                continue
            err = _edge_error(sp, i, part, seed)
        row |= {"area": err.area_error, "mean": err.mean_distance, "hausdorff": err.hausdorff}
        if tf["bounded"]:
            row |= {"volume": err.volume_error, "volume_sigma": tr["floor"].volume, "area_sigma": tr["floor"].area}
        else:
            row |= {"d_floor": tr["floor"]}
        if _reaches_edge(sp, i):  # the surface, its ions and their count inside the compared region only
            keep = _interior(sp, i, sp.ions.positions)
            ions = IonTable(sp.ions.positions[keep], sp.ions.mz[keep], {k: v[keep] for k, v in sp.ions.extra.items()})
            found, windows = run_chemistry(inner, ions, sp.ranges, species, seg)
            (per_area, inside, start), true_area = found.get(POOLED, found.get(0)), err.true_area
        else:
            (per_area, inside, start), true_area = chemistry[m], tf["area_nm2"]
        # the inside plateau the object's own ions hold, counted in its true frame in the window the run's rule
        # gives the true object (its own depth from its ions' true distances: not the run's window, so a run
        # that misjudges an object's depth or surface is caught, not followed)
        d, atoms = tr["distance"], tr["atoms"]
        own = tr["region"] & (d < 0) & (d >= -windows[1])
        [true_start] = inside_windows(depth=-d[own], atoms=atoms[own].sum(axis=1), inner=windows[0])
        window = tr["region"] & (d <= -true_start) & (d >= -windows[1])
        n_in = float(atoms[window].sum())
        c_in = float(atoms[window, tr["k_iso"]].sum()) / max(n_in, 1.0)
        if seg:  # per area, scaled to the true area
            held, measured = ct.excess_ions[tr["k_seg"]], per_area * true_area
            row |= {"excess": measured - held, "excess_rel": measured / held - 1, "excess_sigma": tr["excess_sigma"]}
        row |= {"plateau_in": inside - c_in, "plateau_sigma": np.sqrt(c_in * (1 - c_in) / max(n_in, 1.0)),
                "plateau_from": (start, true_start) if min(start, true_start) < windows[0] else None}
        rows.append(row)
    return rows, sum(1 for j in range(len(parts)) if j not in used)


def fmt(r: dict) -> str:
    if not r["found"]:
        return "not found"
    cells = []
    if "volume" in r:
        cells += [f"V {100 * r['volume']:+.1f}% (σ {100 * r['volume_sigma']:.1f})",
                  f"A {100 * r['area']:+.1f}% (σ {100 * r['area_sigma']:.1f})"]
    else:
        cells.append(f"area/volume {100 * r['area']:+.1f}%")
    cells.append(f"d {r['mean']:.3f}" + (f" (floor {r['d_floor'].mean:.3f} at l {r['d_floor'].length:.1f} nm)"
                                         if "d_floor" in r else ""))
    cells.append(f"H {r['hausdorff']:.2f}")
    if "excess_rel" in r:
        cells.append(f"excess {100 * r['excess_rel']:+.1f}% ({r['excess'] / r['excess_sigma']:+.1f}σ)")
    if r["plateau_sigma"] > 0:
        cells.append(f"in {100 * r['plateau_in']:+.2f} at.% ({r['plateau_in'] / r['plateau_sigma']:+.1f}σ"
                     + (", window from {:.2f} nm, true {:.2f}".format(*r["plateau_from"]) if r.get("plateau_from")
                        else "") + ")")
    else:  # the run's window lies deeper than the object: no count to compare with (not within)
        cells.append(f"in {100 * r['plateau_in']:+.2f} at.% (none of the object's ions in the run's window)")
    return ", ".join(cells)


def _within(r: dict, key: str) -> bool:
    return abs(r[key]) <= max(0.05, 2 * r[key + "_sigma"])


def summary(rows: dict, spurious: dict) -> str:
    """Per family and pipeline: how many objects meet each of the issue's targets."""
    lines = ["| family | pipeline | found (>= 30 nm³) | spurious | volume within max(5 %, 2σ) | area within | worst "
             "volume | mean d <= 0.15 (interfaces 0.1) | Hausdorff <= 1 | excess within 2σ | plateau within 2σ | "
             "interfaces: area/volume within 5 % |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    families = list(dict.fromkeys(r["family"] for r in rows[PIPELINES[0]]))
    for fam in families + ["all"]:
        for p in PIPELINES:
            mine = [r for r in rows[p] if fam in ("all", r["family"])]
            found = [r for r in mine if r["found"]]
            closed = [r for r in found if r["bounded"]]
            big = [r for r in mine if r["bounded"] and r["true_volume"] >= 30]
            faces = [r for r in found if not r["bounded"]]
            ex = [r for r in found if "excess" in r]
            worst = max((abs(r["volume"]) for r in closed), default=np.nan)
            lines.append(
                f"| {fam} | {p} | {len(found)} / {len(mine)} ({sum(r['found'] for r in big)} / {len(big)}) | "
                f"{sum(spurious[p].get(fam, 0) for fam in (families if fam == 'all' else [fam]))} | "
                f"{sum(_within(r, 'volume') for r in closed)} of {len(closed)} | "
                f"{sum(_within(r, 'area') for r in closed)} of {len(closed)} | {100 * worst:.1f}% | "
                f"{sum(r['mean'] <= r['d_target'] for r in found)} of {len(found)} | "
                f"{sum(r['hausdorff'] <= 1 for r in found)} of {len(found)} | "
                f"{sum(abs(r['excess']) <= 2 * r['excess_sigma'] for r in ex)} of {len(ex)} | "
                f"{sum(abs(r['plateau_in']) <= 2 * r['plateau_sigma'] for r in found)} of {len(found)} | "
                f"{sum(abs(r['area']) <= 0.05 for r in faces)} of {len(faces)} |")
    return "\n".join(lines)


def summary_rows(rows: dict) -> list[tuple[str, str, str, str, str]]:
    """The results file's summary rows (benchmarks/__main__.py gathers them into RESULTS.md)."""
    def figures(p):
        found = [r for r in rows[p] if r["bounded"] and r["found"]]
        closed = sum(r["bounded"] for r in rows[p])
        d = float(np.nanmean([r["mean"] for r in found])) if found else np.nan
        return sum(_within(r, "volume") for r in found), sum(_within(r, "area") for r in found), closed, d

    (v_ours, a_ours, n, d_ours), (v_peer, a_peer, _, d_peer) = figures("defaults"), figures("AP")
    # a closed object not found counts as outside: n is every closed true object
    return [("refine", "held-out zoo closed objects with volume within max(5 %, 2 counting σ) (not found: outside)",
             f"{v_ours} of {n}", f"{v_peer} of {n} (AP Suite-style)", "-"),
            ("refine", "held-out zoo closed objects with area within max(5 %, 2 counting σ) (not found: outside)",
             f"{a_ours} of {n}", f"{a_peer} of {n} (AP Suite-style)", "-"),
            ("refine", "held-out zoo mean distance to the true surface, mean over objects", f"{d_ours:.3f} nm",
             f"{d_peer:.3f} nm (AP Suite-style)", ratio(d_ours, d_peer))]


def _describe(artefact) -> str:
    if artefact.kind == "local_magnification":
        return f"density ratio {artefact.ratio:.2f}"
    return "depths " + ", ".join(f"{d:.2f}" for d in artefact.depths)


def specimen(family: str, seed: int):
    """(specimen, iso species, user's iso-value, a heading line describing the draw) of one zoo draw."""
    spec = zoo_specimen(family, seed)
    sp = generate(spec, seed)
    species, iso = iso_surface(spec, sp.truth)
    f0 = spec.features[0]
    seg = f0.segregation[0] if f0.segregation else None
    header = (f"## {family} seed {seed}: {len(sp.ions):,} ions, {species} {100 * spec.matrix[species]:.1f} -> "
              f"{100 * f0.composition[species]:.1f} at.%, iso {100 * iso:.1f}, width {f0.width:.2f} nm, efficiency "
              f"{spec.efficiency:.2f}, blur {spec.blur[0]:.2f}/{spec.blur[1]:.2f}, segregant "
              f"{'none' if seg is None else f'{seg.species} peak {seg.peak:.3f} sigma {seg.sigma:.2f}'}"
              + "".join(f"; {a.kind} {_describe(a)}" for a in spec.artefacts[:2]))
    return sp, species, iso, header


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", default="heldout", choices=list(SPLITS))
    ap.add_argument("--count", type=int, default=8, help="draws, families in turn")
    ap.add_argument("--families", nargs="+", help="only these families (of the split's draws)")
    ap.add_argument("--skip", type=int, default=0, help="leave out the first draws")
    ap.add_argument("--write", action="store_true", help="write benchmarks/results_zoo.md (summary block first)")
    ap.add_argument("--intro", help="a file whose text goes between the summary block and the draws")
    args = ap.parse_args(argv)
    rows = {p: [] for p in PIPELINES}
    spurious = {p: {} for p in PIPELINES}
    lines = [f"## Draws: {args.split}, {args.count}", "",
             "machine: 2 cores shared with other jobs; times are wall seconds of one run", ""]
    print("\n".join(lines))

    def say(text=""):
        lines.append(text)
        print(text, flush=True)

    for family, seed in draws(args.split, args.count)[args.skip:]:
        if args.families and family not in args.families:
            continue
        sp, species, iso, header = specimen(family, seed)
        say(header)
        truth = truths(sp, species)
        for p, (mesh, seconds, note) in surfaces(sp, species, iso).items():
            r, n_spurious = evaluate(sp, mesh, species, truth, seed, family)
            rows[p] += r
            spurious[p][family] = spurious[p].get(family, 0) + n_spurious
            say(f"  {p} ({seconds:.1f} s{', ' + note if note else ''}; {n_spurious} spurious)")
            for row, tf in zip(r, sp.truth["features"]):
                say(f"    {row['name']} ({tf['volume_nm3'] or 0:.0f} nm³): {fmt(row)}")
        say()
    say(f"## summary: {args.split}, {args.count} draws\n")
    say(summary(rows, spurious))
    if args.write:
        intro = open(args.intro, encoding="utf-8").read() if args.intro else ""
        write_results("zoo", f"bench_zoo: the defaults on the specimen zoo ({args.split})", summary_rows(rows),
                      ["\n".join(lines)], intro=intro)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
