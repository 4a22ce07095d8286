"""``apt-filters audit``: wiring of the sub-command (the io readers are stood in until they merge)."""

import json

import numpy as np
import pytest

import apt_filters.io
from apt_filters.cli.main import main
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from tests.audit_helpers import relabel, synth_mz, synth_ranges


@pytest.fixture
def readers(monkeypatch):
    """Stand-ins for apt_filters.io.read_ions / read_ranges returning a mislabelled synthetic file."""
    ranges, index = relabel(synth_ranges(), 57.94, (("Fe", 1),))
    mz = synth_mz(31)
    monkeypatch.setattr(apt_filters.io, "read_ions", lambda path: IonTable(np.zeros((len(mz), 3), np.float32), mz,
                                                                           source=str(path)), raising=False)
    monkeypatch.setattr(apt_filters.io, "read_ranges", lambda path: RangeTable(ranges, source=str(path)),
                        raising=False)
    return index


def test_cli_prints_text_and_json(readers, capsys):
    assert main(["audit", "spec.pos", "--range", "spec.rrng"]) == 0
    text = capsys.readouterr().out
    assert "spec.rrng" in text and "spec.pos" in text and "ERROR" in text and "Ni+" in text
    assert main(["audit", "spec.pos", "-r", "spec.rrng", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [f["range"] for f in data["findings"] if f["severity"] != "info"] == [readers]


def test_cli_rejects_bad_resolution(readers, capsys):
    assert main(["audit", "spec.pos", "-r", "spec.rrng", "--resolution", "0"]) == 2
    assert "resolution must be positive" in capsys.readouterr().err
