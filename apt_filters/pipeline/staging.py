"""Output folders that appear whole or not at all.

A run writes into a hidden staging folder beside the target and renames it onto the
target when every file is written, so a failed run leaves no half-written output and an
existing non-empty folder is only replaced with ``force``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from apt_filters.core.errors import AptFiltersError


@contextlib.contextmanager
def staged_folder(target: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield an empty staging folder; on success it replaces ``target``."""
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise AptFiltersError("exists and is not a folder", target)
    if target.is_dir() and any(target.iterdir()) and not force:
        raise AptFiltersError("output folder is not empty; pass --force to replace it", target)
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp.", dir=target.parent))
    try:
        yield stage
        if target.exists():
            old = target.with_name(f".{target.name}.old.{os.getpid()}")
            target.rename(old)
            stage.rename(target)
            shutil.rmtree(old)
        else:
            stage.rename(target)
    finally:
        if stage.exists():
            shutil.rmtree(stage)
