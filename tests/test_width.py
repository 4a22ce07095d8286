"""Interface width, position and plateau windows fitted from profiles with exact truth."""

import numpy as np
import pytest
from scipy.special import ndtr

from apt_filters.analysis.proxigram import compute_proxigram
from apt_filters.analysis.width import (OUTER_FACTOR, fit_profile, fitted_proxigram, midpoint, plateau_windows)
from apt_filters.core.errors import AptFiltersError
from apt_filters.io.ions import IonTable
from apt_filters.pipeline import config as cfg
from tests.proxigram_specimens import RANGES, plane

S = np.arange(-12.0, 12.0, 0.1) + 0.05
"""Bin centres of a profile, nm."""


def draw(rng, fraction, atoms_per_bin=400):
    total = rng.poisson(atoms_per_bin, len(S))
    return rng.binomial(total, np.clip(fraction, 0, 1)), total


@pytest.mark.parametrize("sigma", [0.3, 1.0, 2.0])
def test_a_symmetric_step_gives_its_width_position_and_errors(sigma):
    """Over 30 draws: the 10-90 % width (2.563 sigma) and the 50 % point within their stated errors
    (z-scores of unit spread, mean near 0)."""
    rng = np.random.default_rng(int(10 * sigma))
    true_width, centre = 2 * 1.2815515655446004 * sigma, 0.3
    z_width, z_centre = [], []
    for _ in range(30):
        n, total = draw(rng, 0.02 + 0.3 * ndtr((S - centre) / sigma))
        fit = fit_profile(s=S, n=n, total=total)
        z_width.append((fit.width - true_width) / fit.width_error)
        z_centre.append((fit.centre - centre) / fit.centre_error)
        assert fit.outside == pytest.approx(0.02, abs=0.003) and fit.inside == pytest.approx(0.32, abs=0.01)
    for z in (np.array(z_width), np.array(z_centre)):
        assert abs(z.mean()) < 0.6 and 0.6 < z.std() < 1.5, (z.mean(), z.std())


def test_an_asymmetric_step_puts_its_50_percent_point_where_the_profile_crosses():
    """Steep on one side, a long tail on the other: the 50 %-of-the-way point is the profile's own crossing,
    the reach covers the long tail."""
    rng = np.random.default_rng(3)
    true = np.where(S < 0, 0.5 * np.exp(S / 2.0), 1 - 0.5 * np.exp(-S / 0.3))  # crosses 50 % at s = 0
    n, total = draw(rng, 0.01 + 0.5 * true, 2000)
    fit = fit_profile(s=S, n=n, total=total)
    assert abs(fit.centre) <= 3 * fit.centre_error + 0.02, (fit.centre, fit.centre_error)
    assert fit.sigma_outside > 3 * fit.sigma_inside
    # the tail holds 0.5 % of the step 2 ln(100) = 9.2 nm out: the fitted half-Gaussian reaches 5-10 nm
    assert 5.0 < fit.reach < 10.0


def test_midpoint_follows_a_decreasing_step_too():
    rng = np.random.default_rng(4)
    n, total = draw(rng, 0.4 - 0.3 * ndtr((S + 1.0) / 0.5), 1000)
    position, error = midpoint(s=S, n=n, total=total, outside=0.4, inside=0.1)
    assert abs(position + 1.0) < 3 * error and 0 < error < 0.1


def windows_of(profiles, species="Al", solutes=(), **given):
    """plateau_windows on counts (bins of S) for species name -> fraction profile."""
    from apt_filters.analysis.proxigram import Proxigram, shell_volumes

    rng = np.random.default_rng(5)
    names = list(profiles)
    total = rng.poisson(2000, len(S))
    counts = np.stack([rng.binomial(total, profiles[k]) for k in names], axis=1)
    counts = np.concatenate([counts, (total - counts.sum(axis=1))[:, None]], axis=1)
    edges = np.append(S - 0.05, S[-1] + 0.05)
    prox = Proxigram(edges=edges, ions=names + ["Fe"], elements=names + ["Fe"],
                     element_matrix=np.eye(len(names) + 1, dtype=np.int64), colors={}, object_ids=np.array([0]),
                     counts=counts[None], unranged=np.zeros((1, len(S)), np.int64), areas=np.array([100.0]),
                     shell_volumes=shell_volumes(edges, np.array([100.0]), np.zeros(1), np.zeros(1)))
    return plateau_windows(proxigram=prox, species=species, solutes=list(solutes), **given)


def test_windows_scale_with_the_width_and_cover_a_wider_peak():
    sharp = windows_of({"Al": 0.05 + 0.3 * ndtr(S / 0.2)})
    wide = windows_of({"Al": 0.05 + 0.3 * ndtr(S / 2.0)})
    # 0.5 % of a Gaussian step lies beyond 2.58 sigma
    assert sharp.inner == pytest.approx(2.58 * 0.2, abs=0.15) and wide.inner == pytest.approx(2.58 * 2.0, abs=0.5)
    assert wide.outer == pytest.approx(OUTER_FACTOR * wide.inner, abs=0.1) and wide.source == "fitted"
    # a segregant shell (sigma 0.6 nm at +0.4 nm) wider than the sharp step sets the windows
    shell = windows_of({"Al": 0.05 + 0.3 * ndtr(S / 0.2), "B": 0.002 + 0.05 * np.exp(-0.5 * ((S - 0.4) / 0.6) ** 2)},
                       solutes=["B"])
    [peak] = shell.peaks
    assert peak.peak == pytest.approx(0.05, rel=0.15) and peak.peak_sigma == pytest.approx(0.6, rel=0.15)
    assert shell.inner == pytest.approx(0.4 + 2.58 * 0.6, abs=0.25)
    # no peak where there is none: the solute does not move the windows
    flat = windows_of({"Al": 0.05 + 0.3 * ndtr(S / 0.2), "B": np.full(len(S), 0.003)}, solutes=["B"])
    assert flat.peaks[0].peak == 0.0 and flat.inner == sharp.inner


def test_given_windows_are_kept_and_a_range_too_short_for_the_interface_is_refused():
    profile = {"Al": 0.05 + 0.3 * ndtr(S / 2.0)}
    given = windows_of(profile, inner=1.0, outer=3.0)
    assert (given.inner, given.outer, given.source) == (1.0, 3.0, "given")
    assert windows_of(profile, inner=2.0).outer == pytest.approx(6.0)
    short = windows_of(profile, outer=3.0)  # a given range is kept, the windows cut, and it is said
    assert (short.inner, short.outer) == (1.0, 3.0) and "beyond the given range" in short.note
    # no species (an iso-density surface): 1 and 3 nm, said so
    none = windows_of(profile, species="")
    assert (none.inner, none.outer, none.source) == (1.0, 3.0, "fallback") and "no species" in none.note


def test_the_widest_fitted_range_is_spelled_alike_where_no_analysis_code_is_imported():
    from apt_filters.analysis.width import MAX_RANGE
    from apt_filters.cli.proxigram import MAX_RANGE as cli_range

    assert MAX_RANGE == cli_range == cfg.MAX_FITTED_RANGE


def planar_ions(rng, sigma, half=14.0, depth=24.0, density=40.0):
    """Fe/Al across the plane z = 0 (Al-rich below: the region above the iso-value, where plane() points
    away from), an error-function step of width ``sigma``."""
    n = rng.poisson(density * (2 * half) ** 2 * 2 * depth)
    p = np.column_stack([rng.uniform(-half, half, (n, 2)), rng.uniform(-depth, depth, n)])
    al = rng.random(n) < 0.05 + 0.3 * ndtr(-p[:, 2] / sigma)
    return IonTable(p.astype(np.float32), np.where(al, 27.0, 56.0).astype(np.float32))


def test_a_wide_interface_widens_the_proxigram_to_its_windows():
    rng = np.random.default_rng(6)
    ions, mesh = planar_ions(rng, 2.0), plane(14.0, 14)
    prox, windows = fitted_proxigram(ions=ions, ranges=RANGES, mesh=mesh, species="Al")
    assert windows.step.width == pytest.approx(2 * 1.2816 * 2.0, abs=3 * windows.step.width_error + 0.05)
    assert windows.inner > 4.5 and prox.edges[-1] == pytest.approx(windows.outer)
    # cut from a wider proxigram: the counts a proxigram over that range holds (but for the float32
    # rounding of a distance on a bin edge)
    direct = compute_proxigram(ions, RANGES, mesh, max_distance=windows.outer)
    assert prox.counts.sum() == direct.counts.sum()
    assert np.abs(prox.counts - direct.counts).sum() <= 1e-5 * direct.counts.sum()
    # from a selection of the ions within the first range: selected again over the range the fit asks for
    asked = []

    def select(reach):
        asked.append(reach)
        return ions, None

    near = ions.subset(np.flatnonzero(np.abs(ions.positions[:, 2]) < 3.05))
    again, same = fitted_proxigram(ions=near, ranges=RANGES, mesh=mesh, species="Al", covered=3.0, select=select)
    assert asked and asked[0] > 3.0 and same.inner == windows.inner
    np.testing.assert_array_equal(again.counts, prox.counts)
    np.testing.assert_allclose(prox.edges, direct.edges, atol=1e-9)


def test_the_run_options_reach_the_configuration_and_bad_pairs_are_refused():
    config = cfg.with_options(cfg.PipelineConfig(), {"plateau_inner": 2.0, "proxigram_range": 7.0}, "command line")
    assert (config.proxigram.inner, config.proxigram.extent) == (2.0, 7.0)
    with pytest.raises(AptFiltersError, match="must be below extent"):
        cfg.check(cfg.with_options(cfg.PipelineConfig(), {"plateau_inner": 3.0, "proxigram_range": 3.0}, "x"))


def test_a_profile_that_ends_within_its_step_gets_one_width_where_two_are_undetermined():
    """A cut object's cap: the inside thins out to no ion 1 nm in, short of the step's plateau (symmetric, sigma
    0.8 nm). Where the two widths of the split normal cannot be told apart (two free widths: 3.8 ± 8.3, 3.5 ± 17,
    2.4 ± 5.6 nm, the inside plateau 0.58 ± 2.3 for 0.41), one width is fitted: every fit's width is determined
    (its error below it), its inside plateau a fraction, and a fit with one width within two errors of the
    truth."""
    true = 2 * 1.2815515655446004 * 0.8
    for seed in range(10):
        rng = np.random.default_rng(seed)
        total = rng.poisson(np.where(S < 0, 300, 300 * np.clip(1 - S / 1.0, 0, 1)))
        fit = fit_profile(s=S, n=rng.binomial(total, 0.06 + 0.35 * ndtr(S / 0.8)), total=total, species="Al")
        assert fit.width_error < fit.width and fit.inside <= 1, (seed, fit.width, fit.width_error, fit.inside)
        if fit.sigma_inside == fit.sigma_outside:
            assert abs(fit.width - true) < 2 * fit.width_error, (seed, fit.width, fit.width_error)


def test_the_pooled_profile_of_thin_objects_finds_its_segregation_peak():
    """Objects so thin that no ion lies 1.3 nm inside, a B shell (sigma 0.6 nm) and 0.15 % B in both phases:
    the step-and-peak fit of the pooled B profile finds the peak and the inside level within 3 errors of the model
    in at least 18 of 20 draws. From the deeper bins' mean alone as the start, 5 of 20 ended in a step to
    0.13-0.65 with no peak, as thin 10131's B did (0.56 ± 0.90)."""
    profile = np.arange(-4.0, 4.0, 0.1) + 0.05
    off = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        total = rng.poisson(np.where(profile < 0, 1500 - 300 * profile,
                                     1500 * np.clip(1 - profile / 1.3, 0, 1) ** 1.5))
        al = rng.binomial(total, 0.15 + 0.17 * ndtr((profile - 0.1) / 0.5))
        b = rng.binomial(total, 0.0015 + 0.043 * np.exp(-0.5 * ((profile + 0.1) / 0.6) ** 2))
        step = fit_profile(s=profile, n=al, total=total, species="Al")
        fit = fit_profile(s=profile, n=b, total=total, species="B", step=step)
        off += fit.peak == 0 or abs(fit.inside - 0.0015) > 3 * fit.inside_error
    assert off <= 2, off


def test_an_object_thinner_than_its_windows_takes_the_fitted_plateaus():
    """A 2.4 nm slab whose step (sigma 0.5 nm) needs windows from ~1.3 nm: no inside window, yet the B shell's
    excess comes out within its error of the model, from its own profile under the fitted shapes (the pooled
    profile here: its levels and their errors are the fit's, the peak's centre and width errors carried)."""
    from apt_filters.analysis.excess import interfacial_excess
    from tests.proxigram_specimens import box_distance, cube

    rng = np.random.default_rng(8)
    half, density, peak, tau = (12.0, 12.0, 1.2), 40.0, 0.05, 0.3
    lo, hi = np.array([-15.0, -15.0, -6.0]), np.array([15.0, 15.0, 6.0])
    n = rng.poisson(density * np.prod(hi - lo))
    p = rng.uniform(lo, hi, (n, 3))
    d = box_distance(p, half)  # positive inside
    u = rng.random(n)
    c_al, c_b = 0.05 + 0.3 * ndtr(d / 0.5), 0.002 + peak * np.exp(-0.5 * (d / tau) ** 2)
    mz = np.where(u < c_b, 11.0, np.where(u < c_b + c_al, 27.0, 56.0))
    ions = IonTable(p.astype(np.float32), mz.astype(np.float32))
    mesh = cube(half, 5)
    prox, windows = fitted_proxigram(ions=ions, ranges=RANGES, mesh=mesh, species="Al", solutes=["B"])
    assert windows.inner > half[2], "the slab is thinner than its windows"
    with pytest.raises(AptFiltersError, match="no ions in a plateau window"):
        interfacial_excess(prox, "B", 1.0, windows.inner, windows.outer)
    [ex] = interfacial_excess(prox, "B", 1.0, windows.inner, windows.outer, fit=windows.fit_of("B"))
    fit = windows.fit_of("B")
    assert ex.precipitate.value == pytest.approx(fit.inside, abs=0.1 * fit.inside_error)
    assert ex.precipitate.error == pytest.approx(fit.inside_error, rel=0.1)
    true = density * peak * tau * np.sqrt(2 * np.pi)  # detected atoms per nm² of interface
    est = ex.integration
    assert abs(est.gamma_detected - true) < 2.5 * est.gamma_detected_error, (est.gamma_detected, true)
    assert est.gamma_detected_error < 0.1 * true and ex.cumulative == est


def test_a_rich_segregation_shell_is_counted_whole_with_the_fitted_windows():
    """A sphere's segregation shell holding ~12,000 ions (B, Gaussian sigma 0.4 nm, none in either plateau):
    the Krakauer-Seidman excess over the fitted windows recovers the exact count of the B ions within half a
    counting sigma (the tail the windows leave out is at most 0.1 sigma each side, ``TAIL_SIGMAS``). Windows
    that leave 0.5 % of the peak beyond each edge lose 1 % of it here (1.1 sigma): the tail, and about as
    much again where the levels extrapolate its slope to the surface."""
    from apt_filters.analysis.excess import interfacial_excess
    from tests.proxigram_specimens import icosphere, sphere_distance

    rng = np.random.default_rng(25)
    radius, reach, density = 8.0, 4.5, 50.0
    lo, hi = radius - reach, radius + reach
    n = rng.poisson(density * 4 / 3 * np.pi * (hi ** 3 - lo ** 3))
    u = rng.normal(size=(n, 3))
    p = u / np.linalg.norm(u, axis=1, keepdims=True) * np.cbrt(rng.uniform(lo ** 3, hi ** 3, n))[:, None]
    d = sphere_distance(p, radius)  # positive inside
    draw_ = rng.random(n)
    boron = draw_ < 0.3 * np.exp(-0.5 * (d / 0.4) ** 2)
    al = ~boron & (draw_ < 0.3 * np.exp(-0.5 * (d / 0.4) ** 2) + 0.10 + 0.25 * ndtr(d / 0.2))
    ions = IonTable(p.astype(np.float32), np.select([boron, al], [11.0, 27.0], 56.0).astype(np.float32))
    prox, windows = fitted_proxigram(ions=ions, ranges=RANGES, mesh=icosphere(radius, 4), species="Al",
                                     solutes=["B"])
    [excess] = interfacial_excess(prox, "B", 1.0, windows.inner, windows.outer)
    exact = int(boron.sum())
    assert abs(excess.cumulative.count - exact) <= 0.5 * np.sqrt(exact), (excess.cumulative.count, exact, windows.inner)


def test_a_plate_thinner_than_its_windows_reports_the_plateau_its_own_ions_hold():
    """A plate 2 nm thick whose step (sigma 0.5 nm) asks for windows from ~1.3 nm: none of its ions lies that
    deep. Its inside composition is counted from half its own depth and comes out within two binomial sigmas
    of what its ions hold there, counted against the exact plate in the window the same rule gives the exact
    plate (its ions' true depths); the plateau the model puts there is within the same error."""
    from apt_filters.analysis.width import inside_windows
    from apt_filters.pipeline.summary import object_plateaus, window_composition
    from tests.proxigram_specimens import box_distance, cube

    rng = np.random.default_rng(12)
    half, density = (10.0, 10.0, 1.0), 40.0
    lo, hi = np.array([-12.0, -12.0, -5.0]), np.array([12.0, 12.0, 5.0])
    n = rng.poisson(density * np.prod(hi - lo))
    p = rng.uniform(lo, hi, (n, 3))
    d = box_distance(p, half)  # positive inside

    def model(x):
        return 0.05 + 0.4 * ndtr(x / 0.5)

    al = rng.random(n) < model(d)
    ions = IonTable(p.astype(np.float32), np.where(al, 27.0, 56.0).astype(np.float32))
    prox, windows = fitted_proxigram(ions=ions, ranges=RANGES, mesh=cube(half, 5), species="Al")
    assert windows.inner > half[2], "the plate is thinner than its windows"
    measured = window_composition(prox, windows.inner, windows.outer)["inside"]["fraction"]["Al"]
    assert measured is not None, "the window holds none of the plate's atoms"
    [plate] = object_plateaus(prox, windows.inner, windows.outer)
    assert plate["nearer"] and 0.3 < plate["from_nm"] < 0.5 * half[2], plate["from_nm"]
    assert plate["fraction"]["Al"] == pytest.approx(measured)
    # the truth: the plate's own ions in the window its exact depths give
    own = (d > 0) & (d <= windows.outer)
    [start] = inside_windows(depth=d[own], atoms=np.ones(own.sum()), inner=windows.inner)
    window = (d >= start) & (d <= windows.outer)
    held, atoms = al[window].mean(), window.sum()
    sigma = np.sqrt(held * (1 - held) / atoms)
    assert atoms > 2000 and abs(measured - held) < 2 * sigma, (measured, held, sigma)
    assert abs(model(d[window]).mean() - held) < 3 * sigma
