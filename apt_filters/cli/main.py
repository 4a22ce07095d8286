"""Entry point of ``apt-filters``.

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``, and
``ORDER``, an int that places it in ``--help``. Modules are found by discovery, so adding a
command touches no shared file.
User mistakes arrive as :class:`~apt_filters.core.errors.AptFiltersError` and are printed
on one line with exit status 2; no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from apt_filters import __version__
from apt_filters.cli.options import check_output
from apt_filters.core.errors import AptFiltersError


def command_modules() -> list:
    """The sub-command modules of this package, in ``ORDER``."""
    import apt_filters.cli as package

    modules = [importlib.import_module(f"{package.__name__}.{info.name}")
               for info in pkgutil.iter_modules(package.__path__) if info.name not in ("main", "options")]
    return sorted((m for m in modules if hasattr(m, "register")), key=lambda m: (getattr(m, "ORDER", 99), m.__name__))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="apt-filters",
        description="Atom probe tomography iso-surfaces, MeshLab filter chains and interface chemistry.",
    )
    parser.add_argument("--version", action="version", version=f"apt-filters {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in command_modules():
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_output(args)
    try:
        return int(args.func(args) or 0)
    except AptFiltersError as exc:
        print(f"apt-filters {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("apt-filters: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
