"""Range files: IVAS RRNG, Oak Ridge RNG (with the polyatomic extension) and ENV.

The file must have a range-file extension (``.rrng``, ``.rng``, ``.env``, any case); the
dialect is read from the content, since RRNG files are often saved as ``.rng``: a
``[Ranges]`` section means RRNG; otherwise a first line of two integers (ion count, range
count) followed by a dashed table line means RNG, and without the dashed line ENV.

Dialects, as found in files in the wild (no formal specification exists):

RRNG
    ``[Ions]`` (ignored: the ranges carry their atoms) and ``[Ranges]`` with ``Number=n``
    and ``RangeK=lower upper [Vol:v] [Name:ion] El:count ... [Color:RRGGBB]``; keys in any
    case; counts may be written ``1.000``; without ``El:count`` items the ``Name`` is read
    as a formula. ``Number`` must match the ranges listed.
RNG
    ``n_ions n_ranges``; per column a long-name line and a ``name r g b [(formula)]`` line;
    a dashed line, optionally followed by the column names (short or long); then per range
    ``. lower upper count_1 .. count_n`` (the leading marker may be ``.``, a row number, or
    absent). A row with several non-zero counts is a molecular ion made of those columns
    (CrO = Cr 1, O 1); a column with a ``(formula)`` stands for that formula. A following
    ``--- polyatomic extension`` block is a second RNG table naming molecular ranges of the
    first (matched by their bounds): it must agree with the first table's atoms, and gives
    the ion's name order and colour.
ENV
    ``#`` comments; ``n_ions n_ranges``; per ion ``name r g b``; per range
    ``name lower upper [numbers]``; anything after the declared ranges is not range data
    and is ignored.

Species names are element formulas checked against the periodic table (see
:mod:`apt_filters.io.formula`); ``check_elements=False`` reads made-up names as opaque species.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

from apt_filters.core.errors import InputError
from apt_filters.io.formula import Composition, combine, species
from apt_filters.io.ranges import Range, RangeTable, ion_name

RANGE_EXTENSIONS = (".rrng", ".rng", ".env")
_HEX = re.compile(r"[0-9A-Fa-f]{6}")


@dataclass(frozen=True)
class Line:
    """One non-blank line of a range file and its 1-based number."""

    no: int
    text: str

    @property
    def tokens(self) -> list[str]:
        return self.text.split()


def _lines(path: str) -> list[Line]:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", path) from None
    if not data.strip():
        raise InputError("empty range file", path)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # IVAS writes the local code page; names are ASCII anyway
    if "\x00" in text:
        raise InputError("binary data (NUL bytes) in a range file", path)
    return [Line(i, line.strip()) for i, line in enumerate(text.splitlines(), 1) if line.strip()]


def _number(token: str, path: str, line: Line, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise InputError(f"line {line.no}: {what} {token!r} is not a finite number", path)
    return value


def _count(token: str, path: str, line: Line) -> int:
    value = _number(token, path, line, "atom count")
    if value < 0 or value != int(value):
        raise InputError(f"line {line.no}: atom count {token!r} is not a whole number >= 0", path)
    return int(value)


def _rgb(tokens: list[str], path: str, line: Line) -> str:
    """``"RRGGBB"`` from three fractions in [0, 1]."""
    values = [_number(t, path, line, "colour component") for t in tokens]
    if any(not 0 <= v <= 1 for v in values):
        raise InputError(f"line {line.no}: colour {' '.join(tokens)} is outside 0..1", path)
    return "".join(f"{round(v * 255):02X}" for v in values)


def _counts_header(lines: list[Line], i: int, path: str) -> tuple[int, int]:
    """(ion count, range count) from the line ``lines[i]``."""
    if i >= len(lines):
        raise InputError(f"ends before its 'ion count, range count' line (after line {lines[-1].no})", path)
    line = lines[i]
    toks = line.tokens
    if len(toks) != 2 or not all(t.isdigit() for t in toks):
        raise InputError(f"line {line.no}: expected 'ion count, range count', got {line.text[:40]!r}", path)
    n_ions, n_ranges = int(toks[0]), int(toks[1])
    if n_ions < 1 or n_ranges < 1:
        raise InputError(f"line {line.no}: declares {n_ions} ions and {n_ranges} ranges; nothing to range", path)
    return n_ions, n_ranges


def _take(lines: list[Line], i: int, n: int, path: str, what: str) -> list[Line]:
    if i + n > len(lines):
        raise InputError(f"ends after {len(lines) - i} of the {n} declared {what}", path)
    return lines[i:i + n]


# --- RNG --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _RngTable:
    """One RNG table: its columns and its rows, before molecular names are applied."""

    columns: list[tuple[Composition, str]]  # (composition, colour) per column
    rows: list[tuple[Line, float, float, list[int]]]  # (line, lower, upper, counts)
    end: int  # index of the first line after the table


def _rng_table(lines: list[Line], i: int, path: str, check: bool, formulas: bool = False) -> _RngTable:
    """The RNG table whose counts line is ``lines[i]``; ``formulas``: column names are formulas."""
    n_ions, n_ranges = _counts_header(lines, i, path)
    i += 1
    names: list[tuple[str, str]] = []
    columns: list[tuple[Composition, str]] = []
    for k in range(n_ions):
        long_line, short_line = _take(lines, i + 2 * k, 2, path, "ion name lines")
        toks = short_line.tokens
        if len(toks) < 4 or toks[0].startswith("-"):
            raise InputError(f"line {short_line.no}: expected 'name red green blue', got {short_line.text[:40]!r}", path)
        colour = _rgb(toks[1:4], path, short_line)
        rest = " ".join(toks[4:])
        if rest and not (rest.startswith("(") and rest.endswith(")")):
            raise InputError(f"line {short_line.no}: unexpected {rest!r} after the colour", path)
        comp = (species(rest[1:-1], path, short_line.no, check, formula=True) if rest
                else species(toks[0], path, short_line.no, check, formula=formulas))
        names.append((toks[0], long_line.text))
        columns.append((comp, colour))
    i += 2 * n_ions
    dash = _take(lines, i, 1, path, "table lines")[0]
    if not dash.text.startswith("-"):
        raise InputError(f"line {dash.no}: expected the dashed line that starts the range table", path)
    header = dash.text.lstrip("-").split()
    if header and (len(header) != n_ions or any(h not in pair for h, pair in zip(header, names))):
        raise InputError(f"line {dash.no}: table columns {header} do not match the {n_ions} ions listed above", path)
    rows = []
    for line in _take(lines, i + 1, n_ranges, path, "range rows"):
        toks = line.tokens
        if len(toks) == n_ions + 3:
            if not (toks[0] == "." or toks[0].isdigit()):
                raise InputError(f"line {line.no}: range row starts with {toks[0]!r}, expected '.'", path)
            toks = toks[1:]
        if len(toks) != n_ions + 2:
            raise InputError(f"line {line.no}: range row has {len(line.tokens)} fields, expected {n_ions + 3}", path)
        lower = _number(toks[0], path, line, "lower bound")
        upper = _number(toks[1], path, line, "upper bound")
        rows.append((line, lower, upper, [_count(t, path, line) for t in toks[2:]]))
    return _RngTable(columns, rows, i + 1 + n_ranges)


def _rng_ranges(table: _RngTable, path: str) -> list[Range]:
    ranges = []
    for line, lower, upper, counts in table.rows:
        used = [(table.columns[k], n) for k, n in enumerate(counts) if n]
        if not used:
            raise InputError(f"line {line.no}: range {lower:g}-{upper:g} assigns no ion", path)
        comp = combine([(c, n) for (c, _), n in used])
        colour = used[0][0][1] if len(used) == 1 and used[0][1] == 1 else None
        ranges.append(Range(lower, upper, comp, color=colour))
    return ranges


def _apply_polyatomic(ranges: list[Range], poly: _RngTable, path: str) -> list[Range]:
    """Name and colour molecular ranges from the polyatomic extension table."""
    by_bounds = {(r.lower, r.upper): k for k, r in enumerate(ranges)}
    ranges = list(ranges)
    for line, lower, upper, counts in poly.rows:
        used = [k for k, n in enumerate(counts) if n]
        if len(used) != 1 or counts[used[0]] != 1:
            raise InputError(f"line {line.no}: a polyatomic row must name exactly one ion", path)
        if (lower, upper) not in by_bounds:
            raise InputError(f"line {line.no}: polyatomic range {lower:g}-{upper:g} is not in the main table", path)
        k = by_bounds[(lower, upper)]
        comp, colour = poly.columns[used[0]]
        if dict(comp) != dict(ranges[k].composition):
            main = " ".join(f"{el}:{n}" for el, n in ranges[k].composition)
            raise InputError(f"line {line.no}: polyatomic ion {ion_name(comp)} "
                             f"does not match the main table's atoms ({main}) for {lower:g}-{upper:g}", path)
        ranges[k] = Range(lower, upper, comp, color=colour)
    return ranges


def parse_rng(lines: list[Line], path: str, check_elements: bool = True) -> list[Range]:
    """Ranges of an Oak Ridge RNG file, including its polyatomic extension block."""
    main = _rng_table(lines, 0, path, check_elements)
    ranges = _rng_ranges(main, path)
    rest = lines[main.end:]
    if rest and rest[0].text.startswith("--"):
        # Polyatomic names are formulas even in anonymised files, so that they can be
        # checked against the main table's atoms.
        poly = _rng_table(rest, 1, path, check_elements, formulas=True)
        ranges = _apply_polyatomic(ranges, poly, path)
        rest = rest[poly.end:]
    if rest:
        raise InputError(f"line {rest[0].no}: unexpected text after the range table: {rest[0].text[:40]!r}", path)
    return ranges


# --- RRNG -------------------------------------------------------------------------------------


_RANGE_KEY = re.compile(r"range(\d+)", re.IGNORECASE)


def _rrng_range(line: Line, value: str, path: str, check: bool) -> Range:
    toks = value.split()
    if len(toks) < 2:
        raise InputError(f"line {line.no}: expected 'lower upper El:count ...', got {value[:40]!r}", path)
    lower = _number(toks[0], path, line, "lower bound")
    upper = _number(toks[1], path, line, "upper bound")
    parts: list[tuple[Composition, int]] = []
    name = colour = volume = None
    for tok in toks[2:]:
        key, sep, val = tok.partition(":")
        if not sep or not key or not val:
            raise InputError(f"line {line.no}: expected 'key:value', got {tok!r}", path)
        low = key.lower()
        if low in ("vol", "volume"):
            volume = _number(val, path, line, "volume")
        elif low == "name":
            name = val
        elif low in ("color", "colour"):
            if not _HEX.fullmatch(val):
                raise InputError(f"line {line.no}: colour {val!r} is not RRGGBB hex", path)
            colour = val.upper()
        else:
            parts.append((species(key, path, line.no, check), _count(val, path, line)))
    comp = combine(parts)
    if not comp:
        if name is None:
            raise InputError(f"line {line.no}: range {lower:g}-{upper:g} lists no atoms and no name", path)
        comp = species(name, path, line.no, check)
    return Range(lower, upper, comp, color=colour, volume=volume)


def parse_rrng(lines: list[Line], path: str, check_elements: bool = True) -> list[Range]:
    """Ranges of an IVAS RRNG file."""
    section = None
    declared: tuple[Line, int] | None = None
    found: dict[int, Range] = {}
    for line in lines:
        if line.text.startswith(("#", ";")):
            continue
        if line.text.startswith("[") and line.text.endswith("]"):
            section = line.text[1:-1].strip().lower()
            continue
        key, sep, value = line.text.partition("=")
        if not sep:
            raise InputError(f"line {line.no}: expected 'key=value' or '[section]', got {line.text[:40]!r}", path)
        if section != "ranges":
            continue
        key = key.strip()
        match = _RANGE_KEY.fullmatch(key)
        if key.lower() == "number":
            if not value.strip().isdigit():
                raise InputError(f"line {line.no}: Number={value.strip()!r} is not a count", path)
            declared = (line, int(value))
        elif match:
            k = int(match.group(1))
            if k in found:
                raise InputError(f"line {line.no}: Range{k} is given twice", path)
            found[k] = _rrng_range(line, value, path, check_elements)
        else:
            raise InputError(f"line {line.no}: unknown key {key!r} in [Ranges]", path)
    if section is None and not found:
        raise InputError("no [Ranges] section", path)
    if declared is not None and declared[1] != len(found):
        raise InputError(f"line {declared[0].no}: declares Number={declared[1]} but lists {len(found)} ranges", path)
    if not found:
        raise InputError("lists no ranges", path)
    return [found[k] for k in sorted(found)]


# --- ENV --------------------------------------------------------------------------------------


def parse_env(lines: list[Line], path: str, check_elements: bool = True) -> list[Range]:
    """Ranges of an ENV file; text after the declared ranges is ignored."""
    lines = [line for line in lines if not line.text.startswith("#")]
    n_ions, n_ranges = _counts_header(lines, 0, path)
    ions: dict[str, tuple[Composition, str]] = {}
    for line in _take(lines, 1, n_ions, path, "ion lines"):
        toks = line.tokens
        if len(toks) != 4:
            raise InputError(f"line {line.no}: expected 'name red green blue', got {line.text[:40]!r}", path)
        ions[toks[0]] = (species(toks[0], path, line.no, check_elements), _rgb(toks[1:], path, line))
    ranges = []
    for line in _take(lines, 1 + n_ions, n_ranges, path, "range lines"):
        toks = line.tokens
        if len(toks) < 3:
            raise InputError(f"line {line.no}: expected 'name lower upper', got {line.text[:40]!r}", path)
        if toks[0] not in ions:
            raise InputError(f"line {line.no}: range names ion {toks[0]!r}, which is not listed above", path)
        comp, colour = ions[toks[0]]
        lower = _number(toks[1], path, line, "lower bound")
        upper = _number(toks[2], path, line, "upper bound")
        for tok in toks[3:]:
            _number(tok, path, line, "value")
        ranges.append(Range(lower, upper, comp, color=colour))
    return ranges


# --- entry point ------------------------------------------------------------------------------


def _check_extension(path: str) -> None:
    ext = Path(path).suffix.lower()
    if ext not in RANGE_EXTENSIONS:
        raise InputError(f"unknown range file extension {ext or '(none)'!r}; "
                         f"expected one of {', '.join(RANGE_EXTENSIONS)}", path)


def range_dialect(path: str, lines: list[Line]) -> str:
    """``"rrng"``, ``"rng"`` or ``"env"`` from the lines of a range file."""
    if any(line.text.lower().replace(" ", "") == "[ranges]" for line in lines):
        return "rrng"
    content = [line for line in lines if not line.text.startswith("#")]
    toks = content[0].tokens if content else []
    if len(toks) == 2 and all(t.isdigit() for t in toks):
        return "rng" if any(line.text.startswith("-") for line in content[1:]) else "env"
    raise InputError("not a range file: no [Ranges] section and no 'ion count, range count' first line", path)


PARSERS = {"rrng": parse_rrng, "rng": parse_rng, "env": parse_env}


def read_ranges(path: str | os.PathLike, *, check_elements: bool = True) -> RangeTable:
    """Read an RRNG, RNG or ENV range file into a :class:`RangeTable`.

    Parameters
    ----------
    path : path-like
        ``.rrng``, ``.rng`` or ``.env`` file (any case); the dialect is read from the content.
    check_elements : bool
        Species names must be formulas of chemical elements (default). ``False`` reads
        made-up names (anonymised test files) as opaque species.

    Returns
    -------
    RangeTable
        Ranges in file order, molecular ions decomposed into elements with multiplicity
        (RNG row ``Cr 1, O 2`` or RRNG ``Cr:1 O:2`` -> ``(("Cr", 1), ("O", 2))``), with
        colours and (RRNG) atomic volumes where the file gives them.

    Raises
    ------
    InputError
        Unknown extension, unreadable or malformed file, unknown element: one line naming
        the file, the line number and the problem.
    AptFiltersError
        Overlapping ranges (naming both) or a lower bound not below the upper one.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError("no such file" if not os.path.exists(path) else "not a regular file", path)
    _check_extension(path)
    lines = _lines(path)
    ranges = PARSERS[range_dialect(path, lines)](lines, path, check_elements)
    return RangeTable(ranges, source=path)
