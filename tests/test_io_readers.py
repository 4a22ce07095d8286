"""Ion file readers: the real Si measurement in three formats, round trips, text tables, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.io import IonTable, iter_ion_chunks, read_ions
from apt_filters.io.readers import ion_format
from apt_filters.io.writers import EPOS_EXTRA, write_epos, write_pos

N_SI = 945_211


@pytest.fixture(scope="module")
def si(real_si):
    return {ext: read_ions(real_si / f"Si.{ext}") for ext in ("pos", "epos", "apt")}


def test_real_files_agree_exactly(si):
    pos = si["pos"]
    assert len(pos) == N_SI
    for other in (si["epos"], si["apt"]):
        assert len(other) == N_SI
        np.testing.assert_array_equal(other.positions, pos.positions)
        np.testing.assert_array_equal(other.mz, pos.mz)
    for table in si.values():
        assert table.positions.dtype == np.float32 and table.positions.dtype.isnative
        assert table.mz.dtype == np.float32 and table.mz.dtype.isnative
        assert table.positions.flags.c_contiguous


def test_real_values_match_provenance(si):
    # SOURCE.txt: x -20.43..19.71, y -17.86..21.28, z -75.08..-0.02 nm, m/z 0..378.3 Da
    lo, hi = si["pos"].bounds()
    np.testing.assert_allclose(lo, [-20.43, -17.86, -75.08], atol=0.01)
    np.testing.assert_allclose(hi, [19.71, 21.28, -0.02], atol=0.01)
    assert si["pos"].mz.min() == 0 and abs(si["pos"].mz.max() - 378.3) < 0.01
    # the first POS record, decoded by hand from its 16 big-endian bytes
    raw = np.fromfile(si["pos"].source, dtype=">f4", count=4)
    np.testing.assert_array_equal(si["pos"].positions[0], raw[:3])
    assert si["pos"].mz[0] == raw[3]


def test_real_extras(si):
    epos, apt = si["epos"], si["apt"]
    assert set(epos.extra) == set(EPOS_EXTRA)
    assert set(apt.extra) == {"tofc", "XDet_mm", "YDet_mm", "Multiplicity", "Detector Coordinates"}
    np.testing.assert_array_equal(epos.extra["det_x"], apt.extra["XDet_mm"])
    np.testing.assert_array_equal(epos.extra["det_y"], apt.extra["YDet_mm"])
    np.testing.assert_array_equal(epos.extra["multiplicity"], apt.extra["Multiplicity"])
    np.testing.assert_array_equal(apt.extra["Detector Coordinates"][:, 0], apt.extra["XDet_mm"])
    assert apt.extra["Multiplicity"].dtype == np.int32
    # SOURCE.txt: multiplicity 0: 20366, 1: 906554, 2: 17158, 3: 778
    counts = np.bincount(epos.extra["multiplicity"])
    assert list(counts[:4]) == [20366, 906554, 17158, 778]
    assert not epos.extra["tof"].any()  # the export filled tof with zeros


def test_apt6_is_zero_copy_and_read_only(real_si):
    mapped = read_ions(real_si / "Si.apt")
    assert not mapped.positions.flags.owndata and not mapped.positions.flags.writeable
    copied = read_ions(real_si / "Si.apt", mmap=False)
    assert copied.positions.flags.owndata and copied.positions.flags.writeable
    np.testing.assert_array_equal(mapped.positions, copied.positions)


@pytest.mark.parametrize("ext", ["pos", "epos", "apt"])
def test_chunks_reassemble_the_file(real_si, si, ext):
    chunks = list(iter_ion_chunks(real_si / f"Si.{ext}", chunk_size=300_000))
    assert [len(c) for c in chunks] == [300_000, 300_000, 300_000, N_SI - 900_000]
    np.testing.assert_array_equal(np.concatenate([c.positions for c in chunks]), si[ext].positions)
    np.testing.assert_array_equal(np.concatenate([c.mz for c in chunks]), si[ext].mz)
    for name, col in si[ext].extra.items():
        np.testing.assert_array_equal(np.concatenate([c.extra[name] for c in chunks]), col)
    assert all(c.positions.dtype.isnative for c in chunks)


def _asymmetric(n: int = 1000, seed: int = 0) -> IonTable:
    """Ions whose x, y, z ranges differ, so that a swapped axis is caught."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(0, 1, (n, 3)).astype(np.float32) * np.float32([1, 10, 100]) + np.float32([0, -50, 500])
    return IonTable(pos, rng.uniform(0.5, 200, n).astype(np.float32))


def test_pos_round_trip_keeps_axis_order(tmp_path):
    ions = _asymmetric()
    write_pos(tmp_path / "a.pos", ions)
    back = read_ions(tmp_path / "a.pos")
    np.testing.assert_array_equal(back.positions, ions.positions)
    np.testing.assert_array_equal(back.mz, ions.mz)
    lo, hi = back.bounds()
    assert lo[0] >= 0 and hi[0] <= 1 and lo[1] >= -50 and hi[1] <= -40 and lo[2] >= 500


def test_epos_round_trip_with_extras(tmp_path):
    ions = _asymmetric()
    ions.extra["det_x"] = np.linspace(-10, 10, len(ions), dtype=np.float32)
    ions.extra["multiplicity"] = np.arange(len(ions), dtype=np.int32) % 4
    write_epos(tmp_path / "a.epos", ions)
    back = read_ions(tmp_path / "a.epos")
    np.testing.assert_array_equal(back.positions, ions.positions)
    np.testing.assert_array_equal(back.extra["det_x"], ions.extra["det_x"])
    np.testing.assert_array_equal(back.extra["multiplicity"], ions.extra["multiplicity"])
    assert back.extra["multiplicity"].dtype == np.int32
    assert not back.extra["tof"].any()


def test_chunks_when_file_is_smaller_than_a_chunk(tmp_path):
    ions = _asymmetric(10)
    write_pos(tmp_path / "a.pos", ions)
    (chunk,) = iter_ion_chunks(tmp_path / "a.pos", chunk_size=1000)
    np.testing.assert_array_equal(chunk.positions, ions.positions)
    with pytest.raises(AptFiltersError, match="chunk size"):
        next(iter_ion_chunks(tmp_path / "a.pos", chunk_size=0))


@pytest.mark.parametrize("text", [
    "x,y,z,m/z\n1,20,300,27.9\n2,21,301,14.0\n",
    "# exported\nz (nm); m; x (nm); y (nm)\n300;27.9;1;20\n301;14.0;2;21\n",
    "1 20 300 27.9\n2\t21  301 14.0\n\n",
    "X,Y,Z,Da,tof\n1,20,300,27.9,5\n2,21,301,14.0,6\n",
])
def test_text_tables(tmp_path, text):
    path = tmp_path / "ions.csv"
    path.write_text(text)
    ions = read_ions(path)
    np.testing.assert_array_equal(ions.positions, np.float32([[1, 20, 300], [2, 21, 301]]))
    np.testing.assert_array_equal(ions.mz, np.float32([27.9, 14.0]))
    assert len(list(iter_ion_chunks(path, 1))) == 2


def test_text_extra_column(tmp_path):
    path = tmp_path / "ions.txt"
    path.write_text("x y z mz tof\n1 2 3 4 5\n")
    assert read_ions(path).extra["tof"][0] == 5


def test_format_by_extension(tmp_path):
    assert [ion_format(f"a.{e}") for e in ("pos", "EPOS", "apt", "csv", "TXT")] == ["pos", "epos", "apt6", "text", "text"]


def _expect_input_error(path, *words):
    with pytest.raises(InputError) as err:
        read_ions(path)
    msg = str(err.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    for word in words:
        assert word in msg, msg
    return msg


def test_bad_ion_files(tmp_path):
    empty = tmp_path / "empty.pos"
    empty.write_bytes(b"")
    _expect_input_error(empty, "empty")
    ragged = tmp_path / "ragged.pos"
    ragged.write_bytes(b"\0" * 33)
    _expect_input_error(ragged, "33 bytes", "16-byte", "POS")
    ragged_epos = tmp_path / "ragged.epos"
    ragged_epos.write_bytes(b"\0" * 45)
    _expect_input_error(ragged_epos, "44-byte", "EPOS")
    wrong = tmp_path / "ions.xyz"
    wrong.write_bytes(b"\0" * 16)
    _expect_input_error(wrong, "extension", ".xyz")
    _expect_input_error(tmp_path / "missing.pos", "no such file")
    not_apt = tmp_path / "ions.apt"
    not_apt.write_bytes(b"\0" * 1000)
    _expect_input_error(not_apt, "not an APT6 file")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("column", [0, 2, 3])
def test_non_finite_values_are_refused(tmp_path, bad, column):
    rec = np.ones((50, 4), dtype=">f4")
    rec[37, column] = bad
    path = tmp_path / "bad.pos"
    rec.tofile(path)
    _expect_input_error(path, "ion 37", "non-finite")
    with pytest.raises(InputError, match="ion 37"):
        list(iter_ion_chunks(path, chunk_size=10))


@pytest.mark.parametrize("text, words", [
    ("", ["empty"]),
    ("# only a comment\n", ["no ions"]),
    ("x,y,z,m\n", ["no ions"]),
    ("1,2,3\n", ["3 columns and no header"]),
    ("x,y,mass\n1,2,3\n", ["lacks", "z"]),
    ("x,y,z,m\n1,2,3,4\n1,2,3\n", ["line 3", "3 columns, expected 4"]),
    ("1 2 3 4\n1 2 three 4\n", ["line 2", "'three' is not a number"]),
    ("1 2 3 4\n1 2 nan 4\n", ["ion 1", "non-finite"]),
    ("1 2 3 1e300\n", ["ion 0", "non-finite"]),
    ("x,y,z,m,mass\n1,2,3,4,5\n", ["twice"]),
])
def test_bad_text_tables(tmp_path, text, words):
    path = tmp_path / "t.csv"
    path.write_text(text)
    _expect_input_error(path, *words)


def test_text_that_is_not_utf8(tmp_path):
    path = tmp_path / "t.txt"
    path.write_bytes(b"1 2 3 \xff\n")
    _expect_input_error(path, "not UTF-8")
