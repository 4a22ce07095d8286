"""Range files: IVAS RRNG, Oak Ridge RNG (with the polyatomic extension) and ENV (GPM Rouen).

The file must have a range-file extension (``.rrng``, ``.rng``, ``.env``, any case); the
dialect is read from the content, since RRNG files are often saved as ``.rng``: a
``[Ranges]`` section means RRNG; otherwise a first line of two integers (ion count, range
count; after an ENV ``Rev_2.0`` version line) followed by a dashed table line means RNG, and
without the dashed line ENV.

Reading policy (docs/io.md): everything whose meaning is unambiguous is read, and each quirk
met on the way (decimal commas, a range index given twice, overlapping ranges of one species,
names that are not formulas, a column-header line, a layout variant, an encoding other than
UTF-8) becomes a :class:`~apt_filters.io.ranges.ReadNote` with its line number and what was
done; the audit reports the notes as findings. Only what cannot be read without guessing is
refused, in one line naming the file and the line: two different species claiming the same
m/z window, a malformed range line, a count that is not a whole number, an element count of an
unknown element.

Dialects, as found in files in the wild (no formal specification exists):

RRNG
    ``[Ions]`` (ignored: the ranges carry their atoms) and ``[Ranges]`` with ``Number=n``
    and ``RangeK=lower upper [Vol:v] [Name:ion] El:count ... [Color:RRGGBB]``; keys in any
    case; counts may be written ``1.000``; without ``El:count`` items the ``Name`` is the
    species. Lines before the first section (a column header) are skipped.
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
    ``#`` comments; an optional ``Rev_2.0`` version line (GPM Rouen); ``n_ions n_ranges``; per
    ion ``name r g b``; per range ``name lower upper [volume increment]`` (the Rev 2.0 atomic
    volume is in Å³); anything after the declared ranges is not range data and is ignored.

Species names that are formulas of chemical elements are decomposed into their atoms; other
names (``unknown60``, ``X23``, ``Hyd``) are kept as unknown species, each counted as its own
field, or left unranged with ``unknown="unranged"``. Tokens that claim to count atoms of an
element (RRNG ``El:count``, an RNG ``(formula)``, the polyatomic block) must name elements.
``check_elements=False`` reads every name as an opaque species (anonymised test files).
"""

from __future__ import annotations

import codecs
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

from apt_filters.core.errors import InputError
from apt_filters.io.formula import ELEMENTS, Composition, clip, combine, is_formula, species, split_formula
from apt_filters.io.ranges import MAX_ATOMS, Range, RangeTable, ReadNote, ion_name

RANGE_EXTENSIONS = (".rrng", ".rng", ".env")
UNKNOWN_SPECIES = ("species", "unranged")
"""What unknown species names become: their own field (default), or unranged ions."""
_HEX = re.compile(r"[0-9A-Fa-f]{6}")
_WHOLE = re.compile(r"[0-9]{1,12}")  # ASCII digits: str.isdigit() also takes "²", which int() refuses
_DECIMAL_COMMA = re.compile(r"[+-]?[0-9]+,[0-9]+(?:[eE][+-]?[0-9]+)?")
_NAME = re.compile(r"[^\s:=]+")
_ENV_VERSION = re.compile(r"rev_?\s*[0-9.]+", re.IGNORECASE)
_BOMS = ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"), (codecs.BOM_UTF8, "utf-8-sig"),
         (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))


@dataclass(frozen=True)
class Line:
    """One non-blank line of a range file and its 1-based number."""

    no: int
    text: str

    @property
    def tokens(self) -> list[str]:
        return self.text.split()


@dataclass
class _Reader:
    """State of one read: the file, the naming policy, and the notes taken so far."""

    path: str
    check: bool = True
    notes: list[ReadNote] = field(default_factory=list)
    commas: list[int] = field(default_factory=list)
    unknown: dict[str, int] = field(default_factory=dict)  # unknown species name -> first line

    def note(self, kind: str, line: int | None, message: str) -> None:
        self.notes.append(ReadNote(kind, line, message))

    def fail(self, line: Line | int | None, message: str) -> InputError:
        no = line.no if isinstance(line, Line) else line
        return InputError(f"line {no}: {message}" if no is not None else message, self.path)

    def number(self, token: str, line: Line, what: str) -> float:
        if _DECIMAL_COMMA.fullmatch(token):
            self.commas.append(line.no)
            token = token.replace(",", ".")
        try:
            value = float(token)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise self.fail(line, f"{what} {clip(token)} is not a finite number")
        return value

    def count(self, token: str, line: Line) -> int:
        value = self.number(token, line, "atom count")
        if not 0 <= value <= MAX_ATOMS or value != int(value):
            raise self.fail(line, f"atom count {clip(token)} is not a whole number from 0 to {MAX_ATOMS:,}")
        return int(value)

    def element(self, text: str, line: Line, formula: bool = False) -> Composition:
        """A token that claims to be an element (or a formula): checked unless reading opaque names."""
        return species(text, self.path, line.no, self.check, formula=formula)

    def name(self, text: str, line: Line) -> Composition:
        """A species name: a formula of elements, or else an unknown species kept under its name."""
        if not self.check or is_formula(text):
            return species(text, self.path, line.no, self.check)
        comp = species(text, self.path, line.no, check_elements=False)  # checks it is one token
        self.unknown.setdefault(text, line.no)
        return comp

    def finish(self, items: list[tuple[int, Range]], unknown: str) -> list[Range]:
        """Ranges with same-species overlaps merged, unknown species applied, notes completed."""
        if self.commas:
            lines = sorted(set(self.commas))
            self.note("decimal_comma", lines[0], f"decimal commas read as decimal points ({len(self.commas)} numbers "
                      f"on {len(lines)} line{'s' if len(lines) > 1 else ''}, first line {lines[0]})")
        used = {el for _, r in items for el, _ in r.composition}
        for text, no in self.unknown.items():
            if text not in used:  # an RNG column no range uses
                continue
            done = "its ions counted as its own species" if unknown == "species" else "its ranges left unranged"
            self.note("unknown_species", no, f"{text!r} is not a formula of chemical elements: kept as an unknown "
                      f"species, {done}")
        if unknown == "unranged":
            items = [(no, r) for no, r in items if not any(el in self.unknown for el, _ in r.composition)]
        return _resolve_overlaps(self, items)


def _resolve_overlaps(rd: _Reader, items: list[tuple[int, Range]]) -> list[Range]:
    """Merge overlapping ranges of one species into their union; refuse different species in one window.

    One pass over the ranges sorted by lower bound: kept ranges are disjoint, so only the last
    kept one can overlap the next.
    """
    order = sorted(range(len(items)), key=lambda k: items[k][1].lower)
    kept: list[int] = []  # indices into items, in lower-bound order
    merged: dict[int, Range] = {}
    for k in order:
        no, r = items[k]
        if kept:
            j = kept[-1]
            prev = merged.get(j, items[j][1])
            if r.lower < prev.upper:
                if r.composition != prev.composition:
                    raise rd.fail(no, f"ranges overlap: {prev.describe()} (line {items[j][0]}) and {r.describe()}: "
                                      "two species claim the same m/z window")
                union = Range(prev.lower, max(prev.upper, r.upper), prev.composition, color=prev.color or r.color,
                              volume=prev.volume if prev.volume is not None else r.volume)
                if (r.lower, r.upper) == (prev.lower, prev.upper):
                    rd.note("duplicate_range", no, f"{r.describe()} repeats line {items[j][0]}: dropped")
                else:
                    rd.note("merged_overlap", no, f"{r.describe()} overlaps {prev.describe()} (line {items[j][0]}) "
                            f"of the same species: merged into [{union.lower:g}, {union.upper:g}] Da")
                merged[j] = union
                continue
        kept.append(k)
    return [merged.get(k, items[k][1]) for k in sorted(kept)]


def _decode(data: bytes, rd: _Reader) -> str:
    """Text of a range file: UTF-8, UTF-16/32 (by BOM, or UTF-16 by its NUL pattern), else Latin-1."""
    encoding = next((enc for bom, enc in _BOMS if data.startswith(bom)), None)
    if encoding is None and len(data) >= 4 and b"\x00" in data:
        zeros = [data[k::2].count(0) / max(len(data[k::2]), 1) for k in (0, 1)]
        if max(zeros) > 0.9 and min(zeros) < 0.1:
            encoding = "utf-16-le" if zeros[1] > zeros[0] else "utf-16-be"
    if encoding is not None and encoding != "utf-8-sig":
        try:
            text = data.decode(encoding)
        except UnicodeDecodeError as exc:
            raise InputError(f"text in {encoding.upper()} (by its byte order mark or NUL pattern) does not decode "
                             f"at byte {exc.start}", rd.path) from None
        rd.note("encoding", None, f"text encoded as {encoding.upper().replace('-LE', ' LE').replace('-BE', ' BE')}: "
                "decoded")
        return text
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")  # IVAS writes the local code page; names are ASCII anyway


def _lines(path: str, rd: _Reader) -> list[Line]:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", path) from None
    if not data.strip():
        raise InputError("empty range file", path)
    text = _decode(data, rd)
    if "\x00" in text:
        raise InputError("binary data (NUL bytes) in a range file; not text in UTF-8, UTF-16, UTF-32 or Latin-1",
                         path)
    return [Line(i, line.strip()) for i, line in enumerate(text.splitlines(), 1) if line.strip()]


def _rgb(rd: _Reader, tokens: list[str], line: Line) -> str | None:
    """``"RRGGBB"`` from three fractions in [0, 1]; 0..255 components are scaled, others dropped.

    A colour is cosmetic: one outside the scale is noted and left out rather than refused.
    """
    values = [rd.number(t, line, "colour component") for t in tokens]
    if all(0 <= v <= 1 for v in values):
        return "".join(f"{round(v * 255):02X}" for v in values)
    shown = clip(" ".join(tokens), quote=False)
    if all(0 <= v <= 255 and v == int(v) for v in values):
        rd.note("colour", line.no, f"colour {shown} read as 0..255 components")
        return "".join(f"{int(v):02X}" for v in values)
    rd.note("colour", line.no, f"colour {shown} is outside 0..1: left out")
    return None


def _counts_header(rd: _Reader, lines: list[Line], i: int) -> tuple[int, int]:
    """(ion count, range count) from the line ``lines[i]``."""
    if i >= len(lines):
        raise InputError(f"ends before its 'ion count, range count' line (after line {lines[-1].no})", rd.path)
    line = lines[i]
    toks = line.tokens
    if len(toks) != 2 or not all(_WHOLE.fullmatch(t) for t in toks):
        raise rd.fail(line, f"expected 'ion count, range count', got {clip(line.text)}")
    n_ions, n_ranges = int(toks[0]), int(toks[1])
    if n_ions < 1 or n_ranges < 1:
        raise rd.fail(line, f"declares {n_ions} ions and {n_ranges} ranges; nothing to range")
    return n_ions, n_ranges


def _take(rd: _Reader, lines: list[Line], i: int, n: int, what: str) -> list[Line]:
    if i + n > len(lines):
        raise InputError(f"ends after {max(len(lines) - i, 0)} of the {n} declared {what}", rd.path)
    return lines[i:i + n]


# --- RNG --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _RngTable:
    """One RNG table: its columns and its rows, before molecular names are applied."""

    columns: list[tuple[Composition, str | None]]  # (composition, colour) per column
    rows: list[tuple[Line, float, float, list[int]]]  # (line, lower, upper, counts)
    end: int  # index of the first line after the table


def _rng_table(rd: _Reader, lines: list[Line], i: int, formulas: bool = False) -> _RngTable:
    """The RNG table whose counts line is ``lines[i]``; ``formulas``: column names are formulas."""
    n_ions, n_ranges = _counts_header(rd, lines, i)
    i += 1
    names: list[tuple[str, str]] = []
    columns: list[tuple[Composition, str | None]] = []
    name_lines = _take(rd, lines, i, 2 * n_ions, "ion name lines")
    for long_line, short_line in zip(name_lines[::2], name_lines[1::2]):
        toks = short_line.tokens
        if len(toks) < 4 or toks[0].startswith("-"):
            raise rd.fail(short_line, f"expected 'name red green blue', got {clip(short_line.text)}")
        colour = _rgb(rd, toks[1:4], short_line)
        rest = " ".join(toks[4:])
        if rest and not (rest.startswith("(") and rest.endswith(")")):
            raise rd.fail(short_line, f"unexpected {clip(rest)} after the colour")
        comp = (rd.element(rest[1:-1], short_line, formula=True) if rest
                else rd.element(toks[0], short_line, formula=True) if formulas else rd.name(toks[0], short_line))
        names.append((toks[0], long_line.text))
        columns.append((comp, colour))
    i += 2 * n_ions
    dash = _take(rd, lines, i, 1, "table lines")[0]
    if not dash.text.startswith("-"):
        raise rd.fail(dash, "expected the dashed line that starts the range table")
    header = dash.text.lstrip("-").split()
    if header and (len(header) != n_ions or any(h not in pair for h, pair in zip(header, names))):
        raise rd.fail(dash, f"table columns {clip(' '.join(header))} do not match the {n_ions} ions listed above")
    rows = []
    for line in _take(rd, lines, i + 1, n_ranges, "range rows"):
        toks = line.tokens
        if len(toks) == n_ions + 3:
            if not (toks[0] == "." or _WHOLE.fullmatch(toks[0])):
                raise rd.fail(line, f"range row starts with {clip(toks[0])}, expected '.'")
            toks = toks[1:]
        if len(toks) != n_ions + 2:
            raise rd.fail(line, f"range row has {len(line.tokens)} fields, expected {n_ions + 3}")
        lower = rd.number(toks[0], line, "lower bound")
        upper = rd.number(toks[1], line, "upper bound")
        rows.append((line, lower, upper, [rd.count(t, line) for t in toks[2:]]))
    return _RngTable(columns, rows, i + 1 + n_ranges)


def _rng_ranges(rd: _Reader, table: _RngTable) -> list[tuple[int, Range]]:
    ranges = []
    for line, lower, upper, counts in table.rows:
        used = [(table.columns[k], n) for k, n in enumerate(counts) if n]
        if not used:
            raise rd.fail(line, f"range {lower:g}-{upper:g} assigns no ion")
        comp = _atoms(rd, combine([(c, n) for (c, _), n in used]), line)
        colour = used[0][0][1] if len(used) == 1 and used[0][1] == 1 else None
        ranges.append((line.no, _range(rd, line, lower, upper, comp, colour)))
    return ranges


def _atoms(rd: _Reader, comp: Composition, line: Line) -> Composition:
    big = [(el, n) for el, n in comp if n > MAX_ATOMS]
    if big:
        raise rd.fail(line, f"{big[0][1]:,} atoms of {clip(big[0][0])} in one ion, more than {MAX_ATOMS:,}")
    return comp


def _range(rd: _Reader, line: Line, lower: float, upper: float, comp: Composition, colour: str | None = None,
           volume: float | None = None) -> Range:
    if not lower < upper:
        raise rd.fail(line, f"range {ion_name(comp)} [{lower:g}, {upper:g}] Da has lower bound not below upper bound")
    return Range(lower, upper, comp, color=colour, volume=volume)


def _apply_polyatomic(rd: _Reader, ranges: list[tuple[int, Range]], poly: _RngTable) -> list[tuple[int, Range]]:
    """Name and colour molecular ranges from the polyatomic extension table."""
    by_bounds = {(r.lower, r.upper): k for k, (_, r) in enumerate(ranges)}
    ranges = list(ranges)
    for line, lower, upper, counts in poly.rows:
        used = [k for k, n in enumerate(counts) if n]
        if len(used) != 1 or counts[used[0]] != 1:
            raise rd.fail(line, "a polyatomic row must name exactly one ion")
        if (lower, upper) not in by_bounds:
            raise rd.fail(line, f"polyatomic range {lower:g}-{upper:g} is not in the main table")
        k = by_bounds[(lower, upper)]
        comp, colour = poly.columns[used[0]]
        no, main = ranges[k]
        if dict(comp) != dict(main.composition):
            atoms = " ".join(f"{el}:{n}" for el, n in main.composition)
            raise rd.fail(line, f"polyatomic ion {clip(ion_name(comp), quote=False)} does not match the main "
                                f"table's atoms ({clip(atoms, quote=False)}) for {lower:g}-{upper:g}")
        ranges[k] = (no, Range(lower, upper, comp, color=colour))
    return ranges


def parse_rng(lines: list[Line], rd: _Reader) -> list[tuple[int, Range]]:
    """(line, range) of an Oak Ridge RNG file, including its polyatomic extension block."""
    main = _rng_table(rd, lines, 0)
    ranges = _rng_ranges(rd, main)
    rest = lines[main.end:]
    if rest and rest[0].text.startswith("--"):
        # Polyatomic names are formulas even in anonymised files, so that they can be
        # checked against the main table's atoms.
        poly = _rng_table(rd, rest, 1, formulas=True)
        ranges = _apply_polyatomic(rd, ranges, poly)
        rest = rest[poly.end:]
    if rest:
        raise rd.fail(rest[0], f"unexpected text after the range table: {clip(rest[0].text)}")
    return ranges


# --- RRNG -------------------------------------------------------------------------------------


_RANGE_KEY = re.compile(r"range(\d{1,12})", re.IGNORECASE)


def _rrng_range(rd: _Reader, line: Line, value: str) -> Range:
    toks = value.split()
    if len(toks) < 2:
        raise rd.fail(line, f"expected 'lower upper El:count ...', got {clip(value)}")
    lower = rd.number(toks[0], line, "lower bound")
    upper = rd.number(toks[1], line, "upper bound")
    parts: list[tuple[Composition, int]] = []
    name = colour = volume = None
    for tok in toks[2:]:
        key, sep, val = tok.partition(":")
        if not sep or not key or not val:
            raise rd.fail(line, f"expected 'key:value', got {clip(tok)}")
        low = key.lower()
        if low in ("vol", "volume"):
            volume = rd.number(val, line, "volume")
        elif low == "name":
            name = val
        elif low in ("color", "colour"):
            colour = val.lstrip("#").upper()
            if not _HEX.fullmatch(colour):
                rd.note("colour", line.no, f"colour {clip(val)} is not RRGGBB hex: left out")
                colour = None
        else:
            parts.append((rd.element(key, line), rd.count(val, line)))
    comp = _atoms(rd, combine(parts), line)
    if not comp:
        if name is None:
            raise rd.fail(line, f"range {lower:g}-{upper:g} lists no atoms and no name")
        comp = rd.name(name, line)
    return _range(rd, line, lower, upper, comp, colour, volume)


def parse_rrng(lines: list[Line], rd: _Reader) -> list[tuple[int, Range]]:
    """(line, range) of an IVAS RRNG file, in the order of the range numbers."""
    section = None
    declared: tuple[Line, int] | None = None
    found: dict[int, tuple[Line, Range]] = {}
    extra: list[tuple[Line, Range]] = []  # second ranges under an index already used
    for line in lines:
        if line.text.startswith(("#", ";")):
            continue
        if line.text.startswith("[") and line.text.endswith("]"):
            section = line.text[1:-1].strip().lower()
            continue
        key, sep, value = line.text.partition("=")
        if section != "ranges":
            if not sep:
                where = "before the first section" if section is None else f"in [{section}]"
                rd.note("header_line", line.no, f"{clip(line.text)} {where} is not 'key=value': skipped")
            continue
        if not sep:
            raise rd.fail(line, f"expected 'key=value' or '[section]', got {clip(line.text)}")
        key = key.strip()
        match = _RANGE_KEY.fullmatch(key)
        if key.lower() == "number":
            if not _WHOLE.fullmatch(value.strip()):
                raise rd.fail(line, f"Number={clip(value.strip())} is not a count")
            declared = (line, int(value))
        elif match:
            k = int(match.group(1))
            r = _rrng_range(rd, line, value)
            if k not in found:
                found[k] = (line, r)
            elif found[k][1] == r:
                rd.note("duplicate_range", line.no, f"Range{k} repeats line {found[k][0].no}: dropped")
            else:
                extra.append((line, r))
                rd.note("duplicate_index", line.no, f"Range{k} given again (first on line {found[k][0].no}) with "
                        f"other bounds or atoms: both kept, this one as range {len(found) + len(extra)}")
        else:
            raise rd.fail(line, f"unknown key {clip(key)} in [Ranges]")
    listed = len(found) + len(extra) + sum(n.kind == "duplicate_range" for n in rd.notes)
    if declared is not None and declared[1] > listed:
        raise rd.fail(declared[0], f"declares Number={declared[1]} but lists {listed} ranges")
    if declared is not None and declared[1] < listed:
        rd.note("extra_ranges", declared[0].no, f"declares Number={declared[1]} but lists {listed} ranges: "
                "all listed ranges read")
    if not found:
        raise InputError("lists no ranges", rd.path)
    return [(found[k][0].no, found[k][1]) for k in sorted(found)] + [(line.no, r) for line, r in extra]


# --- ENV --------------------------------------------------------------------------------------


def parse_env(lines: list[Line], rd: _Reader) -> list[tuple[int, Range]]:
    """(line, range) of an ENV file; text after the declared ranges is ignored."""
    lines = [line for line in lines if not line.text.startswith("#")]
    rev2 = bool(lines) and _ENV_VERSION.fullmatch(lines[0].text) is not None
    if rev2:
        rd.note("layout", lines[0].no, f"GPM Rouen ENV layout {clip(lines[0].text)}: range rows "
                "'name lower upper volume increment', atomic volumes read as Å³")
        lines = lines[1:]
    n_ions, n_ranges = _counts_header(rd, lines, 0)
    ions: dict[str, tuple[Composition, str | None]] = {}
    for line in _take(rd, lines, 1, n_ions, "ion lines"):
        toks = line.tokens
        if len(toks) != 4:
            raise rd.fail(line, f"expected 'name red green blue', got {clip(line.text)}")
        ions[toks[0]] = (rd.name(toks[0], line), _rgb(rd, toks[1:], line))
    ranges = []
    for line in _take(rd, lines, 1 + n_ions, n_ranges, "range lines"):
        toks = line.tokens
        if len(toks) < 3:
            raise rd.fail(line, f"expected 'name lower upper', got {clip(line.text)}")
        if toks[0] not in ions:
            raise rd.fail(line, f"range names ion {clip(toks[0])}, which is not listed above")
        comp, colour = ions[toks[0]]
        lower = rd.number(toks[1], line, "lower bound")
        upper = rd.number(toks[2], line, "upper bound")
        values = [rd.number(tok, line, "value") for tok in toks[3:]]
        volume = values[0] * 1e-3 if rev2 and values else None  # Å³ -> nm³
        ranges.append((line.no, _range(rd, line, lower, upper, comp, colour, volume)))
    return ranges


# --- entry point ------------------------------------------------------------------------------


def _check_extension(path: str) -> None:
    ext = Path(path).suffix.lower()
    if ext not in RANGE_EXTENSIONS:
        raise InputError(f"unknown range file extension {clip(ext) if ext else repr('(none)')}; "
                         f"expected one of {', '.join(RANGE_EXTENSIONS)}", path)


def range_dialect(path: str, lines: list[Line]) -> str:
    """``"rrng"``, ``"rng"`` or ``"env"`` from the lines of a range file."""
    if any(line.text.lower().replace(" ", "") == "[ranges]" for line in lines):
        return "rrng"
    content = [line for line in lines if not line.text.startswith("#")]
    if content and _ENV_VERSION.fullmatch(content[0].text):
        return "env"
    toks = content[0].tokens if content else []
    if len(toks) == 2 and all(_WHOLE.fullmatch(t) for t in toks):
        return "rng" if any(line.text.startswith("-") for line in content[1:]) else "env"
    raise InputError("not a range file: no [Ranges] section and no 'ion count, range count' first line", path)


PARSERS = {"rrng": parse_rrng, "rng": parse_rng, "env": parse_env}


def read_ranges(path: str | os.PathLike, *, check_elements: bool = True, unknown: str = "species") -> RangeTable:
    """Read an RRNG, RNG or ENV range file into a :class:`RangeTable`.

    Parameters
    ----------
    path : path-like
        ``.rrng``, ``.rng`` or ``.env`` file (any case); the dialect is read from the content.
    check_elements : bool
        Tokens that count atoms of an element must name one, and species names that are
        formulas of elements are decomposed (default). ``False`` reads every name as an
        opaque species (anonymised test files).
    unknown : {"species", "unranged"}
        What a species name that is not a formula of elements (``unknown60``, ``X23``)
        becomes: its own species (default), or its ranges are dropped and its ions unranged.

    Returns
    -------
    RangeTable
        Ranges in file order, molecular ions decomposed into elements with multiplicity
        (RNG row ``Cr 1, O 2`` or RRNG ``Cr:1 O:2`` -> ``(("Cr", 1), ("O", 2))``), with
        colours and atomic volumes (nm³) where the file gives them; ``notes`` lists each
        quirk met and what was done (see the module docstring).

    Raises
    ------
    InputError
        Unknown extension, unreadable or malformed file, unknown element in an element count,
        two species claiming one m/z window: one line naming the file, the line and the problem.

    Notes
    -----
    Time is linear in the size of the file (10^5 ranges: about a second).
    """
    path = os.fspath(path)
    if unknown not in UNKNOWN_SPECIES:
        raise InputError(f"unknown species must become one of {', '.join(UNKNOWN_SPECIES)}, not {clip(unknown)}")
    if not os.path.isfile(path):
        raise InputError("no such file" if not os.path.exists(path) else "not a regular file", path)
    _check_extension(path)
    rd = _Reader(path, check_elements)
    lines = _lines(path, rd)
    items = PARSERS[range_dialect(path, lines)](lines, rd)
    ranges = rd.finish(items, unknown)
    if not ranges:
        raise InputError("every range is of an unknown species left unranged: nothing to range", path)
    return RangeTable(ranges, source=path, notes=rd.notes)


def relabel(table: RangeTable, pairs: Sequence[str], *, origin: str = "command line") -> RangeTable:
    """The ranges of ``table`` with species renamed: ``"Cr2O=Ni"`` labels every Cr2O range Ni.

    Parameters
    ----------
    table : RangeTable
    pairs : sequence of str
        ``OLD=NEW``; OLD names an ion of the table (``table.ions``; a formula also matches the same
        atoms written in another order), NEW is a formula of elements or an unknown species name.
        Applied in order.
    origin : str
        Where the relabelling comes from, for the notes.

    Returns
    -------
    RangeTable
        Colours and volumes kept; one ``relabel`` note per pair added to ``table.notes``.

    Raises
    ------
    InputError
        A pair without ``=``, an OLD no range carries, a NEW that is not a species name.
    """
    ranges, notes = list(table.ranges), list(table.notes)
    for pair in pairs:
        if not isinstance(pair, str):
            raise InputError(f"relabel {clip(repr(pair), quote=False)}: expected OLD=NEW text, e.g. Cr2O=Ni")
        old, sep, new = (part.strip() for part in pair.partition("="))
        if not sep or not old or not new:
            raise InputError(f"relabel {clip(pair)}: expected OLD=NEW, e.g. Cr2O=Ni")
        atoms = dict(split_formula(old) or ()) if is_formula(old) else None  # "Cr2O" also finds "OCr2"
        hits = [k for k, r in enumerate(ranges) if r.ion == old or dict(r.composition) == atoms]
        if not hits:
            raise InputError(f"relabel {clip(pair)}: no range is labelled {clip(old)} "
                             f"(species: {clip(', '.join(dict.fromkeys(r.ion for r in ranges)), 200)})", table.source)
        if not _NAME.fullmatch(new):
            raise InputError(f"relabel {clip(pair)}: {clip(new)} is not a species name")
        comp = split_formula(new) if is_formula(new) else ((new, 1),)
        for k in hits:
            r = ranges[k]
            ranges[k] = Range(r.lower, r.upper, comp, color=r.color, volume=r.volume)
        spans = ", ".join(f"[{ranges[k].lower:g}, {ranges[k].upper:g}]" for k in hits[:5])
        more = f" and {len(hits) - 5} more" if len(hits) > 5 else ""
        unknown = "" if all(el in ELEMENTS for el, _ in comp) else " (an unknown species)"
        notes.append(ReadNote("relabel", None, f"{old} relabelled {ion_name(comp)}{unknown} ({origin}): "
                                               f"{len(hits)} range(s), {spans}{more} Da"))
    return RangeTable(ranges, source=table.source, notes=notes)
