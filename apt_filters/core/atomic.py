"""Atomic file output: write to a temporary file beside the target, then rename.

A crash or an exception while writing leaves no half-written file behind, and an
existing file is only replaced when the caller allows it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from apt_filters.core.errors import AptFiltersError


def _check_target(path: Path, overwrite: bool) -> None:
    if path.exists() and not overwrite:
        raise AptFiltersError("exists already; pass overwrite/--force to replace it", path)
    if not path.parent.exists():
        raise AptFiltersError("folder does not exist", path.parent)


def _default_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, overwrite: bool = False) -> Iterator[Path]:
    """Yield a temporary path to write; on success it is renamed to ``path``.

    The temporary file keeps the target's extension so that writers which pick the format
    from the extension (pymeshlab, open3d) still work; its name starts with ``.`` and holds
    ``.tmp.`` so that a leftover is easy to recognise.
    """
    path = Path(path)
    _check_target(path, overwrite)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, _default_mode())  # mkstemp makes 0600 files; outputs are ordinary files
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write_bytes(path: str | os.PathLike, data: bytes, overwrite: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    with atomic_output(path, overwrite) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically and return the path."""
    return atomic_write_bytes(path, text.encode("utf-8"), overwrite)
