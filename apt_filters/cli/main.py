"""Entry point of ``apt-filters``.

Each sub-command lives in its own module of this package and exposes
``register(subparsers)``, which adds its parser and sets ``func(args) -> int``, and
``ORDER``, an int that places it in ``--help``. Modules are found by discovery, so adding a
command touches no shared file.
User mistakes arrive as :class:`~apt_filters.core.errors.AptFiltersError` and are printed
on one line with exit status 2; no traceback. Mistakes argparse finds (an unknown option, a
number out of range) are one line too.

SIGTERM and SIGHUP end a command the way Ctrl-C does: the exception unwinds every ``with``
block, so staged output folders and temporary files are removed, and the exit status is
128 + the signal number. The process then ends at once (:func:`run`). A reader that closes the pipe early (``apt-filters info --json | head``)
ends the command quietly with status 141, as SIGPIPE ends a C program.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import signal
import sys

from apt_filters import __version__
from apt_filters.cli.options import check_output
from apt_filters.core.atomic import raise_on_signal, received_interrupt, unraisable_hook
from apt_filters.core.errors import AptFiltersError, readable

SIGPIPE_STATUS = 128 + 13


class OneLineParser(argparse.ArgumentParser):
    """argparse whose mistakes are one line on stderr (status 2), pointing at ``--help``."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {readable(message)} (see {self.prog} --help)\n")


def command_modules() -> list:
    """The sub-command modules of this package, in ``ORDER``."""
    import apt_filters.cli as package

    modules = [importlib.import_module(f"{package.__name__}.{info.name}")
               for info in pkgutil.iter_modules(package.__path__) if info.name not in ("main", "options")]
    return sorted((m for m in modules if hasattr(m, "register")), key=lambda m: (getattr(m, "ORDER", 99), m.__name__))


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="apt-filters",
        description="Atom probe tomography iso-surfaces, MeshLab filter chains and interface chemistry.",
    )
    parser.add_argument("--version", action="version", version=f"apt-filters {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in command_modules():
        module.register(sub)
    return parser


def _say(text: str) -> None:
    """Print to stderr; a closed terminal (SIGHUP) must not turn the message into a traceback."""
    try:
        print(text, file=sys.stderr)
    except OSError:
        pass


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    check_output(args)
    # Ctrl-C too, where it is live (a shell's background job ignores it, and must go on doing so): recorded,
    # it still ends the run when a callback swallowed its exception
    caught = (signal.SIGTERM, signal.SIGHUP) + ((signal.SIGINT,) if signal.getsignal(signal.SIGINT)
                                                 is signal.default_int_handler else ())
    previous = {signum: signal.signal(signum, raise_on_signal) for signum in caught}
    previous_hook, sys.unraisablehook = sys.unraisablehook, unraisable_hook
    try:
        status = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at exit
        return status
    except AptFiltersError as exc:
        _say(f"apt-filters {args.command}: error: {exc}")
        return 2
    except BrokenPipeError:
        # Point stdout at /dev/null so that the interpreter's own flush at exit stays quiet.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return SIGPIPE_STATUS
    except (KeyboardInterrupt, Exception) as exc:
        interrupt = _interrupt_behind(exc)
        if interrupt is None:
            raise
        signum = getattr(interrupt, "signum", signal.SIGINT)
        _say(f"apt-filters {args.command}: interrupted ({signal.Signals(signum).name})")
        return 128 + signum
    finally:
        sys.unraisablehook = previous_hook
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _interrupt_behind(exc: BaseException) -> KeyboardInterrupt | None:
    """The interrupt that ended the command with ``exc``, if any.

    A signal handler's exception raised while a compiled kernel is called comes back wrapped (numba's
    dispatcher: "SystemError: ... returned a result with an exception set", the interrupt its cause);
    one swallowed by a callback leaves what it stopped to fail in its own words (numba's compiler:
    "no compiled object yet"), the signal recorded.
    """
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return received_interrupt()


def run() -> None:
    """The ``apt-filters`` command: :func:`main`, its status the process's exit status.

    A command ended by a signal exits at once when its clean-up is done, without the interpreter's
    finalization: the signal can stop a library halfway (an import, a kernel's compilation, a pool's
    threads), and finalizing that state crashed the process after its clean-up (SIGSEGV or "double
    free" in ~1 of 100 runs stopped by SIGTERM under load), so it ended on a crash, not 128 + signal.
    """
    status = main()
    if status > 128:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except OSError:  # a closed pipe or terminal: nothing left to tell
                pass
        os._exit(status)
    sys.exit(status)


if __name__ == "__main__":  # pragma: no cover
    run()
