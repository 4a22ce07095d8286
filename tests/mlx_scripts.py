"""Hypothesis strategy of hostile MeshLab ``.mlx`` scripts, for the replay fuzz test and campaign.

Scripts are built from MeshLab's own vocabulary (the allowed filters, their parameter names
and types) mixed with wrong spellings, junk names, values that are not numbers, NaN,
infinities, huge counts, repeated parameters, nested elements (up to 60,000 deep), long runs
of one filter, DTDs and entities, and finally byte-level damage (truncation, insertion).
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

from hypothesis import strategies as st

from apt_filters.meshlab.filters import MLX_NAMES
from apt_filters.meshlab.mlx import PARAMS, RICH_TYPES

PARAM_NAMES = sorted({name for params in PARAMS.values() for name in params})
TYPES = sorted({t for types in RICH_TYPES.values() for t in types}) + ["RichString", "RichMatrix44f", ""]
ODD_VALUES = ["abc", "", "1e9", "1e300", "-1e300", "0x10", " 5", "true", "false", "TRUE", "nan", "NaN", "inf",
              "-inf", "-0", "1_000", "10" * 40, "0.5", "-0.53", "10", "1000", "1001", "2147483648", "\u00e9"]

TEXT = st.text(st.characters(blacklist_categories=("Cs", "Cc")), max_size=20)  # control characters: byte damage
values = st.one_of(
    st.sampled_from(ODD_VALUES),
    st.integers(-(10**12), 10**12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(0, 1).map(lambda v: f"{v:.6g}"),
    TEXT,
)


def rarely(draw, one_in: int) -> bool:
    """True about once in ``one_in`` draws (hypothesis' integers lean to their bounds)."""
    return draw(st.sampled_from(range(one_in))) == one_in - 1


def _valid_value(kind: str, interval: str):
    if kind == "bool":
        return st.sampled_from(["true", "false"])
    lo, hi = (float(v) for v in interval[1:-1].split(","))
    if kind in ("int", "enum"):
        return st.integers(int(lo), int(min(hi, 1000))).map(str)
    return st.floats(lo, min(hi, 1e3), exclude_min=interval[0] == "(", exclude_max=interval[-1] == ")").map(
        lambda v: f"{v:.6g}")


@st.composite
def params(draw, known: dict, valid: bool) -> str:
    """A ``<Param>`` of a filter whose parameters are ``known`` (MeshLab name -> (kind, interval)):
    a valid one, or one with a hostile name, value, type, attribute or nesting."""
    own = sorted(known)
    how = "own" if valid else draw(st.sampled_from(["own"] * 6 + ["lower", "other", "junk"]))
    name = draw(st.sampled_from(own)) if own and how in ("own", "lower") else \
        draw(st.sampled_from(PARAM_NAMES) if how == "other" else TEXT)
    kind, interval = known.get(name, ("float", "[0, 1]"))
    name = name.lower() if how == "lower" else name
    good = valid or draw(st.booleans())
    attrs = {"name": name, "value": draw(_valid_value(kind, interval) if good else values)}
    if valid or not rarely(draw, 10):  # MeshLab always writes the type; leave it out now and then
        attrs["type"] = sorted(RICH_TYPES[kind])[0] if valid or not rarely(draw, 8) else draw(st.sampled_from(TYPES))
    if not valid and rarely(draw, 10):
        attrs[draw(st.sampled_from(["min", "max", "enum_cardinality", "tooltip", "x", "val0"]))] = draw(values)
    text = " ".join(f"{k}={quoteattr(v)}" for k, v in attrs.items() if "\x00" not in v)
    depth = 0 if valid else draw(st.sampled_from([0] * 12 + [1, 3, 60_000]))
    return f"  <Param {text}>" + "<a>" * depth + "</a>" * depth + "</Param>\n"


@st.composite
def filters(draw) -> str:
    """One ``<filter>``: an allowed one (nine in ten) with valid parameters (half of them) or hostile ones."""
    name = draw(TEXT) if rarely(draw, 10) else draw(st.sampled_from(sorted(MLX_NAMES)))
    known = PARAMS.get(MLX_NAMES.get(name, ""), {})
    valid = draw(st.booleans())
    body = draw(st.lists(params(known, valid), max_size=4 if known or not valid else 0,
                         unique_by=(lambda line: line.split('"')[1]) if valid else None))
    if body and not valid and rarely(draw, 6):
        body.append(body[0])  # a parameter given twice
    return f" <filter name={quoteattr(name)}>\n" + "".join(body) + " </filter>\n"


@st.composite
def scripts(draw) -> bytes:
    """One ``.mlx`` script as bytes (a long run of one filter may pass the 1 MiB limit)."""
    body = draw(st.lists(filters(), max_size=6))
    if body and rarely(draw, 10):
        body = body[:1] * draw(st.integers(50, 3000))  # a long run of one filter
    head = draw(st.sampled_from(["<!DOCTYPE FilterScript>\n"] * 7 + ["", '<?xml version="1.0"?>\n',
                                 '<!DOCTYPE FilterScript [<!ENTITY a "aaaa">]>\n']))
    data = (head + "<FilterScript>\n" + "".join(body) + "</FilterScript>\n").encode("utf-8", "replace")
    damage = draw(st.sampled_from(["none"] * 8 + ["truncate", "insert"]))
    if damage == "truncate":
        data = data[: draw(st.integers(0, len(data)))]
    elif damage == "insert":
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(max_size=16)) + data[at:]
    return data
