"""ATO (LAWATAP / GPM Rouen) versions 3 and 5: synthetic files written from the documented byte
layout (docs/io.md), read back whole, in chunks, and refused when malformed."""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.cli.main import main
from apt_filters.core.errors import InputError
from apt_filters.io import iter_ion_chunks, read_ions
from apt_filters.io.ato import ATO3_EXTRA

V3 = np.dtype([("xyz", "<f4", 3), ("mz", "<f4")] + [(name, "<f4") for name in ATO3_EXTRA])
V5 = np.dtype([("x", "<i2"), ("y", "<i2"), ("z", "<f4"), ("mz", "<f4"), ("rest", "V28")])


def _specimen(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-40, 40, (n, 3)).astype(np.float32)  # nm
    xyz[:, 2] = rng.uniform(-300, 0, n)
    return xyz, rng.uniform(0.5, 200, n).astype(np.float32)


def write_ato(path, xyz: np.ndarray, mz: np.ndarray, version: int) -> None:
    """An ATO file as the public description lays it out: a header whose second uint32 is the version."""
    header = np.zeros(2 if version == 3 else 1250, dtype="<u4")  # 8 or 5000 bytes
    header[1] = version
    if version == 3:
        rec = np.zeros(len(mz), dtype=V3)
        rec["xyz"] = xyz * 10  # Å
        rec["mz"] = mz
        rec["pulse"] = np.arange(len(mz))
    else:
        rec = np.zeros(len(mz), dtype=V5)
        rec["x"], rec["y"] = np.round(xyz[:, 0] * 100), np.round(xyz[:, 1] * 100)  # 0.01 nm
        rec["z"] = xyz[:, 2] * 10  # Å
        rec["mz"] = mz
    path.write_bytes(header.tobytes() + rec.tobytes())


@pytest.mark.parametrize("version, tolerance", [(3, 1e-5), (5, 0.005)])
def test_round_trip(tmp_path, version, tolerance):
    xyz, mz = _specimen(10_001)
    path = tmp_path / "s.ATO"
    write_ato(path, xyz, mz, version)
    ions = read_ions(path)
    assert len(ions) == 10_001 and ions.positions.dtype == np.float32
    np.testing.assert_allclose(ions.positions, xyz, atol=tolerance, rtol=1e-6)  # v5 x, y: 0.01 nm steps
    np.testing.assert_array_equal(ions.mz, mz)
    if version == 3:
        assert set(ions.extra) == set(ATO3_EXTRA)
        np.testing.assert_array_equal(ions.extra["pulse"], np.arange(10_001, dtype=np.float32))
    chunks = list(iter_ion_chunks(path, chunk_size=4096))
    assert [len(c) for c in chunks] == [4096, 4096, 1809]
    np.testing.assert_array_equal(np.concatenate([c.positions for c in chunks]), ions.positions)
    np.testing.assert_array_equal(np.concatenate([c.mz for c in chunks]), mz)


def test_info_reads_ato(tmp_path, capsys):
    xyz, mz = _specimen(500)
    write_ato(tmp_path / "s.ato", xyz, mz, 3)
    assert main(["info", str(tmp_path / "s.ato")]) == 0
    assert "ATO (LAWATAP / GPM Rouen), 500 ions" in capsys.readouterr().out


@pytest.mark.parametrize("edit, fragment", [
    (lambda b: b[:4] + (4).to_bytes(4, "little") + b[8:], "ATO version 4 is not supported (versions 3 and 5 are)"),
    (lambda b: b[:-3], "is not a 8-byte ATO v3 header and whole 56-byte records (99 records and 53 bytes left over)"),
    (lambda b: b[:8], "ATO v3 file holds no ions"),
    (lambda b: b[:5], "too small for an ATO header"),
])
def test_malformed(tmp_path, edit, fragment):
    xyz, mz = _specimen(100)
    good = tmp_path / "good.ato"
    write_ato(good, xyz, mz, 3)
    bad = tmp_path / "bad.ato"
    bad.write_bytes(edit(good.read_bytes()))
    with pytest.raises(InputError) as err:
        read_ions(bad)
    assert str(err.value).startswith(f"{bad}: ") and fragment in str(err.value)


def test_non_finite_values_are_refused(tmp_path):
    xyz, mz = _specimen(100)
    mz[37] = np.nan
    write_ato(tmp_path / "nan.ato", xyz, mz, 5)
    with pytest.raises(InputError, match="ion 37 has a non-finite"):
        read_ions(tmp_path / "nan.ato")
