"""The fast paths of the scatter: bin-table ranging, the multi-threaded scatter and its default thread count."""

import os

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.io import IonTable, Range, RangeTable
from apt_filters.voxel import Grid, kernel_reach, voxelize
from apt_filters.voxel import grid as grid_module
from apt_filters.voxel.grid import available_cores, field_bytes, scatter_threads
from apt_filters.voxel import transfer
from apt_filters.voxel.ranging import MzLookup
from apt_filters.voxel.transfer import BlockAccumulator
from tests.voxel_helpers import ions, random_ions, ranges


def touching_ranges() -> RangeTable:
    """Ranges that touch (upper == next lower), a narrow one, bounds not exact in float32, one repeated ion."""
    return RangeTable([
        Range(10.0, 10.7, (("B", 1),)),
        Range(10.7, 11.3, (("C", 1),)),
        Range(27.0, 27.001, (("Al", 1),)),
        Range(0.1, 0.3, (("H", 1),)),
        Range(55.93, 56.17, (("Fe", 1),)),
        Range(199.9, 200.3, (("B", 1),)),
    ])


@pytest.mark.parametrize("table", [touching_ranges(), ranges()], ids=["touching", "helpers"])
def test_lookup_ranging_equals_ion_index_everywhere(table):
    rng = np.random.default_rng(3)
    bounds = np.array([b for r in table.ranges for b in (r.lower, r.upper)])
    at_bounds = np.concatenate([
        bounds.astype(np.float32),
        np.nextafter(bounds.astype(np.float32), np.float32(np.inf)),
        np.nextafter(bounds.astype(np.float32), np.float32(-np.inf)),
    ])
    special = np.array([np.nan, np.inf, -np.inf, -5.0, 0.0, 1e30, 3e38], dtype=np.float32)
    mz = np.concatenate([rng.uniform(-1, 260, 200_000).astype(np.float32), at_bounds, special])
    want = table.ion_index(mz) + 1
    lookup = MzLookup.from_ranges(table)
    for threads in (1, 3):
        np.testing.assert_array_equal(lookup.rows_of(mz, threads), want, err_msg=f"{threads} threads")


def dense_square(pos, grid):
    f = grid.fractional_index(pos)
    idx = np.floor(f + 0.5).astype(np.int64)
    out = np.zeros(grid.shape)
    np.add.at(out, tuple(idx.T), 1.0)
    return out


def dense_sawtooth(pos, grid):
    f = grid.fractional_index(pos)
    i0 = np.floor(f).astype(np.int64)
    t = f - i0
    out = np.zeros(grid.shape)
    for a in (0, 1):
        for b in (0, 1):
            for c in (0, 1):
                w = np.where(a, t[:, 0], 1 - t[:, 0]) * np.where(b, t[:, 1], 1 - t[:, 1])
                w = w * np.where(c, t[:, 2], 1 - t[:, 2])
                np.add.at(out, (i0[:, 0] + a, i0[:, 1] + b, i0[:, 2] + c), w)
    return out


@pytest.mark.parametrize("kernel, reference", [("square", dense_square), ("sawtooth", dense_sawtooth)])
@pytest.mark.parametrize("order", ["detection", "shuffled"])
def test_threaded_scatter_equals_numpy_reference(kernel, reference, order):
    """Many block layers (z spans 12 of them), ions on layer boundaries, every thread count."""
    table = random_ions(30_000, [0.0, 0.0, 0.0], [9.0, 13.0, 95.0], seed=5, names=("Cu",))
    pos = table.positions.copy()
    pos[:200, 2] = np.float32(8 * np.arange(200) % 96)  # exactly on block-layer boundaries
    pos = pos[np.argsort(-pos[:, 2])] if order == "detection" else pos
    grid = Grid.covering(np.zeros(3), [9.0, 13.0, 95.0], 1.0, kernel_reach(kernel))
    want = reference(pos.astype(np.float64), grid)
    for threads in (1, 2, 3):
        got = voxelize(ions(pos, ["Cu"] * len(pos)), ranges(), grid=grid, kernel=kernel, threads=threads)
        np.testing.assert_allclose(got.counts["Cu"].dense(), want, rtol=0, atol=1e-9, err_msg=f"{threads} threads")


def test_threaded_gaussian_is_independent_of_thread_count_and_order():
    table = random_ions(20_000, [0.0, 0.0, 0.0], [7.0, 9.0, 70.0], seed=6)
    grid = Grid.covering(np.zeros(3), [7.0, 9.0, 70.0], 1.0, kernel_reach("gaussian"))
    perm = np.argsort(-table.positions[:, 2])
    results = []
    for threads, idx in ((1, perm), (2, perm), (3, np.arange(len(perm)))):
        t = IonTable(table.positions[idx], table.mz[idx])
        results.append(voxelize(t, ranges(), grid=grid, kernel="gaussian", threads=threads))
    for f in results[1:]:
        for name in f.names:
            np.testing.assert_allclose(f.counts[name].dense(), results[0].counts[name].dense(), rtol=0, atol=1e-9)


def test_thread_count_below_one_is_refused():
    with pytest.raises(AptFiltersError, match="threads must be at least 1"):
        voxelize(ions([[1.0, 1.0, 1.0]], ["Cu"]), ranges(), kernel="square", threads=0)


@pytest.mark.parametrize("kernel, reference", [("square", dense_square), ("sawtooth", dense_sawtooth)])
def test_pool_growth_resumes_without_losing_or_repeating_an_ion(kernel, reference):
    """A first chunk of one ion sizes the pool for a few blocks; the next chunks fill an
    asymmetric box of many blocks, so the fused scatter stops at full pools and resumes."""
    table = random_ions(40_000, [0.0, 0.0, 0.0], [37.0, 21.0, 70.0], seed=8, names=("Cu",))
    pos = table.positions
    grid = Grid.covering(np.zeros(3), [37.0, 21.0, 70.0], 1.0, kernel_reach(kernel))
    chunks = [ions(pos[:1], ["Cu"]), ions(pos[1:15_000], ["Cu"] * 14_999), ions(pos[15_000:], ["Cu"] * 25_000)]
    got = voxelize(chunks, ranges(), grid=grid, kernel=kernel)
    np.testing.assert_allclose(got.counts["Cu"].dense(), reference(pos.astype(np.float64), grid), rtol=0, atol=1e-9)
    assert got.n_counted["Cu"] == len(pos)
    blocks = np.unique(np.floor(grid.fractional_index(pos) + (0.5 if kernel == "square" else 0)).astype(int) // 8,
                       axis=0)
    assert got.counts["Cu"].n_blocks >= len(blocks)


def test_blocks_come_out_in_block_order_whatever_the_ion_order_and_threads():
    table = random_ions(5_000, [0.0, 0.0, 0.0], [30.0, 17.0, 41.0], seed=9)
    grid = Grid.covering(np.zeros(3), [30.0, 17.0, 41.0], 1.0, kernel_reach("sawtooth"))
    runs = [voxelize(IonTable(table.positions[idx], table.mz[idx]), ranges(), grid=grid, kernel="sawtooth",
                     threads=threads)
            for threads, idx in ((1, np.arange(5_000)), (2, np.arange(5_000)[::-1]), (3, np.argsort(table.mz)))]
    for f in runs:
        coords = f.total.coords
        assert np.array_equal(coords, coords[np.lexsort(coords.T[::-1])])
        np.testing.assert_array_equal(coords, runs[0].total.coords)


def test_default_threads_are_one_per_core_within_the_memory_budget(monkeypatch):
    grid = Grid.covering(np.zeros(3), [100.0, 60.0, 140.0], 1.0)
    per_field = field_bytes(grid, 1)
    monkeypatch.setattr(grid_module, "available_cores", lambda: 4)
    assert scatter_threads(grid, 3, 10**13) == 4
    # t threads need (t + 1) * 3 + 2 fields: 14 fit 3 threads, not 4 (17); 8 fit one
    assert scatter_threads(grid, 3, 14 * per_field) == 3
    assert scatter_threads(grid, 3, 14 * per_field - 1) == 2
    assert scatter_threads(grid, 3, 8 * per_field) == 1
    assert scatter_threads(grid, 3, 1) == 1  # and check_budget refuses it


def test_available_cores_is_this_process_s_share():
    assert 1 <= available_cores() <= (os.cpu_count() or 1)


@pytest.mark.parametrize("kernel", ["square", "sawtooth", "gaussian"])
def test_fields_are_the_same_bit_for_bit_on_any_number_of_threads(kernel):
    """A run's surface must not depend on the machine's cores: the pools' sums are exact (whole quanta), so
    one, two or three scatter threads and any ion order give identical fields (float pools rounded in each
    pool's order: one core against two moved a held-out surface by 0.08 nm)."""
    table = random_ions(20_000, [0.0, 0.0, 0.0], [7.0, 9.0, 40.0], seed=7)
    grid = Grid.covering(np.zeros(3), [7.0, 9.0, 40.0], 1.0, kernel_reach(kernel))
    shuffled = np.random.default_rng(8).permutation(len(table.positions))
    results = [voxelize(IonTable(table.positions[idx], table.mz[idx]), ranges(), grid=grid, kernel=kernel,
                        threads=threads)
               for threads, idx in ((1, np.arange(len(shuffled))), (2, np.arange(len(shuffled))), (3, shuffled))]
    for f in results[1:]:
        for name in f.names:
            np.testing.assert_array_equal(f.counts[name].dense(), results[0].counts[name].dense(), err_msg=name)


def accumulated(grid, kernel, rows, n_channels, positions, row_of_ion, threads):
    """Dense (n_channels, *grid.shape) fields of a BlockAccumulator fed ``positions`` in three chunks."""
    acc = BlockAccumulator(grid, kernel, rows, n_channels, threads=threads)
    for part in np.array_split(np.arange(len(positions)), 3):
        acc.add(positions[part], row_of_ion[part])
    coords, channels = acc.result()
    out = np.zeros((n_channels,) + tuple(np.asarray(grid.block_shape) * 8))
    for c, values in enumerate(channels):
        for (x, y, z), block in zip(coords, values):
            out[c, 8 * x: 8 * x + 8, 8 * y: 8 * y + 8, 8 * z: 8 * z + 8] = block
    return out[(slice(None),) + tuple(slice(0, n) for n in grid.shape)]


@pytest.mark.parametrize("kernel", ["square", "sawtooth", "gaussian"])
def test_a_grid_point_beyond_the_int64_pool_s_reach_is_summed_right(kernel):
    """300 ions of weight 2**20 (and -1.5 * 2**20 in a second field) on one grid point: 2**28 weights,
    32 times what an int64 of 2**-40 quanta holds (numba's sums wrap silently). The guard spills whole
    weights out of the pools, so the fields equal a float64 reference and stay the same bit for bit on
    any thread count."""
    rng = np.random.default_rng(11)
    grid = Grid.covering(np.zeros(3), [20.0, 20.0, 20.0], 1.0, kernel_reach(kernel))
    positions = np.concatenate([np.full((300, 3), 10.3), rng.uniform(0.0, 20.0, (3000, 3))])
    row_of_ion = np.concatenate([np.ones(300, dtype=np.int64), rng.integers(0, 3, 3000)])
    scale = 2.0**20
    rows = (np.array([0, 0, 2, 3]), np.array([0, 1, 0]), np.array([scale, -1.5 * scale, 1.0]))
    runs = [accumulated(grid, kernel, rows, 2, positions, row_of_ion, threads) for threads in (1, 2, 3)]
    for got in runs[1:]:
        np.testing.assert_array_equal(got, runs[0])
    if kernel == "gaussian":  # reference: the same ions with weight 1 (2**18 weights at most: no spill), scaled
        unit = (np.array([0, 0, 1, 2]), np.array([0, 0]), np.array([1.0, 1.0]))
        heavy = accumulated(grid, kernel, unit, 1, positions[row_of_ion == 1], row_of_ion[row_of_ion == 1], 1)[0]
        light = accumulated(grid, kernel, unit, 1, positions[row_of_ion == 2], row_of_ion[row_of_ion == 2] - 1, 1)[0]
    else:
        reference = dense_square if kernel == "square" else dense_sawtooth
        heavy, light = (reference(positions[row_of_ion == r], grid) for r in (1, 2))
    want = np.stack([scale * heavy + light, -1.5 * scale * heavy])
    assert np.abs(want).max() > 2.0**23
    np.testing.assert_allclose(runs[0], want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


def test_spilled_pools_give_the_unspilled_fields_bit_for_bit(monkeypatch):
    """With the pools' limit lowered to 16 weights every dense block spills many times (gaussian, molecular
    ions, three threads): the fields must be the very ones of the unspilled run."""
    table = random_ions(20_000, [0.0, 0.0, 0.0], [7.0, 9.0, 40.0], seed=12)
    grid = Grid.covering(np.zeros(3), [7.0, 9.0, 40.0], 1.0, kernel_reach("gaussian"))
    want = voxelize(table, ranges(), grid=grid, kernel="gaussian", threads=1)
    monkeypatch.setattr(transfer, "POOL_LIMIT", 16.0)
    got = voxelize(table, ranges(), grid=grid, kernel="gaussian", threads=3)
    for name in want.names:
        np.testing.assert_array_equal(got.counts[name].dense(), want.counts[name].dense(), err_msg=name)
