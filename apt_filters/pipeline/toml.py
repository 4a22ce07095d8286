"""A TOML writer for the pipeline configuration (reading uses the standard ``tomllib``).

The configuration is a table of tables holding strings, numbers, booleans and flat lists,
plus arrays of tables (``[[surface]]``); that is all this writer supports.
"""

from __future__ import annotations

import json
import math


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a valid TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps(data: dict) -> str:
    """TOML text for ``{section: {key: value}}`` and ``{section: [{key: value}, ...]}``."""
    out: list[str] = []
    for section, body in data.items():
        tables = body if isinstance(body, list) else [body]
        header = f"[[{section}]]" if isinstance(body, list) else f"[{section}]"
        for table in tables:
            out.append(header)
            out += [f"{k} = {_value(v)}" for k, v in table.items() if v is not None]
            out.append("")
    return "\n".join(out)
