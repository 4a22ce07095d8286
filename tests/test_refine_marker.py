"""A segregant's peak as a second reading of each object's offset (``apt_filters.refine.marker``), against objects
whose true offsets are drawn and known."""

import numpy as np
import pytest

from apt_filters.refine.marker import combined_offset_errors, marker_offsets
from apt_filters.refine.peak import fit_peak

WIDTH, BACKGROUND, PEAK = 0.35, 0.005, 0.08


def _objects(offsets, layer, ions=20_000, seed=0):
    """Ions of objects whose interface lies ``offsets`` (nm) outside their surface, a segregant layer ``layer`` nm
    farther out: uniform in the signed distance d over +-2 nm, one atom each, the segregant with probability
    ``BACKGROUND + PEAK exp(-(d - offset - layer)^2 / 2 WIDTH^2)``."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(-2.0, 2.0, (len(offsets), ions))
    p = BACKGROUND + PEAK * np.exp(-0.5 * ((d - np.asarray(offsets)[:, None] - layer) / WIDTH) ** 2)
    marker = (rng.random(d.shape) < p).astype(np.float64)
    component = np.repeat(np.arange(len(offsets)), ions)
    return d.ravel(), marker.ravel(), np.ones(d.size), component


def test_the_peak_fit_finds_a_layer_and_its_centre():
    d, marker, total, _ = _objects([0.07], 0.0, ions=200_000)
    peak = fit_peak(d, marker, total)
    assert peak.significant(5.0, 1.5)
    assert abs(peak.centre - 0.07) < 3 * peak.se[2] and peak.se[2] < 0.01
    assert abs(peak.width - WIDTH) < 3 * peak.se[3]


def test_marker_offsets_recover_the_objects_offsets_beyond_the_step():
    """Forty objects, each's true offset drawn with the step's error (0.03 nm), the layer 0.05 nm out: the moves
    land nearer the truth than the step (which reads 0), as near as the reported errors say, and the layer's offset
    comes out within its standard error."""
    sigma, layer = 0.03, 0.05
    truth = np.random.default_rng(1).normal(0.0, sigma, 40)
    d, marker, total, component = _objects(truth, layer)
    marks = marker_offsets(d, marker, total, component, np.full(len(truth), sigma), "B")
    assert marks.marked == len(truth) and marks.name == "B"
    assert abs(marks.layer_offset - layer) < 3 * marks.layer_offset_se
    residual = marks.shift - truth
    rms = np.sqrt(np.mean(residual ** 2))
    assert rms < 0.75 * np.sqrt(np.mean(truth ** 2))  # measured 0.56
    assert 0.7 < rms / np.sqrt(np.mean(marks.errors ** 2)) < 1.3  # the errors are honest
    assert np.all(marks.errors < sigma)


def test_one_object_or_no_peak_does_not_move():
    d, marker, total, component = _objects([0.05], 0.0)
    alone = marker_offsets(d, marker, total, component, np.array([0.03]))
    assert alone.marked == 0 and np.isfinite(alone.centre[0]) and np.isnan(alone.layer_offset)
    assert alone.errors[0] == 0.03
    rng = np.random.default_rng(2)
    d = rng.uniform(-2, 2, 40_000)
    flat = marker_offsets(d, (rng.random(d.size) < 0.01).astype(float), np.ones(d.size), np.repeat([0, 1], 20_000),
                          np.array([0.03, 0.03]))
    assert flat.marked == 0 and np.isnan(flat.centre).all()
    # an object the step did not place (NaN error) is left alone
    d, marker, total, component = _objects([0.0, 0.0, 0.0], 0.0)
    marks = marker_offsets(d, marker, total, component, np.array([0.03, np.nan, 0.03]))
    assert np.isnan(marks.centre[1]) and marks.shift[1] == 0 and marks.marked == 2


@pytest.mark.parametrize("k", [2, 4, 100])
def test_combined_errors_between_the_peak_alone_and_the_step(k):
    step, peak = np.full(k, 0.036), np.full(k, 0.03)
    combined = combined_offset_errors(step, peak)
    known = np.sqrt(1 / (1 / 0.036 ** 2 + 1 / 0.03 ** 2))  # the layer's offset known
    assert np.all(combined > known) and np.all(combined < 0.036)
    # more objects fix the layer's offset better
    assert combined[0] == pytest.approx(known, rel=0.02) if k == 100 else combined[0] > 1.02 * known
    # a useless peak leaves the step's error
    assert combined_offset_errors(step, np.full(k, 1e3))[0] == pytest.approx(0.036, rel=1e-3)
