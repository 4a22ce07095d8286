"""Synthetic mass spectra: peaks from natural abundances, sampling, ranges."""

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.synth.spectrum import MzSampler, SpectrumModel, noise_window, peaks, range_table


def test_peaks_follow_natural_abundances_and_charge_states():
    model = SpectrumModel(charge_states={"Al": {1: 0.25, 2: 0.75}})
    pk = peaks(["Ni", "Al"], model)
    al = {p.charge: p for p in pk if p.species == "Al"}
    assert al[1].mz == pytest.approx(26.9815, abs=1e-3) and al[2].mz == pytest.approx(13.4908, abs=1e-3)
    assert (al[1].probability, al[2].probability) == pytest.approx((0.25, 0.75))
    ni58 = [p for p in pk if p.species == "Ni" and p.isotope == 58]
    assert sum(p.probability for p in ni58) == pytest.approx(0.680769, abs=1e-5)
    assert sum(p.probability for p in pk if p.species == "Ni") == pytest.approx(1.0)
    assert al[1].sigma == pytest.approx(al[1].mz / (2.3548 * 1000))


def test_sampled_mz_land_in_their_peaks_with_the_right_frequencies():
    species = ["Ni", "Al", "B"]
    pk = peaks(species, SpectrumModel())
    sampler = MzSampler(species, pk, noise_window(pk, SpectrumModel()))
    which = np.repeat([0, 1, 2, -1], 100_000)
    mz = sampler.sample(which, np.random.default_rng(1))
    for p in pk:
        own = mz[which == species.index(p.species)]
        frac = (np.abs(own - p.mz) < 5 * p.sigma).mean()
        assert abs(frac - p.probability) < 4 * np.sqrt(p.probability * (1 - p.probability) / len(own)) + 1e-9
    noise = mz[which < 0]
    lo, hi = noise_window(pk, SpectrumModel())
    assert lo <= noise.min() and noise.max() <= hi
    assert abs(noise.mean() - (lo + hi) / 2) < 4 * (hi - lo) / np.sqrt(12 * len(noise))


def test_ranges_cover_peaks_and_merge_only_within_a_species():
    model = SpectrumModel(mass_resolution=150)
    pk = peaks(["Ni", "B"], model)
    table = range_table(pk, model)
    idx = table.range_index(np.array([p.mz for p in pk]))
    assert (idx >= 0).all() and [table.ranges[i].ion for i in idx] == [p.species for p in pk]
    assert len(table) < len(pk)  # at 150, the Ni2+ windows at 30 and 30.5 Da merge
    with pytest.raises(AptFiltersError, match="peaks overlap"):
        range_table(peaks(["Cr", "Al"], SpectrumModel(charge_states={"Al": {1: 1.0}})), SpectrumModel())
