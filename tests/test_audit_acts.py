"""The audit acts: the Si data's "Cr2O" range (really Ni+) relabelled by --relabel and by the
corrected range file that ``audit --write-ranges`` writes; the run and its report say so."""

from __future__ import annotations

import json

import pytest

from apt_filters.cli.main import main
from apt_filters.io import read_ions, read_ranges
from apt_filters.io.writers import write_pos
from apt_filters.pipeline.config import load as load_config

RUN = ["--species", "Ni", "--iso", "0.3", "--remesh", "none", "--no-cross-fit", "--no-mode-selection", "-q"]


@pytest.fixture(scope="module")
def si_sample(real_si, tmp_path_factory):
    """Every 10th ion of Si.pos (94,522 ions: the same spectrum, a tenth of the counts)."""
    path = tmp_path_factory.mktemp("si") / "si10.pos"
    write_pos(path, read_ions(real_si / "Si.pos").subset(slice(None, None, 10)))
    return path


def _ni_share(report: dict) -> float:
    return report["composition"].get("Ni", 0.0)


def test_written_range_file_relabels_cr2o_as_ni(si_sample, real_si, tmp_path, capsys):
    fixed = tmp_path / "fixed.rrng"
    assert main(["audit", str(si_sample), "-r", str(real_si / "Si.RRNG"), "--write-ranges", str(fixed)]) == 0
    assert "corrected range file" in capsys.readouterr().out
    text = fixed.read_text()
    assert "; Cr2O [57.819, 61.159] Da relabelled Ni: 100% of its ions fit Ni+ (mislabelled)" in text
    assert "NOT applied" in text and "fits Ni+: Range" in text  # uncovered Ni+ peaks proposed, as comments
    table = read_ranges(fixed)
    cr2o = [r for r in table.ranges if (r.lower, r.upper) == (57.819, 61.159)]
    assert [r.ion for r in cr2o] == ["Ni"] and len(table) == 25
    assert main(["audit", str(si_sample), "-r", str(real_si / "Si.RRNG"), "--write-ranges", str(fixed)]) == 2
    assert "exists" in capsys.readouterr().err  # never replaced unasked

    out = tmp_path / "run"
    assert main(["run", str(si_sample), "-r", str(fixed), "-o", str(out), *RUN]) == 0
    report = json.loads((out / "report.json").read_text())
    assert 0.12 < _ni_share(report) < 0.15  # Ni+ and Ni++ ranges: 13 at.% of the ranged atoms
    assert not any("57.819" in f["message"] for f in report["audit"]), "the Ni range now fits its label"


def test_relabel_on_the_command_line(si_sample, real_si, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", str(si_sample), "-r", str(real_si / "Si.RRNG"), "--relabel", "Cr2O=Ni",
                 "-o", str(out), *RUN[:-1]]) == 0
    printed = "".join(capsys.readouterr())  # step lines go to stderr
    assert "ERROR   Si [28.826, 29.255] Da" in printed, "audit errors are named in words without --verbose"
    report = json.loads((out / "report.json").read_text())
    assert 0.09 < _ni_share(report) < 0.11 and "Cr2O" not in json.dumps(report["composition"])
    [note] = [n for n in report["range_file"] if n["kind"] == "relabel"]
    assert note["message"].startswith("Cr2O relabelled Ni ([input] relabel, --relabel): 1 range(s), [57.819, 61.159]")
    assert load_config(out / "config.toml").input.relabel == ["Cr2O=Ni"], "the relabel is recorded for --config"
    assert "Cr2O relabelled Ni" in (out / "report.html").read_text()
    assert not any("57.819" in f["message"] for f in report["audit"])


def test_relabel_mistakes_are_one_line(si_sample, real_si, capsys):
    assert main(["info", str(si_sample), "-r", str(real_si / "Si.RRNG"), "--relabel", "Fe=Ni"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no range is labelled 'Fe'" in err[0]
    assert main(["info", str(si_sample), "--relabel", "Cr2O=Ni"]) == 2
    assert "--relabel needs a range file" in capsys.readouterr().err
