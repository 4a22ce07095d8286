"""Numeric command-line options checked at the door: finite and within a plausible interval."""

from __future__ import annotations

import argparse
from typing import Callable

from apt_filters.core.numbers import within


def number(interval: str, unit: str = "") -> Callable[[str], float]:
    """An argparse ``type``: a float inside ``interval`` (``"(0, 1]"``, see :func:`apt_filters.core.numbers.within`).

    NaN, infinities and values outside the interval are refused by argparse, before any file
    is read, in one line (exit status 2).
    """
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not within(value, interval):
            raise argparse.ArgumentTypeError(f"{text} is outside {interval} {unit}".rstrip())
        return value

    parse.__name__ = "number"
    return parse
