"""Options every command spells the same way.

``-o/--output`` names what a command writes (a file or a folder); the older spellings
(``--out``, ``--outdir``) are still accepted but no longer shown in ``--help``.
"""

from __future__ import annotations

import argparse

OLD_OUTPUT_NAMES = ("--out", "--outdir")


def add_output(parser: argparse.ArgumentParser, help: str, *, metavar: str = "OUT", default: str | None = None) -> None:
    """Add ``-o/--output`` (dest ``output``) and its hidden old spellings.

    Without a ``default`` the option is required; :func:`apt_filters.cli.main.main` checks it
    (argparse cannot require one of several spellings of an option).
    """
    parser.add_argument("-o", "--output", dest="output", metavar=metavar, default=default, help=help)
    for name in OLD_OUTPUT_NAMES:
        parser.add_argument(name, dest="output", help=argparse.SUPPRESS)
    if default is None:
        parser.set_defaults(output_parser=parser)


def check_output(args: argparse.Namespace) -> None:
    """Exit with argparse's usage error when a required ``-o/--output`` was not given."""
    parser = getattr(args, "output_parser", None)
    if parser is not None and args.output is None:
        parser.error("the following arguments are required: -o/--output")
