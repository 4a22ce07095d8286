"""Reading ion files: one entry point for POS, EPOS, APT6, ATO and CSV/TXT, whole or in chunks.

The format is picked by extension (``.pos``, ``.epos``, ``.apt``, ``.ato``, ``.csv``, ``.txt``,
any case) and confirmed by content: sizes must be whole numbers of records, APT6 files must
carry their signature and consistent section headers, ATO files a known version, text must
parse as a table. Every
problem is an :class:`~apt_filters.core.errors.InputError` naming the file.

Binary files are memory-mapped and read column-wise in chunks of :data:`CHUNK` ions
(see :mod:`apt_filters.io.mapped`); coordinates and m/z must be finite.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import numpy as np

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.threads import available_cores, on_threads, shares
from apt_filters.io.apt6 import map_apt6
from apt_filters.io.ato import map_ato
from apt_filters.io.csvtxt import read_text_ions
from apt_filters.io.ions import IonTable
from apt_filters.io.mapped import MappedIons
from apt_filters.io.records import map_epos, map_pos

ION_FORMATS = {".pos": "pos", ".epos": "epos", ".apt": "apt6", ".ato": "ato", ".csv": "text", ".txt": "text"}
"""File extension (lower case) -> format name."""

CHUNK = 1 << 20
"""Ions converted per step when reading a whole file (16 MiB of mapped POS pages)."""

_MIN_SHARE = 1 << 16
"""Fewest rows one conversion thread takes: below that a thread's start costs more than it saves."""


def ion_format(path: str | os.PathLike) -> str:
    """Format name of an ion file from its extension: "pos", "epos", "apt6", "ato" or "text"."""
    ext = Path(path).suffix.lower()
    if ext not in ION_FORMATS:
        known = ", ".join(ION_FORMATS)
        raise InputError(f"unknown ion file extension {ext or '(none)'!r}; expected one of {known}", path)
    return ION_FORMATS[ext]


def _file_size(path: str) -> int:
    try:
        if not os.path.isfile(path):
            raise InputError("no such file" if not os.path.exists(path) else "not a regular file", path)
        size = os.path.getsize(path)
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", path) from None
    if size == 0:
        raise InputError("empty file (0 bytes)", path)
    return size


def _open(path: str | os.PathLike) -> MappedIons | IonTable:
    """Mapped column views of a binary file, or the parsed table of a text file."""
    path = os.fspath(path)
    fmt = ion_format(path)
    size = _file_size(path)
    if fmt == "text":
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read ({exc.strerror})", path) from None
        return read_text_ions(path, data)
    return {"pos": map_pos, "epos": map_epos, "apt6": map_apt6, "ato": map_ato}[fmt](path, size)


def _check_finite(path: str, positions: np.ndarray, mz: np.ndarray, start: int) -> None:
    # flat reductions first: a per-row all(axis=1) costs 15x more, and is only needed to name the ion
    if np.isfinite(positions).all() and np.isfinite(mz).all():
        return
    ok = np.isfinite(positions).all(axis=1) & np.isfinite(mz)
    if not ok.all():
        i = int(np.argmin(ok))
        x, y, z = positions[i]
        raise InputError(f"ion {start + i} has a non-finite coordinate or m/z "
                         f"(x={x}, y={y}, z={z}, m/z={mz[i]})", path)


def _columns(src: MappedIons) -> dict[str, tuple[np.ndarray, np.dtype]]:
    """Every column of ``src`` with the native dtype it is read into (float32 for positions, m/z)."""
    cols = {"positions": (src.positions, np.dtype(np.float32)), "mz": (src.mz, np.dtype(np.float32))}
    cols.update({name: (view, view.dtype.newbyteorder("=")) for name, view in src.extra.items()})
    return cols


def read_ions(path: str | os.PathLike, *, mmap: bool = True) -> IonTable:
    """Read a whole ion file (POS, EPOS, APT6, CSV/TXT) into an :class:`IonTable`.

    Parameters
    ----------
    path : path-like
        The ion file; its extension picks the format (see :data:`ION_FORMATS`).
    mmap : bool
        Keep columns that are already native, contiguous float32/int arrays in the file
        (APT6 ``Position``, ``Mass`` and its other sections) as read-only views of the
        memory map instead of copying them. Big-endian POS/EPOS columns are converted to
        native arrays either way. With ``False`` every column is an in-memory copy.

    Returns
    -------
    IonTable
        positions (N, 3) float32 nm, mz (N,) float32 Da, ``extra`` columns (EPOS: the
        names in ``EPOS_EXTRA``; APT6: its per-ion section names such as ``tofc``,
        ``XDet_mm``, ``Multiplicity``, ``Detector Coordinates``), ``source`` = path.

    Notes
    -----
    Peak memory beyond the result is one chunk of mapped pages (:data:`CHUNK` records),
    never a second copy of a column: each column is converted chunk by chunk straight from
    the map and the pages are released behind the conversion. The result is

    - POS: 16 B/ion (12 B native float32 positions + 4 B m/z);
    - EPOS: 44 B/ion (positions, m/z and seven 4-byte extras);
    - APT6 with ``mmap=True``: nothing resident; the columns are views of the file, paged in
      from the page cache when used (``mmap=False``: the sum of its per-ion sections);
    - CSV/TXT: the text plus float64 parse (8 B per value) on top of 16 B/ion; for small tables.

    Raises
    ------
    InputError
        Unknown extension, empty file, size not a whole number of records, corrupt APT6
        headers, unparsable text, or a non-finite coordinate or m/z (naming the ion).
    """
    src = _open(path)
    if isinstance(src, IonTable):
        _check_finite(src.source, src.positions, src.mz, 0)
        return src
    cols = _columns(src)
    out = {}
    for name, (view, dtype) in cols.items():
        native = mmap and view.dtype == dtype and view.flags.c_contiguous
        out[name] = view if native else np.empty(view.shape, dtype=dtype)
    threads = available_cores()
    for start in range(0, len(src), CHUNK):
        stop = min(start + CHUNK, len(src))
        copies = [(out[name][start:stop], view[start:stop]) for name, (view, _) in cols.items() if out[name] is not view]
        if not _copy_rows(copies, out["positions"][start:stop], out["mz"][start:stop], threads):
            _check_finite(src.path, out["positions"][start:stop], out["mz"][start:stop], start)
        src.release(start, stop)
    positions, mz = out.pop("positions"), out.pop("mz")
    return IonTable(positions, mz, out, source=src.path)


def iter_ion_chunks(path: str | os.PathLike, chunk_size: int = 1 << 22, threads: int | None = None, *,
                    start: int = 0, stop: int | None = None) -> Iterator[IonTable]:
    """Yield the ions of a file as consecutive :class:`IonTable` chunks of ``chunk_size`` ions.

    ``start`` and ``stop`` (ion indices, ``stop`` None: the end) limit the pass to one share of
    the file without reading the rest of it (so workers of a cluster each map their own share).

    For streaming passes over 10^8-10^9 ions (voxelisation, counting): binary files are
    memory-mapped, each chunk is converted to native float32 (POS/EPOS; APT6 chunks are
    views of the map), checked to be finite, and the chunk's mapped pages are released
    when the next one is requested. Peak memory: one chunk (16 B/ion for POS, 44 B/ion for
    EPOS; only its pages for APT6) plus what the caller keeps. Text files are parsed whole
    and then sliced. Chunk ``source`` is the file; the first ion of a chunk is the sum of
    the lengths of the chunks before it. ``threads`` (default: one per available core) convert
    each chunk's rows in contiguous shares at once.

    Raises
    ------
    AptFiltersError
        ``chunk_size`` < 1; and :class:`InputError` as :func:`read_ions` (a non-finite
        value is reported when its chunk is reached).
    """
    if int(chunk_size) < 1:
        raise AptFiltersError(f"chunk size must be at least 1 ion, got {chunk_size}")
    src = _open(path)
    end = len(src) if stop is None else min(int(stop), len(src))
    if not 0 <= int(start) <= end:
        raise AptFiltersError(f"ion share [{start}, {stop}) is not within the file's {len(src)} ions", str(path))
    if isinstance(src, IonTable):
        _check_finite(src.source, src.positions, src.mz, 0)
        for a in range(int(start), end, chunk_size):
            yield src.subset(slice(a, min(a + chunk_size, end)))
        return
    cols = _columns(src)
    threads = available_cores() if threads is None else max(1, int(threads))
    for a in range(int(start), end, chunk_size):
        b = min(a + chunk_size, end)
        chunk = _native_chunk(src.path, cols, a, b, threads)
        positions, mz = chunk.pop("positions"), chunk.pop("mz")
        yield IonTable(positions, mz, chunk, source=src.path)
        src.release(a, b)


def count_ions(path: str | os.PathLike) -> int:
    """Number of ions in a file, from its size or header (text files are parsed)."""
    return len(_open(path))


def _copy_rows(copies: list[tuple[np.ndarray, np.ndarray]], positions: np.ndarray, mz: np.ndarray,
               threads: int) -> bool:
    """``dst[:] = src`` for each (dst, src) pair of equally long row ranges, then whether ``positions`` and
    ``mz`` (among the destinations, or views that need no copy) are all finite: ``threads``
    contiguous shares of the rows at once (numpy's byte-swapping copies release the GIL, and the
    mapped pages are faulted in by the thread that reads them)."""
    def convert(a: int, b: int) -> bool:
        for dst, src in copies:
            with np.errstate(over="ignore"):  # float64 beyond float32 range -> inf, refused by the caller
                dst[a:b] = src[a:b]
        return bool(np.isfinite(positions[a:b]).all() and np.isfinite(mz[a:b]).all())

    return all(on_threads(convert, shares(len(mz), max(1, min(threads, len(mz) // _MIN_SHARE)))))


def _native_chunk(path: str, cols: dict, start: int, stop: int, threads: int) -> dict[str, np.ndarray]:
    """Rows ``start:stop`` of every column as native arrays (views where they already are), checked
    finite, converted on ``threads`` threads (:func:`_copy_rows`)."""
    out, copies = {}, []
    for name, (view, dtype) in cols.items():
        part = view[start:stop]
        if part.dtype == dtype and part.flags.c_contiguous:
            out[name] = part
        else:
            out[name] = np.empty(part.shape, dtype=dtype)
            copies.append((out[name], part))
    if not _copy_rows(copies, out["positions"], out["mz"], threads):
        _check_finite(path, out["positions"], out["mz"], start)
    return out


def map_ions(path: str | os.PathLike, scratch: str | os.PathLike, *, chunk_size: int = 1 << 22,
             threads: int | None = None) -> IonTable:
    """The positions and m/z of a file as native, read-only memory-mapped columns: a table of any size
    that holds no memory of its own.

    Passes that take the table in slices (voxelization, objects, proxigram, audit, ion-cloud export)
    then stream it: its pages are read from the page cache as they are touched and are clean, so
    the kernel can drop them whenever memory is short.

    Parameters
    ----------
    path : path-like
        The ion file. APT6 ``Position`` and ``Mass`` sections are little-endian float32 already:
        their views of the file are used as they are. POS/EPOS (big-endian) and text are
        converted chunk by chunk (:func:`iter_ion_chunks`) into a native scratch file.
    scratch : path-like
        Folder for the scratch file (16 bytes per ion; the caller removes it). Other columns
        (EPOS extras, APT6 sections) are not kept.
    chunk_size, threads
        As :func:`iter_ion_chunks`.

    Returns
    -------
    IonTable
        positions (N, 3) float32 and mz (N,) float32, read-only ``numpy.memmap`` views.
    """
    src = _open(path)
    if isinstance(src, MappedIons) and all(v.dtype == np.dtype("<f4") and v.flags.c_contiguous
                                           for v in (src.positions, src.mz)):
        for start in range(0, len(src), CHUNK):  # checked like every reader, pages released behind
            stop = min(start + CHUNK, len(src))
            _check_finite(src.path, src.positions[start:stop], src.mz[start:stop], start)
            src.release(start, stop)
        return IonTable(src.positions, src.mz, source=src.path)
    stem = Path(scratch) / Path(path).stem
    with open(f"{stem}.xyz.f4", "wb") as xyz, open(f"{stem}.mz.f4", "wb") as mass:  # written, never mapped dirty
        for chunk in iter_ion_chunks(path, chunk_size, threads):
            chunk.positions.tofile(xyz)
            chunk.mz.tofile(mass)
    n = len(src)
    return IonTable(np.memmap(f"{stem}.xyz.f4", np.float32, "r", shape=(n, 3)),
                    np.memmap(f"{stem}.mz.f4", np.float32, "r", shape=(n,)), source=os.fspath(path))
