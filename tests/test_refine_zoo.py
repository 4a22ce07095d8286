"""The specimen zoo (synth.zoo): exact shapes, reproducible draws, splits held out by seed and family."""

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.synth.zoo import FAMILIES, SPLITS, Ellipsoid, RoundedCuboid, draws, zoo_specimen


def _brute_distance(shape, points, spacing=0.05):
    """Unsigned distance of points to a dense sampling of the shape's surface (upper bound, ~spacing/2 tight)."""
    from scipy.spatial import cKDTree

    return cKDTree(shape.mesh(spacing).vertices).query(points)[0]


def test_ellipsoid_distance_is_exact():
    shape = Ellipsoid((1.0, -2.0, 0.5), (1.2, 1.8, 2.6), rotation=5)
    rng = np.random.default_rng(0)
    points = shape.center + rng.uniform(-4, 4, (3000, 3))
    d = shape.sdf(points)
    # a mesh's vertices lie on the surface (within the grid's error): the exact distance is never larger than
    # the distance to them and at most half a grid diagonal smaller
    brute = _brute_distance(shape, points)
    assert np.all(np.abs(d) <= brute + 2e-3)
    assert np.all(np.abs(d) >= brute - 0.08)  # the mesh is a 0.1 nm grid's marching cubes
    inside = np.sum((((points - shape.center) @ shape.rotation) / shape.axes) ** 2, axis=1) < 1
    assert np.array_equal(d < 0, inside)
    assert shape.volume() == pytest.approx(4 / 3 * np.pi * 1.2 * 1.8 * 2.6)
    assert shape.mesh(0.1).signed_volume() == pytest.approx(shape.volume(), rel=5e-3)  # marching cubes at 0.1 nm


def test_rounded_cuboid_measures_are_exact():
    shape = RoundedCuboid((0, 0, 0), (4.0, 5.0, 3.5), 1.2, rotation=3)
    mesh = shape.mesh(0.05)
    assert mesh.signed_volume() == pytest.approx(shape.volume(), rel=2e-3)
    assert mesh.area() == pytest.approx(shape.area(), rel=5e-3)
    rng = np.random.default_rng(1)
    points = rng.uniform(-4, 4, (2000, 3))
    assert np.allclose(np.abs(shape.sdf(points)), _brute_distance(shape, points), atol=0.03)
    with pytest.raises(AptFiltersError):
        RoundedCuboid((0, 0, 0), 4.0, 2.0)


def test_draws_are_reproducible_and_the_splits_apart():
    a, b = zoo_specimen("rod", 3), zoo_specimen("rod", 3)
    assert [f.shape.params() for f in a.features] == [f.shape.params() for f in b.features]
    assert a.matrix == b.matrix and a.efficiency == b.efficiency
    dev, held = draws("dev", 40), draws("heldout", 40)
    assert not {s for _, s in dev} & {s for _, s in held}, "no seed in both"
    assert set(SPLITS["heldout"].families) - set(SPLITS["dev"].families), "families the development never saw"
    assert set(SPLITS["heldout"].families) <= set(FAMILIES)
    with pytest.raises(AptFiltersError):
        draws("test", 1)
    with pytest.raises(AptFiltersError):
        zoo_specimen("torus", 0)


@pytest.mark.parametrize("family", ["plate", "lath", "open"])
def test_every_family_fits_its_box(family):
    spec = zoo_specimen(family, 11)
    assert 1 <= len(spec.features) <= 4
    assert 0.37 <= spec.efficiency <= 0.8
    assert spec.expected_ions() < 1.7e6, "small enough for a loaded 2-core machine"
