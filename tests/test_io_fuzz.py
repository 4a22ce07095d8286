"""Corrupt bytes for every ion and range reader: only the project's error may escape.

(APT6 is fuzzed in test_io_apt6.py, from a constructed valid file.)
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from apt_filters.core.errors import AptFiltersError
from apt_filters.io import iter_ion_chunks, read_ions, read_ranges

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _survives(read, path) -> None:
    try:
        read(path)
    except AptFiltersError:
        pass


def _mutate(data: bytes, edits: list[tuple[int, bytes]], cut: int) -> bytes:
    out = bytearray(data)
    for at, patch in edits:
        at %= max(1, len(out))
        out[at:at + len(patch)] = patch
    return bytes(out[: max(0, len(out) - cut)])


def _read_all_chunks(path):
    return sum(len(c) for c in iter_ion_chunks(path, 5))


@FUZZ
@given(data=st.binary(max_size=400), ext=st.sampled_from(["pos", "epos", "csv", "txt", "apt", "ato"]))
def test_random_bytes_ion_files(fuzz_dir, data, ext):
    path = fuzz_dir / f"f.{ext}"
    path.write_bytes(data)
    _survives(read_ions, path)
    _survives(_read_all_chunks, path)


TEXT_TABLE = b"x,y,z,m/z,tof\n1.5,2,3,27.9,1\n-1,2e1,3,14.0,2\n# note\n0,0,0,1,3\n"


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 200), st.binary(min_size=1, max_size=4)), max_size=4),
       cut=st.integers(0, 60), ext=st.sampled_from(["csv", "txt"]))
def test_corrupted_text_tables(fuzz_dir, edits, cut, ext):
    path = fuzz_dir / f"t.{ext}"
    path.write_bytes(_mutate(TEXT_TABLE, edits, cut))
    _survives(read_ions, path)


@FUZZ
@given(text=st.text(alphabet=st.sampled_from(list("0123456789.-+eE,; \t\nxyzm/#naif")), max_size=200))
def test_random_text_tables(fuzz_dir, text):
    path = fuzz_dir / "r.csv"
    path.write_text(text)
    _survives(read_ions, path)


@pytest.fixture(scope="module")
def range_samples(real_si, dialects):
    files = [real_si / "Si.RRNG", real_si / "Si.RNG", dialects / "test1.env", dialects / "test3.rng",
             dialects / "test12.rng", dialects / "test6.rrng"]
    return [(p.suffix, p.read_bytes()) for p in files]


@FUZZ
@given(which=st.integers(0, 5), edits=st.lists(st.tuples(st.integers(0, 3000), st.binary(min_size=1, max_size=6)),
                                                max_size=5),
       cut=st.integers(0, 1500), check=st.booleans())
def test_corrupted_range_files(fuzz_dir, range_samples, which, edits, cut, check):
    suffix, data = range_samples[which]
    path = fuzz_dir / f"r{suffix}"
    path.write_bytes(_mutate(data, edits, cut))
    _survives(lambda p: read_ranges(p, check_elements=check), path)


@FUZZ
@given(which=st.integers(0, 5), drop=st.lists(st.integers(0, 80), max_size=3),
       swap=st.lists(st.tuples(st.integers(0, 80), st.sampled_from(["0", "-", ".", "1 1", "[Ranges]", "Number=3",
                                                                  "Range1=", "x:y", "Cr:-1", "1e999", "--"])),
                     max_size=3))
def test_range_files_with_edited_lines(fuzz_dir, range_samples, which, drop, swap):
    suffix, data = range_samples[which]
    lines = data.decode("latin-1").splitlines()
    for i, token in swap:
        if lines:
            words = lines[i % len(lines)].split()
            words[i % max(1, len(words)):i % max(1, len(words)) + 1] = [token]
            lines[i % len(lines)] = " ".join(words)
    for i in sorted({i % max(1, len(lines)) for i in drop}, reverse=True):
        if lines:
            del lines[i]
    path = fuzz_dir / f"l{suffix}"
    path.write_text("\n".join(lines), encoding="latin-1")
    for check in (True, False):
        _survives(lambda p: read_ranges(p, check_elements=check), path)


@FUZZ
@given(data=st.binary(max_size=300), ext=st.sampled_from(["rrng", "rng", "env"]))
def test_random_bytes_range_files(fuzz_dir, data, ext):
    path = fuzz_dir / f"b.{ext}"
    path.write_bytes(data)
    _survives(read_ranges, path)
