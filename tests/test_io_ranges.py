"""Range files: the real Si RRNG/RNG pair, 3Depict's odd dialect files, formulas, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.io import Range, RangeTable, read_ranges
from apt_filters.io.formula import ELEMENTS, split_formula
from apt_filters.io.writers import format_rrng


def _key(table: RangeTable):
    return sorted((r.lower, r.upper, dict(r.composition), r.color) for r in table.ranges)


def test_real_rrng_and_rng_agree(real_si):
    rrng = read_ranges(real_si / "Si.RRNG")
    rng = read_ranges(real_si / "Si.RNG")
    assert len(rrng) == len(rng) == 25
    assert _key(rrng) == _key(rng)
    assert set(rrng.ions) == set(rng.ions) == {"Si", "Cr", "Cu", "C", "O", "CrO", "CrO2", "Cr2O"}
    assert set(rrng.elements) == {"Si", "Cr", "Cu", "C", "O"}
    m = rng.element_matrix()
    row = m[rng.ions.index("Cr2O")]
    assert row[rng.elements.index("Cr")] == 2 and row[rng.elements.index("O")] == 1
    # the RNG polyatomic block gives CrO2 its own colour (0 1 0), as the RRNG does
    assert rng.ion_colors()["CrO2"] == rrng.ion_colors()["CrO2"] == "00FF00"
    assert rrng.ranges[0] == Range(13.8745, 14.2410, (("Si", 1),), "CCCCCC", 0.02003)
    assert rng.ranges[0].volume is None  # RNG carries no atomic volumes


def test_real_ranging(real_si):
    # SOURCE.txt: 92.8 % of the ions fall inside a range; the tallest peak, 14.03 Da, is Si2+
    from apt_filters.io import read_ions

    mz = read_ions(real_si / "Si.pos").mz
    ranges = read_ranges(real_si / "Si.RNG")
    ion = ranges.ion_index(mz)
    assert abs((ion >= 0).mean() - 0.928) < 0.001
    assert ranges.ions[ranges.ion_index(np.float32([14.03]))[0]] == "Si"


# Outcome of every 3Depict test file, read as chemistry (default) and with made-up names
# allowed. Every file uses anonymised species names ("Aa", "HiggsBoson", "In-P"). By default a
# name that is not a formula of elements is kept as an unknown species (and noted), but a token
# that counts atoms of an element (RRNG "A:1", an RNG "(formula)", the polyatomic block) must
# name one: those files are refused, naming the line and the name. Read with
# check_elements=False every file parses. Decisions that differ from or go beyond 3Depict:
#  - test4.rng: Q [58.0012, 58.1525] lies inside Q [58, 69.11]; one species, so the union is
#    kept and noted (3Depict refuses the file).
#  - test6.rng (one row with B 1, C 1) parses as the molecular ion BC: an RNG row of counts
#    over element columns is exactly how Si.RNG writes CrO. 3Depict refuses it because it
#    has no colour for the new ion; ours simply has none.
#  - test7.rng / test8.rng: a window -0.5..0.5 Da is kept (it catches m/z = 0 ions; ordered
#    finite bounds are all a window needs); test8's row marker "3" is a row number.
#  - test9/test10.rng: the table header names the long names; either name is accepted.
#  - test1.env: the lines after the declared ranges are not range data and are ignored.
DIALECTS = {
    # file: (default outcome, lenient outcome); an outcome is (n_ranges, ions) or an error fragment
    "test1.env": ((1, ["HiggsBoson"]), (1, ["HiggsBoson"])),
    "test1.rng": ((6, ["Aa", "Bb", "Cc"]), (6, ["Aa", "Bb", "Cc"])),
    "test2.rng": ((9, ["Ts", "Es", "El", "H", "So", "Pr"]), (9, ["Ts", "Es", "El", "H", "So", "Pr"])),
    "test3.rng": ("line 11: unknown element 'Qi' in 'PQi'", (59, None)),
    "test4.rng": ((3, ["Q"]), (3, ["Q"])),
    "test5.rng": ("line 9: unknown element 'Ab' in 'AbCd2'", (2, ["Cd2", "AbCd2"])),
    "test6.rng": ((1, ["BC"]), (1, ["BC"])),
    "test7.rng": ((2, ["M", "N"]), (2, ["M", "N"])),
    "test8.rng": ((2, ["M", "N"]), (2, ["M", "N"])),
    "test9.rng": ((3, ["InsidePart", "OutsidePart", "BorderPart"]), (3, ["InsidePart", "OutsidePart", "BorderPart"])),
    "test10.rng": ((3, ["Inside-Part", "Outside-Part", "Border-Part"]),
                   (3, ["Inside-Part", "Outside-Part", "Border-Part"])),
    "test11.rng": ((10, ["Aa", "Ab", "Ac", "AaAd"]), (10, ["Aa", "Ab", "Ac", "AaAd"])),
    "test12.rng": ("line 26: unknown element 'Aa' in 'AaAd'", (10, ["Aa", "Ab", "Ac", "AaAd"])),
    "test1.rrng": ((1, ["A"]), (1, ["A"])),
    "test2.rrng": ("line 8: unknown element 'A'", (6, ["A", "B", "C"])),
    "test3.rrng": ("line 8: unknown element 'A'", (42, ["A", "B", "B2", "C", "B3", "B4", "AC", "A2"])),
    "test4.rrng": ("line 14: unknown element 'A'", (15, None)),
    "test5.rrng": ("line 7: unknown element 'Ab'", (1, ["Ab"])),
    "test6.rrng": ("line 9: unknown element 'A'", (4, ["A", "B"])),
}


def test_every_dialect_file_has_an_expected_outcome(dialects):
    on_disk = {p.name for p in dialects.iterdir() if p.suffix.lower() in (".rng", ".rrng", ".env")}
    assert on_disk == set(DIALECTS)


@pytest.mark.parametrize("name", sorted(DIALECTS))
@pytest.mark.parametrize("check", [True, False])
def test_dialect_files(dialects, name, check):
    expected = DIALECTS[name][0 if check else 1]
    path = dialects / name
    if isinstance(expected, str):
        with pytest.raises(InputError) as err:
            read_ranges(path, check_elements=check)
        assert str(err.value) == f"{path}: {expected}"
        return
    table = read_ranges(path, check_elements=check)
    n, ions = expected
    assert len(table) == n
    if ions is not None:
        assert table.ions == ions
    # every name kept as an unknown species is reported, with the line it first appears on
    unknown = {el for el in table.elements if el not in ELEMENTS}
    noted = {n.message.split("'")[1] for n in table.notes if n.kind == "unknown_species"}
    assert noted == (unknown if check else set())


def test_dialect_details(dialects):
    t3 = read_ranges(dialects / "test3.rng", check_elements=False)
    # column "QiP ... (PQi)" is the formula P Qi; rows with P 1 and Qi 1 are that ion
    assert t3.ion_compositions()["PQi"] == (("P", 1), ("Qi", 1))
    assert t3.ion_compositions()["P2A"] == (("P", 2), ("A", 1))
    t6 = read_ranges(dialects / "test6.rrng", check_elements=False)
    assert t6.ranges[0].volume == 12.11 and t6.ranges[0].composition == (("A", 1),)
    t12 = read_ranges(dialects / "test12.rng", check_elements=False)
    assert t12.ion_colors()["AaAd"] == "CCCCFF"  # from the polyatomic block (0.8 0.8 1.0)
    t7 = read_ranges(dialects / "test7.rng", check_elements=False)
    assert (t7.ranges[0].lower, t7.ranges[0].upper) == (-0.5, 0.5)
    env = read_ranges(dialects / "test1.env", check_elements=False)
    assert (env.ranges[0].lower, env.ranges[0].upper, env.ranges[0].color) == (110, 135, "0000FF")


def test_formulas():
    assert split_formula("CrO2") == (("Cr", 1), ("O", 2))
    assert split_formula("Cr2O") == (("Cr", 2), ("O", 1))
    assert split_formula("CrOCr") == (("Cr", 2), ("O", 1))
    assert split_formula("H") == (("H", 1),)
    for bad in ("", "cr", "Cr-O", "2Cr", "Cr O", "Cr0"):
        assert split_formula(bad) is None
    assert len(ELEMENTS) == 118 and "Og" in ELEMENTS and "D" not in ELEMENTS


def test_rrng_round_trip(tmp_path, real_si):
    table = read_ranges(real_si / "Si.RRNG")
    path = tmp_path / "again.rrng"
    path.write_text(format_rrng(table))
    assert read_ranges(path).ranges == table.ranges


RRNG_HEAD = "[Ions]\nNumber=2\nIon1=Fe\nIon2=O\n[Ranges]\n"


@pytest.mark.parametrize("name, text, fragment", [
    ("a.rrng", "", "empty range file"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 28.1 Xx:1 Color:FF0000\n", "line 7: unknown element 'Xx'"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 28.1 Fe:1.5\n", "line 7: atom count '1.5'"),
    ("a.rrng", RRNG_HEAD + "Number=2\nRange1=27.9 28.1 Fe:1\n", "line 6: declares Number=2 but lists 1"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 Fe:1\n", "line 7: upper bound 'Fe:1' is not a finite number"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 28.1 Vol:0.1\n", "line 7: range 27.9-28.1 lists no atoms"),
    ("a.rrng", RRNG_HEAD + "Number=1\nthis line is broken\n", "line 7: expected 'key=value'"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 28.1 Fe:1e20\n", "line 7: atom count '1e20' is not a whole number"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 28.1 Fe:999999999999999999\n", "from 0 to 1,000"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=27.9 28.1 Fe:600 Fe:600\n", "line 7: 1,200 atoms of 'Fe' in one ion"),
    ("a.rng", "1 1\nFe\nFe 1 0 0\n-- Fe\n. 27 28 1e20\n", "line 5: atom count '1e20'"),
    ("a.rng", "1 1\nFe\nFe99999999999999999999 1 0 0\n-- Fe99999999999999999999\n. 27 28 1\n",
     "line 3: 'Fe99999999999999999999' has 99,999,999,999,999,999,999 atoms of one element, more than 1,000"),
    ("a.env", "1 1\nFe 1 0 0\nFe 27 28 1e999\n", "line 3: value '1e999' is not a finite number"),
    ("a.rrng", RRNG_HEAD + "Number=2\nRange1=27 28.5 Fe:1\nRange2=28 30 O:1\n",
     "line 8: ranges overlap: Fe [27, 28.5] Da (line 7) and O [28, 30] Da: two species claim the same m/z window"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=28 27 Fe:1\n", "lower bound not below upper bound"),
    ("a.rrng", RRNG_HEAD + "Number=1\nRange1=nan 27 Fe:1\n", "line 7: lower bound 'nan'"),
    ("a.pos", RRNG_HEAD, "unknown range file extension '.pos'"),
    ("a.rng", "2 1\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n. 27 28 1 0 1\n", "line 7: range row has 6 fields"),
    ("a.rng", "2 2\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n. 27 28 1 0\n", "ends after 1 of the 2 declared range rows"),
    ("a.rng", "2 1\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe Cr\n. 27 28 1 0\n", "line 6: table columns"),
    ("a.rng", "2 1\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n. 27 28 0 0\n", "line 7: range 27-28 assigns no ion"),
    ("a.rng", "2 1\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n. 27 28 1 0\nextra\n", "line 8: unexpected text"),
    ("a.rng", "2 1\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n. 27 28 1 1\n-- polyatomic\n1 1\nFeO2\nFeO2 1 1 1\n"
              "------ FeO2\n. 27 28 1\n", "line 13: polyatomic ion FeO2 does not match the main table's atoms (Fe:1 O:1)"),
    ("a.rng", "2 1\nFe\nFe 1 0 0\nO\nO 0 0 1\n-------- Fe O\n. 27 28 1 1\n-- polyatomic\n1 1\nFeO\nFeO 1 1 1\n"
              "------ FeO\n. 29 30 1\n", "line 13: polyatomic range 29-30 is not in the main table"),
    ("a.env", "1 1\nFe 1 0 0\nO 27 28\n", "line 3: range names ion 'O', which is not listed above"),
    ("a.env", "1 2\nFe 1 0 0\nFe 27 28\n", "ends after 1 of the 2 declared range lines"),
    ("a.rng", "hello\n", "not a range file"),
    ("a.rng", "\u00b2 1\nFe\nFe 1 0 0\n-- Fe\n. 1 2 1\n", "not a range file"),  # "²".isdigit() is True
    ("a.rrng", RRNG_HEAD + "Number=\u00b2\n", "line 6: Number='²' is not a count"),
    ("a.rng", "1 1\nFe\x00\n", "NUL bytes"),
])
def test_bad_range_files(tmp_path, name, text, fragment):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(AptFiltersError) as err:
        read_ranges(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg
    assert fragment in msg, msg


def test_molecular_ions_and_rrng_saved_as_rng(tmp_path):
    path = tmp_path / "ivas.rng"  # RRNG content under an .rng name: content decides
    path.write_text(RRNG_HEAD + "Number=3\nRange1=35.9 36.1 Fe:1 O:2 Color:00ff00\n"
                    "Range2=16 16.1 Name:O2\nRange3=71.9 72.1 Fe:1 Fe:1 O:1\n")
    table = read_ranges(path)
    assert table.ions == ["FeO2", "O2", "Fe2O"]
    assert table.ranges[0].color == "00FF00"
    assert table.elements == ["Fe", "O"]
    np.testing.assert_array_equal(table.element_matrix(), [[1, 2], [0, 2], [2, 1]])
