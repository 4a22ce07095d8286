"""Replay bounded: hostile ``.mlx`` scripts are refused in one line before MeshLab sees them.

Each case is one the adversarial run found (old behaviour in the docstring); the hypothesis
test is a small version of the campaign in ``benchmarks/fuzz_replay.py``.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings

from apt_filters.cli.main import main
from apt_filters.core.atomic import TMP_TAG, host_tag
from apt_filters.core.errors import AptFiltersError
from apt_filters.meshlab import mlx
from apt_filters.meshlab.chains import apply_chain
from apt_filters.meshlab.exports import write_ply
from tests.meshlab_shapes import sphere
from tests.mlx_scripts import scripts

HEAD = "<!DOCTYPE FilterScript>\n<FilterScript>\n"


def taubin(lam="0.5", mu="-0.53", steps="10", extra="") -> str:
    return (' <filter name="Taubin Smooth">\n'
            f'  <Param name="lambda" value="{lam}" type="RichFloat"/>\n'
            f'  <Param name="mu" value="{mu}" type="RichFloat"/>\n'
            f'  <Param name="stepSmoothNum" value="{steps}" type="RichInt"/>\n{extra} </filter>\n')


@pytest.fixture(scope="module")
def mesh(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("mesh") / "in.ply"
    write_ply(sphere(5.0, subdiv=3), path)  # 1,280 faces
    return path


NESTED = ' <filter name="Taubin Smooth">\n  <Param name="lambda" value="0.5" type="RichFloat">' \
         + "<a>" * 50_000 + "</a>" * 50_000 + "</Param>\n </filter>\n"


@pytest.mark.parametrize("body, problem", [
    (NESTED, "holds nested elements"),                                     # was: MeshLab's loader segfaulted
    (taubin(steps="1e9"), "stepSmoothNum='1e9' is not a whole number"),    # was: ran past a minute
    (taubin(steps="1000000000"), "outside [0, 1000]"),
    (taubin(extra='  <Param name="stepSmoothNum" value="20" type="RichInt"/>\n'), "given twice"),  # was: last won
    (taubin() * 1557, "1557 filters"),                                     # was: ran past a minute
    (taubin(steps="1000") * 11, "11,000 smoothing steps"),
    (taubin(steps="abc"), "not a whole number"),                           # was: MeshLab's default, silently
    (taubin(lam="nan"), "lambda='nan' is outside (0, 1]"),                 # was: an empty mesh and exit 0
    (taubin(lam="inf"), "is outside"),
    (taubin(mu="0.5"), "mu='0.5' is outside [-1, 0)"),
    (taubin().replace('type="RichInt"', 'type="RichFloat"'), "has type 'RichFloat'"),
    (taubin().replace('"stepSmoothNum"', '"stepsmoothnum"'), "MeshLab spells it stepSmoothNum"),
    (taubin().replace('type="RichInt"', 'type="RichInt" min="nan"'), "not a finite number"),
    (' <filter name="Repair non Manifold Edges">\n  <Param name="method" value="7" type="RichEnum"/>\n </filter>\n',
     "outside [0, 1]"),
    (' <filter name="Close Holes">\n  <Param name="Selected" value="yes" type="RichBool"/>\n </filter>\n',
     "not true or false"),
])
def test_hostile_scripts_are_refused_in_one_line(mesh, tmp_path, capsys, body, problem):
    script = tmp_path / "s.mlx"
    script.write_text(HEAD + body + "</FilterScript>\n")
    start = time.perf_counter()
    assert main(["replay", str(script), str(mesh), "-o", str(tmp_path / "out.ply")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and problem in err and "s.mlx" in err, err
    assert time.perf_counter() - start < 10
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.mlx"]


def test_the_work_on_the_mesh_is_estimated_before_running(mesh, tmp_path, monkeypatch):
    script = tmp_path / "s.mlx"
    script.write_text(HEAD + taubin(steps="1000") * 2 + "</FilterScript>\n")
    assert mlx.script_work(mlx.parse_script(script.read_bytes()), 1280) == 2000 * 1280
    monkeypatch.setattr(mlx, "MAX_WORK", 2000 * 1280 - 1)
    with pytest.raises(AptFiltersError, match=r"~2\.6e\+06 face visits on this mesh of 1,280 faces"):
        mlx.replay_file(script, mesh, tmp_path / "out.ply")
    monkeypatch.setattr(mlx, "MAX_WORK", 2000 * 1280)
    mlx.replay_file(script, mesh, tmp_path / "out.ply")


def test_written_scripts_have_one_attribute_order(tmp_path):
    """Was: MeshLab wrote a <Param>'s attributes in a per-process hash order, so reruns differed."""
    apply_chain(sphere(5.0, subdiv=3), "clean", tmp_path / "c.mlx")
    data = (tmp_path / "c.mlx").read_bytes()
    params = re.findall(rb"<Param ([^>]*)/>", data)
    assert params and all(p.startswith(b'name="') and b' value="' in p.split(b" type=")[0] for p in params)
    assert mlx.canonical_script(data) == data
    assert mlx.parse_script(data)  # still a script we replay


def test_a_killed_replay_leaves_nothing_a_later_one_does_not_tidy(mesh, tmp_path):
    """Was: killed replays left /tmp/apt-filters-mlx-* folders. The checked copy now lives beside the output,
    named after its process, and the next replay there removes it once that process is gone."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    leftover = tmp_path / f".s.mlx.{TMP_TAG}.{host_tag()}-{dead.pid}.0123abcd.mlx"
    leftover.write_text("<FilterScript/>")
    script = tmp_path / "s.mlx"
    script.write_text(HEAD + taubin() + "</FilterScript>\n")
    mlx.replay_file(script, mesh, tmp_path / "out.ply")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.ply", "s.mlx"]


@settings(max_examples=40, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                 HealthCheck.data_too_large])
@given(data=scripts())
def test_fuzzed_scripts_replay_or_are_refused_quickly(mesh, tmp_path, data):
    script = tmp_path / "f.mlx"
    script.write_bytes(data)
    start = time.perf_counter()
    try:
        mlx.replay_file(script, mesh, tmp_path / "out.ply", overwrite=True)
    except AptFiltersError as exc:
        assert "\n" not in str(exc) and len(str(exc)) < 2500
    assert time.perf_counter() - start < 10
