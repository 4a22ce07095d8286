"""Excess and composition maps against synthetic interfaces whose segregation varies by design."""

import numpy as np
import pytest

from apt_filters.analysis import compute_proxigram, excess_maps, interfacial_excess
from apt_filters.analysis.maps import patch_sums
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.synth import MAP_SPECIMENS, generate, map_specimen, map_surface, true_excess_map


@pytest.fixture(scope="module")
def mapped(request):
    """kind -> (specimen, surface, maps, true B excess per vertex in detected atoms/nm²)."""
    out = {}
    for kind in MAP_SPECIMENS:
        spec = map_specimen(kind)
        specimen = generate(spec, seed=getattr(request, "param", 3))
        surface = map_surface(specimen)
        # min_patches 30: Al's excess is barely measurable, its maps resolve ~30 patches (B's unchanged)
        maps = excess_maps(mesh=surface, ions=specimen.ions, ranges=specimen.ranges, solutes=["B", "Al"],
                           min_patches=30)
        out[kind] = specimen, surface, maps, true_excess_map(spec, 0, "B", surface.vertices) * spec.efficiency
    return out


def test_map_recovers_the_designed_segregation_within_its_errors(mapped):
    z_all, z_levels = [], []
    for kind, (specimen, surface, maps, truth) in mapped.items():
        # Al's plateau maps, one vertex per disjoint patch, against the object's plateaus (uniform)
        al = maps.maps["Al"]
        idx = np.flatnonzero(al.patch >= 0)
        first = idx[np.unique(al.patch[idx], return_index=True)[1]]
        z_levels += [(al.c_in[first] - al.objects[0].c_in) / al.c_in_sigma[first],
                     (al.c_out[first] - al.objects[0].c_out) / al.c_out_sigma[first]]
        m = maps.maps["B"]
        per_vertex, per_patch = maps.patch_average(truth, "B")
        z_all.append((m.patch_excess - per_patch) / m.patch_sigma)
        ok = np.isfinite(m.excess)
        assert ok.mean() > 0.99, kind
        # every vertex's value against the truth over its own patch (correlated between neighbours,
        # so only the typical size is checked here: |z| of a unit normal has median 0.67)
        z = (m.excess[ok] - per_vertex[ok]) / m.excess_sigma[ok]
        assert np.median(np.abs(z)) < 0.85, kind
        # the truth spans 0..2x (facets 0.25..2x): the map must see it, and the test must say so
        stats = m.objects[0]
        assert stats.map_p95 - stats.map_p5 > 1.5 * np.mean(truth), kind
        assert stats.p_value < 1e-6, kind
    # within 2 SE on >= 90 % of the independent patches, and stated errors right (unit spread), over
    # the three interfaces' patches together (one interface's 20-50 patches cannot tell 90 % from 95 %)
    z_all = np.concatenate(z_all)
    assert len(z_all) > 100
    assert np.mean(np.abs(z_all) < 2) >= 0.9
    assert 0.8 <= np.std(z_all) <= 1.2
    # the plateau (composition) maps' errors too
    z_levels = np.concatenate(z_levels)
    assert len(z_levels) > 80
    assert 0.8 <= np.std(z_levels) <= 1.2


def detected_fraction(specimen, composition: dict, element: str) -> float:
    """The fraction of ``element`` a detector reports in a phase of true ``composition``: the
    specimen's own ions tell how often each true species (and the uniform background) is ranged
    as each element (the synthetic spectrum's ranges and noise)."""
    species = np.asarray(specimen.ions.extra["species"])
    ranged = specimen.ranges.ion_index(np.asarray(specimen.ions.mz))
    counts = specimen.ranges.element_matrix()[ranged] * (ranged >= 0)[:, None]
    col = list(specimen.ranges.elements).index(element)
    names = specimen.truth["species"]
    noise = species < 0
    rate = {name: counts[species == k].sum(axis=0) / np.count_nonzero(species == k) for k, name in enumerate(names)}
    ions = sum(x * rate[name] for name, x in composition.items())
    ions = (1 - noise.mean()) * ions + noise.mean() * counts[noise].sum(axis=0) / noise.sum()
    return float(ions[col] / ions.sum())


def test_trace_composition_maps_have_right_errors(mapped):
    # B at 0.5 at.% in both phases: each disjoint patch's plateau levels (one vertex per patch, its
    # own patch) against the detected fraction the synthetic detector produces in each phase
    z = []
    for kind, (specimen, surface, maps, truth) in mapped.items():
        feature = specimen.spec.features[0]
        c_in = detected_fraction(specimen, feature.composition, "B")
        c_out = detected_fraction(specimen, specimen.spec.matrix, "B")
        assert 0.004 < c_out < 0.006 and 0.004 < c_in < 0.006
        m = maps.maps["B"]
        idx = np.flatnonzero(m.patch >= 0)
        first = idx[np.unique(m.patch[idx], return_index=True)[1]]
        z += [(m.c_in[first] - c_in) / m.c_in_sigma[first], (m.c_out[first] - c_out) / m.c_out_sigma[first]]
    z = np.concatenate(z)
    assert len(z) > 150 and np.isfinite(z).all()
    assert abs(np.mean(z)) < 0.25
    assert 0.8 <= np.std(z) <= 1.2


@pytest.mark.parametrize("kind", MAP_SPECIMENS)
def test_map_mean_is_the_object_excess_and_the_proxigram_definition(mapped, kind):
    specimen, surface, maps, truth = mapped[kind]
    prox = compute_proxigram(specimen.ions, specimen.ranges, surface)
    for solute in ("B", "Al"):
        stats = maps.maps[solute].objects[0]
        ref = interfacial_excess(prox, solute, 1.0)[0]
        # the object's figure is the proxigram's integration estimate (same bins, windows, fits)
        assert stats.excess == pytest.approx(ref.integration.gamma_detected, rel=1e-9, abs=1e-12)
        assert stats.excess_sigma == pytest.approx(ref.integration.gamma_detected_error, rel=0.15)
        assert abs(stats.map_mean - stats.excess) < 2 * stats.excess_sigma
    # plateau maps: the phases' Al levels next to the surface, per vertex with their errors, against
    # the object's own plateaus from the same ions (the model's 20 / 10 at.% are shifted by the
    # synthetic spectrum's ranged noise, ~1 % of the level, which no map can remove)
    al = maps.maps["Al"]
    ok = np.isfinite(al.c_in)
    ref = interfacial_excess(prox, "Al", 1.0)[0]
    assert ref.precipitate.value == pytest.approx(0.20, rel=0.03) and ref.matrix.value == pytest.approx(0.10, rel=0.03)
    w = maps.vertex_area[ok]
    assert np.sum(w * al.c_in[ok]) / w.sum() == pytest.approx(ref.precipitate.value, abs=2 * ref.precipitate.error)
    assert np.sum(w * al.c_out[ok]) / w.sum() == pytest.approx(ref.matrix.value, abs=2 * ref.matrix.error)
    assert al.objects[0].c_in == pytest.approx(ref.precipitate.value, rel=1e-9)
    assert al.objects[0].c_out == pytest.approx(ref.matrix.value, rel=1e-9)


def test_vertex_properties_and_patch_levels(mapped):
    specimen, surface, maps, truth = mapped["cuboid"]
    scalars = maps.vertex_scalars()
    for name in ("excess_B", "excess_B_sigma", "c_in_B", "c_out_B", "c_in_B_sigma", "c_out_B_sigma",
                 "patch_radius_B", "excess_Al"):
        assert scalars[name].shape == (surface.n_vertices,)
    m = maps.maps["B"]
    ok = np.isfinite(m.excess)
    # a patch stops growing once its predicted error reaches the level, or holds its whole object
    assert np.median(m.excess_sigma[ok] / m.target[ok]) < 1.0
    assert maps.most_significant() == "B"
    lo, hi = maps.limits("B")
    assert lo < np.median(m.excess[ok]) < hi


@pytest.mark.parametrize("seed", [11, 12])
def test_uniform_segregation_is_reported_uniform(seed):
    spec = map_specimen("flat", modulated=False)
    specimen = generate(spec, seed=seed)
    maps = excess_maps(mesh=map_surface(specimen), ions=specimen.ions, ranges=specimen.ranges, solutes=["B"])
    stats = maps.maps["B"].objects[0]
    assert stats.n_patches >= 20
    # each seed passes at the 5 % level with probability 0.95; benchmarks/bench_maps.py counts over many
    assert stats.p_value > 0.01


def test_patch_sums_match_brute_force():
    rng = np.random.default_rng(0)
    points = rng.random((400, 3)) * 10
    normals = rng.standard_normal((400, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    obj = rng.integers(0, 2, 400)
    values = rng.random((400, 3))
    queries = np.arange(0, 400, 7)
    got = patch_sums(points, normals, obj, values, queries, 2.5, cells=None)
    for j, q in enumerate(queries):
        near = ((np.linalg.norm(points - points[q], axis=1) <= 2.5) & (obj == obj[q])
                & (normals @ normals[q] > 0))
        np.testing.assert_allclose(got[j], values[near].sum(axis=0))
    # grouped by cells of radius / 4: the same sums where no group straddles the patch's boundary,
    # and every value counted once over a radius that holds everything
    up = np.array([0.0, 0.0, 1.0]) + 0.1 * rng.standard_normal((400, 3))
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    grouped = patch_sums(points, up, obj, values, queries, 1e3)
    for j, q in enumerate(queries):
        np.testing.assert_allclose(grouped[j], values[obj == obj[q]].sum(axis=0))


def test_bad_arguments():
    spec = map_specimen("flat")
    specimen = generate(spec, seed=0)
    surface = map_surface(specimen)
    with pytest.raises(AptFiltersError, match="not an element"):
        excess_maps(mesh=surface, ions=specimen.ions, ranges=specimen.ranges, solutes=["Xx"])
    with pytest.raises(AptFiltersError):
        excess_maps(mesh=surface, ions=specimen.ions, ranges=specimen.ranges, inner=4.0)
    with pytest.raises(AptFiltersError, match="no triangles"):
        excess_maps(mesh=TriMesh(np.zeros((0, 3)), np.zeros((0, 3))), ions=specimen.ions, ranges=specimen.ranges)
