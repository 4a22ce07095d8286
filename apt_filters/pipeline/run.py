"""``apt-filters run``: every step from an ion file to a report, in one call.

read -> range -> audit -> voxelize -> contour -> specks and refinement against the ions ->
clean (MeshLab chain, saved as .mlx) -> remesh (CVT) -> objects -> proxigram and excess ->
exports (PLY, ion cloud, MeshLab project) -> report.json / report.html / config.toml.

Everything is written into a staging folder that replaces the output folder only when
the run succeeds, and the output folder is checked before any work (:mod:`.staging`). The
memory the voxel grid may need is checked right after reading, before the audit. Runs are
deterministic: the same configuration gives the same numbers and meshes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apt_filters.core.atomic import atomic_write_text, remove, scratch_path, signals_held
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.io import read_ions
from apt_filters.io.summary import summarize
from apt_filters.pipeline import report as rep
from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig, check_config
from apt_filters.pipeline.inputs import check_inputs, config_ranges
from apt_filters.pipeline.picture import render_surfaces
from apt_filters.pipeline.staging import staged_folder
from apt_filters.pipeline.surface import contour_surface
from apt_filters.pipeline.steps import StepLog
from apt_filters.pipeline.summary import surface_summary

MINORITY = 0.10
"""Elements below this overall fraction are the default solutes of the excess."""


def surface_label(surface: SurfaceConfig) -> str:
    """File-name label of an iso-surface: ``Al15`` (15 at.% Al) or ``density40`` (atoms/nm³)."""
    if surface.species:
        return f"{surface.species}{surface.iso * 100:g}"
    return f"density{surface.iso:g}"


@dataclass
class SurfaceResult:
    label: str
    surface: SurfaceConfig
    mesh: TriMesh
    objects: list[dict] = field(default_factory=list)
    excess: list[dict] = field(default_factory=list)
    proxigram: object = None
    stats: dict = field(default_factory=dict)
    summary: list[dict] = field(default_factory=list)
    maps: list[dict] = field(default_factory=list)
    quality: tuple | None = None
    """(vertex scalar, colour range, meaning) MeshLab shows as quality; None: the scene's local composition."""


def _counting_errors(mesh, offset_errors) -> list[dict]:
    """Per refined object: the counting-statistics standard error of its mean offset and, if closed, of its volume."""
    from apt_filters.core.mesh import split_components

    out = []
    for c, (e, part) in enumerate(zip(offset_errors, split_components(mesh))):
        if np.isfinite(e):
            closed = len(part.boundary_edges()) == 0  # an open interface encloses no volume
            out.append({"component": c, "offset_se_nm": float(e), "area_nm2": part.area(),
                        "volume_nm3": part.signed_volume() if closed else None,
                        "volume_se_nm3": float(e) * part.area() if closed else None})
    return out


def _finite(values) -> list:
    """Floats for JSON, which has no NaN: None where not finite."""
    return [float(v) if np.isfinite(v) else None for v in values]


def _marker(marks) -> dict | None:
    """The segregant's mark in report.json: each object's peak centre, the layer's offset and the moves (nm)."""
    if marks is None:
        return None
    return {"species": marks.name, "objects_moved": marks.marked,
            "layer_offset_nm": _finite([marks.layer_offset])[0],
            "layer_offset_se_nm": _finite([marks.layer_offset_se])[0],
            "peak_centre_nm": _finite(marks.centre), "peak_centre_se_nm": _finite(marks.centre_se),
            "shift_nm": _finite(marks.shift)}


ION_BYTES = 16
"""Bytes per ion of a table in memory: positions and m/z, float32."""


def memory_budget(config: PipelineConfig) -> int:
    """The run's memory budget in bytes: ``[input] memory_budget`` GB, or the machine's default."""
    from apt_filters.voxel import default_budget

    if config.input.memory_budget < 0 or not np.isfinite(config.input.memory_budget):
        raise AptFiltersError(f"memory budget must be a positive number of GB, got {config.input.memory_budget:g}")
    return int(config.input.memory_budget * 1e9) if config.input.memory_budget > 0 else default_budget()


def load_ions(config: PipelineConfig, ranges, summary, scratch: Path):
    """The ions, in memory when the table fits the memory budget beside the fields, else memory-mapped.

    The fields' bound (every block of the ions' box occupied, :func:`~apt_filters.voxel.check_budget`)
    comes first: a run whose fields cannot fit the budget even with the ions streamed is refused
    here, in one line, before any work. Then the table (:data:`ION_BYTES` per ion) is read into
    memory if it fits beside them, or else mapped from a native scratch copy in ``scratch``
    (:func:`~apt_filters.io.map_ions`), so that every later pass reads it slice by slice.
    """
    from apt_filters.io import map_ions
    from apt_filters.voxel import Grid, check_budget, kernel_reach

    v, budget = config.voxel, memory_budget(config)
    grid = Grid.covering(summary.lower, summary.upper, v.size, kernel_reach(v.kernel, v.size, v.delocalization))
    n_fields = len(ranges.elements) + bool(v.include_unranged)
    fields = check_budget(grid, n_fields, budget)
    if summary.ions * ION_BYTES + fields <= budget:
        return read_ions(config.input.ions)
    return map_ions(config.input.ions, scratch)


@contextlib.contextmanager
def scratch_folder(out: str | Path):
    """A temporary folder beside the output folder (same file system), removed afterwards.

    Named after this process (:func:`~apt_filters.core.atomic.scratch_path`), so that a run
    killed outright leaves a folder the next run there removes (:func:`~apt_filters.core.atomic.tidy`).
    """
    folder = scratch_path(Path(out).resolve())
    folder.mkdir()
    try:
        yield folder
    finally:
        with signals_held():
            remove(folder)


def _absolute_inputs(config: PipelineConfig) -> PipelineConfig:
    """``config`` with absolute input paths (its config.toml then works from any folder)."""
    ions, ranges = (os.path.abspath(Path(p).expanduser()) for p in (config.input.ions, config.input.ranges))
    return dataclasses.replace(config, input=dataclasses.replace(config.input, ions=ions, ranges=ranges))


def segregant_basis(mesh: TriMesh, ions, ranges, species: str, basis, include=()):
    """The basis a concentration surface of ``species`` is drawn in: ``basis`` without the segregants its first
    contour ``mesh`` shows (:func:`~apt_filters.refine.segregants.find_segregants`; those in ``include`` stay).
    Returns (basis, Segregants), or (``basis``, None) for a density surface; ``basis`` itself where none is found."""
    from apt_filters.refine.segregants import find_segregants
    from apt_filters.voxel import ConcentrationBasis

    if not species:
        return basis, None
    found = find_segregants(mesh, ions, ranges, species, basis=basis, include=tuple(include))
    if not found.species:
        return basis, found
    return ConcentrationBasis(tuple(basis.exclude) + found.species, basis.include_unranged), found


def run_pipeline(config: PipelineConfig, out: str | Path, force: bool = False, quiet: bool = False,
                 verbose: bool = False, truth: dict | None = None) -> dict:
    """Run every step and write the output folder ``out``; returns the report's content.

    Prints one line per step (time, peak memory, what it found) unless ``quiet``; ``verbose``
    adds every range-file finding. ``truth`` (a synthetic specimen's truth.json) adds a
    comparison with the ground truth.
    """
    from apt_filters.analysis.excess import interfacial_excess
    from apt_filters.analysis.objects import object_table
    from apt_filters.analysis.proxigram import compute_proxigram
    from apt_filters.audit import audit_ranges
    from apt_filters.meshlab.chains import apply_chain
    from apt_filters.pipeline.scene import scene_species, write_scene
    from apt_filters.refine import refine_surface, remove_specks
    from apt_filters.remesh import remesh
    from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

    check_config(config)
    config = check_inputs(config)
    config = _absolute_inputs(config)
    per_surface = 4 + (config.remesh.method == "cvt") + config.analysis.maps
    n_refined = sum(bool(config.refine.enabled and s.species) for s in config.surface)
    log = StepLog(quiet=quiet, total=3 + config.analysis.audit + per_surface * len(config.surface) + n_refined)
    report: dict = {"apt-filters": rep.versions(), "config": dataclasses.asdict(config)}
    with staged_folder(out, force=force, inputs=[config.input.ions, config.input.ranges]) as stage, \
            scratch_folder(out) as scratch:
        (stage / "meshes").mkdir()
        with log.step("read") as s:
            ranges = config_ranges(config)
            report["range_file"] = [dataclasses.asdict(n) for n in ranges.notes]
            summary = summarize(config.input.ions, ranges)  # streamed from the file: nothing kept
            ions = load_ions(config, ranges, summary, scratch)
            report["inputs"] = [rep.file_record(config.input.ions), rep.file_record(config.input.ranges)]
            report["ions"] = {"count": summary.ions, "ranged_fraction": summary.ranged_fraction,
                              "bounds_nm": [summary.lower.tolist(), summary.upper.tolist()]}
            report["composition"] = summary.composition()
            s.summary = (f"{len(ions):,} ions{' (memory-mapped)' if isinstance(ions.mz, np.memmap) else ''}, "
                         f"{summary.ranged_fraction:.1%} ranged, {len(ranges)} ranges")
        if config.analysis.audit:
            with log.step("audit") as s:
                result = audit_ranges(ions, ranges)
                report["audit"] = [dataclasses.asdict(f) for f in result.flagged]
                errors = [f for f in report["audit"] if f["severity"] == "error"]
                n_warn = len(report["audit"]) - len(errors)
                s.summary = (f"{len(errors)} range-file errors, {n_warn} warnings"
                             + (" (--verbose lists them)" if n_warn and not verbose else ""))
                # errors make figures wrong: always in words; warnings only when asked
                shown = report["audit"] if verbose else errors
                s.summary += "".join(f"\n    {f['severity'].upper():7} {f['message']}" for f in shown)
                if errors:
                    s.summary += ("\n    figures that count a mislabelled range are wrong: relabel it (--relabel "
                                  "OLD=NEW, e.g. Cr2O=Ni) or correct the range file, and run again")
        with log.step("voxelize") as s:
            v = config.voxel
            basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
            fields = voxelize(ions, ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size,
                              basis=basis, efficiency=config.analysis.efficiency)
            mask = inside_mask(fields).dense()
            report["voxel"] = {"grid_shape": list(fields.grid.shape), "origin_nm": list(fields.grid.origin),
                               "basis": basis.describe(), "inside_fraction": float(mask.mean())}
            s.summary = f"grid {fields.grid.shape}, {fields.total.n_blocks} blocks, basis: {basis.describe()}"
        results = []
        for surface in config.surface:
            label = surface_label(surface)
            with log.step("contour") as s:
                mesh = contour_surface(fields, mask, surface.species, surface.iso, config.contour.method,
                                       config.contour.close_at_edge)
                surface_basis, segregants = segregant_basis(mesh, ions, ranges, surface.species, basis,
                                                            config.voxel.include)
                if surface_basis is not basis:  # contoured again without the segregants' dilution
                    mesh = contour_surface(fields, mask, surface.species, surface.iso, config.contour.method,
                                           config.contour.close_at_edge, basis=surface_basis)
                s.summary = (f"{label}: {mesh.n_vertices:,} vertices, {mesh.n_faces:,} faces ({config.contour.method})"
                             + (f"; {segregants.describe()}, basis: {surface_basis.describe()}" if segregants else ""))
            raw_area = mesh.area()
            if config.refine.enabled and surface.species:
                with log.step("refine") as s:
                    mesh, specks = remove_specks(mesh, config.refine.min_volume, config.refine.min_area)
                    refined = refine_surface(mesh, ions, ranges, surface.species, surface_basis,
                                             iterations=config.refine.iterations, facets=config.refine.facets,
                                             blur=tuple(config.refine.blur) or "auto",
                                             cross_fit=config.refine.cross_fit,
                                             select_modes=config.refine.select_modes,
                                             marker=config.refine.marker)
                    mesh = refined.mesh
                    estimate = refined.blur_estimate
                    refine_stats = {"basis": surface_basis.describe(),
                                    "segregants": None if segregants is None else dataclasses.asdict(segregants),
                                    "specks_removed": specks.count, "speck_volumes_nm3": specks.volumes,
                                    "displacement_nm": refined.displacement, "folded_pairs": refined.folded_pairs,
                                    "self_intersections": refined.self_intersections, "facets": refined.facets,
                                    "sharpened_vertices": refined.sharpened, "blur_nm": list(refined.blur),
                                    "blur_estimate": None if estimate is None else
                                    {"lateral_nm": estimate.lateral, "slope_nm2": estimate.slope,
                                     "slope_se_nm2": estimate.slope_se, "source": estimate.source},
                                    "cross_fit": config.refine.cross_fit,
                                    "modes": None if refined.modes is None else
                                    {str(c): k for c, k in sorted(refined.modes.modes.items())},
                                    "marker": _marker(refined.marker),
                                    "counting_errors": _counting_errors(mesh, refined.offset_errors)}
                    s.summary = (f"{label}: {specks.count} specks removed, mean displacement "
                                 f"{refined.displacement['mean']:+.2f} nm, {refined.folded_pairs} folds")
            else:
                refine_stats = None
            remesh_stats = None
            if mesh.n_faces == 0:  # every component was a speck: reported, nothing to clean, measure or export
                report.setdefault("warnings", []).append(f"no surface at this iso-value: every component of {label} "
                                                         "was a speck")
                results.append(SurfaceResult(label, surface, mesh, stats={
                    "raw_area_nm2": raw_area, "refine": refine_stats, "faces": 0, "vertices": 0, "area_nm2": 0.0,
                    "boundary_edges": 0}))
                continue
            with log.step("clean") as s:
                mesh, _ = apply_chain(mesh, "clean", script=stage / f"clean_{label}.mlx")
                s.summary = f"{label}: {mesh.n_faces:,} faces after the clean chain"
            if config.remesh.method == "cvt":
                with log.step("remesh") as s:
                    edge = config.remesh.edge_length or fields.grid.voxel / 2
                    try:
                        remeshed = remesh(mesh, edge_length=edge, feature_angle=config.remesh.feature_angle)
                        mesh, kept = remeshed.mesh, remeshed.kept_input
                        remesh_stats = {"components": len(remeshed.checks), "kept_input": kept,
                                        "failed": [dataclasses.asdict(c) for c in remeshed.checks if not c.ok]}
                        s.summary = f"{label}: {mesh.n_faces:,} faces at edge length {edge:g} nm"
                        if kept:  # each component whose remesh changed the surface keeps its input
                            warning = (f"remeshing {label}: {kept} of {len(remeshed.checks)} components changed "
                                       f"the surface and keep the cleaned mesh")
                            report.setdefault("warnings", []).append(warning)
                            s.summary += "; WARNING " + warning
                    except Exception as exc:  # noqa: BLE001 - a remesher failure must not cost the whole run
                        warning = f"remeshing {label} failed ({type(exc).__name__}: {exc}); the cleaned mesh is used"
                        report.setdefault("warnings", []).append(" ".join(warning.split()))
                        s.summary = "WARNING " + report["warnings"][-1]
            # One object numbering for the object table, the proxigram and the excess.
            mesh.face_scalars["object_id"] = mesh.face_components()
            res = SurfaceResult(label, surface, mesh)
            with log.step("objects") as s:
                table = object_table(mesh, ions, ranges, cap_open=config.contour.close_at_edge)
                table.write_csv(stage / f"objects_{label}.csv")
                table.write_json(stage / f"objects_{label}.json")
                res.objects = table.rows()
                res.stats["objects_dropped"] = table.n_dropped
                s.summary = f"{label}: {len(res.objects)} objects"
            with log.step("proxigram") as s:
                prox = compute_proxigram(ions, ranges, mesh, bin_width=config.proxigram.bin,
                                         max_distance=config.proxigram.extent,
                                         keep_edge=not config.proxigram.exclude_edge,
                                         iso_value=surface.iso if surface.species else None)
                prox.write_csv(stage / f"proxigram_{label}.csv")
                prox.plot(stage / f"proxigram_{label}.png", title=f"proxigram across {label}")
                solutes = config.proxigram.solutes or [
                    el for el, c in report["composition"].items() if c < MINORITY and el != surface.species]
                for solute in solutes:
                    res.excess += [dataclasses.asdict(e) for e in
                                   interfacial_excess(prox, solute, config.analysis.efficiency, skip_unmeasurable=True)]
                res.proxigram = prox
                res.summary = surface_summary(objects=res.objects, proxigram=prox, solutes=solutes,
                                              efficiency=config.analysis.efficiency)
                measured = {e["object_id"] for e in res.excess}
                res.stats["objects_without_excess"] = sorted(int(i) for i in set(prox.object_ids) - measured)
                s.summary = (f"{label}: excess of {', '.join(solutes) or 'no solute'}; "
                             f"{len(res.stats['objects_without_excess'])} objects too thin for plateaus")
            if config.analysis.maps:
                with log.step("maps") as s:
                    res.maps = _maps(res, ions, ranges, solutes, config, stage / f"map_{label}.png")
                    tested = [m for m in res.maps if m["p_value"] is not None]
                    s.summary = f"{label}: " + ("; ".join(
                        f"{m['solute']} on object {m['object_id']}: p = {m['p_value']:.2g}" for m in tested[:4])
                        or "no map tested")
            res.stats |= {"raw_area_nm2": raw_area, "refine": refine_stats, "remesh": remesh_stats, "faces": mesh.n_faces, "vertices": mesh.n_vertices, "area_nm2": mesh.area(),
                         "boundary_edges": len(mesh.boundary_edges())}
            results.append(res)
        with log.step("export") as s:
            drawn = [r for r in results if r.mesh.n_faces]  # a surface of specks only has nothing to show
            scene = write_scene(folder=stage, surfaces={r.label: r.mesh for r in drawn},
                                species={r.label: scene_species(r.surface.species or ranges.elements[0], r.summary) for r in drawn},
                                ions=ions, ranges=ranges,
                                quality={r.label: r.quality for r in drawn if r.quality is not None})
            sample = ions.positions[:: max(1, len(ions) // 20_000)]
            render_surfaces({r.label: r.mesh for r in drawn}, stage / "surfaces.png", points=sample)
            report["scene"] = scene
            s.summary = (f"project.mlp: {len(drawn)} surface(s) coloured by "
                         + ", ".join(f"{x['element']} at.%" for x in scene["surfaces"])
                         + f", {len(scene['ion_layers'])} ion layers, legend.png")
        report["surfaces"] = [{"label": r.label, "species": r.surface.species, "iso": r.surface.iso,
                               "mesh": r.stats, "summary": r.summary, "objects": r.objects, "excess": r.excess,
                               "maps": r.maps}
                              for r in results]
        rep.write_json(stage / "excess.json", {r.label: r.excess for r in results})
        if truth is not None:
            from apt_filters.truth.specimen import compare_with_truth, counted_excess

            report["truth"] = compare_with_truth(results, truth, counted_excess(truth, ions, ranges))
        report["steps"] = log.as_dicts()
        atomic_write_text(stage / "config.toml", config.to_toml())
        rep.write_json(stage / "report.json", report)
        pictures = [(stage / "surfaces.png", "The iso-surfaces seen from the side (z, the analysis direction, up), "
                     "each object in its own colour and numbered as in the tables; grey dots: a sample of the ions.")]
        pictures += [(stage / f"proxigram_{r.label}.png", f"Proxigram across {r.label}, all objects pooled: "
                      "ion (top) and atomic (bottom) concentration against the distance to the surface, "
                      "positive inside; bars are binomial standard errors.") for r in results]
        pictures += [(stage / f"map_{r.label}.png", f"The most significant excess map on {r.label}: detected atoms "
                      "per nm² per vertex, seen face-on and from behind (grey: no patch).") for r in results if r.maps]
        pictures.append((stage / "legend.png", "Legend of the MeshLab scene (project.mlp): each surface's colour, "
                         "the composition near it, and the ions drawn per species."))
        rep.write_html(stage / "report.html", report, pictures)
    return report


def _maps(res: SurfaceResult, ions, ranges, solutes: list[str], config: PipelineConfig, picture: Path) -> list[dict]:
    """Excess maps of ``solutes`` on ``res.mesh``: vertex properties on the mesh (PLY properties
    ``excess_<El>`` ...), a picture of the most significant one; returns the statistics rows."""
    from apt_filters.analysis.maps import excess_maps

    if not solutes:
        return []
    maps = excess_maps(mesh=res.mesh, ions=ions, ranges=ranges, solutes=solutes, bin_width=config.proxigram.bin,
                       max_distance=config.proxigram.extent, keep_edge=not config.proxigram.exclude_edge,
                       relative_error=config.analysis.map_error)
    res.mesh.vertex_scalars.update(maps.vertex_scalars())
    shown = maps.most_significant()
    maps.plot(picture, res.mesh, shown, overwrite=True)
    res.quality = (f"excess_{shown}", maps.limits(shown),
                   f"{shown} interfacial excess map, detected atoms/nm2 (analysis.maps; error: excess_{shown}_sigma)")
    return maps.rows()
