"""AP Suite / IVAS 4 ``.apt`` files (APT6): a little-endian file header, then named sections.

Layout (all little-endian; strings are UTF-16 padded with NULs)::

    file header (iHeaderSize bytes, 540 in version 2)
        char[4]   "APT\\0"
        int32     iHeaderSize, iHeaderVersion
        wchar[256] original file name
        uint64    creation time (Windows FILETIME)
        int64     llIonCount
    then, until the end of the file, sections:
        section header (iHeaderSize bytes, at least 148; "Position" carries 24 more bytes
        with its bounding box, which we do not need)
            char[4]   "SEC\\0"
            int32     iHeaderSize, iHeaderVersion
            wchar[32] section name ("Position", "Mass", "tofc", "XDet_mm", "Multiplicity", ...)
            int32     iSectionVersion
            int32     eRelationshipType (1: one record per ion)
            int32     eRecordType (1: fixed size)
            int32     eRecordDataType (1: int, 2: unsigned int, 3: float, 4: string, 5: other)
            int32     iDataTypeSize (bits of one value)
            int32     iRecordSize (bytes of one record: one or more values)
            wchar[16] unit ("nm", "Da", "mm", ...)
            int64     llRecordCount, llByteCount
        section data (llByteCount bytes)

Sections with one fixed-size numeric record per ion become column views of the memory map
(``Position`` (N, 3), ``Mass`` (N,), others (N,) or (N, k) under their own names); other
kinds (indexed, variable-size, strings) are skipped. Every size and offset is checked
against the file before a view is made, so a corrupt header is an :class:`InputError`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from apt_filters.core.errors import InputError
from apt_filters.io.mapped import MappedIons, column, open_map

SIGNATURE = b"APT\x00"
SECTION_SIGNATURE = b"SEC\x00"
FILE_HEADER = struct.Struct("<4sii512sQq")  # 540 bytes
SECTION_HEADER = struct.Struct("<4sii64siiiiii32sqq")  # 148 bytes
ONE_TO_ONE, FIXED_SIZE = 1, 1
_KINDS = {1: "i", 2: "u", 3: "f"}
_FLOAT_BITS = {32, 64}
_INT_BITS = {8, 16, 32, 64}


@dataclass(frozen=True)
class Section:
    """One APT6 section header, with the byte offset of its data."""

    name: str
    unit: str
    data_offset: int
    relationship: int
    record_type: int
    data_type: int
    bits: int
    record_size: int
    record_count: int
    byte_count: int

    def numpy_dtype(self) -> np.dtype | None:
        """Little-endian dtype of one value, or None for kinds we do not read."""
        kind = _KINDS.get(self.data_type)
        if kind is None or self.bits not in (_FLOAT_BITS if kind == "f" else _INT_BITS):
            return None
        return np.dtype(f"<{kind}{self.bits // 8}")


def _text(raw: bytes) -> str:
    return raw.decode("utf-16-le", errors="replace").split("\x00", 1)[0]


def read_header(path: str, buf, size: int) -> tuple[int, int]:
    """(header size, ion count) of the APT6 file whose first bytes are ``buf``."""
    if size < FILE_HEADER.size:
        raise InputError(f"too short for an APT6 header ({size} bytes, needs {FILE_HEADER.size})", path)
    sig, header_size, _version, _name, _time, ions = FILE_HEADER.unpack_from(buf, 0)
    if sig != SIGNATURE:
        raise InputError(f"not an APT6 file: signature {sig!r}, expected {SIGNATURE!r}", path)
    if not FILE_HEADER.size <= header_size <= size:
        raise InputError(f"APT6 header size {header_size} is outside {FILE_HEADER.size}..{size} bytes", path)
    if ions <= 0:
        raise InputError(f"APT6 header gives {ions} ions; there is nothing to read", path)
    return header_size, ions


def read_sections(path: str, buf, size: int, start: int) -> list[Section]:
    """All section headers from byte ``start`` to the end of the file, each checked to fit."""
    sections: list[Section] = []
    offset = start
    while offset < size:
        if size - offset < SECTION_HEADER.size:
            raise InputError(f"truncated APT6 section header at byte {offset}", path)
        (sig, header_size, _hv, name, _sv, rel, rtype, dtype, bits, rsize, unit,
         count, nbytes) = SECTION_HEADER.unpack_from(buf, offset)
        if sig != SECTION_SIGNATURE:
            raise InputError(f"bad APT6 section signature {sig!r} at byte {offset}", path)
        name = _text(name)
        if not SECTION_HEADER.size <= header_size <= size - offset:
            raise InputError(f"APT6 section {name!r} at byte {offset} has header size {header_size}", path)
        data_offset = offset + header_size
        if not 0 <= nbytes <= size - data_offset:
            raise InputError(
                f"APT6 section {name!r} is truncated: {nbytes} bytes at byte {data_offset}, file has {size}", path)
        sections.append(Section(name, _text(unit), data_offset, rel, rtype, dtype, bits, rsize, count, nbytes))
        offset = data_offset + nbytes
    return sections


def _per_ion_column(path: str, mm, sec: Section, ions: int) -> np.ndarray | None:
    """Column view of a one-record-per-ion numeric section, None for kinds we skip."""
    dtype = sec.numpy_dtype()
    if sec.relationship != ONE_TO_ONE or sec.record_type != FIXED_SIZE or dtype is None:
        return None
    if sec.record_count != ions:
        raise InputError(f"APT6 section {sec.name!r} has {sec.record_count} records for {ions} ions", path)
    if sec.record_size <= 0 or sec.record_size % dtype.itemsize:
        raise InputError(
            f"APT6 section {sec.name!r} has record size {sec.record_size} bytes for {sec.bits}-bit values", path)
    if sec.byte_count != ions * sec.record_size:
        raise InputError(
            f"APT6 section {sec.name!r} holds {sec.byte_count} bytes, expected {ions} x {sec.record_size}", path)
    return column(mm, ions, dtype, sec.data_offset, sec.record_size, sec.record_size // dtype.itemsize)


def map_apt6(path: str, size: int) -> MappedIons:
    """Map an APT6 file: ``Position`` and ``Mass`` become positions and m/z, other per-ion sections extras."""
    mm = open_map(path, size)
    header_size, ions = read_header(path, mm, size)
    columns: dict[str, np.ndarray] = {}
    spans = []
    for sec in read_sections(path, mm, size, header_size):
        view = _per_ion_column(path, mm, sec, ions)
        if view is None:
            continue
        if sec.name in columns:
            raise InputError(f"APT6 section {sec.name!r} appears twice", path)
        columns[sec.name] = view
        spans.append((sec.data_offset, sec.record_size))
    for name, width in (("Position", 3), ("Mass", 1)):
        if name not in columns:
            raise InputError(f"APT6 file has no per-ion {name!r} section", path)
        got = 1 if columns[name].ndim == 1 else columns[name].shape[1]
        if got != width:
            raise InputError(f"APT6 section {name!r} has {got} values per ion, expected {width}", path)
    positions, mz = columns.pop("Position"), columns.pop("Mass")
    return MappedIons(path=path, fmt="apt6", mm=mm, positions=positions, mz=mz, extra=columns, spans=spans)
