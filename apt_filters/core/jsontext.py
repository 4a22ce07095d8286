"""Strict JSON text: what every JSON file and ``--json`` output of apt-filters is written with.

JSON has no NaN or infinity; Python's ``json`` writes them as the bare words ``NaN`` and
``Infinity`` by default, which strict parsers (browsers, ``jq``, most languages) refuse.
Here every non-finite number becomes ``null`` and, where it was the value of a key, a sibling
key ``<key>_null`` says what it was (``"NaN: not defined"``, ``"+infinity"``), so that a
reader can tell a missing figure from an undefined one. numpy scalars and arrays become
plain numbers and lists, paths become strings.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

NULL_SUFFIX = "_null"
"""Suffix of the key that says why its sibling is null."""


def _why(number: float) -> str:
    return "NaN: not defined" if math.isnan(number) else f"{'+' if number > 0 else '-'}infinity"


def _clean(value) -> tuple[object, str | None]:
    """(JSON-ready value, why it or something in it became null) of one value."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value), None
    if isinstance(value, (int, np.integer)):
        return int(value), None
    if isinstance(value, (float, np.floating)):
        number = float(value)
        return (number, None) if math.isfinite(number) else (None, _why(number))
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, os.PathLike):
        return os.fspath(value), None
    if isinstance(value, dict):
        out: dict = {}
        for key, item in value.items():
            clean, why = _clean(item)
            out[key] = clean
            if why is not None and not isinstance(item, dict):
                out.setdefault(f"{key}{NULL_SUFFIX}", why)
        return out, None
    if isinstance(value, (list, tuple)):
        items = [_clean(item) for item in value]
        nulls = [why for _, why in items if why is not None]
        return [clean for clean, _ in items], (f"{len(nulls)} non-finite entries written as null" if nulls else None)
    return value, None


def strict_json(value) -> object:
    """``value`` made JSON-ready: non-finite numbers null with a ``<key>_null`` reason beside them."""
    return _clean(value)[0]


def dumps(value, **kwargs) -> str:
    """:func:`json.dumps` of :func:`strict_json` ``(value)``, refusing any NaN left (``allow_nan=False``)."""
    return json.dumps(strict_json(value), allow_nan=False, **kwargs)
