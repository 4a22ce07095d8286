"""Ion species names -> element compositions, checked against the periodic table.

``"CrO2"`` -> ``(("Cr", 1), ("O", 2))``. Symbols are checked against the table maintained
by the ``periodictable`` package (H..Og; the isotope labels D and T are not elements).
Range files written by anonymising tools use made-up species names ("Aa", "In-P"); reading
them with ``check_elements=False`` keeps every name as one opaque species instead.
"""

from __future__ import annotations

import re

import periodictable

from apt_filters.core.errors import InputError
from apt_filters.io.ranges import MAX_ATOMS

ELEMENTS = frozenset(el.symbol for el in periodictable.elements if el.number >= 1)
"""Chemical element symbols (118)."""

Composition = tuple[tuple[str, int], ...]

_PART = re.compile(r"([A-Z][a-z]*)(\d*)")
_OPAQUE = re.compile(r"[^\s:=]+")
CLIP = 40
"""Characters of a file's text quoted in an error line (a 1 MB token must not make a 1 MB line)."""


def clip(text: str, limit: int = CLIP, quote: bool = True) -> str:
    """``repr(text)`` (``text`` without ``quote``), cut to ``limit`` characters and marked with the
    full length when longer."""
    show = repr if quote else str
    if len(text) <= limit:
        return show(text)
    return f"{show(text[:limit])}... ({len(text):,} characters)"


def is_formula(text: str) -> bool:
    """True when ``text`` is a formula of known element symbols (``"Cr2O"``; counts not checked)."""
    comp = split_formula(text)
    return comp is not None and all(el in ELEMENTS for el, _ in comp)


def split_formula(text: str) -> Composition | None:
    """Symbols and counts of a formula such as ``"Cr2O"``, in order; None if ``text`` is not one.

    Repeated symbols are summed (``"CrOCr"`` -> ``(("Cr", 2), ("O", 1))``); symbols are not
    checked here.
    """
    if not text or _PART.sub("", text):
        return None
    counts: dict[str, int] = {}
    for symbol, digits in _PART.findall(text):
        n = int(digits) if digits else 1
        if n < 1:
            return None
        counts[symbol] = counts.get(symbol, 0) + n
    return tuple(counts.items())


def species(text: str, path: str, line_no: int, check_elements: bool = True, formula: bool = False) -> Composition:
    """Composition of the species named ``text`` on line ``line_no`` of range file ``path``.

    With ``check_elements`` the name must be a formula of known element symbols. Without
    it the name is one opaque species, unless ``formula`` says the text is given as a
    formula (an RNG column's ``(formula)`` or a polyatomic block name), which is then split.

    Raises
    ------
    InputError
        Naming the file, the line and the offending name.
    """
    if not check_elements and not formula:
        if not _OPAQUE.fullmatch(text):
            raise InputError(f"line {line_no}: {clip(text)} is not a species name", path)
        return ((text, 1),)
    comp = split_formula(text)
    if comp is None:
        what = "unknown element" if check_elements else "not a chemical formula"
        raise InputError(f"line {line_no}: {what} {clip(text)}", path)
    if check_elements:
        unknown = [el for el, _ in comp if el not in ELEMENTS]
        if unknown:
            raise InputError(f"line {line_no}: unknown element {clip(unknown[0])}"
                             + (f" in {clip(text)}" if text != unknown[0] else ""), path)
    big = [n for _, n in comp if n > MAX_ATOMS]
    if big:
        raise InputError(f"line {line_no}: {clip(text)} has {big[0]:,} atoms of one element, more than {MAX_ATOMS:,}",
                         path)
    return comp


def combine(parts: list[tuple[Composition, int]]) -> Composition:
    """Sum of compositions times multiplicities, elements in order of first appearance."""
    counts: dict[str, int] = {}
    for comp, times in parts:
        for el, n in comp:
            counts[el] = counts.get(el, 0) + n * times
    return tuple((el, n) for el, n in counts.items() if n > 0)
