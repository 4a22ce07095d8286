"""APT6 (AP Suite .apt) parsing on constructed files: sections, kinds we skip, corrupt headers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.io import iter_ion_chunks, read_ions
from apt_filters.io.apt6 import FILE_HEADER, SECTION_HEADER

FLOAT, INT = 3, 1


def _wide(text: str, size: int) -> bytes:
    return text.encode("utf-16-le").ljust(size, b"\0")


def section(name: str, values: np.ndarray, kind: int = FLOAT, unit: str = "", relationship: int = 1,
            record_type: int = 1, extra_header: bytes = b"", count: int | None = None) -> bytes:
    """One APT6 section (header + little-endian data) holding ``values`` (N,) or (N, k)."""
    values = np.ascontiguousarray(values, dtype=values.dtype.newbyteorder("<"))
    width = 1 if values.ndim == 1 else values.shape[1]
    data = values.tobytes()
    header = SECTION_HEADER.pack(
        b"SEC\0", SECTION_HEADER.size + len(extra_header), 2, _wide(name, 64), 1, relationship, record_type,
        kind, values.dtype.itemsize * 8, values.dtype.itemsize * width, _wide(unit, 32),
        len(values) if count is None else count, len(data))
    return header + extra_header + data


def apt6(ions: int, *sections: bytes) -> bytes:
    return FILE_HEADER.pack(b"APT\0", FILE_HEADER.size, 2, _wide("made.apt", 512), 0, ions) + b"".join(sections)


@pytest.fixture
def small():
    rng = np.random.default_rng(1)
    pos = (rng.uniform(0, 1, (100, 3)) * [1, 10, 100]).astype("<f4")
    mz = rng.uniform(1, 100, 100).astype("<f4")
    return pos, mz


def test_sections_in_any_order_with_extras(tmp_path, small):
    pos, mz = small
    mult = np.arange(100, dtype="<i4") % 3
    path = tmp_path / "a.apt"
    path.write_bytes(apt6(100, section("Multiplicity", mult, INT),
                          section("Position", pos, unit="nm", extra_header=np.zeros(6, "<f4").tobytes()),
                          section("Mass", mz, unit="Da")))
    ions = read_ions(path)
    np.testing.assert_array_equal(ions.positions, pos)
    np.testing.assert_array_equal(ions.mz, mz)
    np.testing.assert_array_equal(ions.extra["Multiplicity"], mult)
    assert [len(c) for c in iter_ion_chunks(path, 40)] == [40, 40, 20]


def test_float64_sections_are_converted(tmp_path, small):
    pos, mz = small
    path = tmp_path / "a.apt"
    path.write_bytes(apt6(100, section("Position", pos.astype("<f8")), section("Mass", mz.astype("<f8"))))
    ions = read_ions(path)
    assert ions.positions.dtype == np.float32
    np.testing.assert_array_equal(ions.positions, pos)


def test_sections_of_other_kinds_are_skipped(tmp_path, small):
    pos, mz = small
    path = tmp_path / "a.apt"
    path.write_bytes(apt6(100, section("Position", pos), section("Mass", mz),
                          section("Pulse table", np.arange(7, dtype="<i8"), INT, relationship=2, count=7),
                          section("Notes", np.arange(5, dtype="<u1"), 4, count=5)))
    assert set(read_ions(path).extra) == set()


@pytest.mark.parametrize("build, words", [
    (lambda p, m: apt6(100, section("Position", p)), ["no per-ion 'Mass'"]),
    (lambda p, m: apt6(100, section("Position", p[:, :2].copy()), section("Mass", m)), ["'Position' has 2 values"]),
    (lambda p, m: apt6(99, section("Position", p), section("Mass", m)), ["100 records for 99 ions"]),
    (lambda p, m: apt6(100, section("Position", p), section("Mass", m))[:-8], ["truncated"]),
    (lambda p, m: apt6(100, section("Position", p), section("Mass", m), section("Mass", m)), ["twice"]),
    (lambda p, m: apt6(0, section("Position", p), section("Mass", m)), ["0 ions"]),
    (lambda p, m: apt6(100, section("Position", p), b"XYZ\0" + section("Mass", m)[4:]), ["section signature"]),
    (lambda p, m: apt6(100, section("Position", p), section("Mass", m))[:600], ["truncated"]),
    (lambda p, m: apt6(100)[:300], ["too short"]),
])
def test_corrupt_apt6(tmp_path, small, build, words):
    path = tmp_path / "bad.apt"
    path.write_bytes(build(*small))
    with pytest.raises(InputError) as err:
        read_ions(path)
    msg = str(err.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    for word in words:
        assert word in msg, msg


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_apt6")


def _valid() -> bytes:
    rng = np.random.default_rng(2)
    return apt6(20, section("Position", rng.uniform(-5, 5, (20, 3)).astype("<f4"), extra_header=b"\0" * 24),
                section("Mass", rng.uniform(1, 50, 20).astype("<f4")),
                section("Multiplicity", np.ones(20, "<i4"), INT))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(edits=st.lists(st.tuples(st.integers(0, 2000), st.binary(min_size=1, max_size=8)), max_size=4),
       cut=st.integers(0, 2000))
def test_corrupted_apt6_raises_only_project_errors(fuzz_dir, edits, cut):
    data = bytearray(_valid())
    for at, patch in edits:
        at %= len(data)
        data[at:at + len(patch)] = patch
    path = fuzz_dir / "f.apt"
    path.write_bytes(bytes(data[: max(1, len(data) - cut)]))
    for read in (read_ions, lambda p: sum(len(c) for c in iter_ion_chunks(p, 7))):
        try:
            read(path)
        except AptFiltersError:
            pass
