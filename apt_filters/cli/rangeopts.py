"""Range-file options shared by ``info``, ``audit`` and ``run``: relabelling and unknown species."""

from __future__ import annotations

import argparse


def add_range_options(parser: argparse.ArgumentParser) -> None:
    """``--relabel OLD=NEW`` (repeatable) and ``--unknown-species {species,unranged}``."""
    parser.add_argument("--relabel", action="append", metavar="OLD=NEW",
                        help="label the ranges of species OLD as NEW, e.g. Cr2O=Ni (repeatable; applied after "
                             "reading, recorded in the output)")
    parser.add_argument("--unknown-species", choices=["species", "unranged"],
                        help="range-file names that are not chemical formulas (unknown60, X23): counted as their "
                             "own species (default) or left unranged")


def load_ranges(path: str, relabel: list[str] | None = None, unknown: str | None = None):
    """The range file read with the reading policy (docs/io.md), then relabelled."""
    from apt_filters.io.rangefiles import read_ranges, relabel as apply

    table = read_ranges(path, unknown=unknown or "species")
    return apply(table, relabel) if relabel else table
