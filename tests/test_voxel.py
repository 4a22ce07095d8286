"""Voxelization: conservation, orientation, kernel values, sparse memory, streaming, bases."""

import re

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.voxel import (
    BLOCK, ConcentrationBasis, Grid, KERNELS, check_budget, kernel_reach, second_pass_sigma, voxelize,
)
from tests.voxel_helpers import MZ, ions, random_ions, ranges


def expected_atoms(table, species="elements", unranged=False):
    """Atoms per field counted independently of the voxel code."""
    rt = ranges()
    idx = rt.ion_index(table.mz)
    per_ion = np.bincount(idx[idx >= 0], minlength=len(rt.ions)).astype(float)
    if species == "ions":
        out = dict(zip(rt.ions, per_ion))
    else:
        out = dict(zip(rt.elements, per_ion @ rt.element_matrix()))
    if unranged:
        out["unranged"] = float(np.sum(idx < 0))
    return out


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("species", ["elements", "ions"])
def test_conservation_all_kernels(kernel, species):
    table = random_ions(4000, [0.0, 0.0, 0.0], [7.0, 9.0, 11.0], seed=1)
    # ions exactly on the data box's corners and faces, on grid points and half-way between
    edge = np.array([[0, 0, 0], [7, 9, 11], [0, 9, 11], [7, 0, 0], [3.5, 0, 11], [0.5, 8.5, 10.5]], np.float32)
    table = ions(np.vstack([table.positions, edge]), list(np.array(list(MZ) + ["?"])[np.arange(len(table) + 6) % 5]))
    f = voxelize(table, ranges(), kernel=kernel, species=species, voxel=1.0, keep_unranged=True)
    want = expected_atoms(table, species, unranged=True)
    assert f.n_counted == pytest.approx(want, rel=0, abs=0)
    for name, field in f.counts.items():
        assert abs(field.sum() / want[name] - 1) < 1e-6, name
        assert np.all(field.data >= -1e-12)


@pytest.mark.parametrize("kernel", KERNELS)
def test_conservation_at_the_admissible_edge_of_a_given_grid(kernel):
    grid = Grid((0.0, 0.0, 0.0), 0.5, (30, 31, 32))
    margin = kernel_reach(kernel, 0.5, (3, 3, 1.5))
    lo = grid.points(margin - (0.5 if kernel == "square" else 0))  # the lowest admissible point
    hi = grid.points(np.asarray(grid.shape) - 1 - margin)
    pts = np.array([lo, hi, [lo[0], hi[1], lo[2]], (lo + hi) / 2])
    f = voxelize(ions(pts, ["Cu"] * 4), ranges(), grid=grid, kernel=kernel)
    assert abs(f.counts["Cu"].sum() - 4) < 1e-9
    dense = f.counts["Cu"].dense()
    assert abs(dense.sum() - 4) < 1e-9  # nothing stored outside the grid's shape
    outside = grid.points(np.asarray(grid.shape) + 0.1)
    with pytest.raises(AptFiltersError, match="outside the grid"):
        voxelize(ions(np.vstack([pts, outside]), ["Cu"] * 5), ranges(), grid=grid, kernel=kernel)


def test_nan_position_is_refused():
    pts = np.array([[1.0, 1.0, 1.0], [np.nan, 2.0, 2.0]])
    grid = Grid((-10.0, -10.0, -10.0), 1.0, (30, 30, 30))
    with pytest.raises(AptFiltersError, match="outside the grid"):
        voxelize(ions(pts, ["Cu", "Cu"]), ranges(), grid=grid, kernel="sawtooth")


def test_square_kernel_single_ion():
    grid = Grid((0.0, 0.0, 0.0), 1.0, (6, 9, 4))
    f = voxelize(ions([[2.3, 4.6, 1.2]], ["Cu"]), ranges(), grid=grid, kernel="square")
    dense = f.counts["Cu"].dense()
    assert dense.shape == (6, 9, 4)
    assert dense[2, 5, 1] == 1.0 and dense.sum() == 1.0


def test_sawtooth_kernel_single_ion_lever_rule():
    grid = Grid((0.0, 0.0, 0.0), 0.5, (10, 12, 14))
    # fractional index (4.5, 9.0, 3.75): x shared 0.5/0.5, y all on 9 (t = 0), z 0.25/0.75
    f = voxelize(ions([[2.25, 4.5, 1.875]], ["O"]), ranges(), grid=grid, kernel="sawtooth")
    dense = f.counts["O"].dense()
    want = np.zeros(grid.shape)
    for i, wx in ((4, 0.5), (5, 0.5)):
        for k, wz in ((3, 0.25), (4, 0.75)):
            want[i, 9, k] = wx * wz
    np.testing.assert_allclose(dense, want, atol=1e-12)


def gaussian_1d(f, n, sigma):
    """Hand-built profile of one axis: 3-point pass 1 (sigma = voxel/6) then the truncated pass 2."""
    profile = np.zeros(n)
    c = int(np.floor(f + 0.5))
    w = np.exp(-((np.arange(c - 1, c + 2) - f) ** 2) / (2 * (1 / 6) ** 2))
    profile[c - 1: c + 2] = w / w.sum()
    r = int(4 * sigma + 0.5)
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    return np.convolve(profile, k / k.sum(), mode="same")


def test_gaussian_kernel_single_ion_matches_hand_built_profile():
    voxel, deloc = 1.0, (3.0, 3.0, 1.5)
    grid = Grid((0.0, 0.0, 0.0), voxel, (21, 23, 17))
    p = np.array([10.3, 11.0, 8.45], dtype=np.float32).astype(np.float64)  # as the IonTable holds it
    f = voxelize(ions([p], ["Cu"]), ranges(), grid=grid, kernel="gaussian", delocalization=deloc)
    sig = second_pass_sigma(voxel, deloc)
    np.testing.assert_allclose(sig, np.sqrt((np.array(deloc) / 3) ** 2 - 1 / 36))
    want = np.einsum("i,j,k->ijk", *(gaussian_1d(p[a], grid.shape[a], sig[a]) for a in range(3)))
    dense = f.counts["Cu"].dense()
    np.testing.assert_allclose(dense, want, atol=1e-12)
    # the hand values at the peak: on-axis y (exactly on a grid point) keeps 1/(1 + 2 e^-18) in pass 1
    assert abs(dense.sum() - 1) < 1e-12
    assert np.unravel_index(np.argmax(dense), dense.shape) == (10, 11, 8)


def test_xyz_orientation_on_an_asymmetric_blob():
    rng = np.random.default_rng(3)
    centre, spread = np.array([4.0, 9.0, 17.0]), np.array([0.8, 1.6, 3.2])
    pos = centre + spread * rng.standard_normal((20000, 3))
    table = ions(pos, ["Cu"] * len(pos))
    for kernel in KERNELS:
        f = voxelize(table, ranges(), kernel=kernel, voxel=0.5)
        dense = f.counts["Cu"].dense()
        assert dense.shape == f.grid.shape
        coords = np.meshgrid(*(f.grid.axis(a) for a in range(3)), indexing="ij")
        mean = np.array([(dense * c).sum() for c in coords]) / dense.sum()
        tol = 0.02 if kernel != "square" else 0.05
        np.testing.assert_allclose(mean, pos.mean(axis=0), atol=tol)
        var = np.array([(dense * (c - m) ** 2).sum() for c, m in zip(coords, mean)]) / dense.sum()
        assert np.all(np.diff(var) > 0), (kernel, var)  # x narrowest, z widest


def test_sparse_memory_grows_with_occupied_blocks_not_the_box():
    grid = Grid((0.0, 0.0, 0.0), 1.0, (512, 512, 512))  # 1 GB if dense float64
    rng = np.random.default_rng(5)
    sizes = []
    for n_clusters in (1, 2, 4):
        corners = rng.choice(60, (n_clusters, 3), replace=False) * BLOCK + 8  # distinct far-apart blocks
        pos = np.repeat(corners, 50, axis=0) + rng.uniform(0, BLOCK - 1, (50 * n_clusters, 3))
        f = voxelize(ions(pos, ["Cu"] * len(pos)), ranges(), grid=grid, kernel="sawtooth")
        field = f.counts["Cu"]
        occupied = np.unique(np.vstack([np.floor(pos).astype(int) // BLOCK,
                                        (np.floor(pos).astype(int) + 1) // BLOCK]), axis=0)
        assert field.n_blocks == len(occupied)
        assert field.nbytes == field.n_blocks * (BLOCK**3 * 8 + 3 * 4)
        sizes.append(field.nbytes)
        assert field.values_at(np.floor(pos[:1]).astype(int))[0] > 0
    assert sizes[1] <= 2 * sizes[0] * 1.5 and sizes[2] >= sizes[0] * 2
    assert sizes[2] < 1e-3 * grid.n_voxels * 8


def test_memory_budget_refusal_says_what_fits():
    table = random_ions(100, [0, 0, 0], [200, 200, 800], seed=2)
    budget = 9_000_000_000
    with pytest.raises(AptFiltersError, match=r"over the memory budget.*would fit: voxel >= [0-9.]+ nm, or at most 1 "
                       ) as err:
        voxelize(table, ranges(), kernel="square", voxel=0.5, memory_budget=budget)
    fit = float(re.search(r"voxel >= ([0-9.]+) nm", str(err.value)).group(1))
    lower, upper = table.bounds()
    check_budget(Grid.covering(lower, upper, fit, kernel_reach("square")), 4, budget)  # the hint holds
    check_budget(Grid.covering(lower, upper, 0.5, kernel_reach("square")), 1, budget)
    f = voxelize(table, ranges(), kernel="square", voxel=4.0, memory_budget=budget)
    assert f.counts["Cu"].n_blocks <= 100


def test_streaming_chunks_equal_whole_table():
    table = random_ions(5000, [0, 0, 0], [8, 6, 12], seed=4)
    whole = voxelize(table, ranges(), kernel="gaussian")
    parts = [table.subset(slice(i, i + 700)) for i in range(0, len(table), 700)]
    chunked = voxelize(parts, ranges(), kernel="gaussian")
    stream = voxelize(iter(parts), ranges(), grid=whole.grid, kernel="gaussian")
    for name in whole.names:
        np.testing.assert_allclose(chunked.counts[name].dense(), whole.counts[name].dense(), atol=1e-9)
        np.testing.assert_allclose(stream.counts[name].dense(), whole.counts[name].dense(), atol=1e-9)
    with pytest.raises(AptFiltersError, match="needs a grid"):
        voxelize(iter(parts), ranges())


def test_molecular_ions_decompose_into_elements():
    f = voxelize(ions([[1.0, 1.0, 1.0]], ["CrO2"]), ranges(), kernel="sawtooth")
    assert f.counts["Cr"].sum() == pytest.approx(1) and f.counts["O"].sum() == pytest.approx(2)
    c = f.concentration("O").dense()
    np.testing.assert_allclose(c[np.isfinite(c)], 2 / 3)
    fi = voxelize(ions([[1.0, 1.0, 1.0]], ["CrO2"]), ranges(), kernel="sawtooth", species="ions")
    assert fi.names == ["Cu", "CrO2", "O", "B"] and fi.counts["CrO2"].sum() == pytest.approx(1)


def test_concentration_basis_density_and_undefined_voxels():
    # one voxel (square kernel): 2 Cu, 1 CrO2, 1 B, 1 unranged; an empty voxel elsewhere
    pos = [[2.0, 2.0, 2.0]] * 5 + [[6.0, 2.0, 2.0]]
    table = ions(pos, ["Cu", "Cu", "CrO2", "B", "?", "Cu"])
    rt, grid = ranges(), Grid((0.0, 0.0, 0.0), 1.0, (8, 4, 4))
    f = voxelize(table, rt, grid=grid, kernel="square", efficiency=0.5)
    assert f.basis.describe() == "all ranged species, unranged ions excluded"
    assert "unranged" not in f.names
    cu = f.concentration("Cu").dense()
    assert cu[2, 2, 2] == pytest.approx(2 / 6)  # Cu, Cu, Cr, O, O, B
    assert np.isnan(cu[4, 2, 2]) and cu[6, 2, 2] == 1.0
    assert f.density().dense()[2, 2, 2] == pytest.approx(6 / 0.5)
    no_b = ConcentrationBasis(exclude=("B",))
    assert f.concentration("Cu", no_b).dense()[2, 2, 2] == pytest.approx(2 / 5)
    with_bg = ConcentrationBasis(include_unranged=True)
    g = voxelize(table, rt, grid=grid, kernel="square", basis=with_bg)
    assert g.concentration("Cu").dense()[2, 2, 2] == pytest.approx(2 / 7)
    assert g.basis.describe() == "all ranged species, unranged ions included"
    with pytest.raises(AptFiltersError, match="not voxelized"):
        f.concentration("Cu", with_bg)
    with pytest.raises(AptFiltersError, match="unknown species Zr"):
        voxelize(table, rt, kernel="square", basis=ConcentrationBasis(exclude=("Zr",)))


def test_bad_parameters_are_one_line_errors():
    table = random_ions(10, [0, 0, 0], [5, 5, 5])
    for kwargs, match in [
        (dict(kernel="box"), "unknown transfer function"),
        (dict(delocalization=(0.3, 3, 3)), "must exceed half the voxel"),
        (dict(species="atoms"), "species must be"),
        (dict(efficiency=0), "efficiency"),
    ]:
        with pytest.raises(AptFiltersError, match=match):
            voxelize(table, ranges(), **kwargs)
