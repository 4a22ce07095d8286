"""Atomic file output and the temporary files it needs.

A file is written to a temporary name beside the target and renamed onto it, so a crash
or an exception while writing leaves no half-written file behind, and an existing file is
only replaced when the caller allows it.

Every temporary name apt-filters makes holds ``.apt-filters-tmp.<host>-<pid>.``
(:func:`scratch_path`): beside the output it belongs to, hidden, and tagged with the process
that made it. A process that dies without cleaning up (``kill -9``, power loss) leaves it
behind; the next apt-filters process that writes into that folder removes it
(:func:`tidy`) once that process no longer runs. Clean-ups hold off SIGINT, SIGTERM and
SIGHUP (:func:`signals_held`) so that a second Ctrl-C cannot leave them half done.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import secrets
import shutil
import signal
import socket
import sys
import threading
from pathlib import Path
from typing import Iterable, Iterator

from apt_filters.core.errors import AptFiltersError

TMP_TAG = "apt-filters-tmp"
INTERRUPTS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Signals that end a run the way Ctrl-C does (see :mod:`apt_filters.cli.main`)."""
_LEFTOVER = re.compile(rf"^\..*\.{TMP_TAG}\.([0-9a-f]{{6}})-(\d+)\.")


def host_tag() -> str:
    """Six hex digits naming this machine (a folder may be shared between machines)."""
    return hashlib.sha256(socket.gethostname().encode()).hexdigest()[:6]


def scratch_path(target: str | os.PathLike, suffix: str = "") -> Path:
    """A fresh temporary name beside ``target``: ``.NAME.apt-filters-tmp.<host>-<pid>.<token>SUFFIX``."""
    target = Path(target)
    return target.parent / f".{target.name}.{TMP_TAG}.{host_tag()}-{os.getpid()}.{secrets.token_hex(4)}{suffix}"


def process_runs(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine (an unknown answer counts as yes)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # not ours to signal: it runs
        return True
    return True


def remove(path: Path) -> None:
    """Delete a file or a folder tree; gone already is fine."""
    with contextlib.suppress(FileNotFoundError):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()


def tidy(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary files and folders in ``folder`` left by apt-filters processes of
    this machine that no longer run; returns what was removed."""
    removed = []
    with contextlib.suppress(OSError), os.scandir(folder) as entries:
        for entry in entries:
            m = _LEFTOVER.match(entry.name)
            if m and m.group(1) == host_tag() and not process_runs(int(m.group(2))):
                remove(Path(entry.path))
                removed.append(Path(entry.path))
    return removed


class Interrupted(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised where the program is, like Ctrl-C's KeyboardInterrupt."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


_received: list[int] = []
"""Termination signals this process has received (see :func:`raise_if_interrupted`)."""


def raise_on_signal(signum, frame) -> None:
    """Signal handler for SIGTERM and SIGHUP: remember the signal and raise :class:`Interrupted`."""
    _received.append(signum)
    raise Interrupted(signum)


def received_interrupt() -> Interrupted | None:
    """The last termination signal this process received, as the :class:`Interrupted` it raised; None if none.

    A handler's exception can be swallowed where Python cannot propagate it (a ctypes callback,
    e.g. numba's compiled-code cache, prints "Exception ignored" and carries on), and what was
    stopped can then fail in its own words ("no compiled object yet"): the signal is the cause.
    """
    return Interrupted(_received[-1]) if _received else None


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` again if a termination signal arrived (see :func:`received_interrupt`):
    the steps of a run and the commit of an output folder ask here before going on."""
    if _received:
        raise received_interrupt()


def unraisable_hook(unraisable) -> None:
    """``sys.unraisablehook`` that keeps a swallowed :class:`Interrupted` quiet (it is raised again
    by :func:`raise_if_interrupted`) and hands everything else to Python's own hook."""
    if not isinstance(unraisable.exc_value, Interrupted):
        sys.__unraisablehook__(unraisable)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP back while a clean-up runs; they arrive after it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, INTERRUPTS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def refuse_inputs(outputs: Iterable[str | os.PathLike], inputs: Iterable[str | os.PathLike | None]) -> None:
    """Raise AptFiltersError if an output path would overwrite an input file or hold one.

    Paths are compared after resolving links, so ``out.ply -> in.ply`` is caught too.
    """
    resolved = [(Path(i), Path(i).resolve()) for i in inputs if i]
    for out in outputs:
        target = Path(out).resolve()
        for given, path in resolved:
            if path == target:
                raise AptFiltersError(f"would overwrite the input {given}; choose another output", out)
            if target in path.parents:
                raise AptFiltersError(f"holds the input {given}, which replacing it would delete; "
                                      "choose another output", out)
            if path in target.parents:
                raise AptFiltersError(f"lies inside the input {given}; choose another output", out)


def _check_target(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise AptFiltersError("exists already; pass overwrite/--force to replace it", path)
    if path.is_dir():
        raise AptFiltersError("is a folder; give a file name", path)
    if not path.parent.exists():
        raise AptFiltersError("folder does not exist", path.parent)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it is renamed to ``path``.

    The temporary file (:func:`scratch_path`) keeps the target's extension so that writers
    which pick the format from the extension (pymeshlab, open3d) still work. It is created
    with the permissions of an ordinary file (0666 less the umask).
    """
    path = Path(path)
    _check_target(path, overwrite)
    tidy(path.parent)
    tmp_path = scratch_path(path, path.suffix)
    try:
        # created inside the try: a signal arriving right after it must still remove the file
        os.close(os.open(tmp_path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        with signals_held():
            remove(tmp_path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    with atomic_output(path, overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically and return the path."""
    return atomic_write_bytes(path, text.encode("utf-8"), overwrite)
