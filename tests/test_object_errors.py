"""Objects' counting errors and speck-test figures in the object table (issue 25), against exact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from apt_filters.analysis.objects import area_growth, counting_errors, object_table
from apt_filters.synth import Cuboid, Sphere
from tests.meshlab_shapes import merge


def test_area_growth_is_twice_the_integrated_mean_curvature():
    assert area_growth(Sphere((0, 0, 0), 3.0).mesh(0.1)) == pytest.approx(8 * math.pi * 3.0, rel=2e-3)
    # a cube grows on its edges only: its parallel body's area is 6 a² + 6 pi a d + 4 pi d² (12 edges turning pi/2)
    assert area_growth(Cuboid((0, 0, 0), (4.0, 4.0, 4.0)).mesh(0.1)) == pytest.approx(6 * math.pi * 4.0, rel=1e-6)


def test_counting_errors_map_each_object_to_its_reference_component():
    """Two spheres; the reference is the same surface moved 0.2 nm out (as a remesh or clean step would leave
    it) and listed in the other order; each object takes its own offset error."""
    a, b = Sphere((0, 0, 0), 3.0).mesh(0.25), Sphere((12, 0, 0), 2.0).mesh(0.25)
    mesh = merge(a, b)
    ref = merge(Sphere((12, 0, 0), 2.2).mesh(0.3), Sphere((0, 0, 0), 3.2).mesh(0.3))
    table = object_table(mesh)
    counting_errors(table, mesh, reference=ref, offset_se=np.array([0.05, 0.02]),
                    p_value=np.array([1e-9, 2e-4]), z=np.array([12.0, 4.1]))
    big, small = sorted(table.objects, key=lambda o: -o.volume)
    assert big.volume_se == pytest.approx(0.02 * big.area, rel=1e-12)
    assert small.volume_se == pytest.approx(0.05 * small.area, rel=1e-12)
    assert big.area_se == pytest.approx(0.02 * 8 * math.pi * 3.0, rel=0.02)
    assert small.area_se == pytest.approx(0.05 * 8 * math.pi * 2.0, rel=0.02)
    assert {(o.p_value, o.z) for o in table.objects} == {(1e-9, 12.0), (2e-4, 4.1)}
    row = table.rows()[0]
    assert {"volume_se", "area_se", "p_value", "z"} <= set(row)


def test_objects_without_a_reference_keep_nan_errors():
    mesh = Sphere((0, 0, 0), 3.0).mesh(0.25)
    table = object_table(mesh)
    assert math.isnan(table.objects[0].volume_se) and math.isnan(table.objects[0].p_value)


def test_the_halves_spread_raises_a_faceted_objects_errors_where_it_is_larger():
    """``shape_se`` (the two cross-fit halves' spread of a faceted object's volume and area) replaces the
    offset's error where it is larger, and leaves it where it is smaller or unknown (NaN)."""
    a, b = Sphere((0, 0, 0), 3.0).mesh(0.25), Cuboid((12, 0, 0), (4.0, 4.0, 4.0)).mesh(0.2)
    mesh = merge(a, b)
    table = object_table(mesh)
    counting_errors(table, mesh, reference=mesh, offset_se=np.array([0.02, 0.02]),
                    shape_se=np.array([[np.nan, np.nan], [0.5, 9.0]]))
    sphere, cube = sorted(table.objects, key=lambda o: o.centroid[0])
    assert sphere.volume_se == pytest.approx(0.02 * sphere.area, rel=1e-12)
    assert sphere.area_se == pytest.approx(0.02 * 8 * math.pi * 3.0, rel=0.02)
    assert cube.volume_se == pytest.approx(0.02 * cube.area, rel=1e-12)  # 1.92 nm³ > 0.5
    assert cube.area_se == 9.0  # > 0.02 * 6 pi 4 = 1.5 nm²
