"""``apt-filters audit``: the sub-command on written files and on the real Si data."""

import json

import numpy as np
import pytest

from apt_filters.cli.main import main
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.io.writers import write_pos, write_rrng
from tests.audit_helpers import relabel, synth_mz, synth_ranges


@pytest.fixture
def readers(tmp_path, monkeypatch):
    """A mislabelled synthetic spectrum written as spec.pos + spec.rrng; returns the bad range's index."""
    ranges, index = relabel(synth_ranges(), 57.94, (("Fe", 1),))
    mz = synth_mz(31)
    write_pos(tmp_path / "spec.pos", IonTable(np.zeros((len(mz), 3), np.float32), mz))
    write_rrng(tmp_path / "spec.rrng", RangeTable(ranges))
    monkeypatch.chdir(tmp_path)
    return index


def test_cli_prints_text_and_json(readers, capsys):
    assert main(["audit", "spec.pos", "--range", "spec.rrng"]) == 0
    text = capsys.readouterr().out
    assert "spec.rrng" in text and "spec.pos" in text and "ERROR" in text and "Ni+" in text
    assert main(["audit", "spec.pos", "-r", "spec.rrng", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [f["range"] for f in data["findings"] if f["severity"] != "info"] == [readers]


def test_cli_rejects_bad_resolution(readers, capsys):
    with pytest.raises(SystemExit) as exit_:  # refused by the parser, before any file is read
        main(["audit", "spec.pos", "-r", "spec.rrng", "--resolution", "0"])
    assert exit_.value.code == 2
    assert "argument --resolution: 0 is outside [1, 1e6]" in capsys.readouterr().err


def test_cli_on_the_real_si_data(real_si, capsys):
    assert main(["audit", str(real_si / "Si.pos"), "--range", str(real_si / "Si.RRNG"), "--json"]) == 0
    findings = json.loads(capsys.readouterr().out)["findings"]
    by_lower = {}
    for f in findings:
        if f.get("range") is not None and f["severity"] == "error":
            by_lower.setdefault(round(f["lower"], 3) if "lower" in f else None, []).append(f)
    cr2o = [f for f in findings if f["severity"] == "error" and "57.819" in f["message"]]
    assert cr2o and cr2o[0]["figures"]["best_fit"] == "Ni+"
    for lower in ("28.826", "29.783"):
        hits = [f for f in findings if f["severity"] == "error" and lower in f["message"]]
        assert hits and hits[0]["figures"]["foreign_species"] == "Ni++"
