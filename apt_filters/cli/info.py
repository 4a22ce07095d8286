"""``apt-filters info FILE [--range R] [--json]``: what an ion file holds.

Ion count, bounding box, m/z span and, with a range file, the ranged fraction and the
composition by element (molecular ions decomposed into their atoms), by
:func:`apt_filters.io.summary.summarize`: the file is streamed in chunks, so 10^9-ion files
need one chunk of memory.
"""

from __future__ import annotations

import argparse
import dataclasses

from apt_filters.cli.rangeopts import add_range_options, load_ranges
from apt_filters.core import jsontext
from apt_filters.core.errors import AptFiltersError

ORDER = 10
NOTES_SHOWN = 10
"""Range-file notes printed in full; the rest are counted."""
FORMAT_NAMES = {"pos": "POS", "epos": "EPOS", "apt6": "APT6 (AP Suite)", "ato": "ATO (LAWATAP / GPM Rouen)",
                "text": "text table"}


def _as_json(path: str, summary, ranges) -> dict:
    from apt_filters.io.readers import ion_format

    out = {
        "file": path,
        "format": ion_format(path),
        "ions": summary.ions,
        "bounds_nm": {"lower": summary.lower.tolist(), "upper": summary.upper.tolist()},
        "mz_da": [summary.mz_min, summary.mz_max],
    }
    if ranges:
        out.update({
            "range_file": ranges.source,
            "ranges": len(ranges),
            "range_notes": [dataclasses.asdict(n) for n in ranges.notes],
            "ranged_ions": summary.ranged,
            "ranged_fraction": summary.ranged_fraction,
            "ion_counts": summary.ion_counts,
            "atoms": summary.atoms,
            "composition": summary.composition(),
        })
    return out


def _as_text(path: str, summary, ranges) -> str:
    from apt_filters.io.readers import ion_format

    axes = "   ".join(f"{a} {lo:.3f} .. {hi:.3f}" for a, lo, hi in zip("xyz", summary.lower, summary.upper))
    lines = [
        f"{path}: {FORMAT_NAMES[ion_format(path)]}, {summary.ions:,} ions",
        f"  bounds (nm)   {axes}",
        f"  m/z (Da)      {summary.mz_min:.3f} .. {summary.mz_max:.3f}",
    ]
    if ranges:
        lines += [
            f"  ranges        {ranges.source}: {len(ranges)} ranges, {len(ranges.ions)} ions, "
            f"{len(ranges.elements)} elements",
            *(f"  range file    {f'line {n.line}: ' if n.line is not None else ''}{n.message}"
              for n in ranges.notes[:NOTES_SHOWN]),
            *([f"  range file    ... and {len(ranges.notes) - NOTES_SHOWN} more (apt-filters audit lists them all)"]
              if len(ranges.notes) > NOTES_SHOWN else []),
            f"  ranged        {summary.ranged:,} ions ({100 * summary.ranged_fraction:.2f} %)",
            "  composition   at.% (molecular ions decomposed into atoms)",
        ]
        lines += [f"    {el:<3} {100 * frac:7.3f}   ({summary.atoms[el]:,} atoms)"
                  for el, frac in summary.composition().items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from apt_filters.io.readers import ion_format

    if args.relabel and not args.range_file:
        raise AptFiltersError("--relabel needs a range file (--range)")
    ranges = load_ranges(args.range_file, args.relabel, args.unknown_species) if args.range_file else None
    ion_format(args.file)  # an unknown extension is refused before numba loads
    from apt_filters.io.summary import summarize

    summary = summarize(args.file, ranges)
    if args.json:
        print(jsontext.dumps(_as_json(args.file, summary, ranges), indent=2))
    else:
        print(_as_text(args.file, summary, ranges))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "info", help="summarise an ion file (count, bounds, m/z, composition)",
        description="Summarise an APT ion file: ion count, bounding box (nm), m/z span (Da) and, with a "
                    "range file, the ranged fraction and the composition by element (at.%; molecular "
                    "ions decomposed into atoms). The file is streamed in chunks.")
    p.add_argument("file", metavar="FILE", help="ion file: .pos, .epos, .apt (AP Suite APT6), .ato, .csv or .txt")
    p.add_argument("--range", "-r", dest="range_file", metavar="R",
                   help="range file (.rrng, .rng or .env) for ranged fraction and composition")
    p.add_argument("--json", action="store_true", help="print JSON instead of text (composition as fractions)")
    add_range_options(p)
    p.set_defaults(func=run)
