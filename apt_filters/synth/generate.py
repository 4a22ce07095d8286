"""Generating ions from a :class:`~.specimen.SpecimenSpec`, and writing a specimen folder.

Ions are a Poisson process: the total is Poisson(density x efficiency x volume / (1 - noise)),
drawn once; ions are made in chunks of ``CHUNK`` with their own random streams
(``SeedSequence([seed, 1, k])``), so the output is the same bytes for the same seed whatever
is kept in memory. For each chunk: uniform true positions in the outline; each ion is noise
with probability ``noise_fraction``, otherwise its species is drawn from the local composition
at its true position; then the reconstruction blur is added (after the species are chosen);
then density artefacts (:mod:`.artefacts`) keep each ion with their probability at its true
position; then m/z from its species' peaks (noise: uniform m/z).

Peak memory: about 250 bytes per ion of one chunk (~250 MB for 2^20 ions with 4 species),
plus 17 bytes per ion kept in memory (positions, m/z, species) when ``keep_ions``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_output, atomic_write_text
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.io.writers import write_rrng
from apt_filters.synth import specimen as model
from apt_filters.synth.spectrum import MzSampler, noise_window, peaks, range_table, ranged_noise_fraction

CHUNK = 1 << 20
FORMAT = "apt-filters synthetic specimen 1"


@dataclass
class Specimen:
    """A generated specimen and its ground truth.

    Attributes
    ----------
    spec : SpecimenSpec
        The parameters.
    seed : int
        Random seed of the ions (the layout of presets does not depend on it).
    ions : IonTable or None
        Blurred positions and m/z; ``extra["species"]`` (int8) is each ion's true species index
        into ``truth["species"]``, -1 for noise. None when generated with ``keep_ions=False``.
    ranges : RangeTable
        One range per peak (element species).
    truth : dict
        Everything in truth.json.
    meshes : list of TriMesh
        True surface of each feature (outward normals; a half-space's is its section, open).
    """

    spec: model.SpecimenSpec
    seed: int
    ions: IonTable | None
    ranges: RangeTable
    truth: dict
    meshes: list[TriMesh]

    def feature_sdf(self, index: int) -> Callable[[np.ndarray], np.ndarray]:
        """The exact SDF (nm, negative inside) of feature ``index``."""
        return self.spec.features[index].shape.sdf

    def true_sdf(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance to the nearest bounded feature (precipitate); +inf if there is none."""
        out = np.full(len(points), np.inf)
        for f in self.spec.features:
            if f.shape.bounds() is not None:
                out = np.minimum(out, f.shape.sdf(points))
        return out

    def specimen_sdf(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance to the specimen outline (tip or box)."""
        return self.spec.geometry.sdf(points)

    def summary(self) -> str:
        return summary(self.truth)


def _jsonable(value):
    if hasattr(value, "params"):  # a shape or a segregation's modulation
        return _jsonable(value.params())
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def mesh_name(index: int, feature: model.Feature) -> str:
    """File name of feature ``index``'s true surface mesh."""
    return f"surface_{index:02d}_{feature.shape.kind}.ply"


def build_truth(spec: model.SpecimenSpec, seed: int) -> tuple[dict, RangeTable, list[TriMesh], MzSampler]:
    """Everything known before the ions are drawn: layout checks, measures, excess, ranges, meshes."""
    surface_points = model.check_layout(spec)
    species = spec.species
    peak_list = peaks(species, spec.spectrum)
    window = noise_window(peak_list, spec.spectrum)
    ranges = range_table(peak_list, spec.spectrum, atomic_volume=1.0 / spec.density)
    as_dict = lambda vec: {sp: float(v) for sp, v in zip(species, vec)}  # noqa: E731
    ion_density = spec.density * spec.efficiency
    features, meshes = [], []
    for i, f in enumerate(spec.features):
        c_out = model.outside_composition(spec, i, surface_points[i])
        excess = model.interface_excess(spec, i, c_out)
        area, volume = f.shape.area(spec.geometry), f.shape.volume(spec.geometry)
        mesh = f.shape.mesh(spec.mesh_spacing, spec.geometry)
        meshes.append(mesh)
        centroids = mesh.vertices[mesh.faces].mean(axis=1)
        features.append({
            "index": i, "name": f.name or f"{f.shape.kind}{i}", "shape": f.shape.params(),
            "bounded": f.shape.bounds() is not None,
            "width_nm": f.width, "segregation": [vars(s).copy() for s in f.segregation],
            "composition_inside": as_dict(spec.vector(f.composition)),
            "composition_outside": as_dict(c_out),
            "volume_nm3": volume, "area_nm2": area,
            "depth_nm": f.shape.depth() if f.shape.bounds() is not None else None,
            "expected_detected_atoms_inside": ion_density * volume,
            "excess": {sp: {"atoms_per_nm2": float(g), "ions_per_nm2": float(g * spec.efficiency),
                            "excess_ions": float(g * spec.efficiency * area)}
                       for sp, g in zip(species, excess)},
            "mesh": {"file": mesh_name(i, f), "vertices": mesh.n_vertices,
                     "faces": mesh.n_faces, "area_nm2": mesh.area(),
                     "volume_nm3": mesh.signed_volume() if f.shape.bounds() is not None else None,
                     "max_deviation_nm": float(np.abs(f.shape.sdf(centroids)).max())},
        })
    truth = {
        "format": FORMAT,
        "name": spec.name,
        "seed": int(seed),
        "coordinates": "x, y, z in nm; top of the specimen at z = 0, deeper material at negative z",
        "geometry": {**spec.geometry.params(), "volume_nm3": spec.geometry.volume()},
        "density_atoms_per_nm3": spec.density,
        "efficiency": spec.efficiency,
        "ion_density_per_nm3": ion_density,
        "blur_sigma_nm": {"lateral": spec.blur[0], "depth": spec.blur[1]},
        "mesh_spacing_nm": spec.mesh_spacing,
        "species": species,
        "matrix_composition": as_dict(spec.vector(spec.matrix)),
        "composition_model": "c <- c + 0.5 (1 - tanh(d / w)) (c_feature - c) per feature in order; then per "
                             "segregant g = peak exp(-(d - offset)^2 / (2 sigma^2)), c <- (1 - g) c + g e_s",
        "excess_definition": "Gibbsian excess relative to the dividing surface d = 0 with the plateau compositions "
                             "inside (d < 0) and outside (d > 0): Gamma = density / A(0) * integral (c(d) - "
                             "c_step(d)) A(d) dd, A(d) the area of the level set sdf = d; ions_per_nm2 = "
                             "atoms_per_nm2 x efficiency",
        "spectrum": {
            "mass_resolution_fwhm": spec.spectrum.mass_resolution,
            "range_half_width_sigmas": spec.spectrum.range_sigmas,
            "noise_fraction": spec.spectrum.noise_fraction,
            "noise_mz": list(window),
            "ranged_noise_fraction": ranged_noise_fraction(ranges, window),
            "peaks": [vars(p).copy() for p in peak_list],
        },
        "features": features,
        "artefacts": [a.params() for a in spec.artefacts],
    }
    return truth, ranges, meshes, MzSampler(species, peak_list, window)


def iter_ions(spec: model.SpecimenSpec, seed: int, sampler: MzSampler,
              chunk: int = CHUNK) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Yield (positions (n, 3) f32, mz (n,) f32, species (n,) int8) chunk by chunk (module docstring)."""
    total = int(np.random.default_rng(np.random.SeedSequence([seed, 0])).poisson(spec.expected_ions()))
    lateral, depth = spec.blur
    for k, start in enumerate(range(0, total, chunk)):
        n = min(chunk, total - start)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 1, k]))
        true = spec.geometry.sample(n, rng)
        noise = rng.random(n) < spec.spectrum.noise_fraction
        atoms = np.flatnonzero(~noise)
        cum = np.cumsum(model.composition_at(spec, true[atoms]), axis=1)
        species = np.full(n, -1, dtype=np.int8)
        species[atoms] = np.minimum((cum < rng.random(len(atoms))[:, None]).sum(axis=1), cum.shape[1] - 1)
        blurred = true + rng.standard_normal((n, 3)) * np.array([lateral, lateral, depth])
        if spec.artefacts:  # density artefacts thin the ions by their true positions, species kept
            keep = np.ones(n)
            for artefact in spec.artefacts:
                keep *= artefact.keep(true)
            kept = rng.random(n) < keep
            blurred, species = blurred[kept], species[kept]
        yield blurred.astype(np.float32), sampler.sample(species, rng).astype(np.float32), species


def _generate(spec, seed, keep_ions: bool, pos_file=None) -> Specimen:
    truth, ranges, meshes, sampler = build_truth(spec, seed)
    counts = np.zeros(len(spec.species) + 1, dtype=np.int64)  # last: noise
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    kept = []
    for pos, mz, species in iter_ions(spec, seed, sampler):
        counts += np.bincount(species.astype(np.int64) % len(counts), minlength=len(counts))
        if len(pos):
            lo, hi = np.minimum(lo, pos.min(axis=0)), np.maximum(hi, pos.max(axis=0))
        if pos_file is not None:
            block = np.empty((len(mz), 4), dtype=">f4")
            block[:, :3], block[:, 3] = pos, mz
            pos_file.write(block.tobytes())
        if keep_ions:
            kept.append((pos, mz, species))
    n_atoms = int(counts[:-1].sum())
    truth["ions"] = {
        "expected": spec.expected_ions(), "total": int(counts.sum()), "noise": int(counts[-1]),
        "by_species": {sp: int(c) for sp, c in zip(spec.species, counts)},
        "composition": {sp: float(c / max(n_atoms, 1)) for sp, c in zip(spec.species, counts)},
        "bounds_nm": [lo.tolist(), hi.tolist()] if counts.sum() else None,
    }
    ions = None
    if keep_ions:
        cols = list(zip(*kept)) if kept else [[np.zeros((0, 3), np.float32)], [np.zeros(0, np.float32)],
                                              [np.zeros(0, np.int8)]]
        ions = IonTable(np.concatenate(cols[0]), np.concatenate(cols[1]), {"species": np.concatenate(cols[2])},
                        source=f"synthetic:{spec.name}:{seed}")
    return Specimen(spec, int(seed), ions, ranges, _jsonable(truth), meshes)


def generate(spec: model.SpecimenSpec, seed: int = 0) -> Specimen:
    """Generate a specimen in memory (no files). Memory: see the module docstring."""
    return _generate(spec, seed, keep_ions=True)


def write_specimen(outdir: str | os.PathLike, spec: model.SpecimenSpec, seed: int = 0, overwrite: bool = False,
                   keep_ions: bool = True) -> Specimen:
    """Generate a specimen and write it to ``outdir`` (created if missing).

    Files: ``specimen.pos`` (streamed chunk by chunk), ``specimen.rrng``, one PLY per feature
    (``surface_NN_kind.ply``) and ``truth.json`` (written last). Every file is written atomically;
    existing files are only replaced with ``overwrite``. Same seed -> identical bytes.
    With ``keep_ions=False`` the ions are not held in memory (for 10^8 ions and more).
    """
    out = Path(outdir)
    if out.exists() and not out.is_dir():
        raise AptFiltersError("is not a folder", out)
    out.mkdir(parents=True, exist_ok=True)
    names = ["specimen.pos", "specimen.rrng", "truth.json"] + [mesh_name(i, f) for i, f in enumerate(spec.features)]
    if not overwrite:
        for name in names:
            if (out / name).exists():
                raise AptFiltersError("exists already; pass overwrite/--force to replace it", out / name)
    with atomic_output(out / "specimen.pos", overwrite) as tmp, open(tmp, "wb") as fh:
        result = _generate(spec, seed, keep_ions, pos_file=fh)
    write_rrng(out / "specimen.rrng", result.ranges, overwrite)
    from apt_filters.meshlab.exports import write_ply  # the one mesh writer (pymeshlab loads only here)

    for feature, mesh in zip(result.truth["features"], result.meshes):
        write_ply(mesh, out / feature["mesh"]["file"], quality=None, cmap=None, overwrite=overwrite)
    result.truth["files"] = {"pos": names[0], "rrng": names[1], "meshes": names[3:]}
    atomic_write_text(out / "truth.json", jsontext.dumps(result.truth, indent=1) + "\n", overwrite)
    return result


def summary(truth: dict) -> str:
    """Human-readable summary of a specimen's truth (ion count, bounds, composition, features, excess)."""
    ions, geo = truth["ions"], truth["geometry"]
    if geo["kind"] == "tip":
        shape = (f"apex radius {geo['apex_radius']:g} nm, half-angle {geo['half_angle_deg']:g} deg, "
                 f"length {geo['length']:g} nm")
    else:
        shape = " x ".join(f"{v:g}" for v in geo["size"]) + " nm"
    lines = [f"specimen {truth['name']!r} (seed {truth['seed']}): {ions['total']:,} ions "
             f"({ions['noise']:,} noise; expected {ions['expected']:,.0f}) in a {geo['kind']} ({shape}; "
             f"{geo['volume_nm3']:,.0f} nm3)"]
    if ions["bounds_nm"]:
        lo, hi = ions["bounds_nm"]
        lines.append("bounding box: " + "  ".join(f"{a} [{lo[i]:.1f}, {hi[i]:.1f}]" for i, a in enumerate("xyz")) + " nm")
    lines.append("composition of detected atoms: "
                 + ", ".join(f"{sp} {100 * c:.2f} at.%" for sp, c in ions["composition"].items()))
    lines.append(f"density {truth['density_atoms_per_nm3']:g} atoms/nm3, efficiency {truth['efficiency']:g}, "
                 f"blur {truth['blur_sigma_nm']['lateral']:g}/{truth['blur_sigma_nm']['depth']:g} nm (lateral/depth)")
    for f in truth["features"]:
        inside = ", ".join(f"{sp} {100 * c:.1f}" for sp, c in f["composition_inside"].items() if c)
        outside = ", ".join(f"{sp} {100 * c:.1f}" for sp, c in f["composition_outside"].items() if c)
        seg = [s["species"] for s in f["segregation"]]
        excess = "; ".join(f"excess {sp} {f['excess'][sp]['atoms_per_nm2']:.3f} atoms/nm2 "
                           f"({f['excess'][sp]['ions_per_nm2']:.3f} ions/nm2, {f['excess'][sp]['excess_ions']:.0f} ions)"
                           for sp in seg)
        lines.append(f"  [{f['index']}] {f['name']} ({f['shape']['kind']}): volume {f['volume_nm3']:.1f} nm3, "
                     f"area {f['area_nm2']:.1f} nm2; inside at.% {inside}; outside at.% {outside}"
                     + (f"; {excess}" if excess else ""))
    return "\n".join(lines)
