"""Shared test fixtures: the real data in ../shared (relative to the repository root)."""

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
REAL_SI = SHARED / "data" / "real" / "apav-si"
DIALECTS = SHARED / "data" / "rangefile-dialects" / "3depict-tests"


@pytest.fixture(scope="session")
def real_si() -> Path:
    """Folder with Si.pos, Si.epos, Si.apt, Si.RRNG, Si.RNG (945,211 ions)."""
    if not REAL_SI.is_dir():
        pytest.fail(f"real data missing: {REAL_SI} (CI provides ../shared beside the repository)")
    return REAL_SI


@pytest.fixture(scope="session")
def dialects() -> Path:
    """Folder of deliberately odd range files from 3Depict's test suite."""
    if not DIALECTS.is_dir():
        pytest.fail(f"range-file dialects missing: {DIALECTS}")
    return DIALECTS


@pytest.fixture(scope="session")
def si_run(real_si, tmp_path_factory) -> tuple[Path, dict]:
    """``apt-filters run`` on the Si data with every default (Cr 30 at.% surface): output folder and report.json,
    run once for the tests that read it."""
    from apt_filters.cli.main import main

    out = tmp_path_factory.mktemp("si") / "si"
    assert main(["run", str(real_si / "Si.pos"), "-r", str(real_si / "Si.RRNG"), "-o", str(out),
                 "--species", "Cr", "--iso", "0.3", "-q"]) == 0
    return out, json.loads((out / "report.json").read_text())
