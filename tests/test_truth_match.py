"""Pairing measured parts with true objects (:func:`apt_filters.truth.match_objects`), on exact shapes."""

import numpy as np
import pytest

from apt_filters.synth.shapes import Cylinder, Sphere
from apt_filters.truth import match_objects

DISC = Cylinder([0.0, 0.0, 0.0], 5.0, 1.6)  # a thin disc, 1.6 nm thick (dev zoo thin 30004's kind)


def test_a_disc_measured_thick_is_paired_with_its_truth_not_a_speck_on_its_face():
    """The measured disc's faces stand 0.5 nm out (mean |sdf| of its vertices 0.42 nm); a speck of radius 0.5 nm
    sits on the true top face, its vertices on average nearer the true surface (0.31 nm). Nearness pairs the disc's
    truth with the speck; the disc holds nearly all the truth's volume, the speck under 1 %."""
    sdf = DISC.sdf
    measured = Cylinder([0.0, 0.0, 0.0], 5.0, 2.6).mesh(0.2)
    speck = Sphere([1.0, -2.0, 0.8], 0.5).mesh(0.1)
    near = [np.abs(sdf(p.vertices)).mean() for p in (measured, speck)]
    assert near[1] < near[0] < 1.5, near  # the case: the speck is the nearer, both within reach
    assert match_objects([speck, measured], [sdf]) == [1]
    assert match_objects([measured, speck], [sdf]) == [0]


def test_parts_out_of_reach_match_nothing_and_each_object_gets_its_own():
    """A sphere 3 nm beside the disc is out of reach of the disc and the disc out of reach of it; each true object
    is paired with the part on it, and a true object with no part near it with nothing."""
    far = Sphere([0.0, 0.0, 4.0], 1.0)
    lost = Sphere([20.0, 0.0, 0.0], 1.0)
    parts = [Sphere([0.0, 0.0, 4.1], 1.1).mesh(0.1), DISC.mesh(0.2)]
    assert match_objects(parts, [DISC.sdf, far.sdf, lost.sdf]) == [1, 0, None]


def test_a_part_with_nothing_inside_the_compared_region_gives_undefined_distances_not_an_error():
    """A cut object's surface found only in the margin left out of the comparison (fresh edge draw 10101's AP-style
    sliver): the part's side of the distances is NaN, the truth's side is how far the part stands off."""
    from apt_filters.truth import surface_error_within

    ball = Sphere([0.0, 0.0, 0.0], 2.0)
    inside = ball.mesh(0.2)
    part = Sphere([5.0, 0.0, 0.0], 0.5).mesh(0.1)  # wholly at x > 4, outside the region x < 3

    def region(p):
        return p[:, 0] - 3.0

    err = surface_error_within(part, ball.sdf, inside, region, inside.area())
    assert np.isnan(err.mesh_to_true_mean) and np.isnan(err.mean_distance)
    assert 4.0 < err.hausdorff < 7.5 and err.true_to_mesh_mean > 2.5  # the truth's points 2.5-7 nm from the part
    assert err.area == 0.0


def test_run_truth_rows_pair_a_rod_cut_by_the_specimen_edge_with_its_measured_half():
    """``apt-filters run --truth`` pairs objects as the benchmarks do (shared volume), not by centroid: a rod
    (radius 1, 10 nm long) cut in half by the specimen edge is measured as its half, whose centroid lies 2.5 nm from
    the rod's centre, beyond the rod's depth (1 nm) that a centroid pairing allowed; a speck stands beside it."""
    from types import SimpleNamespace

    from apt_filters.analysis.objects import object_table
    from apt_filters.core.mesh import merge
    from apt_filters.synth.shapes import Capsule
    from apt_filters.truth.specimen import compare_with_truth

    rod = Cylinder([0.0, 0.0, 0.0], 1.0, 10.0)
    half = Cylinder([0.0, 0.0, 2.5], 1.0, 5.0).mesh(0.1)
    speck = Sphere([0.0, 1.6, -1.0], 0.4).mesh(0.1)
    mesh = merge([speck, half])
    objects = object_table(mesh).rows()
    truth = {"features": [
        {"name": "rod", "bounded": True, "shape": rod.params(), "volume_nm3": rod.volume(), "area_nm2": 1.0,
         "depth_nm": rod.depth()},
        {"name": "lost", "bounded": True, "shape": Capsule([9.0, 0.0, 0.0], 1.0, 4.0).params(),
         "volume_nm3": 1.0, "area_nm2": 1.0, "depth_nm": 1.0}]}
    result = SimpleNamespace(label="Cu", mesh=mesh, objects=objects, excess=[])
    rows = {r["feature"]: r for r in compare_with_truth([result], truth)}
    halved = max(objects, key=lambda o: o["volume"])
    assert rows["rod"]["object_id"] == halved["object_id"]
    assert rows["rod"]["volume_ratio"] == pytest.approx(0.5, abs=0.01)
    assert rows["lost"]["object_id"] is None and "volume_ratio" not in rows["lost"]
