"""``apt-filters info``: in-process runs on the real Si data and one subprocess run on a bad file."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from apt_filters.cli.main import main
from apt_filters.io import read_ions, read_ranges

ROOT = Path(__file__).resolve().parents[1]


def test_info_text_on_real_data(real_si, capsys):
    assert main(["info", str(real_si / "Si.pos"), "--range", str(real_si / "Si.RRNG")]) == 0
    out = capsys.readouterr().out
    assert "945,211 ions" in out
    assert "POS" in out and "25 ranges" in out and "92.78 %" in out
    for el in ("Si", "Cr", "O", "C", "Cu"):
        assert f"\n    {el:<3} " in out


def test_info_json_matches_whole_file_ranging(real_si, capsys):
    assert main(["info", str(real_si / "Si.apt"), "-r", str(real_si / "Si.RNG"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["ions"] == 945_211 and info["format"] == "apt6" and info["ranges"] == 25
    ions, ranges = read_ions(real_si / "Si.pos"), read_ranges(real_si / "Si.RRNG")
    np.testing.assert_allclose(info["bounds_nm"]["lower"], ions.positions.min(axis=0))
    np.testing.assert_allclose(info["mz_da"], [ions.mz.min(), ions.mz.max()])
    idx = ranges.ion_index(ions.mz)
    assert info["ranged_ions"] == int((idx >= 0).sum())
    counts = {name: int((idx == k).sum()) for k, name in enumerate(ranges.ions)}
    assert info["ion_counts"] == counts
    # molecular ions are counted by their atoms: O from O, CrO, CrO2 (2 O) and Cr2O
    assert info["atoms"]["O"] == counts["O"] + counts["CrO"] + 2 * counts["CrO2"] + counts["Cr2O"]
    assert info["atoms"]["Cr"] == counts["Cr"] + counts["CrO"] + counts["CrO2"] + 2 * counts["Cr2O"]
    assert abs(sum(info["composition"].values()) - 1) < 1e-12
    total = sum(info["atoms"].values())
    assert abs(info["composition"]["Si"] - info["atoms"]["Si"] / total) < 1e-12


def test_info_without_ranges(real_si, capsys):
    assert main(["info", str(real_si / "Si.epos"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["ions"] == 945_211 and "composition" not in info


def test_info_bad_range_file_is_one_line(tmp_path, real_si, capsys):
    bad = tmp_path / "bad.rrng"
    bad.write_text("[Ranges]\nNumber=1\nRange1=1 2 Qq:1\n")
    assert main(["info", str(real_si / "Si.pos"), "--range", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err == f"apt-filters info: error: {bad}: line 3: unknown element 'Qq'\n"


def test_info_subprocess_bad_file_exits_2_without_traceback(tmp_path):
    bad = tmp_path / "broken.pos"
    bad.write_bytes(b"\0" * 17)
    proc = subprocess.run([sys.executable, "-m", "apt_filters", "info", str(bad)],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert lines[0].startswith(f"apt-filters info: error: {bad}: size 17 bytes")
