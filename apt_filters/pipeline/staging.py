"""Output folders that appear whole or not at all, and never cost the user a file.

A command that writes a folder (``run``, ``demo``, ``synth``) writes it through
:func:`staged_folder`:

- **Checked before any work** (:func:`check_output_folder`): the folder must not be, hold or
  lie inside any input (ion, range, configuration file), nor be the current folder or one
  holding it (``-o .``); an existing non-empty folder is replaced only with ``force`` *and*
  only if apt-filters wrote it (it carries the marker file :data:`MARKER`); anything else is
  refused in one line.
- **Claimed atomically**: the claim folder ``.NAME.apt-filters-run`` beside the target is made
  by one ``rename``, which fails if it exists, so a second run writing to the same folder
  refuses instead of silently overwriting the first one's output. The claim holds who owns it
  (``owner``: host and process id), the staging folder ``out`` and, for a moment at the end,
  the replaced folder ``old``: all temporary work of a run in one place.
- **Renamed into place** when every file is written; on an error, Ctrl-C, SIGTERM or SIGHUP
  (:mod:`apt_filters.cli.main` turns the last two into the same exception) the claim is
  removed. A run killed outright (``kill -9``) leaves its claim; the next run to the same
  folder finds its owner gone, puts back a replaced folder that had not been renamed back and
  removes the claim.

Folders get the permissions of the user's umask, like ``mkdir``.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Iterable, Iterator

from apt_filters import __version__
from apt_filters.core.atomic import (host_tag, process_runs, raise_if_interrupted, refuse_inputs, remove, scratch_path,
                                      signals_held, tidy)
from apt_filters.core.errors import AptFiltersError

MARKER = ".apt-filters-output"
"""File in every folder apt-filters writes; ``--force`` replaces only folders that hold it."""
CLAIM_SUFFIX = ".apt-filters-run"


def check_output_folder(target: str | os.PathLike, inputs: Iterable[str | os.PathLike | None] = (),
                        force: bool = False) -> Path:
    """Refuse an output folder that could cost the user data; return it resolved.

    Parameters
    ----------
    target : path
        The output folder (may not exist yet; links are followed).
    inputs : paths
        Every file the command reads; ``None`` entries are skipped.
    force : bool
        Replace an existing non-empty folder, if apt-filters wrote it.

    Raises
    ------
    AptFiltersError
        One line naming the folder and why it is refused.
    """
    given = target
    target = Path(target).resolve()
    cwd = Path.cwd().resolve()
    if target == cwd or target in cwd.parents:
        raise AptFiltersError("is the current folder or holds it; name a new folder for the output", given)
    if target.exists() and not target.is_dir():
        raise AptFiltersError("exists and is not a folder", given)
    refuse_inputs([given], inputs)
    if target.is_dir() and any(target.iterdir()):
        if not force:
            raise AptFiltersError("output folder is not empty; pass --force to replace it", given)
        if not (target / MARKER).is_file():
            raise AptFiltersError(f"--force replaces only folders apt-filters wrote (they hold {MARKER}); "
                                  "this one does not: choose another output folder", given)
    return target


def _owner(claim: Path) -> tuple[str, int] | None:
    """(host tag, pid) written in a claim, or None if unreadable."""
    try:
        host, pid = (claim / "owner").read_text().split()
        return host, int(pid)
    except (OSError, ValueError):
        return None


def _release_stale(claim: Path, target: Path) -> bool:
    """Remove the claim of a run of this machine that no longer runs; whether it was removed.

    A replaced folder the dead run had moved aside but not yet replaced is put back first.
    """
    owner = _owner(claim)
    if owner is None or owner[0] != host_tag() or process_runs(owner[1]):
        return False
    with signals_held():
        if (claim / "old").is_dir() and not target.exists():
            (claim / "old").rename(target)
        remove(claim)
    return True


def claim_folder(target: Path) -> Path:
    """Claim ``target`` for this process: atomically create ``.NAME.apt-filters-run`` beside it.

    Raises AptFiltersError if another live run holds the claim.
    """
    claim = target.with_name(f".{target.name}{CLAIM_SUFFIX}")
    for _ in range(2):
        draft = scratch_path(claim)
        try:
            draft.mkdir()
            (draft / "owner").write_text(f"{host_tag()} {os.getpid()}\n")
            draft.rename(claim)  # fails when the claim exists: it holds its owner file, so it is not empty
            return claim
        except OSError:
            if not claim.exists():
                raise
        finally:
            with signals_held():
                remove(draft)
        if not _release_stale(claim, target):
            owner = _owner(claim)
            who = f"process {owner[1]}" if owner else "another process"
            raise AptFiltersError(f"another apt-filters run ({who}) is writing this folder; if none is, "
                                  f"delete {claim}", target)
    raise AptFiltersError("could not claim the output folder", target)


@contextlib.contextmanager
def staged_folder(target: str | os.PathLike, force: bool = False,
                  inputs: Iterable[str | os.PathLike | None] = ()) -> Iterator[Path]:
    """Yield an empty staging folder that replaces ``target`` when the block ends without error.

    See the module's description for what is checked and refused. Yields the staging folder
    (it already holds :data:`MARKER`).
    """
    inputs = list(inputs)
    target = check_output_folder(target, inputs, force)
    claim = None
    try:
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            tidy(target.parent)
            with signals_held():  # no signal between making the claim and the clean-up knowing of it
                claim = claim_folder(target)
        except OSError as exc:
            raise AptFiltersError(f"cannot create the output folder: {exc.strerror}", target) from None
        stage = claim / "out"
        stage.mkdir()
        (stage / MARKER).write_text(f"written by apt-filters {__version__}; --force may replace this folder\n")
        yield stage
        raise_if_interrupted()
        with signals_held():
            check_output_folder(target, inputs, force)  # the same checks, in case it changed meanwhile
            if target.exists():
                target.rename(claim / "old")
            stage.rename(target)
    finally:
        if claim is not None:
            with signals_held():
                remove(claim)
