"""``apt-filters run``: every step from an ion file to a report, in one call.

A short list of steps, each returning a typed record that the report serialises: read
(:class:`Inputs`) -> audit -> voxelize (:class:`Voxels`) -> per iso-surface the finished surface
(:func:`~apt_filters.pipeline.surface.finished_surface`: contour, specks, refinement, clean chain,
remesh), the ions near it or inside its objects selected in one streamed pass
(:func:`~apt_filters.pipeline.surface.analysis_ions`), and from them its objects, proxigram, excess
and maps (:class:`SurfaceResult`) -> exports (PLY, ion cloud, MeshLab project) -> report.json /
report.html / config.toml.

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
from apt_filters.core.hull import SpecimenHull
from apt_filters.core.mesh import TriMesh
from apt_filters.io import read_ions
from apt_filters.io.summary import summarize
from apt_filters.pipeline import report as rep
from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig, check_config
from apt_filters.pipeline.inputs import check_inputs, config_ranges
from apt_filters.pipeline.picture import render_surfaces
from apt_filters.pipeline.staging import staged_folder
from apt_filters.pipeline.steps import StepLog
from apt_filters.pipeline.summary import object_plateaus, surface_summary
from apt_filters.pipeline.surface import SurfaceRecord, analysis_ions, finished_surface, surface_label

__all__ = ["MINORITY", "run_pipeline", "surface_label"]

MINORITY = 0.10
"""Elements below this overall fraction are the default solutes of the excess."""


@dataclass
class Inputs:
    """The read step: ions, ranges, the specimen's hull and what report.json says of them."""

    ions: object
    ranges: object
    report: dict
    hull: object = None
    ion_counts: dict = field(default_factory=dict)


@dataclass
class Voxels:
    """The voxelize step: fields, the specimen mask, the concentration basis and report.json's ``voxel``."""

    fields: object
    mask: np.ndarray
    basis: object
    report: dict


@dataclass
class SurfaceResult:
    """One iso-surface, finished and analysed: report.json's entry in ``surfaces``."""

    label: str
    surface: SurfaceConfig
    mesh: TriMesh
    record: SurfaceRecord
    objects: list[dict] = field(default_factory=list)
    excess: list[dict] = field(default_factory=list)
    proxigram: object = None
    windows: object = None
    """The plateau windows and interface fits (:class:`~apt_filters.analysis.width.Windows`)."""
    stats: dict = field(default_factory=dict)
    summary: list[dict] = field(default_factory=list)
    plateaus: list[dict] = field(default_factory=list)
    """Each object's inside composition and the window it was counted in
    (:func:`~apt_filters.pipeline.summary.object_plateaus`)."""
    maps: list[dict] = field(default_factory=list)
    near: object = None
    """The ions the analyses read (:func:`~apt_filters.pipeline.surface.analysis_ions`)."""
    quality: tuple | None = None
    """(vertex scalar, colour range, meaning) MeshLab shows as quality; None: the scene's local composition."""
    map_pictures: list[tuple[Path, str]] = field(default_factory=list)
    """(PNG, caption) of the shown excess map, one per object (the largest :data:`MAP_PICTURES`)."""

    def report(self) -> dict:
        return {"label": self.label, "species": self.surface.species, "iso": self.surface.iso,
                "mesh": self.stats | self.record.as_dict(self.mesh), "summary": self.summary,
                "interface": self.windows.as_dict() if self.windows is not None else None,
                "objects": self.objects, "plateaus": self.plateaus, "excess": self.excess, "maps": self.maps}


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
    try:
        folder.mkdir()  # inside the try: a signal arriving right after it must still remove the folder
        yield folder
    finally:
        with signals_held():
            remove(folder)


def _absolute_inputs(config: PipelineConfig) -> PipelineConfig:
    """``config`` with absolute input paths (its config.toml then works from any folder)."""
    ions, ranges = (os.path.abspath(Path(p).expanduser()) for p in (config.input.ions, config.input.ranges))
    return dataclasses.replace(config, input=dataclasses.replace(config.input, ions=ions, ranges=ranges))


def _read(config: PipelineConfig, log: StepLog, scratch: Path) -> Inputs:
    with log.step("read") as s:
        ranges = config_ranges(config)
        summary = summarize(config.input.ions, ranges)  # streamed from the file: nothing kept
        ions = load_ions(config, ranges, summary, scratch)
        hull = SpecimenHull.from_points(ions.positions)  # the analysed volume, for every surface's objects
        report = {"range_file": [dataclasses.asdict(n) for n in ranges.notes],
                  "inputs": [rep.file_record(config.input.ions), rep.file_record(config.input.ranges)],
                  "ions": {"count": summary.ions, "ranged_fraction": summary.ranged_fraction,
                           "bounds_nm": [summary.lower.tolist(), summary.upper.tolist()]},
                  "composition": summary.composition()}
        s.summary = (f"{len(ions):,} ions{' (memory-mapped)' if isinstance(ions.mz, np.memmap) else ''}, "
                     f"{summary.ranged_fraction:.1%} ranged, {len(ranges)} ranges")
    return Inputs(ions, ranges, report, hull, summary.ion_counts)


def _audit(inputs: Inputs, log: StepLog, verbose: bool) -> list[dict]:
    from apt_filters.audit import audit_ranges

    with log.step("audit") as s:
        flagged = [dataclasses.asdict(f) for f in audit_ranges(inputs.ions, inputs.ranges).flagged]
        errors = [f for f in flagged if f["severity"] == "error"]
        n_warn = len(flagged) - len(errors)
        s.summary = (f"{len(errors)} range-file errors, {n_warn} warnings"
                     + (" (--verbose lists them)" if n_warn and not verbose else ""))
        # errors make figures wrong: always in words; warnings only when asked
        shown = flagged if verbose else errors
        s.summary += "".join(f"\n    {f['severity'].upper():7} {f['message']}" for f in shown)
        if errors:
            s.summary += ("\n    figures that count a mislabelled range are wrong: relabel it (--relabel "
                          "OLD=NEW, e.g. Cr2O=Ni) or correct the range file, and run again")
    return flagged


def _voxelize(config: PipelineConfig, inputs: Inputs, log: StepLog) -> Voxels:
    from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

    with log.step("voxelize") as s:
        v = config.voxel
        basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
        fields = voxelize(inputs.ions, inputs.ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size,
                          basis=basis, efficiency=config.analysis.efficiency)
        mask = inside_mask(fields).dense()
        report = {"grid_shape": list(fields.grid.shape), "origin_nm": list(fields.grid.origin),
                  "basis": basis.describe(), "inside_fraction": float(mask.mean())}
        s.summary = f"grid {fields.grid.shape}, {fields.total.n_blocks} blocks, basis: {basis.describe()}"
    return Voxels(fields, mask, basis, report)


def _surface(config: PipelineConfig, surface: SurfaceConfig, inputs: Inputs, voxels: Voxels, stage: Path,
             log: StepLog) -> SurfaceResult:
    """The finished surface (:func:`finished_surface`), its object table, proxigram and excess."""
    from apt_filters.analysis.excess import interfacial_excess
    from apt_filters.analysis.objects import counting_errors, object_table
    from apt_filters.analysis.width import first_range, fitted_proxigram

    label = surface_label(surface)
    ions, ranges = inputs.ions, inputs.ranges
    mesh, record = finished_surface(voxels.fields, voxels.mask, ions, ranges, surface, config=config,
                                    basis=voxels.basis, clean_script=stage / f"clean_{label}.mlx", step=log.step)
    res = SurfaceResult(label, surface, mesh, record)
    if mesh.n_faces == 0:  # every component was a speck: reported, nothing to measure or export
        return res
    p = config.proxigram
    reach = first_range(inner=p.inner or None, outer=p.extent or None)

    def select(distance: float):
        """The ions within ``distance`` of the surface or inside its objects (kept for every analysis), and
        their signed distances to it."""
        res.near, signed = analysis_ions(ions, mesh, reach=distance, cap_open=config.contour.close_at_edge)
        return res.near, signed

    with log.step("select") as s:
        near, signed = select(reach)
        s.summary = (f"{label}: {len(near):,} ions within {reach:g} nm or inside objects "
                     f"({len(near) / max(len(ions), 1):.1%}), one pass")
    with log.step("objects") as s:
        table = object_table(mesh, near, ranges, specimen=inputs.hull, cap_open=config.contour.close_at_edge)
        if record.refined is not None:  # counting errors and the speck test's figures of each object
            from apt_filters.refine.specks import REACH

            counting_errors(table, mesh, reference=record.refined.mesh, offset_se=record.refined.offset_errors,
                            shape_se=record.refined.shape_errors,
                            **dict(zip(("p_value", "z"), record.specks.of(mesh, REACH))))
        table.write_csv(stage / f"objects_{label}.csv")
        table.write_json(stage / f"objects_{label}.json")
        res.objects = table.rows()
        res.stats["objects_dropped"] = table.n_dropped
        s.summary = f"{label}: {len(res.objects)} objects"
    with log.step("proxigram") as s:
        solutes = p.solutes or [
            el for el, c in inputs.report["composition"].items() if c < MINORITY and el != surface.species]
        # a wide interface asks for a wider range than the first selection: selected again (res.near)
        prox, windows = fitted_proxigram(ions=near, ranges=ranges, mesh=mesh, species=surface.species,
                                         solutes=solutes, bin_width=p.bin, inner=p.inner or None,
                                         outer=p.extent or None, keep_edge=not p.exclude_edge,
                                         iso_value=surface.iso if surface.species else None, covered=reach,
                                         select=select, measured=signed)
        del signed  # the proxigram's alone: its memory back
        again = res.near is not near
        near = res.near
        prox.write_csv(stage / f"proxigram_{label}.csv")
        prox.plot(stage / f"proxigram_{label}.png", title=f"proxigram across {label}",
                  windows=(windows.inner, windows.outer))
        for solute in solutes:
            res.excess += [dataclasses.asdict(e) for e in interfacial_excess(
                prox, solute, config.analysis.efficiency, windows.inner, windows.outer, skip_unmeasurable=True,
                fit=windows.fit_of(solute))]
        res.proxigram, res.windows = prox, windows
        res.summary = surface_summary(objects=res.objects, proxigram=prox, solutes=solutes,
                                      efficiency=config.analysis.efficiency, inner=windows.inner,
                                      outer=windows.outer, fits={s: windows.fit_of(s) for s in solutes})
        res.plateaus = object_plateaus(prox, windows.inner, windows.outer, windows.step)
        # with no solute there is no excess to miss: no object is "too thin" for one
        measured = {e["object_id"] for e in res.excess}
        res.stats["objects_without_excess"] = sorted(int(i) for i in set(prox.object_ids) - measured) if solutes else []
        s.summary = (f"{label}: {windows.describe()}"
                     + (f"; {len(near):,} ions selected again within {windows.outer:g} nm" if again else "")
                     + f"; excess of {', '.join(solutes) or 'no solute'}; "
                     f"{len(res.stats['objects_without_excess'])} objects too thin for plateaus")
    if config.analysis.maps:
        with log.step("maps") as s:
            res.maps = _maps(res, near, ranges, solutes, config, stage)
            tested = [m for m in res.maps if m["p_value"] is not None]
            s.summary = f"{label}: " + ("; ".join(
                f"{m['solute']} on object {m['object_id']}: p = {m['p_value']:.2g}" for m in tested[:4])
                or "no map tested")
    return res


def _export(results: list[SurfaceResult], inputs: Inputs, stage: Path, log: StepLog) -> dict:
    from apt_filters.pipeline.scene import scene_species, write_scene

    ranges = inputs.ranges
    drawn = [r for r in results if r.mesh.n_faces]  # a surface of specks only has nothing to show
    with log.step("export") as s:
        scene = write_scene(folder=stage, surfaces={r.label: r.mesh for r in drawn},
                            species={r.label: scene_species(r.surface.species or ranges.elements[0], r.summary)
                                     for r in drawn},
                            ions=inputs.ions, ranges=ranges, near={r.label: r.near for r in drawn},
                            counts=inputs.ion_counts,
                            quality={r.label: r.quality for r in drawn if r.quality is not None})
        sample = inputs.ions.positions[:: max(1, len(inputs.ions) // 20_000)]
        render_surfaces({r.label: r.mesh for r in drawn}, stage / "surfaces.png", points=sample)
        s.summary = (f"project.mlp: {len(drawn)} surface(s) coloured by "
                     + ", ".join(x["quantity"].split("\n")[0] for x in scene["surfaces"])
                     + f", {len(scene['ion_layers'])} ion layers, legend.png")
    return scene


def run_pipeline(config: PipelineConfig, out: str | Path, force: bool = False, quiet: bool = False,
                 verbose: bool = False, truth: dict | None = None) -> dict:
    """Run every step and write the output folder ``out``; returns the report's content.

    Prints one line per step (time, peak memory, what it found) unless ``quiet``; ``verbose``
    adds every range-file finding. ``truth`` (a synthetic specimen's truth.json) adds a
    comparison with the ground truth.
    """
    check_config(config)
    config = check_inputs(config)
    config = _absolute_inputs(config)
    per_surface = 5 + (config.remesh.method == "cvt") + config.analysis.maps
    n_refined = sum(bool(config.refine.enabled and s.species) for s in config.surface)
    log = StepLog(quiet=quiet, total=3 + config.analysis.audit + per_surface * len(config.surface) + n_refined)
    report: dict = {"apt-filters": rep.versions(), "config": dataclasses.asdict(config)}
    with staged_folder(out, force=force, inputs=[config.input.ions, config.input.ranges]) as stage, \
            scratch_folder(out) as scratch:
        (stage / "meshes").mkdir()
        inputs = _read(config, log, scratch)
        report |= inputs.report
        if config.analysis.audit:
            report["audit"] = _audit(inputs, log, verbose)
        voxels = _voxelize(config, inputs, log)
        report["voxel"] = voxels.report
        results = [_surface(config, surface, inputs, voxels, stage, log) for surface in config.surface]
        warnings = [w for r in results for w in r.record.warnings]
        if warnings:
            report["warnings"] = warnings
        report["scene"] = _export(results, inputs, stage, log)
        report["surfaces"] = [r.report() for r in results]
        rep.write_json(stage / "excess.json", {r.label: r.excess for r in results})
        if truth is not None:
            from apt_filters.truth.specimen import compare_with_truth, counted_excess

            report["truth"] = compare_with_truth(results, truth, counted_excess(truth, inputs.ions, inputs.ranges))
        report["steps"] = log.as_dicts()
        atomic_write_text(stage / "config.toml", config.to_toml())
        rep.write_json(stage / "report.json", report)
        pictures = [(stage / "surfaces.png", "The iso-surfaces seen from the side (z, the analysis direction, up), "
                     "each object in its own colour and numbered as in the tables; grey dots: a sample of the ions.")]
        pictures += [(stage / f"proxigram_{r.label}.png", f"Proxigram across {r.label}, all objects pooled: "
                      "ion (top) and atomic (bottom) concentration against the distance to the surface, "
                      "positive inside; bars are binomial standard errors.") for r in results]
        pictures += [picture for r in results for picture in r.map_pictures]
        pictures.append((stage / "legend.png", "Legend of the MeshLab scene (project.mlp): each surface's colour, "
                         "the composition near it, and the ions drawn per species."))
        rep.write_html(stage / "report.html", report, pictures)
    return report


MAP_PICTURES = 6
"""Objects per surface whose excess map gets its own picture in the report (the largest)."""


def _maps(res: SurfaceResult, ions, ranges, solutes: list[str], config: PipelineConfig, stage: Path) -> list[dict]:
    """Excess maps of ``solutes`` on ``res.mesh``: vertex properties on the mesh (PLY properties
    ``excess_<El>`` ...), a picture of the most significant one per object (``map_<label>_<object>.png``,
    the :data:`MAP_PICTURES` largest objects, into ``res.map_pictures``); returns the statistics rows."""
    from apt_filters.analysis.maps import UNITS, excess_maps

    if not solutes:
        return []
    maps = excess_maps(mesh=res.mesh, ions=ions, ranges=ranges, solutes=solutes, bin_width=config.proxigram.bin,
                       max_distance=res.windows.outer, inner=res.windows.inner,
                       keep_edge=not config.proxigram.exclude_edge,
                       relative_error=config.analysis.map_error)
    res.mesh.vertex_scalars.update(maps.vertex_scalars())
    shown = maps.most_significant()
    objects = sorted(maps.maps[shown].objects, key=lambda o: -o.area)
    for o in objects[:MAP_PICTURES]:
        path = maps.plot(stage / f"map_{res.label}_{o.object_id}.png", res.mesh, shown, o.object_id, overwrite=True)
        res.map_pictures.append((path, f"{shown} excess map on object {o.object_id} of {res.label}: the local excess "
                                 f"at each vertex, from the ions near a patch around it (median patch radius "
                                 f"{o.median_radius:.2g} nm, median error {o.median_sigma:.2g} {UNITS}); grey: no "
                                 "patch. The colours span this object's own range."
                                 + (f" Drawn for the {MAP_PICTURES} largest of {len(objects)} objects; every "
                                    f"object's map is in meshes/{res.label}.ply." if len(objects) > MAP_PICTURES
                                    else "")))
    res.quality = (f"excess_{shown}", maps.limits(shown),
                   f"{shown} interfacial excess map, detected atoms/nm2 (analysis.maps; error: excess_{shown}_sigma)")
    return maps.rows()
