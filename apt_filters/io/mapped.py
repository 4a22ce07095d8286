"""Read-only memory maps of binary ion files, exposed as lazy column views.

A :class:`MappedIons` holds numpy views (any endianness, any stride) straight onto the
file's pages; nothing is read until a view is touched. Readers turn the views into native
arrays chunk by chunk and hand the touched pages back to the kernel with
``madvise(MADV_DONTNEED)``, so that the resident set of a full pass stays at one chunk of
mapped pages plus whatever the caller keeps (file pages of a shared read-only map are
clean: dropping them only means they are faulted in again from the page cache if needed).
"""

from __future__ import annotations

import mmap
import os
from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.errors import InputError

PAGE = mmap.PAGESIZE


def open_map(path: str | os.PathLike, size: int) -> mmap.mmap:
    """Map ``path`` read-only (``size`` > 0 bytes, checked by the caller)."""
    try:
        with open(path, "rb") as fh:
            return mmap.mmap(fh.fileno(), size, access=mmap.ACCESS_READ)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot memory-map the file ({exc})", path) from None


def column(mm: mmap.mmap, rows: int, dtype: str | np.dtype, offset: int, row_bytes: int, width: int = 1) -> np.ndarray:
    """View of ``rows`` records of ``width`` items of ``dtype`` starting at byte ``offset``.

    Returns (rows,) when ``width`` is 1, else (rows, width); records are ``row_bytes`` apart.
    """
    dtype = np.dtype(dtype)
    shape = (rows,) if width == 1 else (rows, width)
    strides = (row_bytes,) if width == 1 else (row_bytes, dtype.itemsize)
    return np.ndarray(shape, dtype=dtype, buffer=mm, offset=offset, strides=strides)


@dataclass
class MappedIons:
    """Lazy views of one ion file's columns over a memory map.

    Attributes
    ----------
    fmt : str
        ``"pos"``, ``"epos"`` or ``"apt6"``.
    positions : (N, 3) view, mz : (N,) view, extra : dict of (N,) or (N, k) views
        Columns in the file's own dtype (big-endian for POS/EPOS, little-endian for APT6).
    spans : list of (offset, row_bytes)
        Byte layout of each stored block, used to release the pages of a row range.
    """

    path: str
    fmt: str
    mm: mmap.mmap
    positions: np.ndarray
    mz: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    spans: list[tuple[int, int]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.mz)

    def release(self, start: int, stop: int) -> None:
        """Drop the mapped pages of rows ``start:stop`` from this process's resident set."""
        if not hasattr(mmap, "MADV_DONTNEED"):  # pragma: no cover - non-Linux
            return
        for offset, row_bytes in self.spans:
            lo = (offset + start * row_bytes) // PAGE * PAGE
            hi = min(offset + stop * row_bytes, len(self.mm))
            if hi > lo:
                self.mm.madvise(mmap.MADV_DONTNEED, lo, hi - lo)
