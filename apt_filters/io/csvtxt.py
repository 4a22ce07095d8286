"""Ion tables as text: CSV or whitespace-separated TXT with x, y, z, m/z columns.

An optional header line names the columns (``x, y, z, m/z`` in any order; units in
brackets such as ``x (nm)`` are ignored; ``mz``, ``m``, ``mass``, ``Da`` and
``mass-to-charge`` name the m/z column; further named columns become extras). Without a
header the file must have exactly four columns in the order x, y, z, m/z. Lines starting
with ``#`` are comments. Text is for small tables: parsing keeps a float64 copy of every
column (8 B per value) besides the float32 result, so use POS/EPOS/APT6 for 10^7+ ions.
"""

from __future__ import annotations

import re

import numpy as np

from apt_filters.core.errors import InputError
from apt_filters.io.ions import IonTable

_MZ_NAMES = {"m/z", "mz", "m", "mass", "da", "mass-to-charge", "mass_to_charge", "masstocharge", "m/n"}
_UNIT = re.compile(r"[\(\[].*?[\)\]]")


def _delimiter(line: str) -> str | None:
    for sep in (",", ";", "\t"):
        if sep in line:
            return sep
    return None  # any whitespace


def _split(line: str, sep: str | None) -> list[str]:
    return [t.strip().strip("'\"") for t in (line.split(sep) if sep else line.split())]


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _column_names(path: str, header: list[str] | None, ncols: int, line_no: int) -> list[str]:
    """Canonical column names: 'x', 'y', 'z', 'mz' and extras under their header names."""
    if header is None:
        if ncols != 4:
            raise InputError(f"line {line_no}: {ncols} columns and no header; expected x, y, z, m/z", path)
        return ["x", "y", "z", "mz"]
    names = []
    for raw in header:
        name = _UNIT.sub("", raw).strip()
        low = name.lower()
        names.append("mz" if low in _MZ_NAMES else low if low in ("x", "y", "z") else name)
    missing = [n for n in ("x", "y", "z", "mz") if n not in names]
    if missing:
        raise InputError(f"line {line_no}: header {header} lacks column(s) {', '.join(missing)}", path)
    if len(set(names)) != len(names):
        raise InputError(f"line {line_no}: header {header} names a column twice", path)
    return names


def _first_bad_line(path: str, rows: list[tuple[int, str]], sep: str | None, ncols: int) -> InputError:
    """The precise message for a table numpy could not parse (slow path, errors only)."""
    for line_no, line in rows:
        tokens = _split(line, sep)
        if len(tokens) != ncols:
            return InputError(f"line {line_no}: {len(tokens)} columns, expected {ncols}", path)
        bad = [t for t in tokens if not _is_number(t)]
        if bad:
            return InputError(f"line {line_no}: {bad[0]!r} is not a number", path)
    return InputError("unreadable numeric table", path)


def read_text_ions(path: str, data: bytes) -> IonTable:
    """Parse the bytes ``data`` of a CSV/TXT ion table read from ``path``.

    Peak memory: the text, one float64 array of all columns and the float32 result.
    """
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"not UTF-8 text (byte {exc.start})", path) from None
    rows = [(i, line) for i, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise InputError("no ions: the text holds no data lines", path)
    sep = _delimiter(rows[0][1])
    first = _split(rows[0][1], sep)
    has_header = not all(_is_number(t) for t in first)
    names = _column_names(path, first if has_header else None, len(first), rows[0][0])
    if has_header:
        rows = rows[1:]
    if not rows:
        raise InputError("no ions: header but no data lines", path)
    try:
        table = np.loadtxt([line for _, line in rows], delimiter=sep, dtype=np.float64, ndmin=2,
                           comments=None, quotechar='"')
    except ValueError:
        raise _first_bad_line(path, rows, sep, len(names)) from None
    if table.shape[1] != len(names):
        raise _first_bad_line(path, rows, sep, len(names))
    cols = {name: table[:, i] for i, name in enumerate(names)}
    with np.errstate(over="ignore"):  # values beyond float32 become inf, refused by the caller's check
        positions = np.stack([cols.pop("x"), cols.pop("y"), cols.pop("z")], axis=1).astype(np.float32)
        mz = cols.pop("mz").astype(np.float32)
        extra = {k: v.astype(np.float32) for k, v in cols.items()}
    return IonTable(positions, mz, extra, source=path)
