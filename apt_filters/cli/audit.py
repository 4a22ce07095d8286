"""``apt-filters audit IONS --range R [--json]``: check a range file against the mass spectrum."""

from __future__ import annotations

import argparse
import os
import sys

from apt_filters.cli.numbers import number
from apt_filters.cli.rangeopts import add_range_options, load_ranges

ORDER = 30


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "audit",
        help="check each range's label against the isotope patterns of the mass spectrum",
        description=(
            "Audit a range file against the mass spectrum of an ion file: for every range, compare the "
            "counts in the windows of its label's isotopes (natural abundances, charge states 1-3, "
            "molecular ions included) with the expected pattern after a local background, propose the "
            "species that fits best when the label does not, and report overlapping ranges, ranges on "
            "background only, isotopes without a range and peaks no range covers, and what reading the "
            "range file met (decimal commas, duplicates merged, unknown species), with line numbers. "
            "--write-ranges writes the corrected range file (relabelled ranges; proposals for uncovered "
            "peaks as comments), saying what changed and why in its header; the input is never changed. "
            "Exit status 0 whatever is found; errors in the files give status 2."
        ),
    )
    parser.add_argument("ions", metavar="IONS", help="ion file (POS, EPOS, APT, CSV)")
    parser.add_argument("--range", "-r", dest="range_file", metavar="R", required=True,
                        help="range file (RRNG, RNG, ENV)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON instead of text")
    parser.add_argument("--resolution", type=number("[1, 1e6]"), default=500.0, metavar="M/DM",
                        help="mass resolving power m/dm (FWHM) of the spectrum (default 500)")
    parser.add_argument("--write-ranges", metavar="FIXED.rrng",
                        help="write the corrected range file (RRNG) here; an existing file is not replaced")
    add_range_options(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apt_filters.audit import AuditSettings, audit_ranges
    from apt_filters.core.errors import AptFiltersError
    from apt_filters.audit.fix import write_corrected_ranges
    from apt_filters.io import read_ions

    if args.write_ranges and os.path.lexists(args.write_ranges):  # refused before the audit, not after it
        raise AptFiltersError("exists already; the corrected range file is never written over a file",
                              args.write_ranges)
    ranges = load_ranges(args.range_file, args.relabel, args.unknown_species)
    result = audit_ranges(read_ions(args.ions), ranges, AuditSettings(resolution=args.resolution))
    print(result.to_json() if args.json else result)
    if args.write_ranges:
        path, changes, proposals = write_corrected_ranges(args.write_ranges, ranges, result)
        print(f"corrected range file: {path} ({len(changes)} changes, {len(proposals)} proposals not applied)",
              file=sys.stderr if args.json else sys.stdout)
    return 0
