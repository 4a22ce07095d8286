"""Numbers checked at the door: is a value finite and inside its interval."""

from __future__ import annotations

import math


def within(value: float, interval: str) -> bool:
    """Whether ``value`` is finite and inside ``interval``.

    ``interval`` is written as in mathematics: ``"(0, 1]"`` (``(``/``)`` open ends, ``[``/``]``
    closed ends, bounds any float literal). NaN and infinities are never within.
    """
    lo, hi = (float(v) for v in interval[1:-1].split(","))
    above = value > lo if interval[0] == "(" else value >= lo
    below = value < hi if interval[-1] == ")" else value <= hi
    return math.isfinite(value) and above and below
