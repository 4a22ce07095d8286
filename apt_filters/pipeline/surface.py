"""The one way from ions to a finished iso-surface, used by ``apt-filters run``, Python and pymeshlab scripts.

:func:`finished_surface` runs, for one species and iso-value, contour -> specks -> refinement against
the ions -> clean chain -> CVT remesh, with the command line's defaults (:class:`PipelineConfig`:
marching cubes, refinement on), and returns the mesh with a :class:`SurfaceRecord` of what each step
did (report.json's ``mesh`` of the surface). :func:`contour_surface` is its first step alone;
:func:`add_iso_surface` voxelizes, calls :func:`finished_surface` and adds the result to a
``pymeshlab.MeshSet``, the way a MeshLab user's script calls one step. :func:`analysis_ions` selects,
in one streamed pass, the ions that every analysis of the finished surface reads.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Callable, ContextManager

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh, split_components
from apt_filters.io import IonTable, RangeTable
from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig


def field_values(fields, species: str, iso: float, basis=None) -> np.ndarray:
    """Dense (nx, ny, nz) field to contour: the concentration of ``species`` (a fraction; in ``basis``, default
    the voxelization's) or, for ``species == ""``, the atomic density (atoms/nm³); refused when ``iso`` is
    outside its range."""
    field = fields.concentration(species, basis) if species else fields.density()
    values = field.dense()
    finite = values[np.isfinite(values)]
    if not len(finite) or not finite.min() < iso < finite.max():
        lo, hi = (finite.min(), finite.max()) if len(finite) else (np.nan, np.nan)
        what = f"{species} concentration" if species else "atomic density"
        raise AptFiltersError(f"iso-value {iso:g} is outside the {what} range {lo:.4g}..{hi:.4g}: no surface")
    return values


def refine_params(refine):
    """The :class:`~apt_filters.refine.RefineParams` of a ``[refine]`` section (:class:`RefineConfig`): the options
    it names, every other setting at its default."""
    from apt_filters.refine import RefineParams

    return RefineParams(iterations=refine.iterations, facets=refine.facets, blur=tuple(refine.blur) or "auto",
                        cross_fit=refine.cross_fit, select_modes=refine.select_modes, marker=refine.marker)


def contour_surface(fields, mask: np.ndarray, species: str, iso: float, method: str = "mc",
                    close: bool = False, basis=None) -> TriMesh:
    """The iso-surface of ``species`` at ``iso`` (its concentration in ``basis``, default the voxelization's)
    by marching cubes (``"mc"``) or dual contouring (``"dc"``), open where it meets the specimen edge
    (``mask`` False) unless ``close``."""
    from apt_filters.contour import dual_contouring, marching_cubes

    values = field_values(fields, species, iso, basis)
    contour = dual_contouring if method == "dc" else marching_cubes
    mesh = contour(values, iso, spacing=fields.grid.voxel, origin=fields.grid.origin, mask=mask, close=close)
    if mesh.n_faces == 0:
        raise AptFiltersError(f"the {species or 'density'} iso-surface at {iso:g} has no triangles inside the specimen")
    return mesh


def surface_label(surface: SurfaceConfig) -> str:
    """File-name label of an iso-surface: ``Al15`` (15 at.% Al) or ``density40`` (atoms/nm³)."""
    if surface.species:
        return f"{surface.species}{surface.iso * 100:g}"
    return f"density{surface.iso:g}"


@dataclass
class SurfaceRecord:
    """What each step did to one iso-surface; :meth:`as_dict` is report.json's ``mesh`` of that surface.

    Attributes
    ----------
    raw_area : float
        Area of the contoured surface, nm².
    noise_scale : dict or None
        The growth of the delocalization the surface's noise asked for (:class:`~apt_filters.voxel.noise.NoiseScale`;
        None for a density surface or a kernel other than gaussian).
    refine : dict or None
        Specks removed and the refinement's figures (None where the surface was not refined).
    remesh : dict or None
        Components remeshed, those that kept the cleaned mesh and the failed checks (None where
        not remeshed).
    warnings : list of str
        Steps that fell back (a remeshed component that changed the surface keeps the cleaned mesh).
    specks : refine.Specks or None
        The speck test (each kept component's p-value and z, for the object table).
    refined : refine.RefineResult or None
        The refinement (its mesh and each component's counting error, for the object table).
    """

    raw_area: float = 0.0
    noise_scale: dict | None = None
    refine: dict | None = None
    remesh: dict | None = None
    warnings: list[str] = field(default_factory=list)
    specks: object = None
    refined: object = None

    def as_dict(self, mesh: TriMesh) -> dict:
        return {"raw_area_nm2": self.raw_area, "noise_scale": self.noise_scale, "refine": self.refine,
                "remesh": self.remesh, "faces": mesh.n_faces,
                "vertices": mesh.n_vertices, "area_nm2": mesh.area(), "boundary_edges": len(mesh.boundary_edges())}


@contextlib.contextmanager
def _quiet_step(name: str):
    yield SimpleNamespace(summary="")


def segregant_basis(mesh: TriMesh, ions, ranges, species: str, basis, include=(), near=None):
    """The basis a concentration surface of ``species`` is drawn in: ``basis`` without the segregants its first
    contour ``mesh`` shows (:func:`~apt_filters.refine.segregants.find_segregants`; those in ``include`` stay;
    ``near``: its :func:`~apt_filters.refine.segregants.segregant_ions` where the caller has them).
    Returns (basis, Segregants), or (``basis``, None) for a density surface; ``basis`` itself where none is found."""
    from apt_filters.refine.segregants import find_segregants
    from apt_filters.voxel import ConcentrationBasis

    if not species:
        return basis, None
    found = find_segregants(mesh, ions, ranges, species, basis=basis, include=tuple(include), near=near)
    if not found.species:
        return basis, found
    return ConcentrationBasis(tuple(basis.exclude) + found.species, basis.include_unranged), found


def refined_segregants(finished: TriMesh, refined, ions, ranges, species: str, basis, include=()):
    """The segregants the finished surface shows where some object's first contour lay beyond the first search's
    reach; None where none did (no ion read).

    :func:`segregant_basis` reads the peak against the first contour, which need only lie near the interface (a
    shell within ``GAP`` of it stands out of its references): it does where the delocalization shrinks an object
    by a voxel or so. An object thinner than the delocalization, or one a segregant's dilution shrinks to a
    sliver, is drawn as a sliver inside itself, whose distances smear the shell over several nm (seen plate
    10164, 2.2 nm plates with a Si shell at 10 points of contrast: Si 4.9 standard errors on the first contour,
    7.2 on the finished one). So where a component of the refinement (``refined``, a
    :class:`~apt_filters.refine.RefineResult`: its mesh's ``displacement`` per vertex, nm) moved more than ``GAP``
    on average from its first contour, the ``finished`` surface (cleaned and remeshed: the refined mesh's coarse
    triangles can cross at a thin object's rim, and the sides they give the ions read Si at 4.2) is searched again
    (:func:`~apt_filters.refine.segregants.find_segregants`; ``basis``: the one it was drawn in, so only species it
    still counts are tested; ``include`` stays).
    """
    from apt_filters.refine.segregants import GAP, find_segregants

    if refined is None or not species or finished.n_faces == 0:
        return None
    moved = refined.mesh
    component = moved.topology.vertex_components
    used = component >= 0
    far = np.bincount(component[used], np.abs(moved.vertex_scalars["displacement"][used])) > GAP * np.bincount(
        component[used])
    if not far.any():
        return None
    return find_segregants(finished, ions, ranges, species, basis=basis, include=tuple(include))


def _same_mesh(a: TriMesh, b: TriMesh) -> bool:
    """Whether two meshes have the same vertices and faces in the same order (ions selected near one, with their
    closest faces, serve the other)."""
    return np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


def _drawn_surface(fields, mask: np.ndarray, ions: IonTable, ranges: RangeTable, surface: SurfaceConfig,
                   config: PipelineConfig, basis, step: Callable[[str], ContextManager], params
                   ) -> tuple[TriMesh, SurfaceRecord, object]:
    """:func:`finished_surface`'s contour and refinement steps in ``basis`` (segregants its first contour shows left
    out as well), before the clean chain; with the basis it was drawn in."""
    from apt_filters.contour import dual_contouring, marching_cubes
    from apt_filters.refine import refine_surface, remove_specks
    from apt_filters.refine.clipped import close_clipped
    from apt_filters.refine.specks import trim_lobes
    from apt_filters.refine.segregants import segregant_ions
    from apt_filters.refine.thin import add_thin_objects
    from apt_filters.voxel.noise import noise_limited_fields

    label = surface_label(surface)
    record = SurfaceRecord()
    with step("contour") as s:
        c = config.contour
        mesh = contour_surface(fields, mask, surface.species, surface.iso, c.method, c.close_at_edge, basis=basis)
        # one streamed pass selects the ions near the first contour for the segregant search and the speck test
        near = segregant_ions(mesh, ions) if surface.species else None
        first, tested = mesh, None  # the contour the speck test below is drawn on, and that test
        objects = mesh
        if surface.species:
            # the segregants are read off the objects: a low-contrast contour's noise specks are drawn where the iso
            # species is high by chance, and the dip of every other species inside them reads as a peak (dev plate
            # 37539, no shell: Ti 6.5 standard errors with its 32 specks, 0.8 without, left out of the basis and
            # both plates lost)
            tested = remove_specks(mesh, fields=fields, mask=mask, ions=ions, ranges=ranges, species=surface.species,
                                   iso=surface.iso, basis=basis, alpha=config.refine.speck_alpha, near=near)
            objects = tested[0] if tested[0].n_faces else mesh  # all specks: the contour is all there is to read
        surface_basis, segregants = segregant_basis(objects, ions, ranges, surface.species, basis,
                                                    config.voxel.include,
                                                    near=near if _same_mesh(objects, mesh) else None)
        if surface_basis is not basis:  # contoured again without the segregants' dilution
            mesh = contour_surface(fields, mask, surface.species, surface.iso, c.method, c.close_at_edge,
                                   basis=surface_basis)
            near = None  # another mesh: the speck test selects its own ions
        if surface.species and fields.kernel == "gaussian":
            # a wide low-contrast interface is drawn at the delocalization its noise allows (voxel.noise)
            fields, mask, scale = noise_limited_fields(fields, mask, ions, ranges, surface.species, surface.iso,
                                                       basis=surface_basis)
            record.noise_scale = dataclasses.asdict(scale)
            if scale.factor > 1.0:
                mesh = contour_surface(fields, mask, surface.species, surface.iso, c.method, c.close_at_edge,
                                       basis=surface_basis)
                near = None
        record.raw_area = mesh.area()
        s.summary = (f"{label}: {mesh.n_vertices:,} vertices, {mesh.n_faces:,} faces ({c.method})"
                     + (f"; {segregants.describe()}, basis: {surface_basis.describe()}" if segregants else "")
                     + (f"; delocalization x{scale.factor:.2f} for its noise" if record.noise_scale
                        and scale.factor > 1.0 else ""))
    if config.refine.enabled and surface.species:
        with step("refine") as s:
            r = config.refine
            if mesh is first:  # drawn in the basis and on the fields of the speck test above: its outcome
                mesh, specks = tested
            else:
                first = mesh
                mesh, specks = remove_specks(mesh, fields=fields, mask=mask, ions=ions, ranges=ranges,
                                             species=surface.species, iso=surface.iso, basis=surface_basis,
                                             alpha=r.speck_alpha, near=near)
            # noise lobes joined to an object at low contrast: each part of a component tested like a speck
            contour = dual_contouring if c.method == "dc" else marching_cubes
            mesh, lobes = trim_lobes(mesh, specks, values=field_values(fields, surface.species, surface.iso,
                                                                       surface_basis),
                                     fields=fields, mask=mask, ions=ions, ranges=ranges, species=surface.species,
                                     iso=surface.iso, basis=surface_basis, alpha=r.speck_alpha,
                                     contour=functools.partial(contour, close=c.close_at_edge),
                                     near=near if near is not None and _same_mesh(mesh, first) else None)
            near = None  # its memory back before the refinement
            # objects thinner than the delocalization, drawn one octave finer where this scale thins them
            mesh, thin = add_thin_objects(mesh, specks, fields=fields, mask=mask, ions=ions, ranges=ranges,
                                          species=surface.species, iso=surface.iso, basis=surface_basis,
                                          alpha=r.speck_alpha)
            record.specks = thin.specks
            # closed objects the specimen-edge clip holed, closed again where the ions beyond the hole are matrix
            mesh, clipped = close_clipped(mesh, mask=mask, grid=fields.grid, ions=ions, ranges=ranges,
                                          species=surface.species, iso=surface.iso, basis=surface_basis)
            refined = refine_surface(mesh, ions, ranges, surface.species, surface_basis,
                                     refine_params(r) if params is None else params)
            mesh, record.refined = refined.mesh, refined
            record.refine = {"basis": surface_basis.describe(),
                             "segregants": None if segregants is None else dataclasses.asdict(segregants),
                             "lobes": dataclasses.asdict(lobes),
                             "thin": thin.as_dict(),
                             "clipped": dataclasses.asdict(clipped),
                             **_refine_record(thin.specks, refined)}
            s.summary = (f"{label}: {specks.count} specks removed, {lobes.describe()}, {thin.describe()}, "
                         f"{clipped.describe()}, "
                         f"mean displacement {refined.displacement['mean']:+.2f} nm, {refined.folded_pairs} folds")
    return mesh, record, surface_basis


def finished_surface(fields, mask: np.ndarray, ions: IonTable, ranges: RangeTable, surface: SurfaceConfig, *,
                     config: PipelineConfig | None = None, basis=None, clean_script: str | os.PathLike | None = None,
                     step: Callable[[str], ContextManager] = _quiet_step, params=None
                     ) -> tuple[TriMesh, SurfaceRecord]:
    """The finished iso-surface of ``surface`` from voxelized ``fields`` and their ``ions``.

    Contour (segregants read off its real components left out of the basis), refinement, clean chain and remesh;
    drawn once more without the segregants the finished surface shows where the first contour lay beyond the
    first search's reach (:func:`refined_segregants`).

    Parameters
    ----------
    fields : voxel.Fields
        The voxelized ions (:func:`apt_filters.voxel.voxelize`).
    mask : (nx, ny, nz) bool
        Inside the specimen (:func:`apt_filters.voxel.inside_mask`).
    ions, ranges : IonTable, RangeTable
        The ions the refinement reads (a memory map is streamed).
    surface : SurfaceConfig
        Species (empty: atomic density) and iso-value.
    config : PipelineConfig, optional
        ``[contour]``, ``[refine]``, ``[remesh]`` settings; default the command line's.
    basis : voxel.ConcentrationBasis, optional
        The concentration basis of ``fields`` (default from ``config.voxel``).
    clean_script : path, optional
        Where the clean chain's ``.mlx`` is recorded.
    step : callable, optional
        ``step(name)`` gives a context manager around each step whose ``summary`` it may set
        (``StepLog.step`` times and prints them).
    params : refine.RefineParams, optional
        Every setting of the refinement (default: :func:`refine_params` of ``config.refine``), for settings
        ``[refine]`` does not name (benchmarks/bench_ablation.py switches stages and knobs one at a time).

    Returns
    -------
    TriMesh, SurfaceRecord
        The surface (refined only for a concentration surface with ``[refine] enabled``) and what each
        step did.
    """
    from apt_filters.voxel import ConcentrationBasis

    config = PipelineConfig() if config is None else config
    basis = ConcentrationBasis(tuple(config.voxel.exclude), config.voxel.include_unranged) if basis is None else basis
    label = surface_label(surface)
    mesh, record, drawn = _drawn_surface(fields, mask, ions, ranges, surface, config, basis, step, params)
    mesh = _cleaned(mesh, record, label, config, fields.grid.voxel, clean_script, step)
    found = refined_segregants(mesh, record.refined, ions, ranges, surface.species, drawn, config.voxel.include)
    if found is not None and found.species:  # drawn again without them: the run a user who knew would make
        with step("segregants") as s:
            s.summary = (f"{label}: {found.describe()} on the finished surface, beyond the first search's reach; "
                         f"drawn again without them")
        again = ConcentrationBasis(tuple(drawn.exclude) + found.species, drawn.include_unranged)
        mesh, record, _ = _drawn_surface(fields, mask, ions, ranges, surface, config, again, step, params)
        mesh = _cleaned(mesh, record, label, config, fields.grid.voxel, clean_script, step)
        record.refine["segregants_refined"] = dataclasses.asdict(found)
    return mesh, record


def _cleaned(mesh: TriMesh, record: SurfaceRecord, label: str, config: PipelineConfig, voxel: float,
             clean_script, step: Callable[[str], ContextManager]) -> TriMesh:
    """:func:`finished_surface`'s clean chain and remesh of a drawn surface (``record`` takes their account), with
    one object numbering for the object table, the proxigram and the excess (``object_id``)."""
    from apt_filters.meshlab.chains import apply_chain
    from apt_filters.remesh import remesh

    if mesh.n_faces == 0:  # every component was a speck: said, and nothing left to clean or remesh
        record.warnings.append(f"no surface at this iso-value: every component of {label} was a speck")
        mesh.face_scalars["object_id"] = np.zeros(0, dtype=np.int64)
        return mesh
    with step("clean") as s:
        mesh, _ = apply_chain(mesh, "clean", script=clean_script, overwrite=True)
        s.summary = f"{label}: {mesh.n_faces:,} faces after the clean chain"
    if config.remesh.method == "cvt":
        with step("remesh") as s:
            edge = config.remesh.edge_length or voxel / 2
            try:
                remeshed = remesh(mesh, edge_length=edge, feature_angle=config.remesh.feature_angle)
                mesh, kept = remeshed.mesh, remeshed.kept_input
                record.remesh = {"components": len(remeshed.checks), "kept_input": kept,
                                 "failed": [dataclasses.asdict(c) for c in remeshed.checks if not c.ok]}
                s.summary = f"{label}: {mesh.n_faces:,} faces at edge length {edge:g} nm"
                if kept:  # each component whose remesh changed the surface keeps its input
                    warning = (f"remeshing {label}: {kept} of {len(remeshed.checks)} components changed "
                               f"the surface and keep the cleaned mesh")
                    record.warnings.append(warning)
                    s.summary += "; WARNING " + warning
            except Exception as exc:  # noqa: BLE001 - a remesher failure must not cost the whole run
                warning = f"remeshing {label} failed ({type(exc).__name__}: {exc}); the cleaned mesh is used"
                record.warnings.append(" ".join(warning.split()))
                s.summary = "WARNING " + record.warnings[-1]
    mesh.face_scalars["object_id"] = mesh.face_components()
    return mesh


def analysis_ions(ions: IonTable, mesh: TriMesh, *, reach: float, cap_open: bool = True):
    """The ions the analyses of a finished surface read, selected in one streamed pass over ``ions``, and their
    signed distances to it.

    Those within ``reach`` nm of ``mesh`` (what the proxigram, the excess, the maps and the scene's
    local composition read) and those that may lie inside its closed or capped objects (what the
    object table counts, :func:`~apt_filters.analysis.objects.ions_in_objects`), in file order:
    :func:`~apt_filters.core.nearby.select_near` reads positions and m/z chunk by chunk (a memory-mapped
    table is read once, in bounded memory). Each analysis given this subset gives the figures it gives
    with the whole table.

    Parameters
    ----------
    ions : IonTable
        The whole table (a memory map is streamed).
    mesh : TriMesh
        The finished surface (face scalar ``object_id``).
    reach : float
        nm; the proxigram's and maps' range.
    cap_open : bool
        As for the object table (``[contour] close_at_edge``).

    Returns
    -------
    IonTable
        Positions and m/z of the selected ions, as the table holds them (16 bytes each).
    core.nearby.NearSurface
        The selection, ``lean``: each selected ion's exact signed distance, face and rim flag within ``reach``
        (those kept only as inside an object beyond it: NaN or their exact distance), which the proxigram
        reads instead of measuring them again (9 bytes per ion; 25 with the table, 37 while the selection's
        chunks of positions are joined).
    """
    from apt_filters.analysis.objects import ions_in_objects
    from apt_filters.core.nearby import select_near

    near = select_near(ions.positions, mesh, reach, also=ions_in_objects(mesh, cap_open),
                       carry=(ions.positions, ions.mz), lean=True)
    positions, mz = near.carried
    near.carried = ()  # the table holds them
    return IonTable(np.asarray(positions, dtype=np.float32), mz, source=ions.source), near


def _finite(values) -> list:
    """Floats for JSON, which has no NaN: None where not finite."""
    return [float(v) if np.isfinite(v) else None for v in values]


def _refine_record(specks, refined) -> dict:
    """The refinement's figures in report.json."""
    estimate, marks = refined.blur_estimate, refined.marker
    return {"specks_removed": specks.count, "speck_volumes_nm3": _finite(specks.volumes),
            "speck_test": {"alpha": specks.alpha, "components_tested": specks.tested,
                           "null_centre": specks.null[0], "null_spread": specks.null[1],
                           "null_components": specks.null[2], "speck_p_values": _finite(specks.p_values[specks.ids]),
                           "kept_p_values": _finite(specks.kept[1]), "kept_z": _finite(specks.kept[2])},
            "displacement_nm": refined.displacement, "folded_pairs": refined.folded_pairs,
            "self_intersections": refined.self_intersections, "facets": refined.facets,
            "sharpened_vertices": refined.sharpened, "blur_nm": list(refined.blur),
            "blur_estimate": None if estimate is None else
            {"lateral_nm": estimate.lateral, "slope_nm2": estimate.slope, "slope_se_nm2": estimate.slope_se,
             "source": estimate.source},
            "cross_fit": refined.params.cross_fit,
            "modes": None if refined.modes is None else {str(c): k for c, k in sorted(refined.modes.modes.items())},
            "lengths_nm": (None if refined.modes is None
                           else {str(c): v for c, v in sorted(refined.modes.lengths.items())}),
            "marker": None if marks is None else
            {"species": marks.name, "objects_moved": marks.marked,
             "layer_offset_nm": _finite([marks.layer_offset])[0],
             "layer_offset_se_nm": _finite([marks.layer_offset_se])[0],
             "peak_centre_nm": _finite(marks.centre), "peak_centre_se_nm": _finite(marks.centre_se),
             "shift_nm": _finite(marks.shift)},
            "counting_errors": _counting_errors(refined.mesh, refined.offset_errors, refined.shape_errors),
            # without their seconds: a rerun's report is identical (the step's time is in report["steps"])
            "stages": [{k: v for k, v in dataclasses.asdict(stage).items() if k != "seconds"}
                       for stage in refined.stages]}


def _counting_errors(mesh: TriMesh, offset_errors, shape_errors) -> list[dict]:
    """Per refined object: the counting-statistics standard error of its mean offset, and of its area and, if
    closed, its volume (:func:`~apt_filters.analysis.objects.size_errors`, the halves' spread included)."""
    from apt_filters.analysis.objects import size_errors

    out = []
    for c, (e, part) in enumerate(zip(offset_errors, split_components(mesh))):
        if np.isfinite(e):
            closed = len(part.boundary_edges()) == 0  # an open interface encloses no volume
            volume_se, area_se = size_errors(part, float(e), shape_errors[c] if c < len(shape_errors)
                                             else (np.nan, np.nan))
            out.append({"component": c, "offset_se_nm": float(e), "area_nm2": part.area(), "area_se_nm2": area_se,
                        "volume_nm3": part.signed_volume() if closed else None,
                        "volume_se_nm3": volume_se if closed else None})
    return out


def add_iso_surface(ms, ions: IonTable, ranges: RangeTable, species: str, iso: float, *,
                    config: PipelineConfig | None = None, clean_script: str | os.PathLike | None = None,
                    label: str | None = None) -> TriMesh:
    """Add the finished iso-surface of ``species`` at ``iso`` (:func:`finished_surface`) to the MeshSet ``ms``.

    Parameters
    ----------
    ms : pymeshlab.MeshSet
        Receives the surface as a new current mesh (vertex quality = the field value).
    ions, ranges : IonTable, RangeTable
    species : str
        Element whose concentration is contoured (``""``: atomic density, atoms/nm³).
    iso : float
        Fraction (or atoms/nm³).
    config : PipelineConfig, optional
        Voxelization, contouring, refinement and remeshing settings, as for ``apt-filters run``
        (default: its defaults, e.g. 1 nm voxels, marching cubes, refinement on, CVT at half a voxel).
    clean_script : path, optional
        Where the clean chain's ``.mlx`` is saved.
    label : str, optional
        Mesh label in the MeshSet (default e.g. ``"Al 15 at.%"``).

    Returns
    -------
    TriMesh
        The surface as added.
    """
    from apt_filters.meshlab.bridge import to_meshset
    from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

    config = PipelineConfig() if config is None else config
    v = config.voxel
    basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
    fields = voxelize(ions, ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size, basis=basis,
                      efficiency=config.analysis.efficiency)
    mesh, _ = finished_surface(fields, inside_mask(fields).dense(), ions, ranges, SurfaceConfig(species, iso),
                               config=config, basis=basis, clean_script=clean_script)
    to_meshset(mesh, label or (f"{species} {100 * iso:g} at.%" if species else f"density {iso:g}"), meshset=ms)
    return mesh
