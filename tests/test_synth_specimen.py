"""Generated specimens against their own truth: counts, compositions, blur, excess, files, determinism."""

import json
import math
import re

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.io.writers import format_rrng
from apt_filters.synth import (Box, Cuboid, Feature, HalfSpace, Segregation, SpecimenSpec, Sphere, SpectrumModel,
                               build_truth, generate, preset, with_ions, write_specimen)
from apt_filters.synth.specimen import check_layout

SIGMAS = 4.0  # every statistical check: |measured - truth| < 4 standard errors


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("small")
    return write_specimen(out, preset("small"), seed=11), out


@pytest.fixture(scope="module")
def cube_in_box():
    """One rotated 6 nm cube with a B shell in the middle of a 19 nm box (far from every wall)."""
    spec = SpecimenSpec(
        Box((19.0, 19.0, 19.0)), {"Ni": 0.745, "Al": 0.10, "Cr": 0.15, "B": 0.005},
        (Feature(Cuboid((0.0, 0.0, -9.5), 6.0, rotation=4), {"Ni": 0.745, "Al": 0.20, "Cr": 0.05, "B": 0.005},
                 0.2, (Segregation("B", 0.08, 0.25),), "cube"),),
        name="cube-in-box")
    return generate(spec, seed=5)


def _tiny():
    """~45k ions: a 2 nm sphere with a B shell in a 10 x 9 x 12 nm box."""
    comp = {"Ni": 0.8, "Al": 0.15, "B": 0.05}
    return SpecimenSpec(Box((10.0, 9.0, 12.0)), comp,
                        (Feature(Sphere((0.5, 0.0, -6.0), 2.0), {"Ni": 0.7, "Al": 0.25, "B": 0.05}, 0.2,
                                 (Segregation("B", 0.1, 0.3),)),), name="tiny")


def _element_of(specimen):
    """Element index (into truth species) of each ion by ranging its m/z; -1 unranged."""
    ranges, species = specimen.ranges, specimen.truth["species"]
    lookup = np.array([species.index(ion) for ion in ranges.ions] + [-1])
    return lookup[ranges.ion_index(specimen.ions.mz)]


def _expected_ranged(specimen, composition):
    """Composition measured by ranging where the true one is ``composition``: noise ions in ranges added."""
    t = specimen.truth
    lo, hi = t["spectrum"]["noise_mz"]
    f = t["spectrum"]["noise_fraction"]
    q = np.zeros(len(t["species"]))
    for r in specimen.ranges.ranges:
        q[t["species"].index(r.ion)] += (min(r.upper, hi) - max(r.lower, lo)) / (hi - lo)
    counts = (1 - f) * np.array([composition[s] for s in t["species"]]) + f * q
    return counts / counts.sum()


def _check_composition(measured_idx, expected):
    n = len(measured_idx)
    assert n > 300
    measured = np.bincount(measured_idx, minlength=len(expected)) / n
    err = np.sqrt(expected * (1 - expected) / n)
    assert (np.abs(measured - expected) < SIGMAS * err + 1e-12).all(), (measured, expected, err)


def test_ion_count_is_poisson_around_density_times_efficiency_times_volume(small):
    specimen, _ = small
    t = specimen.truth
    lam = t["density_atoms_per_nm3"] * t["efficiency"] * t["geometry"]["volume_nm3"] / (1 - t["spectrum"]["noise_fraction"])
    assert t["ions"]["expected"] == pytest.approx(lam)
    assert abs(len(specimen.ions) - lam) < SIGMAS * math.sqrt(lam)
    assert t["ions"]["total"] == len(specimen.ions)
    noise = (specimen.ions.extra["species"] < 0).sum()
    f = t["spectrum"]["noise_fraction"]
    assert abs(noise - f * len(specimen.ions)) < SIGMAS * math.sqrt(f * len(specimen.ions))


def test_ions_inside_each_precipitate_number_density_times_volume(small):
    """Blur moves as many ions in as out of a convex region in uniform density: counts stay unbiased."""
    specimen, _ = small
    t = specimen.truth
    rate = t["ion_density_per_nm3"] / (1 - t["spectrum"]["noise_fraction"])
    pos = specimen.ions.positions.astype(np.float64)
    for i, f in enumerate(t["features"]):
        if f["bounded"]:
            count = (specimen.feature_sdf(i)(pos) < 0).sum()
            lam = rate * f["volume_nm3"]
            assert abs(count - lam) < SIGMAS * math.sqrt(lam), (f["name"], count, lam)


def test_compositions_well_inside_and_outside_match_the_truth(small):
    specimen, _ = small
    t = specimen.truth
    pos = specimen.ions.positions.astype(np.float64)
    measured = _element_of(specimen)
    ranged = measured >= 0
    nearest = np.full(len(pos), np.inf)
    for i, f in enumerate(t["features"]):
        d = specimen.feature_sdf(i)(pos)
        nearest = np.minimum(nearest, np.abs(d))
        if f["bounded"]:
            core = (d < -1.5) & ranged
            _check_composition(measured[core], _expected_ranged(specimen, f["composition_inside"]))
    layer = specimen.feature_sdf(0)(pos)
    inside = specimen.specimen_sdf(pos) < -1.5
    matrix = (nearest > 2.0) & (layer > 0) & inside & ranged
    below = (nearest > 2.0) & (layer < 0) & inside & ranged
    _check_composition(measured[matrix], _expected_ranged(specimen, t["matrix_composition"]))
    _check_composition(measured[below], _expected_ranged(specimen, t["features"][0]["composition_inside"]))


def test_ranging_recovers_the_true_species(small):
    specimen, _ = small
    true = specimen.ions.extra["species"]
    measured = _element_of(specimen)
    atoms = true >= 0
    assert (measured[atoms] == true[atoms]).mean() > 1 - 1e-4  # +-5 sigma ranges
    t = specimen.truth
    noise = ~atoms
    q = t["spectrum"]["ranged_noise_fraction"]
    assert abs((measured[noise] >= 0).mean() - q) < SIGMAS * math.sqrt(q * (1 - q) / noise.sum())


def test_blur_per_axis_from_ions_leaving_the_asymmetric_box(small):
    """Uniform density blurred by N(0, s) puts rho * area * s / sqrt(2 pi) ions beyond each face."""
    specimen, _ = small
    t = specimen.truth
    sx, sy, sz = t["geometry"]["size"]
    rate = t["ion_density_per_nm3"] / (1 - t["spectrum"]["noise_fraction"])
    lateral, depth = t["blur_sigma_nm"]["lateral"], t["blur_sigma_nm"]["depth"]
    p = specimen.ions.positions.astype(np.float64)
    beyond = {"x": (np.abs(p[:, 0]) > sx / 2).sum(), "y": (np.abs(p[:, 1]) > sy / 2).sum(),
              "z": ((p[:, 2] > 0) | (p[:, 2] < -sz)).sum()}
    expected = {"x": 2 * sy * sz * lateral, "y": 2 * sx * sz * lateral, "z": 2 * sx * sy * depth}
    for axis, count in beyond.items():
        lam = rate * expected[axis] / math.sqrt(2 * math.pi)
        assert abs(count - lam) < SIGMAS * math.sqrt(lam), (axis, count, lam)
    lo, hi = t["ions"]["bounds_nm"]
    assert np.allclose(lo, [-sx / 2, -sy / 2, -sz], atol=6 * lateral)
    assert np.allclose(hi, [sx / 2, sy / 2, 0.0], atol=6 * lateral)


def test_excess_at_the_flat_interface_counted_from_ions(small):
    specimen, _ = small
    t = specimen.truth
    layer = t["features"][0]
    z0 = layer["shape"]["point"][2]
    lo, hi = -27.5, -21.2  # away from the box bottom and from the sphere's shell
    area = t["geometry"]["size"][0] * t["geometry"]["size"][1]
    b = t["species"].index("B")
    z = specimen.ions.positions[:, 2].astype(np.float64)
    in_slab = (z > lo) & (z < hi)
    measured = _element_of(specimen)
    n_b = ((measured == b) & in_slab).sum()
    rate = t["ion_density_per_nm3"]
    plateau = rate * area * (layer["composition_inside"]["B"] * (z0 - lo) + layer["composition_outside"]["B"] * (hi - z0))
    noise = _noise_in_ranges_of(specimen, "B") * rate / (1 - t["spectrum"]["noise_fraction"]) * area * (hi - lo)
    gamma = (n_b - plateau - noise) / area
    assert layer["excess"]["B"]["ions_per_nm2"] == pytest.approx(layer["excess"]["B"]["atoms_per_nm2"] * t["efficiency"])
    assert abs(gamma - layer["excess"]["B"]["ions_per_nm2"]) < SIGMAS * math.sqrt(n_b) / area, (gamma, layer["excess"])


def _noise_in_ranges_of(specimen, element):
    t = specimen.truth
    lo, hi = t["spectrum"]["noise_mz"]
    width = sum(min(r.upper, hi) - max(r.lower, lo) for r in specimen.ranges.ranges if r.ion == element)
    return t["spectrum"]["noise_fraction"] * width / (hi - lo)


def test_excess_at_a_rotated_cube_counted_from_ions(cube_in_box):
    """B ions within 2.1 nm of the cube minus the plateaus times the exact volumes = excess x area."""
    specimen = cube_in_box
    t = specimen.truth
    cube = t["features"][0]
    shape = specimen.spec.features[0].shape
    reach = 2.1
    d = np.linspace(0.0, reach, 4001)
    shell = np.trapezoid(shape.level_area(d), d)
    rate = t["ion_density_per_nm3"]
    b = t["species"].index("B")
    near = specimen.feature_sdf(0)(specimen.ions.positions.astype(np.float64)) < reach
    n_b = ((_element_of(specimen) == b) & near).sum()
    plateau = rate * (cube["composition_inside"]["B"] * cube["volume_nm3"] + cube["composition_outside"]["B"] * shell)
    noise = _noise_in_ranges_of(specimen, "B") * rate / (1 - t["spectrum"]["noise_fraction"]) * (cube["volume_nm3"] + shell)
    excess_ions = n_b - plateau - noise
    assert abs(excess_ions - cube["excess"]["B"]["excess_ions"]) < SIGMAS * math.sqrt(n_b), (excess_ions, cube["excess"])
    # the segregant dilutes the others: their excess is negative, and the sum of all is the B shell's
    total = sum(v["atoms_per_nm2"] for v in cube["excess"].values())
    assert cube["excess"]["Al"]["atoms_per_nm2"] < 0 and abs(total) < 0.05


def test_excess_of_a_flat_gaussian_shell_is_analytic():
    """Flat interface, equal plateaus: Gamma_B = rho * peak * sigma * sqrt(2 pi) * (1 - c_B)."""
    comp = {"Ni": 0.9, "B": 0.1}
    spec = SpecimenSpec(Box((10.0, 10.0, 20.0)), comp,
                        (Feature(HalfSpace((0, 0, -10), (0, 0, 1)), comp, 0.3, (Segregation("B", 0.05, 0.4),)),))
    truth = build_truth(spec, 0)[0]
    gamma = truth["features"][0]["excess"]["B"]["atoms_per_nm2"]
    assert gamma == pytest.approx(85.0 * 0.05 * 0.4 * math.sqrt(2 * math.pi) * 0.9, rel=1e-6)
    # a sphere of radius R: A(d) / A(0) = (1 + d/R)^2 adds the shell's second moment
    spec = SpecimenSpec(Box((20.0, 20.0, 20.0)), comp,
                        (Feature(Sphere((0, 0, -10), 3.0), comp, 0.3, (Segregation("B", 0.05, 0.4),)),))
    gamma = build_truth(spec, 0)[0]["features"][0]["excess"]["B"]["atoms_per_nm2"]
    assert gamma == pytest.approx(85.0 * 0.05 * 0.4 * math.sqrt(2 * math.pi) * 0.9 * (1 + 0.4**2 / 9), rel=1e-6)


def test_an_open_interfaces_undefined_excess_is_written_as_null_with_its_reason(tmp_path):
    """Was: write_specimen of a curved interface across the specimen (the zoo's `curved` family) wrote the ions,
    range file and meshes and then failed on truth.json: its excess per area is not defined (NaN)."""
    from apt_filters.synth.implicit import SphereInterface

    comp, inside = {"Al": 0.9, "Mg": 0.09, "Si": 0.01}, {"Al": 0.85, "Mg": 0.14, "Si": 0.01}
    box = Box((24.0, 24.0, 40.0))  # the zoo's draw 10072, at a tenth of its efficiency
    spec = SpecimenSpec(box, comp, (Feature(SphereInterface(box, (11.0, -9.5, -54.45), 40.07, convex=True), inside,
                                            2.15, (Segregation("Si", 0.047, 0.35, 0.18),), "curved interface"),),
                        efficiency=0.04)
    write_specimen(tmp_path, spec, seed=1, keep_ions=False)

    def refuse(word):
        raise ValueError(word)

    truth = json.loads((tmp_path / "truth.json").read_text(), parse_constant=refuse)  # strict JSON
    excess = truth["features"][0]["excess"]["Si"]
    assert excess["atoms_per_nm2"] is None and excess["atoms_per_nm2_null"] == "NaN: not defined"


def test_truth_volumes_and_areas_match_monte_carlo_and_meshes(small):
    specimen, _ = small
    rng = np.random.default_rng(8)
    for i, f in enumerate(specimen.truth["features"]):
        if not f["bounded"]:
            continue
        lo, hi = specimen.spec.features[i].shape.bounds()
        p = rng.uniform(lo, hi, (400_000, 3))
        frac = (specimen.feature_sdf(i)(p) < 0).mean()
        box = float(np.prod(hi - lo))
        assert abs(frac * box - f["volume_nm3"]) < SIGMAS * math.sqrt(frac * (1 - frac) / len(p)) * box
        assert f["mesh"]["volume_nm3"] == pytest.approx(f["volume_nm3"], rel=2e-3)
        assert f["mesh"]["area_nm2"] == pytest.approx(f["area_nm2"], rel=2e-3)
    cube = specimen.truth["features"][1]
    assert (cube["volume_nm3"], cube["area_nm2"]) == pytest.approx((216.0, 216.0))


def test_files_pos_ply_and_truth(small):
    specimen, out = small
    raw = np.fromfile(out / "specimen.pos", dtype=">f4").reshape(-1, 4)
    assert np.array_equal(raw[:, :3], specimen.ions.positions) and np.array_equal(raw[:, 3], specimen.ions.mz)
    truth = json.loads((out / "truth.json").read_text(), parse_constant=lambda c: pytest.fail(f"not JSON: {c}"))
    assert truth["seed"] == 11 and truth["files"]["pos"] == "specimen.pos"
    for f, mesh in zip(truth["features"], specimen.meshes):
        data = (out / f["mesh"]["file"]).read_bytes()
        header, body = data.split(b"end_header\n", 1)
        assert f"element vertex {mesh.n_vertices}".encode() in header
        vertices = np.frombuffer(body[: 24 * mesh.n_vertices], dtype="<f8").reshape(-1, 3)
        faces = np.frombuffer(body[24 * mesh.n_vertices:], dtype=[("n", "u1"), ("v", "<i4", (3,))])
        assert np.array_equal(vertices, mesh.vertices) and (faces["n"] == 3).all()
        assert np.array_equal(faces["v"], mesh.faces)


def test_rrng_round_trips_and_ranges_cover_every_peak(small):
    specimen, out = small
    text = (out / "specimen.rrng").read_text()
    assert text == format_rrng(specimen.ranges)
    rebuilt = []
    for match in re.finditer(r"^Range\d+=(\S+) (\S+) Vol:(\S+) (\w+):(\d+) Color:(\w+)$", text, re.M):
        lo, hi, vol, el, n, color = match.groups()
        rebuilt.append(Range(float(lo), float(hi), ((el, int(n)),), color, float(vol)))
    assert len(rebuilt) == len(specimen.ranges)
    assert format_rrng(RangeTable(rebuilt)) == text
    peaks = specimen.truth["spectrum"]["peaks"]
    idx = specimen.ranges.range_index(np.array([p["mz"] for p in peaks]))
    assert (idx >= 0).all()
    assert [specimen.ranges.ranges[i].ion for i in idx] == [p["species"] for p in peaks]
    assert set(specimen.ranges.elements) == {"Ni", "Al", "Cr", "B"}


def test_same_seed_same_bytes_other_seed_other_ions(tmp_path):
    spec = _tiny()
    written = [write_specimen(tmp_path / name, spec, seed=seed) for name, seed in (("a", 3), ("b", 3), ("c", 4))]
    files = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert len(files) == 4
    for name in files:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    assert (tmp_path / "a" / "specimen.pos").read_bytes() != (tmp_path / "c" / "specimen.pos").read_bytes()
    memory = generate(spec, seed=3)
    assert np.array_equal(memory.ions.positions, written[0].ions.positions)


def test_existing_files_are_not_overwritten_unless_asked(tmp_path):
    spec = _tiny()
    write_specimen(tmp_path, spec, seed=1)
    before = (tmp_path / "specimen.pos").read_bytes()
    with pytest.raises(AptFiltersError, match="exists already"):
        write_specimen(tmp_path, spec, seed=2)
    assert (tmp_path / "specimen.pos").read_bytes() == before
    write_specimen(tmp_path, spec, seed=2, overwrite=True, keep_ions=False)
    assert (tmp_path / "specimen.pos").read_bytes() != before
    assert not [p for p in tmp_path.iterdir() if "tmp" in p.name]


def test_tip_ions_lie_inside_the_tip_and_blur_is_applied_after_species():
    spec = preset("gamma-prime")
    sharp = SpecimenSpec(spec.geometry.with_length(14.0), spec.matrix, (), blur=(0.0, 0.0), name="sharp")
    specimen = generate(sharp, seed=2)
    assert (specimen.specimen_sdf(specimen.ions.positions.astype(np.float64)) < 1e-5).all()
    blurred = generate(SpecimenSpec(sharp.geometry, sharp.matrix, (), name="blurred"), seed=2)
    d = blurred.specimen_sdf(blurred.ions.positions.astype(np.float64))
    assert (d < 6 * 0.3).all() and (d > 0).any()
    # the species drawn do not depend on the blur: same seed, same species and m/z
    assert np.array_equal(blurred.ions.extra["species"], specimen.ions.extra["species"])
    assert np.array_equal(blurred.ions.mz, specimen.ions.mz)


def test_presets_are_valid_and_sized():
    for name, low, high in (("small", 1e5, 3e5), ("gamma-prime", 8e5, 2e6), ("default", 2e6, 6e6)):
        spec = preset(name)
        check_layout(spec)
        assert low < spec.expected_ions() < high
    gp = build_truth(preset("gamma-prime"), 0)[0]
    assert [f["shape"]["kind"] for f in gp["features"]] == ["cuboid", "sphere", "cuboid", "sphere"]
    assert [f["volume_nm3"] for f in gp["features"]] == pytest.approx([343.0, 36 * math.pi, 216.0, 36 * math.pi])
    assert [f["area_nm2"] for f in gp["features"]] == pytest.approx([294.0, 36 * math.pi, 216.0, 36 * math.pi])
    for f in gp["features"]:
        assert f["composition_inside"]["Al"] == 0.20 and f["composition_outside"]["Al"] == pytest.approx(0.10)
        assert f["excess"]["B"]["atoms_per_nm2"] > 3
    assert gp["geometry"]["kind"] == "tip" and gp["efficiency"] == 0.5
    assert gp["blur_sigma_nm"] == {"lateral": 0.3, "depth": 0.1}


def test_bad_specs_are_clear_errors():
    comp = {"Ni": 0.9, "Al": 0.1}
    box = Box((10.0, 10.0, 10.0))
    with pytest.raises(AptFiltersError, match="composition"):
        check_layout(SpecimenSpec(box, {"Ni": 0.9, "Al": 0.2}))
    with pytest.raises(AptFiltersError, match="not inside"):
        check_layout(SpecimenSpec(box, comp, (Feature(Sphere((0, 0, -1), 2.0), comp),)))
    with pytest.raises(AptFiltersError, match="overlap"):
        check_layout(SpecimenSpec(box, comp, (Feature(Sphere((0, 0, -5), 1.5), comp),
                                              Feature(Sphere((1.5, 0, -5), 1.5), comp))))
    with pytest.raises(AptFiltersError, match="not an element"):
        build_truth(SpecimenSpec(box, {"Xx": 1.0}), 0)
    with pytest.raises(AptFiltersError, match="peaks overlap"):
        build_truth(SpecimenSpec(box, comp, spectrum=SpectrumModel(charge_states={"Al": {1: 1.0}, "Ni": {2: 1.0}},
                                                                   mass_resolution=20)), 0)
    with pytest.raises(AptFiltersError, match="too few"):
        with_ions(preset("small"), 1000)


def test_composition_field_is_the_one_dimensional_profile_of_the_truth(small):
    """Near each feature the 3-D field (culling, painting order) equals the profile the excess integrates."""
    from apt_filters.synth.specimen import CULL_TOLERANCE, blend, composition_at

    specimen, _ = small
    spec, t = specimen.spec, specimen.truth
    rng = np.random.default_rng(9)
    for i, f in enumerate(t["features"]):
        feature = spec.features[i]
        mesh = specimen.meshes[i]
        base = mesh.vertices[rng.integers(0, mesh.n_vertices, 3000)]
        p = base + rng.normal(scale=0.8, size=base.shape)
        keep = spec.geometry.sdf(p) < 0
        for j, other in enumerate(spec.features):  # stay on this feature's side of, and away from, the others
            if j != i:
                side = np.sign(other.shape.sdf(mesh.vertices[:1]))
                keep &= other.shape.sdf(p) * side > other.reach(CULL_TOLERANCE)
        p = p[keep]
        assert len(p) > 1000
        d = feature.shape.sdf(p)
        expected = np.tile(spec.vector(f["composition_outside"]), (len(d), 1))
        blend(expected, d, feature, spec.vector(f["composition_inside"]), spec.species)
        assert np.abs(composition_at(spec, p) - expected).max() < 1e-9, f["name"]


def test_species_are_drawn_from_the_local_composition(small):
    """Without blur the ions sit where their species was drawn: counts match the summed probabilities."""
    from apt_filters.synth.specimen import composition_at

    spec = small[0].spec
    sharp = generate(SpecimenSpec(spec.geometry, spec.matrix, spec.features, blur=(0.0, 0.0), name="sharp"), seed=12)
    species = sharp.ions.extra["species"]
    atoms = species >= 0
    prob = composition_at(spec, sharp.ions.positions[atoms].astype(np.float64))
    counts = np.bincount(species[atoms], minlength=prob.shape[1])
    expected, var = prob.sum(axis=0), (prob * (1 - prob)).sum(axis=0)
    assert (np.abs(counts - expected) < SIGMAS * np.sqrt(var)).all(), (counts, expected)
    # and the same near the interfaces alone, where the B shells are
    near = np.min([np.abs(spec.features[i].shape.sdf(sharp.ions.positions[atoms].astype(np.float64)))
                   for i in range(len(spec.features))], axis=0) < 1.0
    counts = np.bincount(species[atoms][near], minlength=prob.shape[1])
    expected, var = prob[near].sum(axis=0), (prob[near] * (1 - prob[near])).sum(axis=0)
    assert (np.abs(counts - expected) < SIGMAS * np.sqrt(var)).all(), (counts, expected)


def test_many_preset_holds_about_fifty_precipitates_that_pass_the_layout_check():
    from apt_filters.synth.presets import many
    from apt_filters.synth.specimen import check_layout

    spec = many()
    check_layout(spec)
    assert 45 <= len(spec.features) <= 55
    assert 7e6 < spec.expected_ions() < 1.1e7
