"""``apt-filters audit IONS --range R [--json]``: check a range file against the mass spectrum."""

from __future__ import annotations

import argparse

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
            "background only, isotopes without a range and peaks no range covers. The ranges are never "
            "changed. Exit status 0 whatever is found; errors in the files give status 2."
        ),
    )
    parser.add_argument("ions", metavar="IONS", help="ion file (POS, EPOS, APT, CSV)")
    parser.add_argument("--range", "-r", dest="range_file", metavar="R", required=True,
                        help="range file (RRNG, RNG, ENV)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON instead of text")
    parser.add_argument("--resolution", type=float, default=500.0, metavar="M/DM",
                        help="mass resolving power m/dm (FWHM) of the spectrum (default 500)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from apt_filters.audit import AuditSettings, audit_ranges
    from apt_filters.core.errors import AptFiltersError
    from apt_filters.io import read_ions, read_ranges

    if not args.resolution > 0:
        raise AptFiltersError(f"--resolution must be positive, got {args.resolution:g}")
    result = audit_ranges(read_ions(args.ions), read_ranges(args.range_file),
                          AuditSettings(resolution=args.resolution))
    print(result.to_json() if args.json else result)
    return 0
