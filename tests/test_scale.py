"""Scale: threaded chunk conversion, thread-independent voxelization, the active-cell crossing numbering,
memory-mapped ion tables and the run's memory budget."""

import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from apt_filters.contour.cells import find_active_cells, prepare_field, strides
from apt_filters.contour.tables import EDGE_AXIS, EDGE_START, case_table
from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.io import iter_ion_chunks, map_ions, read_ions
from apt_filters.io.writers import write_pos
from apt_filters.pipeline.config import PipelineConfig
from apt_filters.pipeline.run import load_ions
from apt_filters.voxel import Grid, check_budget, kernel_reach, voxelize
from apt_filters.voxel.transfer import second_pass, second_pass_blocks, second_pass_sigma
from tests.voxel_helpers import random_ions, ranges


@pytest.fixture
def pos_file(tmp_path):
    ions = random_ions(300_000, (0, 0, 0), (30, 30, 60), seed=4)
    return write_pos(tmp_path / "ions.pos", ions), ions


def test_threaded_chunks_equal_the_file(pos_file):
    path, ions = pos_file
    for threads in (1, 4):
        chunks = list(iter_ion_chunks(path, 100_000, threads=threads))
        assert np.array_equal(np.concatenate([c.positions for c in chunks]), ions.positions)
        assert np.array_equal(np.concatenate([c.mz for c in chunks]), ions.mz)


def test_threaded_chunks_name_the_non_finite_ion(tmp_path):
    ions = random_ions(300_000, (0, 0, 0), (30, 30, 60), seed=5)
    ions.positions[250_001, 1] = np.nan  # in the last of 4 conversion shares
    path = write_pos(tmp_path / "bad.pos", ions)
    with pytest.raises(InputError, match="ion 250001 has a non-finite"):
        list(iter_ion_chunks(path, 300_000, threads=4))


@pytest.mark.parametrize("kernel", ["square", "gaussian"])
def test_fields_do_not_depend_on_threads_or_chunking(pos_file, kernel):
    path, ions = pos_file
    lo, hi = ions.bounds()
    grid = Grid.covering(lo, hi, 1.0, kernel_reach(kernel))
    one = voxelize(ions, ranges(), grid=grid, kernel=kernel, threads=1)
    streamed = voxelize(iter_ion_chunks(path, 70_000, threads=3), ranges(), grid=grid, kernel=kernel, threads=1)
    many = voxelize(iter_ion_chunks(path, 70_000, threads=3), ranges(), grid=grid, kernel=kernel, threads=3)
    for name, field in one.counts.items():
        assert np.array_equal(streamed.counts[name].data, field.data)  # one pool: the same sums in the same order
        assert np.array_equal(many.counts[name].coords, field.coords)
        # three pools merged: only the rounding of the merge differs
        assert np.abs(many.counts[name].data - field.data).max() <= 1e-12 * field.data.max()


def test_second_pass_is_the_same_on_any_number_of_threads():
    grid = Grid((0.0, 0.0, 0.0), 1.0, (61, 45, 37))
    rng = np.random.default_rng(2)
    coords = np.argwhere(rng.random(grid.block_shape) < 0.4).astype(np.int32)
    sigma = second_pass_sigma(1.0, (3.0, 3.0, 1.5))
    coords = second_pass_blocks(grid, coords, sigma)
    start = [rng.random((len(coords), 8, 8, 8)) for _ in range(2)]
    results = []
    for threads in (1, 3, 8):
        channels = [c.copy() for c in start]
        second_pass(grid, coords, channels, sigma, threads)
        results.append(channels)
    for other in results[1:]:
        assert all(np.array_equal(a, b) for a, b in zip(results[0], other))


def test_crossings_are_numbered_like_the_sorted_unique_edges():
    """Each crossed cube edge gets the rank of its (start point, axis) among the distinct crossed
    grid edges of the kept cells: checked against np.unique on a noise field with a mask."""
    rng = np.random.default_rng(7)
    values = gaussian_filter(rng.standard_normal((33, 29, 41)), 1.0)
    mask = rng.random(values.shape) > 0.03
    field = prepare_field(values, 0.05, 1.0, 0.0, mask, False)
    act = find_active_cells(field)
    shape = values.shape
    crossed = case_table().crossed[act.key // 64]
    rows, edges = np.nonzero(crossed)
    key = (act.cell[rows] + (EDGE_START @ strides(shape))[edges]) * 3 + EDGE_AXIS[edges]
    unique, inverse = np.unique(key, return_inverse=True)
    assert np.array_equal(act.edge_crossing[rows, edges], inverse)
    assert np.array_equal(act.edge_crossing[~crossed], np.full((~crossed).sum(), -1))
    assert np.array_equal(act.crossing_start * 3 + act.crossing_axis, unique)
    v0 = values.reshape(-1)[act.crossing_start]
    v1 = values.reshape(-1)[act.crossing_start + strides(shape)[act.crossing_axis]]
    assert np.allclose(v0 + act.crossing_t * (v1 - v0), 0.05, atol=1e-12)


def test_map_ions_is_the_file_without_holding_it(pos_file, tmp_path):
    path, ions = pos_file
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    mapped = map_ions(path, scratch)
    assert isinstance(mapped.positions, np.memmap) and isinstance(mapped.mz, np.memmap)
    assert np.array_equal(mapped.positions, ions.positions) and np.array_equal(mapped.mz, ions.mz)
    lo, hi = ions.bounds()
    grid = Grid.covering(lo, hi, 1.0, kernel_reach("gaussian"))
    a = voxelize(mapped, ranges(), grid=grid, threads=1)
    b = voxelize(read_ions(path), ranges(), grid=grid, threads=1)
    assert all(np.array_equal(a.counts[n].data, b.counts[n].data) for n in a.counts)


def _config(path, budget_gb: float) -> PipelineConfig:
    config = PipelineConfig()
    config.input.ions, config.input.memory_budget = str(path), budget_gb
    return config


def test_the_run_maps_the_ions_when_they_do_not_fit_and_refuses_when_the_fields_cannot(pos_file, tmp_path):
    from apt_filters.io.summary import summarize

    path, ions = pos_file
    summary = summarize(str(path), ranges())
    grid = Grid.covering(summary.lower, summary.upper, 1.0, kernel_reach("gaussian"))
    fields_gb = check_budget(grid, len(ranges().elements), None) / 1e9
    table_gb = len(ions) * 16 / 1e9
    in_memory = load_ions(_config(path, fields_gb + 1.01 * table_gb), ranges(), summary, tmp_path)
    assert not isinstance(in_memory.mz, np.memmap)
    mapped = load_ions(_config(path, fields_gb + 0.99 * table_gb), ranges(), summary, tmp_path)
    assert isinstance(mapped.mz, np.memmap) and np.array_equal(mapped.positions, ions.positions)
    with pytest.raises(AptFiltersError, match="over the memory budget"):
        load_ions(_config(path, 0.99 * fields_gb), ranges(), summary, tmp_path)
    with pytest.raises(AptFiltersError, match="memory budget must be a positive"):
        load_ions(_config(path, -1.0), ranges(), summary, tmp_path)


def test_marching_cubes_does_not_depend_on_the_thread_count(monkeypatch):
    """Triangles, loop centres and vertex positions are written by ranges of cells on threads, each
    starting where the previous range ends: the mesh is the same for 1, 2 and 3 ranges."""
    import importlib

    mc = importlib.import_module("apt_filters.contour.marching_cubes")  # the module, not the function
    values = gaussian_filter(np.random.default_rng(11).standard_normal((72, 80, 88)), 1.5)
    meshes = []
    for cores in (1, 2, 3):
        monkeypatch.setattr(mc, "available_cores", lambda cores=cores: cores)
        meshes.append(mc.marching_cubes(values, 0.0, spacing=(0.5, 1.0, 2.0), origin=(1.0, 2.0, 3.0)))
    assert len(find_active_cells(prepare_field(values, 0.0, 1.0, 0.0, None, False)).cell) >= 3 * 65536  # 3 ranges
    for other in meshes[1:]:
        assert np.array_equal(other.vertices, meshes[0].vertices) and np.array_equal(other.faces, meshes[0].faces)
        assert np.array_equal(other.vertex_scalars["value"], meshes[0].vertex_scalars["value"])
        assert np.array_equal(other.face_scalars["component"], meshes[0].face_scalars["component"])


def test_items_on_threads_come_back_in_order():
    import time

    from apt_filters.core.threads import per_item

    # the later items finish first: each result still lands where its item was
    def slow_square(i):
        time.sleep(0.01 * (6 - i))
        return i * i

    assert per_item(slow_square, list(range(6))) == [i * i for i in range(6)]
    assert per_item(slow_square, [3]) == [9] and per_item(slow_square, []) == []


def test_parallel_kernels_on_threads_survive_numba_workqueue_layer():
    # numba's fallback threading layer (no libgomp, no tbb) aborts the process when two threads launch parallel
    # kernels at once; per_item and on_threads must then run their items one after the other
    script = """
import numpy as np
from numba import njit, prange
from apt_filters.core.threads import kernels_share_threads, on_threads, per_item

@njit(parallel=True)
def total(values):
    out = 0.0
    for i in prange(len(values)):
        out += values[i]
    return out

values = np.ones(200_000)
print(sum(per_item(lambda _: total(values), list(range(8)))), sum(on_threads(total, [(values,)] * 4)),
      kernels_share_threads())
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "NUMBA_THREADING_LAYER": "workqueue"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["1600000.0", "800000.0", "False"]
