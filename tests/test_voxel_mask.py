"""The inside mask on a conical tip built here, and sub-voxel gradients against analytic fields."""

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.hull import SpecimenHull
from apt_filters.voxel import Grid, SparseField, gradient, gradient_at, inside_mask, voxelize
from tests.voxel_helpers import ions, ranges

HALF_ANGLE = np.radians(12.0)
R0, HEIGHT, DENSITY = 6.0, 36.0, 20.0  # nm, nm, ions/nm³


def cone_radius(z):
    return R0 + z * np.tan(HALF_ANGLE)


def cone_distance(p):
    """Signed distance (nm, negative inside) to the truncated cone 0 <= z <= HEIGHT (exact off the rims)."""
    rho = np.hypot(p[..., 0], p[..., 1])
    side = (rho - cone_radius(p[..., 2])) * np.cos(HALF_ANGLE)
    return np.maximum(side, np.maximum(-p[..., 2], p[..., 2] - HEIGHT))


@pytest.fixture(scope="module")
def tip():
    rng = np.random.default_rng(11)
    r_top = cone_radius(HEIGHT)
    n_box = int(DENSITY * (2 * r_top) ** 2 * HEIGHT)
    pos = rng.uniform([-r_top, -r_top, 0], [r_top, r_top, HEIGHT], (n_box, 3))
    pos = pos[cone_distance(pos) <= 0]
    return ions(pos, rng.choice(["Cu", "O"], len(pos)))


@pytest.mark.parametrize("rule", ["density", "hull", "both"])
def test_mask_marks_outside_of_a_conical_tip(tip, rule):
    f = voxelize(tip, ranges(), kernel="gaussian", voxel=1.0)
    hull = SpecimenHull.from_points(tip.positions, chunk=len(tip) // 2 + 1)
    mask = inside_mask(f, rule=rule, hull=hull)
    inside = mask.dense()
    centres = np.stack(np.meshgrid(*(f.grid.axis(a) for a in range(3)), indexing="ij"), axis=-1)
    d = cone_distance(centres)
    far_out, deep_in = d > 1.0, d < -1.0
    assert far_out.sum() > 0.3 * d.size and deep_in.sum() > 0.1 * d.size  # the test has teeth
    assert not inside[far_out].any()
    assert inside[deep_in].all()
    # the boundary itself sits at the surface: the inside volume is the cone's within 5%
    cone_volume = np.pi / 3 * HEIGHT * (R0**2 + R0 * cone_radius(HEIGHT) + cone_radius(HEIGHT) ** 2)
    assert abs(inside.sum() * f.grid.voxel_volume / cone_volume - 1) < 0.05


def test_mask_threshold_moves_the_boundary(tip):
    f = voxelize(tip, ranges(), kernel="gaussian", voxel=1.0)
    sizes = [inside_mask(f, threshold=t).dense().sum() for t in (0.2, 0.5, 0.8)]
    assert sizes[0] > sizes[1] > sizes[2]
    with pytest.raises(AptFiltersError, match="needs the ions' hull"):
        inside_mask(f, rule="hull")
    with pytest.raises(AptFiltersError, match="unknown mask rule"):
        inside_mask(f, rule="alpha")


def test_mask_keeps_a_region_of_fewer_ions_inside_the_specimen():
    """A detector-efficiency patch (a Gaussian dip of 60 %, sigma 4 nm, through the whole depth) in a 24 x 24 x
    20 nm block, and a sphere (radius 4 nm) reconstructed at 0.7 of the matrix's density beside it: 0.28 of the
    bulk count where they overlap. Every voxel 1 nm or more inside the block is inside the specimen, every voxel 1 nm
    or more outside is outside, and the inside volume is the block's within 5 % (the bulk-only rule cut the patch's
    column and the sphere out of the specimen: 1.8 % of the voxels 1 nm or more inside)."""
    rng = np.random.default_rng(5)
    half = np.array([12.0, 12.0, 10.0])
    pos = rng.uniform(-half, half, (int(DENSITY * np.prod(2 * half)), 3))
    keep = 1 - 0.6 * np.exp(-0.5 * np.sum((pos[:, :2] - [3.0, 0.0]) ** 2, axis=1) / 4.0 ** 2)
    keep *= np.where(np.linalg.norm(pos - [-2.0, 0.0, 0.0], axis=1) < 4.0, 0.7, 1.0)
    pos = pos[rng.random(len(pos)) < keep]
    f = voxelize(ions(pos, rng.choice(["Cu", "O"], len(pos))), ranges(), kernel="gaussian", voxel=1.0)
    inside = inside_mask(f).dense()
    centres = np.stack(np.meshgrid(*(f.grid.axis(a) for a in range(3)), indexing="ij"), axis=-1)
    d = np.max(np.abs(centres) - half, axis=-1)  # the block's signed distance (exact inside, a bound outside)
    far_out, deep_in = d > 1.0, d < -1.0
    assert far_out.sum() > 0.3 * d.size and deep_in.sum() > 0.2 * d.size  # the test has teeth
    assert not inside[far_out].any()
    assert inside[deep_in].all()
    assert abs(inside.sum() * f.grid.voxel_volume / np.prod(2 * half) - 1) < 0.05


def quadratic(p):
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return 0.3 * x**2 - 0.2 * x * y + 0.5 * y * z - 0.1 * z**2 + 2 * x - y + 0.7 * z


def quadratic_gradient(p):
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return np.stack([0.6 * x - 0.2 * y + 2, -0.2 * x + 0.5 * z - 1, 0.5 * y - 0.2 * z + 0.7], axis=-1)


@pytest.mark.parametrize("method", ["central", "fit"])
def test_gradient_exact_for_quadratic_fields_between_grid_points(method):
    grid = Grid((-1.0, 2.0, 0.5), 0.5, (12, 15, 19))  # asymmetric shape: catches swapped axes
    centres = np.stack(np.meshgrid(*(grid.axis(a) for a in range(3)), indexing="ij"), axis=-1)
    values = quadratic(centres)
    g = gradient(values, grid.voxel, method)
    np.testing.assert_allclose(g[1:-1, 1:-1, 1:-1], quadratic_gradient(centres)[1:-1, 1:-1, 1:-1], atol=1e-9)
    rng = np.random.default_rng(2)
    pts = grid.points(rng.uniform(1, np.asarray(grid.shape) - 2, (200, 3)))  # sub-voxel positions
    field = SparseField.from_dense(grid, values)
    np.testing.assert_allclose(gradient_at(field, pts, method), quadratic_gradient(pts), atol=1e-9)


def test_fitted_gradient_is_less_noisy_than_central_differences():
    grid = Grid((0.0, 0.0, 0.0), 1.0, (30, 30, 30))
    rng = np.random.default_rng(7)
    i = np.indices(grid.shape).transpose(1, 2, 3, 0)
    values = i @ np.array([1.0, -2.0, 0.5]) + rng.normal(0, 1.0, grid.shape)
    err = {m: np.sqrt(np.mean((gradient(values, 1.0, m)[2:-2, 2:-2, 2:-2] - [1.0, -2.0, 0.5]) ** 2))
           for m in ("central", "fit")}
    assert err["fit"] < 0.65 * err["central"]  # expected ratio 1/sqrt(3) = 0.577
    with pytest.raises(AptFiltersError, match="unknown gradient method"):
        gradient(values, 1.0, "sobel")
