"""Shared test fixtures: the real data in ../shared (relative to the repository root)."""

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
