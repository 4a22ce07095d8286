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


@pytest.mark.parametrize("family", ["plate", "lath", "open", "thin", "edge", "artefact", "curved"])
def test_every_family_fits_its_box(family):
    spec = zoo_specimen(family, 11)
    assert 1 <= len(spec.features) <= 4
    for f in spec.features:  # an object cut by the edge holds less than its whole shape
        assert not f.shape.cut or 0 < f.shape.volume() < 4 / 3 * np.pi * f.shape.radius ** 3
    assert 0.37 <= spec.efficiency <= 0.8
    assert spec.expected_ions() < 1.7e6, "small enough for a loaded 2-core machine"


def test_superellipsoid_measures_against_independent_ones():
    from scipy.spatial import ConvexHull

    from apt_filters.synth.implicit import Superellipsoid

    shape = Superellipsoid((0.5, -1.0, 2.0), (2.0, 2.6, 3.4), (1.7, 3.1, 4.2), rotation=9)
    rng = np.random.default_rng(2)
    # volume: Monte Carlo on the defining inequality, not on the sampled surface
    local = rng.uniform(-1, 1, (400_000, 3)) * shape.axes
    inside = np.sum(np.abs(local / shape.axes) ** shape.exponents, axis=1) <= 1
    assert shape.volume() == pytest.approx(8 * np.prod(shape.axes) * inside.mean(), rel=0.01)
    # area: Cauchy's formula for convex bodies (4 x the mean projected area over directions)
    v = shape.mesh().vertices
    k = np.arange(400) + 0.5
    phi, z = np.pi * (1 + 5 ** 0.5) * k, 1 - 2 * k / 400
    dirs = np.column_stack([np.sqrt(1 - z ** 2) * np.cos(phi), np.sqrt(1 - z ** 2) * np.sin(phi), z])
    projected = []
    for u in dirs:
        a = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
        a /= np.linalg.norm(a)
        projected.append(ConvexHull(np.column_stack([v @ a, v @ np.cross(u, a)])).volume)
    assert shape.area() == pytest.approx(4 * np.mean(projected), rel=0.01)
    # distance: exact against a dense sampling of the surface (an upper bound within its spacing)
    fine = Superellipsoid(shape.center, shape.axes, shape.exponents, rotation=9)
    fine.GRID = 0.04
    points = shape.center + rng.uniform(-5, 5, (3000, 3))
    d = shape.sdf(points)
    brute = _brute_distance(fine, points)
    assert np.all(np.abs(d) <= brute + 2e-3) and np.all(np.abs(d) >= brute - 0.03)
    local = (points - shape.center) @ shape.rotation
    assert np.array_equal(d < 0, np.sum(np.abs(local / shape.axes) ** shape.exponents, axis=1) < 1)
    # exponents 2 and equal axes: a sphere, whose distance and level-set areas are known
    ball = Superellipsoid((0, 0, 0), (3.0, 3.0, 3.0), (2, 2, 2))
    assert np.allclose(ball.sdf(points - shape.center), np.linalg.norm(points - shape.center, axis=1) - 3, atol=1e-3)
    assert np.allclose(ball.level_area(np.array([-1.0, 0.0, 1.5])), 4 * np.pi * np.array([2.0, 3.0, 4.5]) ** 2,
                       rtol=2e-3)


def test_spinodal_area_per_volume_against_stereology():
    from apt_filters.synth import Box
    from apt_filters.synth.implicit import LevelSetInterface

    box = Box((10.0, 10.0, 10.0))
    shape = LevelSetInterface(box, "waves", 6.0, 0.2, seed=4)
    truth = shape.area() / box.volume()
    # Crofton: an isotropic uniform random segment of length dl crosses the surface with probability S_V dl / 2
    # (signs of the field itself: independent of the sampled surface)
    rng = np.random.default_rng(3)
    lo, hi = box.bounds()
    mid = lo + (hi - lo) * rng.random((600_000, 3))
    u = rng.normal(size=mid.shape)
    u *= 0.1 / np.linalg.norm(u, axis=1, keepdims=True)
    crossings = np.count_nonzero((shape._f(mid - u) < 0) != (shape._f(mid + u) < 0))
    assert truth == pytest.approx(2 * crossings / (len(mid) * 0.2), rel=0.03)
    # the distance: exact against a dense sampling of the zero set, its sign that of the field
    points = np.array([0.0, 0.0, -5.0]) + rng.uniform(-1, 1, (2000, 3))
    d = shape.sdf(points)
    from scipy.spatial import cKDTree

    fine = LevelSetInterface(Box((6.0, 6.0, 8.0)), "waves", 6.0, 0.2, seed=4)  # the same field, sampled finely
    fine.GRID = 0.08  # around the points (the box centred on them, with its 2.5 nm pad)
    brute = cKDTree(fine.zero_set().mesh.vertices).query(points)[0]
    assert np.all(np.abs(d) <= brute + 5e-3) and np.all(np.abs(d) >= brute - 0.05)  # surfaces curved up to 6 nm^-1
    assert np.array_equal(d < 0, shape._f(points) < 0)


def test_gyroid_area_per_volume_is_the_known_one():
    from apt_filters.synth import Box
    from apt_filters.synth.implicit import LevelSetInterface

    # the gyroid (level 0) has 3.0915 nm² of surface per cell of edge 1 nm (Schoen; Grosse-Brauckmann)
    box = Box((16.0, 16.0, 16.0))
    shape = LevelSetInterface(box, "gyroid", 8.0, 0.0, seed=1)
    assert shape.area() / box.volume() == pytest.approx(3.0915 / 8.0, rel=0.02)
    assert shape.volume() == pytest.approx(0.5 * box.volume(), rel=0.02)


def test_curved_interface_measures():
    from apt_filters.synth import Box
    from apt_filters.synth.implicit import SphereInterface

    box = Box((20.0, 16.0, 30.0))
    for convex, centre in ((True, (4.0, -3.0, -60.0)), (False, (-5.0, 2.0, 25.0))):
        shape = SphereInterface(box, centre, 45.0, convex=convex)
        mesh = shape.mesh(0.1)
        assert np.abs(shape.sdf(mesh.vertices)).max() < 1e-9
        assert shape.area() == pytest.approx(mesh.area(), rel=1e-4)
        assert (mesh.face_normals() * (mesh.vertices[mesh.faces].mean(axis=1) - shape.center)).sum(axis=1).mean() * \
            (1 if convex else -1) > 0, "normals point out of the inside"
        rng = np.random.default_rng(5)
        lo, hi = box.bounds()
        p = lo + (hi - lo) * rng.random((400_000, 3))
        assert shape.volume() == pytest.approx(box.volume() * np.mean(shape.sdf(p) < 0), rel=0.01)
        # a level set is the concentric sphere's cap
        moved = SphereInterface(box, centre, 45.0 + (1.5 if convex else -1.5), convex=convex)
        assert shape.level_area(np.array([1.5]))[0] == pytest.approx(moved.area(), rel=1e-9)


def test_cut_sphere_measures_are_its_part_inside():
    from apt_filters.synth.implicit import CutSphere

    shape = CutSphere((11.0, 0.0, -20.0), 4.0, (1.0, 0.0, 0.0), 12.0)  # 1 nm of the centre inside the face
    rng = np.random.default_rng(6)
    p = shape.center + rng.uniform(-4, 4, (400_000, 3))
    inside = (np.linalg.norm(p - shape.center, axis=1) < 4) & (p[:, 0] <= 12)
    assert shape.volume() == pytest.approx(512 * inside.mean(), rel=0.01)
    n = rng.normal(size=(400_000, 3))
    on = shape.center + 4 * n / np.linalg.norm(n, axis=1, keepdims=True)
    assert shape.area() == pytest.approx(64 * np.pi * np.mean(on[:, 0] <= 12), rel=0.01)
    assert shape.mesh(0.1).area() == pytest.approx(shape.area(), rel=0.02)  # the open mesh ends near the face
    assert shape.moved_in(1.0).volume() < shape.volume()


def test_density_artefacts_thin_the_ions_not_the_compositions():
    from apt_filters.synth import Box, Feature, SpecimenSpec, Sphere, generate
    from apt_filters.synth.artefacts import EfficiencyPatches, LocalMagnification

    sphere = Sphere((0.0, 0.0, -10.0), 5.0)
    inside = {"Ni": 0.5, "Al": 0.5}
    spec = SpecimenSpec(Box((20.0, 20.0, 20.0)), {"Ni": 0.9, "Al": 0.1}, (Feature(sphere, inside, 0.2),),
                        efficiency=0.8,
                        artefacts=(EfficiencyPatches([[6.0, 6.0]], [2.0], [0.5]), LocalMagnification(sphere, 0.5, 0.2)))
    sp = generate(spec, 1)
    pos = sp.ions.positions.astype(np.float64)
    atoms = sp.ions.extra["species"] >= 0
    d = sphere.sdf(pos)
    patch = np.hypot(pos[:, 0] - 6, pos[:, 1] - 6) < 1.0
    far = (np.hypot(pos[:, 0] + 6, pos[:, 1] + 6) < 2) & (d > 1)
    density = lambda m, v: m.sum() / v  # noqa: E731
    ratio_patch = density(patch & (d > 1), np.pi * 20) / density(far, np.pi * 4 * 20)
    assert ratio_patch == pytest.approx(1 - 0.5 * 8 * (1 - np.exp(-1 / 8)), abs=0.06)  # mean over the 1 nm disc
    core = d < -1
    ratio_inside = density(core, 4 / 3 * np.pi * 4 ** 3) / density(far, np.pi * 4 * 20)
    assert ratio_inside == pytest.approx(0.5, abs=0.05)
    al = sp.truth["species"].index("Al")
    assert np.mean(sp.ions.extra["species"][core & atoms] == al) == pytest.approx(0.5, abs=0.02)
    assert sp.truth["artefacts"][1]["ratio"] == 0.5
