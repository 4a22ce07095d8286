import os
import pathlib
import signal

import numpy as np
import pytest

from apt_filters.core import AptFiltersError, atomic
from apt_filters.pipeline.run import scratch_folder
from apt_filters.pipeline import config as cfg
from apt_filters.pipeline.staging import CLAIM_SUFFIX, MARKER, staged_folder
from apt_filters.pipeline.steps import StepLog


def test_config_round_trips_through_toml(tmp_path):
    c = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.15), cfg.SurfaceConfig("", 40.0)])
    c.voxel.exclude = ["B"]
    path = tmp_path / "c.toml"
    path.write_text(c.to_toml())
    assert cfg.load(path) == c


def test_config_with_non_bmp_paths_and_quotes_round_trips(tmp_path):
    """Paths with emoji (outside the Basic Multilingual Plane), quotes, backslashes and newlines reload as written."""
    c = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.15)])
    c.input.ions = 'data/😀 run "1"\\tip\n.pos'
    c.input.ranges = "𝔘nicode ranges 🧪.rrng"
    c.proxigram.solutes = ["B", "Cr"]
    path = tmp_path / "c.toml"
    path.write_text(c.to_toml(), encoding="utf-8")
    loaded = cfg.load(path)  # relative input paths are relative to the configuration file's folder
    assert (loaded.input.ions, loaded.input.ranges) == (str(tmp_path / c.input.ions), str(tmp_path / c.input.ranges))
    loaded.input.ions, loaded.input.ranges = c.input.ions, c.input.ranges
    assert loaded == c


@pytest.mark.parametrize("text, problem", [
    ("[voxel]\nsize = 'big'\n", "size = 'big' should be float"),
    ("[voxel]\nkernel = 'cubic'\n", "kernel must be one of gaussian, sawtooth, square"),
    ("[voxle]\nsize = 1\n", "unknown section(s): voxle"),
    ("[refine]\niterations = 2.5\n", "should be int"),
    ("[proxigram]\nbins = 0.1\n", "unknown key(s) in [proxigram]: bins"),
    ("[voxel\n", "not valid TOML"),
])
def test_config_mistakes_are_one_line_naming_the_file(tmp_path, text, problem):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(AptFiltersError) as info:
        cfg.load(path)
    msg = str(info.value)
    assert msg.startswith(str(path)) and problem in msg and "\n" not in msg


def test_int_where_float_expected_is_accepted():
    c = cfg.from_dict(cfg.tomllib.loads("[voxel]\nsize = 2\n"))
    assert c.voxel.size == 2.0 and isinstance(c.voxel.size, float)


def test_staged_folder_appears_whole_or_not_at_all(tmp_path):
    target = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with staged_folder(target) as stage:
            (stage / "half.json").write_text("{")
            raise RuntimeError("crash")
    assert list(tmp_path.iterdir()) == []
    with staged_folder(target) as stage:
        (stage / "report.json").write_text("{}")
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "report.json"]
    with pytest.raises(AptFiltersError, match="not empty"):
        with staged_folder(target):
            pass
    with staged_folder(target, force=True) as stage:
        (stage / "new.json").write_text("{}")
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "new.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def _signalled_after(monkeypatch, owner, name, made):
    """Make ``owner.name`` send this process SIGTERM right after each call that ``made(args)`` says created
    a temporary path: the moment a signal is most likely to leave one behind."""
    monkeypatch.setattr(atomic, "_received", [])  # the handler records signals; none may reach later tests
    old = signal.signal(signal.SIGTERM, atomic.raise_on_signal)
    original = getattr(owner, name)

    def call(*args, **kwargs):
        result = original(*args, **kwargs)
        if made(args):
            signal.raise_signal(signal.SIGTERM)
        return result

    monkeypatch.setattr(owner, name, call)
    return old


@pytest.mark.parametrize("where", ["scratch folder", "atomic file", "claim"])
def test_a_signal_right_after_a_temporary_path_is_made_still_removes_it(tmp_path, monkeypatch, where):
    """Was: the scratch folder, the atomic file's temporary and the claim were made before the ``try`` that removes
    them, so a SIGTERM in between left ``.out.apt-filters-tmp.*`` behind (seen once in CI's interrupted-run test)."""
    target = tmp_path / "out"
    if where == "scratch folder":
        old = _signalled_after(monkeypatch, pathlib.Path, "mkdir", lambda a: atomic.TMP_TAG in a[0].name)
        block = scratch_folder(target)
    elif where == "atomic file":
        old = _signalled_after(monkeypatch, os, "open", lambda a: atomic.TMP_TAG in str(a[0]))
        block = atomic.atomic_output(target)
    else:
        old = _signalled_after(monkeypatch, pathlib.Path, "rename", lambda a: str(a[1]).endswith(CLAIM_SUFFIX))
        block = staged_folder(target)
    try:
        with pytest.raises(atomic.Interrupted):
            with block:
                pass
    finally:
        signal.signal(signal.SIGTERM, old)
    assert list(tmp_path.iterdir()) == []


def test_step_log_measures_peak_memory_of_each_step():
    log = StepLog(quiet=True)
    with log.step("big"):
        block = np.ones(40_000_000)  # 320 MB, touched
        del block
    with log.step("small"):
        np.ones(10)
    big, small = log.records
    assert big.peak_bytes - small.peak_bytes > 250e6
