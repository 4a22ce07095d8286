"""Sweeps, batches and distributed voxelization on a 2-worker Dask LocalCluster, against sequential runs."""

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.io import read_ions, read_ranges
from apt_filters.pipeline import config as cfg
from apt_filters.pipeline.run import run_pipeline
from apt_filters.pipeline.staging import MARKER
from apt_filters.sweep import Choice, choice_grid, dask_client, match_objects, read_manifest, run_batch, run_sweep
from apt_filters.sweep.cluster import run_tasks
from apt_filters.sweep.rows import object_rows
from apt_filters.synth import preset, write_specimen
from apt_filters.voxel import voxelize
from apt_filters.voxel.distributed import voxelize_distributed


@pytest.fixture(scope="module")
def specimen(tmp_path_factory):
    out = tmp_path_factory.mktemp("specimen")
    write_specimen(out, preset("small"), seed=3, keep_ions=False)
    return out


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2, memory_budget=4 << 30) as c:
        yield c


@pytest.fixture(scope="module")
def base(specimen):
    # The sweep's machinery, not the pipeline's accuracy, is under test: the cheaper steps keep it fast. The maps
    # (a third of such a run's CPU, mostly their pictures) feed no row of a sweep.
    config = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.15)])
    config.input.ions, config.input.ranges = str(specimen / "specimen.pos"), str(specimen / "specimen.rrng")
    config.refine.enabled = False
    config.remesh.method = "none"
    config.analysis.audit = False
    config.analysis.maps = False
    return config


def test_choice_grid_is_the_product_and_refuses_repeats():
    grid = choice_grid(isos=[0.1, 0.2], voxels=[1.0, 0.8, 0.6], delocalizations=[(3, 3, 1.5)])
    assert len(grid) == 6 and {c.iso for c in grid} == {0.1, 0.2} and {c.voxel for c in grid} == {1.0, 0.8, 0.6}
    assert choice_grid() == [Choice()]
    with pytest.raises(AptFiltersError, match="twice"):
        choice_grid(voxels=[1.0, 1.0])
    with pytest.raises(AptFiltersError, match="three"):
        choice_grid(delocalizations=[(3, 3)])


def test_a_choice_is_checked_like_a_configuration(base):
    assert Choice(iso=0.2, voxel=0.5).apply(base).voxel.size == 0.5
    with pytest.raises(AptFiltersError, match="fraction"):
        Choice(iso=1.5).apply(base)
    with pytest.raises(AptFiltersError, match="kernel"):
        Choice(kernel="box").apply(base)


def test_objects_are_matched_by_overlap_not_index():
    a = [[0, 0, 0, 2, 2, 2], [10, 10, 10, 13, 13, 13]]
    # the same two objects listed the other way round and moved a little, one new, the first gone
    b = [[10.2, 10, 10, 13.1, 13, 13], [20, 20, 20, 21, 21, 21], [0.1, 0, 0, 2.1, 2, 2]]
    c = [[10, 10, 10.3, 13, 13, 13.2]]
    assert match_objects([a, b, c]) == [[0, 1], [1, 2, 0], [1]]
    assert match_objects([a, [[5, 5, 5, 6, 6, 6]]]) == [[0, 1], [2]], "no overlap: a new object"


def test_sweep_rows_equal_separate_runs(base, client, tmp_path):
    choices = choice_grid(isos=[0.15, 0.17], voxels=[1.0, 0.9])
    result = run_sweep(base, choices, tmp_path / "sweep", client=client, progress=False)
    assert [r["status"] for r in result.runs] == ["ok"] * 4, result.runs
    for choice in (choices[0], choices[3]):
        config = choice.apply(base)
        report = run_pipeline(config, tmp_path / f"alone{choice.iso}", quiet=True)
        alone = object_rows(report, tmp_path / f"alone{choice.iso}")
        swept = [r for r in result.rows if r["iso"] == choice.iso and r["voxel"] == choice.voxel]
        assert len(swept) == len(alone) > 0
        for s, a in zip(swept, alone):
            assert {k: s[k] for k in a} == a, "a sweep's row is the separate run's, to the last digit"
    # the cube and the sphere are found in every choice and tracked as the same two objects
    assert {r["object"] for r in result.rows} == {1, 2}
    volume = [s for s in result.spread if s["figure"] == "volume"]
    assert [s["found"] for s in volume] == [4, 4]
    assert all(s["sd"] > 0 and s["min"] <= s["mean"] <= s["max"] for s in volume)
    excess = [s for s in result.spread if s["figure"] == "excess_B"]
    assert excess and all(np.isfinite(s["counting_se"]) and s["counting_se"] > 0 for s in excess)
    out = tmp_path / "sweep"
    assert {p.name for p in out.iterdir()} == {MARKER, "sweep.csv", "sweep.json", "report.html", "spread.png"}
    doc = json.loads((out / "sweep.json").read_text(), parse_constant=lambda c: pytest.fail(f"JSON has {c}"))
    assert len(doc["rows"]) == len(result.rows)
    header = (out / "sweep.csv").read_text().splitlines()[0].split(",")
    assert header[:7] == ["iso", "voxel", "delocalization", "kernel", "surface", "label", "object"]
    assert {"volume", "volume_se", "area", "excess_B", "excess_B_se", "c_Al", "c_Al_se"} <= set(header)


def test_batch_isolates_a_failing_dataset(specimen, client, tmp_path):
    manifest = tmp_path / "batch.toml"
    broken = tmp_path / "broken.pos"
    broken.write_bytes(b"\0" * 17)  # not a whole number of 16-byte records
    manifest.write_text(f"""
[defaults]
species = "Al"
iso = 0.15
remesh = "none"
range = "{specimen / 'specimen.rrng'}"

[[dataset]]
name = "good"
input = "{specimen / 'specimen.pos'}"

[[dataset]]
name = "broken"
input = "broken.pos"

[[dataset]]
name = "wrong-iso"
input = "{specimen / 'specimen.pos'}"
iso = 1.5
""")
    datasets = read_manifest(manifest)
    assert [d.name for d in datasets] == ["good", "broken", "wrong-iso"]
    assert datasets[1].config["input"]["ions"] == str(broken), "paths are relative to the manifest"
    rows = run_batch(manifest, tmp_path / "out", client=client, progress=False)
    status = {r["dataset"]: r for r in rows}
    assert status["good"]["status"] == "ok" and status["good"]["Al15 objects"] == 2
    assert status["broken"]["status"] == "error" and "broken.pos" in status["broken"]["error"]
    assert "\n" not in status["broken"]["error"] and "Traceback" not in status["broken"]["error"]
    assert status["wrong-iso"]["status"] == "error" and "fraction" in status["wrong-iso"]["error"]
    assert (tmp_path / "out" / "runs" / "good" / "report.html").is_file()
    assert (tmp_path / "out" / "batch.csv").read_text().count("\n") == 4


def _dies_once(marker: str) -> str:
    if not os.path.exists(marker):
        Path(marker).write_text("died")
        os._exit(1)  # the worker process dies as if killed
    return f"ran in {os.getpid()}"


def test_a_task_whose_worker_dies_is_retried(client, tmp_path):
    [result] = run_tasks(client, _dies_once, [(str(tmp_path / "marker"),)], progress=False)
    assert result.startswith("ran in") and (tmp_path / "marker").read_text() == "died"


@pytest.mark.parametrize("kernel", ["gaussian", "sawtooth"])
def test_distributed_voxelization_equals_the_local_one(specimen, client, kernel):
    ions, ranges = read_ions(specimen / "specimen.pos"), read_ranges(specimen / "specimen.rrng")
    local = voxelize(ions, ranges, kernel=kernel, threads=1)
    dist = voxelize_distributed(specimen / "specimen.pos", ranges, client=client, kernel=kernel, share=70_000)
    assert dist.grid == local.grid and dist.n_counted == local.n_counted
    for name in local.names:
        assert np.array_equal(dist.counts[name].coords, local.counts[name].coords)
        scale = np.abs(local.counts[name].data).max()
        assert np.abs(dist.counts[name].data - local.counts[name].data).max() <= 1e-12 * scale
    assert np.abs(dist.total.data - local.total.data).max() <= 1e-12 * np.abs(local.total.data).max()


def test_dask_is_imported_only_by_sweeps_and_batches():
    import subprocess

    code = "import sys, apt_filters.pipeline.run, apt_filters.sweep, apt_filters.cli.main; print('distributed' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
