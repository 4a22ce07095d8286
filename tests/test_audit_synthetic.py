"""Range audit on synthetic spectra with known species: no false alarms, and every planted fault found.

The spectra (tests/audit_helpers.py) hold Gaussian isotope peaks at natural abundances on a uniform
background; the correct range file ranges every isotope with at least 60 expected ions.
"""

import json

import numpy as np
import pytest

from apt_filters.audit import AuditSettings, audit_ranges, isotope_pattern
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from tests.audit_helpers import SynthSpecies, relabel, synth_mz, synth_ranges


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_correct_range_file_raises_no_flag(seed):
    result = audit_ranges(synth_mz(seed), RangeTable(synth_ranges()))
    assert result.flagged == [], str(result)
    # the labels' own patterns fit: every labelled species is there with about its planted ions
    fitted = {s.name: s.ions for s in result.species}
    assert fitted["Ni+"] == pytest.approx(20_000, rel=0.03)
    assert fitted["Mo+++"] == pytest.approx(10_000, rel=0.03)
    assert not [s for s in result.species if not s.labelled], "species added to a spectrum the labels explain"


FE_CR = (SynthSpecies((("Fe", 1),), 1, 40_000), SynthSpecies((("Cr", 1),), 1, 20_000),
         SynthSpecies((("Fe", 1),), 2, 3_000), SynthSpecies((("Cr", 1), ("O", 1)), 1, 5_000))


@pytest.mark.parametrize("seed", [41, 42])
def test_isotopes_shared_by_two_labelled_species_are_a_note_not_a_flag(seed):
    """54Fe+/54Cr+ share one range labelled Fe: a known overlap of ranged species, not a labelling error."""
    ranges = synth_ranges(FE_CR)
    result = audit_ranges(synth_mz(seed, FE_CR), RangeTable(ranges))
    assert result.flagged == [], str(result)
    (note,) = [f for f in result.findings if f.kind == "shared_peak"]
    assert ranges[note.range].lower < 53.94 < ranges[note.range].upper
    fe, cr = 40_000 * 0.05845, 20_000 * 0.02365  # planted 54Fe+ and 54Cr+ ions
    assert note.figures["foreign_species"] == "Cr+"
    assert note.figures["foreign_fraction"] == pytest.approx(cr / (fe + cr), abs=0.03)


@pytest.mark.parametrize("seed", [11, 12])
@pytest.mark.parametrize("near, wrong, kind", [
    (57.94, (("Fe", 1),), "mislabelled"),        # 58Fe exists (0.28 %): the label fits the m/z, not the pattern
    (51.94, (("Mn", 1),), "label_not_in_range"),  # no Mn isotope at 52 Da in any charge state
    (26.98, (("Cr", 1), ("O", 1)), "label_not_in_range"),
])
def test_one_mislabelled_range_is_the_only_flag(seed, near, wrong, kind):
    ranges, index = relabel(synth_ranges(), near, wrong)
    mz = synth_mz(seed)
    result = audit_ranges(IonTable(np.zeros((len(mz), 3), np.float32), mz), RangeTable(ranges))
    assert result.flagged_ranges() == {index}, str(result)
    (finding,) = result.flagged
    assert finding.kind == kind and finding.severity == "error"
    truth = {57.94: ("Ni+", 1), 51.94: ("Cr+", 1), 26.98: ("Al+", 1)}[near]
    assert (finding.figures["best_fit"], finding.figures["best_fit_charge"]) == truth


SI_NI = (SynthSpecies((("Si", 1),), 1, 20_000), SynthSpecies((("Ni", 1),), 2, 15_000),
         SynthSpecies((("Ni", 1),), 1, 10_000))


@pytest.mark.parametrize("seed", [21, 22])
def test_unranged_species_under_ranged_isotopes_is_named(seed):
    """The real data's case: Ni++ (58Ni++ at 28.97, 60Ni++ at 29.97) hidden under ranges labelled Si."""
    ranges = synth_ranges((SI_NI[0], SI_NI[2]))  # Ni++ left unranged
    result = audit_ranges(synth_mz(seed, SI_NI), RangeTable(ranges))
    si29 = next(i for i, r in enumerate(ranges) if r.lower < 28.97 < r.upper)
    si30 = next(i for i, r in enumerate(ranges) if r.lower < 29.97 < r.upper)
    assert result.flagged_ranges() == {si29, si30}, str(result)
    for index, isotope in [(si29, 1), (si30, 2)]:  # planted share: Ni++ / (Ni++ + Si+) at that isotope
        si = 20_000 * isotope_pattern((("Si", 1),), 1)[1][isotope]
        ni = 15_000 * isotope_pattern((("Ni", 1),), 2)[1][isotope - 1]
        (f,) = [f for f in result.flagged if f.range == index]
        assert f.figures["foreign_species"] == "Ni++"
        assert f.figures["foreign_fraction"] == pytest.approx(ni / (ni + si), abs=0.02)
    # Ni is ranged (as Ni+), so the other Ni++ isotopes (61, 62, 64) are its missing isotopes, once each
    missing = [f for f in result.flagged if f.kind == "missing_isotope"]
    assert sorted(round(f.figures["mz"], 1) for f in missing) == [30.5, 31.0, 32.0]
    assert {f.figures["species"] for f in missing} == {"Ni++"}
    assert not [f for f in result.flagged if f.kind == "uncovered_peak"]


def test_overlap_background_only_and_missing_isotope():
    ranges = synth_ranges()
    ni60 = next(i for i, r in enumerate(ranges) if r.lower < 59.93 < r.upper)
    kept = [r for i, r in enumerate(ranges) if i != ni60]
    kept.append(Range(75.0, 75.3, (("As", 1),)))        # 75As: nothing there
    kept.append(Range(kept[0].upper - 0.01, kept[0].upper + 0.2, (("Al", 1),)))  # overlaps the first
    result = audit_ranges(synth_mz(5), kept)
    kinds = {(f.kind, f.range) for f in result.flagged}
    assert ("background_only", len(kept) - 2) in kinds
    assert ("overlap", 0) in kinds
    missing = [f for f in result.flagged if f.kind == "missing_isotope"]
    assert [(f.figures["species"], round(f.figures["mz"], 1)) for f in missing] == [("Ni+", 59.9)]
    assert missing[0].figures["expected"] == pytest.approx(20_000 * 0.2622, rel=0.05)
    assert not [f for f in result.flagged if f.kind == "uncovered_peak"]  # reported once, as missing isotope


def test_result_prints_and_serialises():
    ranges, index = relabel(synth_ranges(), 57.94, (("Fe", 1),))
    result = audit_ranges(synth_mz(11), RangeTable(ranges, source="synthetic.rrng"))
    text = str(result)
    assert "synthetic.rrng" in text and "ERROR" in text and "Ni+" in text
    data = json.loads(result.to_json())
    assert data["findings"][0]["range"] == index and data["findings"][0]["figures"]["best_fit"] == "Ni+"
    assert len(data["ranges"]) == len(ranges)


def test_settings_change_the_thresholds():
    """A higher required foreign share silences the mixed-range warning: the threshold is live."""
    ranges = synth_ranges((SI_NI[0], SI_NI[2]))  # Ni++ left unranged
    strict = audit_ranges(synth_mz(21, SI_NI), ranges, AuditSettings(min_foreign_fraction=0.999))
    assert not [f for f in strict.flagged if f.range is not None]


def test_counts_no_candidate_explains_are_reported_as_unexplained():
    """With a candidate table and labels that lack Ni, the Ni++ under the Si ranges stays unexplained."""
    ranges = synth_ranges(SI_NI[:1])
    result = audit_ranges(synth_mz(23, SI_NI), ranges, AuditSettings(candidates=((("Al", 1),),)))
    si29 = next(i for i, r in enumerate(ranges) if r.lower < 28.97 < r.upper)
    si30 = next(i for i, r in enumerate(ranges) if r.lower < 29.97 < r.upper)
    unexplained = {f.range: f.figures["unexplained_ions"] for f in result.flagged if f.kind == "unexplained_counts"}
    assert set(unexplained) == {si29, si30}, str(result)
    ni = isotope_pattern((("Ni", 1),), 2)[1]
    assert unexplained[si29] == pytest.approx(15_000 * ni[0], rel=0.1)
    assert unexplained[si30] == pytest.approx(15_000 * ni[1], rel=0.1)
