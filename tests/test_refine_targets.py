"""Issue 9's targets on its own specimen: gamma-prime seeds 1-3 (12 precipitates), AP Suite-style against ours.

The specimen is the issue's (tip, efficiency 0.5, blur 0.3/0.1 nm, cubes of 7 and 6 nm, spheres of 3 nm,
Al 0.20 / 0.10, a B shell); benchmarks/bench_refine.py measures the same on more seeds. Every figure is
against the truth the synth package writes.

The issue's per-object targets (volume and area within 5 %, mean distance <= 0.15 nm, Hausdorff <= 0.8 nm,
excess within 5 %, plateaus within 1 at.%) meet the counting statistics of this specimen: the Cramér-Rao
floor of a 3 nm sphere's volume is 2.4 % (one standard deviation, from its Al / Cr step and its B shell, the
shell's offset from the midpoint fitted over the four precipitates: no method can do better, and 4 % of
unbiased estimates fall outside +-5 %), of the cubes' 1.5-2.0 % (:func:`~apt_filters.truth.counting_floor`).
So each volume is held to 5 % or three standard deviations of its floor, whichever is larger, 11 of the 12 to
the issue's 5 %, and the method's bias and efficiency are tested over the 12 objects. Area, mean distance
and Hausdorff are held to the issue's own figures on every object; excess and the inside plateau to what
these seeds reach with a margin, the issue's figures beside them. Those two targets sit below this specimen's
counting: its objects' own ions, counted in their true frames against the true plateaus
(:func:`~apt_filters.truth.counted_truth`), miss the model's excess by up to 13 % and its inside plateau by up
to 2.1 at.% (seeds 1-8; 12 and 7 of 32 objects outside the targets), so they are also held against that count.
"""

import numpy as np
import pytest

from apt_filters.refine import refine_surface
from apt_filters.synth import generate, preset
from apt_filters.truth.precipitates import (counted_errors, evaluate_precipitates, per_object_start,
                                            reference_surface, volume_floors)
from apt_filters.voxel import ConcentrationBasis, voxelize

SPECIES, SOLUTE, ISO = "Al", "B", 0.15
NO_B = ConcentrationBasis(exclude=(SOLUTE,))


@pytest.fixture(scope="module")
def rows():
    """Per precipitate of seeds 1-3: (AP Suite-style row, refined row), rows of ``evaluate_precipitates``; the
    specks removed, the blur estimate and the B marker of each seed."""
    out, specks, blurs, marks = [], [], [], []
    for seed in (1, 2, 3):
        sp = generate(preset("gamma-prime"), seed=seed)
        fields = voxelize(sp.ions, sp.ranges)
        floor = volume_floors(sp, species=SPECIES, marker=SOLUTE)
        count = counted_errors(sp, species=SPECIES, solute=SOLUTE)
        ap = reference_surface(fields=fields, species=SPECIES, iso=ISO, basis=ConcentrationBasis())
        start, removed = per_object_start(specimen=sp, fields=fields, species=SPECIES, basis=NO_B, iso=ISO,
                                          mesh=reference_surface(fields=fields, species=SPECIES, iso=ISO, basis=NO_B))
        specks.append(removed.count)
        result = refine_surface(start, sp.ions, sp.ranges, SPECIES, NO_B)
        blurs.append(result.blur_estimate)
        marks.append(result.marker)
        out += list(zip(*(evaluate_precipitates(sp, mesh, species=SPECIES, solute=SOLUTE, seed=seed, floor=floor,
                                                count=count) for mesh in (ap, result.mesh))))
    return out, specks, blurs, marks


def test_the_ap_suite_style_surfaces_miss_the_truth(rows):
    """The anchor: 1 nm voxels, 3 x 3 x 1.5 nm delocalization, marching cubes at Al 15 at.%."""
    pairs = rows[0]
    ap = [a for a, _ in pairs]
    assert all(r["found"] for r in ap)
    assert all(r["volume"] < -0.15 for r in ap)  # measured -20 to -50 %
    assert np.mean([r["area"] for r in ap]) < -0.15  # -22 % mean
    assert np.mean([r["mean"] for r in ap]) > 0.3  # 0.41 nm
    assert np.mean([r["excess"] for r in ap]) > 0.15  # the small area inflates the excess per area: +19 %


def test_refined_volumes_are_unbiased_and_at_the_counting_floor(rows):
    pairs = rows[0]
    refined = [r for _, r in pairs]
    assert all(r["found"] for r in refined)
    volume = np.array([r["volume"] for r in refined])
    z = np.array([r["z"] for r in refined])
    floor = np.array([r["floor"] for r in refined])
    # each object within the 5 % or three standard deviations of its floor (3 nm spheres: 7.3 %), and 11
    # of the 12 within 5 % (measured: 11, worst +5.4 %, a 3 nm sphere of seed 1 at 2.2 floors; seeds 1-8: 31 of 32)
    assert np.all(np.abs(volume) <= np.maximum(0.05, 3 * floor)), volume
    assert np.sum(np.abs(volume) <= 0.05) >= 11, volume
    # no bias beyond the mean's own noise (~0.7 % for 12 objects), errors at the floor (measured: mean -0.2 %,
    # rms z 1.13; placed by the Al / Cr step alone, without the B marker, 1.43; the AP Suite-style 15)
    assert abs(volume.mean()) < 0.02
    assert np.sqrt(np.mean(z ** 2)) < 1.3


def test_refined_areas_distances_and_excess_against_the_truth(rows):
    pairs, specks, _, _ = rows
    refined = [r for _, r in pairs]
    area = np.abs([r["area"] for r in refined])
    mean = np.array([r["mean"] for r in refined])
    hausdorff = np.array([r["hausdorff"] for r in refined])
    # issue: area within 5 % each (measured: worst 4.3 %, seed 1's sphere that the B marker moved out with its
    # volume, mean 1.3 %; by the step alone worst 3.3 %, mean 1.7 %, and 3.0-3.1 % with the start's vertices
    # moved by 1e-12 nm)
    assert area.max() <= 0.05 and area.mean() < 0.03
    # issue: mean distance <= 0.15 nm each (measured 0.065-0.111 nm, mean 0.083), Hausdorff <= 0.8 nm (measured
    # 0.26-0.63 nm, mean 0.38)
    assert mean.max() <= 0.15 and mean.mean() < 0.11
    assert hausdorff.max() <= 0.8 and hausdorff.mean() < 0.5
    # B excess per the refined area (issue: 5 %): the TRUE surfaces give up to 15 % on a 3 nm sphere (its
    # ~240 excess ions); measured up to 14 %, mean 6 %, against the AP Suite-style +19 % mean
    excess = np.array([r["excess"] for r in refined])
    assert abs(excess.mean()) < 0.04 and np.abs(excess).max() < 0.2
    # outside plateaus within 1 at.% each; inside ones are counting-limited (~1000 atoms in a sphere's core)
    assert max(abs(r["plateau_out"]) for r in refined) < 1.0
    assert np.mean([abs(r["plateau_in"]) for r in refined]) < 1.0
    assert sum(r["sign_errors"] for r in refined) == 0 and sum(r["folds"] for r in refined) == 0
    assert all(0 <= n <= 6 for n in specks)  # removed by the speck test (docs/refine.md), reported


def test_refined_excess_and_plateaus_against_what_the_ions_hold(rows):
    """Against the objects' own ions counted in their true frames (``counted``), the errors left are the method's."""
    pairs = rows[0]
    refined = [r for _, r in pairs]
    # the 1 at.% on every object (measured: worst 0.81, mean abs 0.24 at.%; seeds 1-8 the same worst)
    assert max(abs(r["plateau_in_beyond"]) for r in refined) <= 1.0
    # B excess per area: the plateaus the estimator must take from the same few ions and the areas' errors
    # (measured: worst 6.9 %, mean abs 2.4 %; the true surfaces 2.9 / 1.8 %; the AP Suite-style +21 % mean)
    excess = np.array([r["excess_beyond"] for r in refined])
    assert np.abs(excess).max() < 0.1 and np.abs(excess).mean() < 0.04
    assert np.mean([a["excess_beyond"] for a, _ in pairs]) > 0.15


def test_the_blur_is_read_off_the_segregant_shell(rows):
    """B, left out of the basis, peaks in its 0.25 nm shell: the lateral blur comes from that peak's width."""
    blurs = rows[2]
    assert all(b.source == "peak of B" for b in blurs)
    # truth: sigma_lat^2 - sigma_depth^2 = 0.3^2 - 0.1^2 = 0.08 nm²; the peak's slope scattered 0.015 nm² (sd)
    # over seeds 1-8, the step's 0.065 (-0.075 on seed 5, which then had no correction)
    assert all(abs(b.slope - 0.08) < 0.04 for b in blurs), [b.slope for b in blurs]


def test_the_b_shell_marks_every_precipitate(rows):
    """B peaks at every interface: each precipitate is placed by its B peak too, and the shell's fitted offset from
    the Al / Cr midpoint is the truth's (centred: 0, up to the blur's second-order effects, ~-0.02 nm measured
    against the true surfaces) within its standard error."""
    for mark in rows[3]:
        assert mark.name == "B" and mark.marked == 4
        assert abs(mark.layer_offset) < 3 * mark.layer_offset_se + 0.02, (mark.layer_offset, mark.layer_offset_se)
        assert np.all(np.abs(mark.shift) < 0.1)  # measured up to 0.03 nm
