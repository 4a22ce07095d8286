"""Shapes and outlines of the synthetic specimens against analytic truth and Monte Carlo."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from apt_filters.core.errors import AptFiltersError
from apt_filters.synth.geometry import Box, Tip
from apt_filters.synth.shapes import (Capsule, Cuboid, CustomShape, Cylinder, HalfSpace, Sphere, rotation_matrix,
                                      shape_from_params)

SIGMAS = 4.0

SOLIDS = {
    "sphere": Sphere((1.0, -2.0, 3.0), 3.0),
    "cube": Cuboid((0.5, 0.0, -1.0), 6.0, rotation=7),
    "cuboid": Cuboid((0.0, 1.0, 0.0), (6.0, 4.0, 2.5), rotation=8),
    "rod": Capsule((0.0, 0.0, 1.0), 1.5, 8.0, rotation=(1.0, 1.0, 0.3)),
    "plate": Cylinder((0.0, 0.0, 0.0), 4.0, 1.2, rotation=9),
}


def _monte_carlo(shape, n=400_000, seed=0):
    """(points, sdf values, box volume) uniform in the shape's bounds grown by 1 nm."""
    lo, hi = shape.bounds()
    lo, hi = lo - 1.0, hi + 1.0
    p = np.random.default_rng(seed).uniform(lo, hi, (n, 3))
    return p, shape.sdf(p), float(np.prod(hi - lo))


def test_analytic_measures_of_simple_cases():
    assert Cuboid((0, 0, 0), 6.0, rotation=3).volume() == pytest.approx(216.0)
    assert Cuboid((0, 0, 0), 6.0, rotation=3).area() == pytest.approx(216.0)
    assert Sphere((0, 0, 0), 3.0).volume() == pytest.approx(36 * math.pi)
    assert Sphere((0, 0, 0), 3.0).area() == pytest.approx(36 * math.pi)
    assert Capsule((0, 0, 0), 1.0, 2.0).volume() == pytest.approx(2 * math.pi + 4 / 3 * math.pi)
    assert Cylinder((0, 0, 0), 2.0, 1.0).area() == pytest.approx(2 * math.pi * 4 + 2 * math.pi * 2)


@pytest.mark.parametrize("name", SOLIDS)
def test_volume_and_level_areas_match_monte_carlo(name):
    shape = SOLIDS[name]
    p, d, box = _monte_carlo(shape)
    frac = (d < 0).mean()
    err = math.sqrt(frac * (1 - frac) / len(d)) * box
    assert abs(frac * box - shape.volume()) < 4 * err
    # thin shells either side: volume between d0 and d0 + 0.2 nm = integral of level areas
    for d0 in (-0.6, 0.4):
        shell = ((d >= d0) & (d < d0 + 0.2)).mean()
        grid = np.linspace(d0, d0 + 0.2, 201)
        exact = np.trapezoid(shape.level_area(grid), grid)
        err = math.sqrt(shell * (1 - shell) / len(d)) * box
        assert abs(shell * box - exact) < 4 * err + 1e-3 * exact, (d0, shell * box, exact)


@pytest.mark.parametrize("name", SOLIDS)
def test_mesh_is_closed_outward_and_on_the_surface(name):
    shape = SOLIDS[name]
    mesh = shape.mesh(0.1)
    assert len(mesh.boundary_edges()) == 0 and mesh.non_manifold_edge_count() == 0
    assert np.abs(shape.sdf(mesh.vertices)).max() < 1e-9
    assert mesh.signed_volume() == pytest.approx(shape.volume(), rel=2e-3)
    assert mesh.area() == pytest.approx(shape.area(), rel=2e-3)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    areas = mesh.face_areas()
    ok = areas > 1e-8  # pole fans of surfaces of revolution have tiny faces
    assert (shape.sdf(centroids[ok] + 0.01 * mesh.face_normals()[ok]) > shape.sdf(centroids[ok])).all()


@pytest.mark.parametrize("name", SOLIDS)
def test_sdf_is_the_euclidean_distance(name):
    """Eikonal |grad sdf| = 1, and p - sdf(p) grad sdf(p) lands on the surface (a bound such as
    max(|p| - h) for a box passes the first test but not the second near edges and corners)."""
    shape = SOLIDS[name]
    p, d, _ = _monte_carlo(shape, n=50_000, seed=1)
    h = 1e-6
    grad = np.stack([(shape.sdf(p + h * e) - shape.sdf(p - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    norm = np.linalg.norm(grad, axis=1)
    smooth = np.abs(norm - 1) < 1e-5
    assert smooth.mean() > 0.999  # the rest straddle the medial axis, where the gradient jumps
    foot = p[smooth] - d[smooth, None] * grad[smooth]
    assert np.abs(shape.sdf(foot)).max() < 1e-5
    mesh = shape.mesh(0.1)
    near = cKDTree(mesh.vertices).query(p[:2000])[0]
    assert (near - np.abs(d[:2000]) > -2e-3).all()  # no surface point is closer than the SDF says


def test_axes_are_x_y_z_in_order():
    box = Cuboid((0, 0, 0), (2.0, 4.0, 6.0))
    pts = np.array([[0.9, 0, 0], [1.1, 0, 0], [0, 1.9, 0], [0, 2.1, 0], [0, 0, 2.9], [0, 0, 3.1]])
    assert (np.sign(box.sdf(pts)) == [-1, 1, -1, 1, -1, 1]).all()
    lo, hi = box.bounds()
    assert np.allclose(hi - lo, [2, 4, 6])
    outline = Box((10.0, 20.0, 30.0))
    lo, hi = outline.bounds()
    assert np.allclose(lo, [-5, -10, -30]) and np.allclose(hi, [5, 10, 0])


def test_rotations():
    for spec in (5, (1.0, 2.0, 3.0), (0.0, 0.0, -1.0)):
        r = rotation_matrix(spec)
        assert np.allclose(r @ r.T, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    r = rotation_matrix((1.0, 2.0, 3.0))
    assert np.allclose(r @ [0, 0, 1], np.array([1, 2, 3]) / math.sqrt(14))
    assert not np.allclose(rotation_matrix(5), rotation_matrix(6))
    rod = Capsule((0, 0, 0), 0.5, 4.0, rotation=(1.0, 0.0, 0.0))  # along x
    assert rod.sdf(np.array([[2.4, 0, 0], [0, 2.4, 0]])).tolist() == pytest.approx([-0.1, 1.9])
    with pytest.raises(AptFiltersError):
        rotation_matrix(np.diag([1.0, 1.0, -1.0]))


@pytest.mark.parametrize("outline", [Tip(10.0, 10.0, 40.0), Box((16.0, 14.0, 28.0))])
def test_outline_volume_sdf_and_sampling(outline):
    lo, hi = outline.bounds()
    p = np.random.default_rng(2).uniform(lo, hi, (400_000, 3))
    d = outline.sdf(p)
    frac = (d < 0).mean()
    box = float(np.prod(hi - lo))
    assert abs(frac * box - outline.volume()) <= 4 * math.sqrt(frac * (1 - frac) / len(p)) * box + 1e-9 * box
    # sections: a thin slab's volume is its cross-section times its thickness
    for z in (-0.5 * outline.length, -0.9 * outline.length):
        slab = ((p[:, 2] > z - 0.5) & (p[:, 2] < z + 0.5) & (d < 0)).mean() * box
        assert slab == pytest.approx(outline.cross_section_area(np.array([z]))[0], rel=0.03)
    s = outline.sample(200_000, np.random.default_rng(3))
    assert (outline.sdf(s) < 1e-12).all()
    # uniform in volume: the counts in the MC cells of a coarse grid match the MC volume fractions
    edges = [np.linspace(lo[i], hi[i], 5) for i in range(3)]
    ref = np.histogramdd(p[d < 0], bins=edges)[0].ravel() / (d < 0).sum()
    got = np.histogramdd(s, bins=edges)[0].ravel() / len(s)
    err = np.sqrt(ref * (1 - ref) * (1 / len(s) + 1 / (d < 0).sum()))
    assert (np.abs(got - ref) <= SIGMAS * err + 1e-12).all()
    # uniform: the fraction in the upper half of the z range matches its volume fraction
    upper = (p[:, 2] > -0.5 * outline.length) & (d < 0)
    expected = upper.mean() / frac
    assert abs((s[:, 2] > -0.5 * outline.length).mean() - expected) < 4 * math.sqrt(expected * (1 - expected) / len(s))


def test_tip_apex_and_shank():
    tip = Tip(10.0, 10.0, 40.0)
    assert tip.sdf(np.array([[0, 0, 0.0], [0, 0, 0.5], [0, 0, -40.0]])).tolist() == pytest.approx([0, 0.5, 0])
    z = -30.0
    r = tip.radius_at(np.array([z]))[0]
    assert tip.sdf(np.array([[r, 0, z], [0, -r, z]])) == pytest.approx([0, 0], abs=1e-9)
    assert r == pytest.approx(10 * math.cos(math.radians(10)) + (-10 + 10 * math.sin(math.radians(10)) - z)
                              * math.tan(math.radians(10)))


def test_halfspace_section_in_tip_and_box():
    tip = Tip(10.0, 10.0, 40.0)
    plane = HalfSpace((0, 0, -20), (0, 0, 1))
    r = tip.radius_at(np.array([-20.0]))[0]
    assert plane.area(tip) == pytest.approx(math.pi * r * r)
    mesh = plane.mesh(0.1, tip)
    assert mesh.area() == pytest.approx(math.pi * r * r, rel=1e-3)
    assert (mesh.face_normals() @ [0, 0, 1] > 0.999).all()
    assert np.abs(plane.sdf(mesh.vertices)).max() < 1e-9
    box = Box((16.0, 14.0, 28.0))
    assert HalfSpace((0, 0, -23), (0, 0, 1)).volume(box) == pytest.approx(16 * 14 * 5)
    # an oblique plane through the box centre: section area from polygons, checked against the formula
    tilt = HalfSpace((0, 0, -14), (0.0, math.sin(0.3), math.cos(0.3)))
    assert tilt.area(box) == pytest.approx(16 * 14 / math.cos(0.3), rel=1e-3)
    assert tilt.volume(box) == pytest.approx(16 * 14 * 28 / 2, rel=2e-3)


def test_custom_shape_matches_the_analytic_one():
    ref = Sphere((0.0, 0.0, 0.0), 2.0)
    custom = CustomShape(ref.sdf, (-2.0, -2.0, -2.0), (2.0, 2.0, 2.0), name="ball", pad=1.0)
    assert custom.volume() == pytest.approx(ref.volume(), rel=2e-3)
    assert custom.area() == pytest.approx(ref.area(), rel=2e-3)
    assert custom.level_area(np.array([-0.5, 0.5])) == pytest.approx(ref.level_area(np.array([-0.5, 0.5])), rel=5e-3)
    assert custom.depth() == pytest.approx(2.0, abs=0.05)


def test_shapes_are_rebuilt_from_their_parameters():
    """truth.json keeps each feature's ``params()`` (JSON numbers): the rebuilt shape has the same SDF."""
    import json

    p = np.random.default_rng(3).uniform(-8, 8, (5000, 3))
    for shape in [*SOLIDS.values(), HalfSpace((0, 0, -1), (0.2, -0.3, 1.0))]:
        again = shape_from_params(json.loads(json.dumps(shape.params())))
        assert type(again) is type(shape)
        assert again.sdf(p) == pytest.approx(shape.sdf(p), abs=1e-12)
    custom = CustomShape(SOLIDS["sphere"].sdf, (-2.0, -5.0, 0.0), (4.0, 1.0, 6.0), name="ball")
    with pytest.raises(AptFiltersError, match="custom"):
        shape_from_params(custom.params())


def test_bad_shape_parameters_are_clear_errors():
    for make in (lambda: Sphere((0, 0, 0), -1), lambda: Cuboid((0, 0, 0), (1, 0, 1)),
                 lambda: HalfSpace((0, 0, 0), (0, 0, 0)), lambda: Tip(10, 10, 1.0), lambda: Box((1, -1, 1))):
        with pytest.raises(AptFiltersError):
            make()
