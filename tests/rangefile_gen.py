"""Generated range files of every dialect, with the quirks labs write and the damage files suffer.

Used by tests/test_rangefile_fuzz.py (hypothesis, modest sizes) and by
benchmarks/fuzz_ranges.py (a one-off campaign of thousands of files).
"""

from __future__ import annotations

from hypothesis import strategies as st

NAMES = ["Fe", "O", "Cr2O", "CrO2", "H", "Si", "Ni", "C", "unknown60", "X23", "Hyd", "All", "Aa", "In-P"]
JUNK = ["", "9" * 5000, "1e20", "nan", "-inf", "1e999", "22,8615", "1,2,3", "\u00b2", "Fe:1e20", "Range1=",
        "[Ranges]", "Number=99999999999", "--------", "Rev_2.0", "mq1 mq2 volume element color", "\x00", "=",
        "Name:", "Color:GGGGGG", "Fe99999999999999999999", "0 0", "1 1", ". 1 2 3"]
DIALECTS = ("rrng", "rng", "env", "env2")
ENCODINGS = ("utf-8", "utf-8-sig", "utf-16", "utf-16-le", "latin-1")


@st.composite
def range_rows(draw, max_ranges: int = 30):
    """(lower, upper, name, count) rows: mostly disjoint windows, some overlapping, repeated or degenerate."""
    n = draw(st.integers(1, max_ranges))
    gaps = draw(st.lists(st.floats(0, 3, allow_nan=False), min_size=n, max_size=n))
    widths = draw(st.lists(st.floats(0.005, 1, allow_nan=False), min_size=n, max_size=n))
    names = draw(st.lists(st.sampled_from(NAMES), min_size=n, max_size=n))
    counts = draw(st.lists(st.sampled_from([1, 1, 1, 2, 0, 3]), min_size=n, max_size=n))
    lower = draw(st.floats(0, 5, allow_nan=False))
    rows = []
    for gap, width, name, count in zip(gaps, widths, names, counts):
        lower += gap
        rows.append((lower, lower + width, name, count))
        lower += width
    if draw(st.integers(0, 4)) == 0:  # a degenerate or far-out window
        rows.insert(draw(st.integers(0, n)), (draw(st.sampled_from([0.0, 27.9, 1e30])),
                                              draw(st.sampled_from([0.0, -1.0, 27.9, 1e31])), names[0], 1))
    if draw(st.booleans()):  # near-duplicates of one species, as some exports repeat them
        rows += [(r[0] + 0.001, r[1] - 0.001, r[2], r[3]) for r in rows[: draw(st.integers(0, 3))]]
    return rows


def _num(x: float, comma: bool) -> str:
    text = f"{x:.4f}"
    return text.replace(".", ",") if comma else text


def render(dialect: str, rows, comma: bool = False, header: bool = False, dup_index: bool = False) -> str:
    """Text of a range file of ``dialect`` holding ``rows``."""
    names = list(dict.fromkeys(r[2] for r in rows))
    if dialect == "rrng":
        lines = ["mq1 mq2 volume element color"] if header else []
        lines += ["[Ions]", f"Number={len(names)}"] + [f"Ion{k}={n}" for k, n in enumerate(names, 1)]
        lines += ["[Ranges]", f"Number={len(rows)}"]
        for k, (lo, hi, name, count) in enumerate(rows, 1):
            atoms = f"{name}:{count}" if count else f"Name:{name}"
            index = 1 if dup_index and k == 2 else k
            lines.append(f"Range{index}={_num(lo, comma)} {_num(hi, comma)} Vol:{_num(0.01, comma)} {atoms} "
                         "Color:FF00FF")
        return "\n".join(lines) + "\n"
    if dialect == "rng":
        lines = [f"{len(names)} {len(rows)}"]
        for n in names:
            lines += [n, f"{n} 1.0 0.0 0.5"]
        lines.append("-" * 8 + " " + " ".join(names))
        for lo, hi, name, count in rows:
            counts = " ".join(str(count if n == name else 0) for n in names)
            lines.append(f". {_num(lo, comma)} {_num(hi, comma)} {counts}")
        return "\n".join(lines) + "\n"
    lines = ["# generated", "Rev_2.0"] if dialect == "env2" else ["# generated"]
    lines.append(f"{len(names)} {len(rows)}")
    lines += [f"{n} 0.0 1.0 0.0" for n in names]
    lines += [f"{name} {_num(lo, comma)} {_num(hi, comma)} 11.66 1.0" for lo, hi, name, _ in rows]
    return "\n".join(lines) + "\n"


@st.composite
def damage(draw):
    """Line edits: (operation, line position, text) with operation in drop, repeat, insert, token."""
    ops = st.tuples(st.sampled_from(["drop", "repeat", "insert", "token"]), st.integers(0, 200),
                    st.sampled_from(JUNK))
    return draw(st.lists(ops, max_size=4))


def apply_damage(text: str, edits) -> str:
    lines = text.split("\n")
    for op, at, junk in edits:
        k = at % max(len(lines), 1)
        if op == "drop" and lines:
            del lines[k]
        elif op == "repeat" and lines:
            lines.insert(k, lines[k])
        elif op == "insert":
            lines.insert(k, junk)
        elif op == "token" and lines and lines[k].split():
            toks = lines[k].split()
            toks[at % len(toks)] = junk
            lines[k] = " ".join(toks)
    return "\n".join(lines)


@st.composite
def range_files(draw, max_ranges: int = 30):
    """(suffix, bytes) of a generated range file: any dialect, quirks, damage and encoding."""
    dialect = draw(st.sampled_from(DIALECTS))
    text = render(dialect, draw(range_rows(max_ranges)), comma=draw(st.booleans()), header=draw(st.booleans()),
                  dup_index=draw(st.booleans()))
    text = apply_damage(text, draw(damage()))
    encoding = draw(st.sampled_from(ENCODINGS))
    suffix = {"rrng": ".rrng", "rng": ".rng"}.get(dialect, ".env")
    return suffix, text.encode(encoding, errors="replace")
