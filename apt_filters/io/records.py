"""POS and EPOS: headerless files of fixed-size big-endian records, memory-mapped.

POS holds 16-byte records (x, y, z in nm, m/z in Da; big-endian float32); EPOS 44-byte
records laid out as :data:`apt_filters.io.writers.EPOS_DTYPE`. Both are mapped as strided
column views (see :mod:`apt_filters.io.mapped`); nothing is read here.
"""

from __future__ import annotations

from apt_filters.core.errors import InputError
from apt_filters.io.mapped import MappedIons, column, open_map
from apt_filters.io.writers import EPOS_DTYPE, EPOS_EXTRA

POS_RECORD = 16
EPOS_RECORD = EPOS_DTYPE.itemsize  # 44


def _record_count(path: str, size: int, record: int, name: str) -> int:
    if size == 0:
        raise InputError(f"empty {name} file (0 bytes)", path)
    if size % record:
        raise InputError(
            f"size {size} bytes is not a whole number of {record}-byte {name} records "
            f"({size // record} records and {size % record} bytes left over)", path)
    return size // record


def map_pos(path: str, size: int) -> MappedIons:
    """Map a POS file of ``size`` bytes: positions (N, 3) and m/z (N,) as big-endian views."""
    n = _record_count(path, size, POS_RECORD, "POS")
    mm = open_map(path, size)
    return MappedIons(
        path=path, fmt="pos", mm=mm,
        positions=column(mm, n, ">f4", 0, POS_RECORD, 3),
        mz=column(mm, n, ">f4", 12, POS_RECORD),
        spans=[(0, POS_RECORD)],
    )


def map_epos(path: str, size: int) -> MappedIons:
    """Map an EPOS file: positions, m/z and the seven further columns named as ``EPOS_EXTRA``."""
    n = _record_count(path, size, EPOS_RECORD, "EPOS")
    mm = open_map(path, size)
    fields = EPOS_DTYPE.fields
    extra = {name: column(mm, n, fields[name][0], fields[name][1], EPOS_RECORD) for name in EPOS_EXTRA}
    return MappedIons(
        path=path, fmt="epos", mm=mm,
        positions=column(mm, n, ">f4", 0, EPOS_RECORD, 3),
        mz=column(mm, n, fields["mz"][0], fields["mz"][1], EPOS_RECORD),
        extra=extra,
        spans=[(0, EPOS_RECORD)],
    )

