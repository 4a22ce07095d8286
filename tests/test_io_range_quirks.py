"""Range files as labs write them: each quirk is read and noted with its line, only ambiguity is refused."""

from __future__ import annotations

import time

import numpy as np
import pytest

from apt_filters.core.errors import InputError
from apt_filters.io import IonTable, Range, RangeTable, read_ranges
from apt_filters.io.rangefiles import relabel
from apt_filters.io.summary import range_edges, summarize

RRNG_HEAD = "[Ions]\nNumber=2\nIon1=Mo\nIon2=C\n[Ranges]\n"


def _read(tmp_path, text: str, name: str = "a.rrng", **kw) -> RangeTable:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return read_ranges(path, **kw)


def _notes(table: RangeTable, kind: str) -> list:
    return [n for n in table.notes if n.kind == kind]


def test_decimal_comma(tmp_path):
    # a German-locale export
    t = _read(tmp_path, RRNG_HEAD + "Number=2\nRange1=22,8615 23,0910 Vol:0,01558 Mo:1\n"
                                    "Range2=5,9830 6,0180 Vol:0,00880 C:1 Color:FF0000\n")
    assert t.ranges[0] == Range(22.8615, 23.0910, (("Mo", 1),), None, 0.01558)
    assert (t.ranges[1].lower, t.ranges[1].upper) == (5.983, 6.018)
    [note] = _notes(t, "decimal_comma")
    assert note.line == 7 and "6 numbers on 2 lines" in note.message


def test_duplicate_index_keeps_both(tmp_path):
    t = _read(tmp_path, RRNG_HEAD + "Number=3\nRange41=95.8 96.1 Mo:1\nRange41=97.8 98.1 Mo:1\nRange2=12 12.1 C:1\n")
    assert [(r.lower, r.ion) for r in t.ranges] == [(12, "C"), (95.8, "Mo"), (97.8, "Mo")]
    [note] = _notes(t, "duplicate_index")
    assert note.line == 8 and "first on line 7" in note.message and "both kept" in note.message


def test_exact_repeat_is_dropped(tmp_path):
    t = _read(tmp_path, RRNG_HEAD + "Number=2\nRange1=95.8 96.1 Mo:1\nRange1=95.8 96.1 Mo:1\n")
    assert len(t) == 1 and _notes(t, "duplicate_range")[0].line == 8


def test_overlapping_near_duplicates_of_one_species_are_merged(tmp_path):
    rows = ["Range1=5.983 6.018 C:1", "Range2=5.985 6.016 C:1", "Range3=12.0 12.1 C:1", "Range4=11.99 12.05 C:1",
            "Range5=95.8 96.1 Mo:1", "Range6=95.9 96.3 Mo:1"]
    t = _read(tmp_path, RRNG_HEAD + f"Number={len(rows)}\n" + "\n".join(rows) + "\n")
    assert [(r.lower, r.upper, r.ion) for r in t.ranges] == [(5.983, 6.018, "C"), (11.99, 12.1, "C"),
                                                             (95.8, 96.3, "Mo")]
    merged = _notes(t, "merged_overlap")
    assert [n.line for n in merged] == [8, 9, 12]
    assert "merged into [5.983, 6.018] Da" in merged[0].message


def test_two_species_in_one_window_are_refused(tmp_path):
    with pytest.raises(InputError) as err:
        _read(tmp_path, RRNG_HEAD + "Number=2\nRange1=95.8 96.1 Mo:1\nRange2=96.0 96.2 C:8\n")
    assert "line 8: ranges overlap: Mo [95.8, 96.1] Da (line 7) and C8 [96, 96.2] Da" in str(err.value)


def test_placeholder_and_unknown_species(tmp_path):
    text = RRNG_HEAD + ("Number=4\nRange1=59.85 60.06 Vol:0.00000 Name:unknown60 Color:FFAFAF\n"
                        "Range2=1.0 1.1 Name:Hyd\nRange3=23 23.2 Name:X23\nRange4=95.8 96.1 Mo:1\n")
    t = _read(tmp_path, text)
    assert t.ions == ["unknown60", "Hyd", "X23", "Mo"]
    assert t.elements == ["unknown60", "Hyd", "X23", "Mo"]  # each its own field
    assert {(n.line, n.message.split("'")[1]) for n in _notes(t, "unknown_species")} == {
        (7, "unknown60"), (8, "Hyd"), (9, "X23")}
    # or left unranged, as the user chooses
    u = _read(tmp_path, text, unknown="unranged")
    assert u.ions == ["Mo"] and all("left unranged" in n.message for n in _notes(u, "unknown_species"))
    # an element count still names an element
    with pytest.raises(InputError, match="line 7: unknown element 'Xx'"):
        _read(tmp_path, RRNG_HEAD + "Number=1\nRange1=1 2 Xx:1\n")


def test_digit_string_names_and_huge_counts(tmp_path):
    # a name made of digits is an unknown species, not a count; counts are bounded before int64
    t = _read(tmp_path, RRNG_HEAD + "Number=1\nRange1=1 2 Name:99999999999999999999999\n")
    assert t.ions == ["99999999999999999999999"] and t.element_matrix().tolist() == [[1]]
    for count in ("1e20", "999999999999999999", "1001"):
        with pytest.raises(InputError, match=f"line 7: atom count '{count}' is not a whole number from 0 to 1,000"):
            _read(tmp_path, RRNG_HEAD + f"Number=1\nRange1=1 2 Si:{count}\n")


def test_colours_are_cosmetic(tmp_path):
    # a colour is never a reason to refuse a file: 0..255 components scaled, '#' dropped, others left out
    t = _read(tmp_path, "2 3\nFe\nFe 255 128 0\nO\nO 0 0 7.5\n-------- Fe O\n. 27 28 1 0\n. 15.9 16.1 0 1\n"
                        ". 31.9 32.1 0 2\n", name="a.rng")
    assert [r.color for r in t.ranges] == ["FF8000", None, None]
    assert [n.line for n in _notes(t, "colour")] == [3, 5]
    t = _read(tmp_path, RRNG_HEAD + "Number=2\nRange1=1 2 Mo:1 Color:#ff0000\nRange2=3 4 C:1 Color:red\n")
    assert [r.color for r in t.ranges] == ["FF0000", None] and _notes(t, "colour")[0].line == 8


def test_rrng_column_header_first_line(tmp_path):
    t = _read(tmp_path, "mq1 mq2 volume element color\n" + RRNG_HEAD + "Number=1\nRange1=95.8 96.1 Mo:1\n")
    assert len(t) == 1
    [note] = _notes(t, "header_line")
    assert note.line == 1 and "before the first section" in note.message


GPM_ENV = """#
#\t\tsome lab / some group
#\t\tRev 2.0 : Environment file for 3D Atom Probe
#

# Version Id
Rev_2.0

# Alloy definition

# Number of elements / Number of mass ranges
5\t6

# List of Element and Color components ( Red / Green / Blue )
O\t0.0\t1.0\t0.0
Mn\t0.0\t0.5\t1.0
MnO2\t0.5\t0.5\t0.5
X23\t0.3\t0.5\t0.5
Hyd\t0.0\t0.0\t0.0

# Definition of  Mass ranges / Atomic volumes / Increment for concentration
O\t15.880\t16.840\t20.000\t1.000
Mn\t27.330\t27.950\t11.660\t1.000
Mn\t54.700\t55.400\t11.660\t1.000
MnO2\t86.700\t87.300\t20.000\t1.000
X23\t22.900\t23.100\t10.000\t1.000
Hyd\t0.900\t1.100\t10.000\t1.000

# Instrument parameters
Flight length 94.0
"""


def test_gpm_rouen_env_rev2(tmp_path):
    t = _read(tmp_path, GPM_ENV, name="lab.ENV")
    assert len(t) == 6 and t.ions == ["O", "Mn", "MnO2", "X23", "Hyd"]
    assert t.ranges[1] == Range(27.33, 27.95, (("Mn", 1),), "0080FF", 0.01166)  # Å³ -> nm³
    assert t.ion_compositions()["MnO2"] == (("Mn", 1), ("O", 2))
    assert [n.line for n in _notes(t, "layout")] == [7]
    assert {n.message.split("'")[1] for n in _notes(t, "unknown_species")} == {"X23", "Hyd"}


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be", "utf-32", "utf-8-sig"])
def test_unicode_encodings(tmp_path, encoding):
    path = tmp_path / "a.rrng"
    path.write_bytes((RRNG_HEAD + "Number=1\nRange1=95.8 96.1 Mo:1\n").encode(encoding))
    t = read_ranges(path)
    assert t.ions == ["Mo"]
    assert bool(_notes(t, "encoding")) == (encoding != "utf-8-sig")


def test_a_huge_bad_token_gives_a_short_line(tmp_path):
    path = tmp_path / "a.rrng"
    path.write_text(RRNG_HEAD + "Number=1\nRange1=95.8 " + "9" * 500_000 + "x Mo:1\n")
    with pytest.raises(InputError) as err:
        read_ranges(path)
    msg = str(err.value)
    assert len(msg) < len(str(path)) + 200 and "500,001 characters" in msg


def test_relabel(tmp_path):
    t = _read(tmp_path, RRNG_HEAD + "Number=3\nRange1=57.8 61.2 Cr:2 O:1 Color:FF00FF\nRange2=52 52.1 Cr:1\n"
                                    "Range3=28.9 29.5 Cr:2 O:1\n")
    r = relabel(t, ["Cr2O=Ni"])
    assert r.ions == ["Ni", "Cr"] and r.ranges[0] == Range(57.8, 61.2, (("Ni", 1),), "FF00FF")
    [note] = _notes(r, "relabel")
    assert "Cr2O relabelled Ni (command line): 2 range(s), [57.8, 61.2], [28.9, 29.5] Da" in note.message
    assert relabel(t, ["OCr2=Ni"]).ions == ["Ni", "Cr"]  # the same atoms, in another order
    with pytest.raises(InputError, match="no range is labelled 'Fe'"):
        relabel(t, ["Fe=Ni"])
    with pytest.raises(InputError, match="expected OLD=NEW"):
        relabel(t, ["Cr2O"])


def _rrng(n: int) -> str:
    rows = [f"Range{k}={1 + 0.01 * k:.4f} {1.005 + 0.01 * k:.4f} Vol:0.01 {'Fe' if k % 3 else 'Cu'}:1 "
            f"{'O:1' if k % 2 else ''}" for k in range(1, n + 1)]
    return RRNG_HEAD + f"Number={n}\n" + "\n".join(rows) + "\n"


def test_many_ranges_read_and_range_in_linear_time(tmp_path):
    # 10^4 ranges took about a minute when each range looked up its ion in a rebuilt list;
    # quadrupling the ranges must not take more than about four times as long (quadratic: 16x).
    def best(n: int) -> float:
        path = tmp_path / f"n{n}.rrng"
        path.write_text(_rrng(n))
        times = []
        for _ in range(3):
            start = time.process_time()  # CPU time: other jobs on the machine disturb it least
            table = read_ranges(path)
            range_edges(table)
            table.element_matrix()
            times.append(time.process_time() - start)
        return min(times)

    small, large = best(2_000), best(8_000)
    assert large < 8 * small, (small, large)
    table = read_ranges(tmp_path / "n8000.rrng")
    mz = np.array([1.0 + 0.01 * k + 0.002 for k in range(1, 8001)], dtype=np.float32)
    s = summarize(IonTable(np.zeros((8000, 3), np.float32), mz), table)
    assert s.ranged == 8000 and s.atoms["O"] == 4000
