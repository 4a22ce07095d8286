"""``apt-filters synth`` and ``apt-filters demo`` (demo on the small preset, to stay fast)."""

import dataclasses
import json

import pytest

from apt_filters.cli.main import main
from apt_filters.synth import presets


def test_synth_writes_a_specimen_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["synth", str(out), "--preset", "small", "--seed", "4"]) == 0
    text = capsys.readouterr().out
    assert "specimen 'small' (seed 4)" in text and "cube 6 nm" in text and "excess B" in text
    truth = json.loads((out / "truth.json").read_text())
    assert truth["seed"] == 4 and truth["ions"]["total"] * 16 == (out / "specimen.pos").stat().st_size
    assert main(["synth", str(out), "--preset", "small"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not empty" in err
    assert main(["synth", str(out), "--preset", "small", "--seed", "5", "--force"]) == 0
    assert json.loads((out / "truth.json").read_text())["seed"] == 5


def test_synth_ions_resizes_the_specimen(tmp_path, capsys):
    assert main(["synth", str(tmp_path), "--preset", "small", "--ions", "3.2e5"]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["ions"]["expected"] == pytest.approx(3.2e5, rel=1e-6)
    assert truth["geometry"]["size"][2] > 28.0
    assert main(["synth", str(tmp_path / "x"), "--preset", "small", "--ions", "1000"]) == 2
    assert "too few" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["synth", str(tmp_path / "y"), "--ions", "lots"])


def test_demo_runs_the_pipeline_then_reuses_the_specimen(tmp_path, capsys, monkeypatch):
    from apt_filters.cli.demo import demo_specimen

    monkeypatch.setitem(presets.PRESETS, "default", lambda: dataclasses.replace(presets.small(), name="default"))
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--quiet"]) == 0
    first = capsys.readouterr().out
    assert "ions" in first and "bounding box" in first and "wrote" in first
    assert "volume/true" in first and "cube 6 nm" in first and "sphere 3 nm" in first
    # the B excess the ions hold (their count against the true surface and plateaus) beside the measured one:
    # within 4 Poisson sd of the model's (~240 excess B ions of a 3 nm sphere: 6.5 % each)
    held = [float(line.split()[-1]) for line in first.splitlines() if line.startswith(("cube 6 nm", "sphere 3 nm"))]
    assert len(held) == 2 and all(abs(h - 1) < 0.26 for h in held), held
    assert (out / "run" / "report.html").is_file() and (out / "run" / "meshes" / "Al15.ply").is_file()
    # B, left out of the basis, marks both precipitates' interfaces (refine.marker): reported per object
    mark = json.loads((out / "run" / "report.json").read_text())["surfaces"][0]["mesh"]["refine"]["marker"]
    assert mark["species"] == "B" and mark["objects_moved"] >= 2 and abs(mark["layer_offset_nm"]) < 0.1
    pos = (out / "specimen" / "specimen.pos").read_bytes()
    assert demo_specimen(out / "specimen")[1], "the same seed reuses the specimen"
    assert (out / "specimen" / "specimen.pos").read_bytes() == pos
    assert main(["demo", "--out", str(out), "--seed", "1"]) == 2
    assert "another specimen" in capsys.readouterr().err


def test_help_texts(capsys):
    for command in ("synth", "demo"):
        with pytest.raises(SystemExit) as exc:
            main([command, "--help"])
        assert exc.value.code == 0
        assert "true" in capsys.readouterr().out
