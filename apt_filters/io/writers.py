"""Writers for POS, EPOS and RRNG files (subsets, synthetic data, round trips).

All writes are atomic: a temporary file beside the target, renamed when complete.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from apt_filters.core.atomic import atomic_output
from apt_filters.io.formula import ELEMENTS
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable

EPOS_DTYPE = np.dtype([
    ("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("mz", ">f4"),
    ("tof", ">f4"), ("vdc", ">f4"), ("vpulse", ">f4"), ("det_x", ">f4"), ("det_y", ">f4"),
    ("delta_pulse", ">i4"), ("multiplicity", ">i4"),
])
"""EPOS record: 11 big-endian fields, 44 bytes (tof in ns, voltages in V, detector x/y in mm)."""

EPOS_EXTRA = EPOS_DTYPE.names[4:]


def write_pos(path: str | os.PathLike, ions: IonTable, overwrite: bool = False, chunk: int = 1 << 22) -> Path:
    """Write ions as POS (big-endian float32 x, y, z, m/z; 16 bytes per ion).

    Written in chunks of ``chunk`` ions, so peak extra memory is 16 bytes x ``chunk``.
    """
    with atomic_output(path, overwrite) as tmp, open(tmp, "wb") as fh:
        for start in range(0, len(ions), chunk):
            stop = min(start + chunk, len(ions))
            block = np.empty((stop - start, 4), dtype=">f4")
            block[:, :3] = ions.positions[start:stop]
            block[:, 3] = ions.mz[start:stop]
            fh.write(block.tobytes())
    return Path(path)


def write_epos(path: str | os.PathLike, ions: IonTable, overwrite: bool = False, chunk: int = 1 << 22) -> Path:
    """Write ions as EPOS; extra columns named as in ``EPOS_EXTRA`` are written, missing ones as 0."""
    with atomic_output(path, overwrite) as tmp, open(tmp, "wb") as fh:
        for start in range(0, len(ions), chunk):
            stop = min(start + chunk, len(ions))
            block = np.zeros(stop - start, dtype=EPOS_DTYPE)
            for axis, name in enumerate("xyz"):
                block[name] = ions.positions[start:stop, axis]
            block["mz"] = ions.mz[start:stop]
            for name in EPOS_EXTRA:
                if name in ions.extra:
                    block[name] = ions.extra[name][start:stop]
            fh.write(block.tobytes())
    return Path(path)


def format_rrng(ranges: RangeTable) -> str:
    """The text of an IVAS RRNG file for ``ranges`` (bounds with 4 decimals, as IVAS writes).

    Species that are not formulas of elements (unknown species) are written as ``Name:species``
    without element counts, as IVAS writes unnamed peaks.
    """
    elements = [el for el in ranges.elements if el in ELEMENTS]
    lines = ["[Ions]", f"Number={len(elements)}"]
    lines += [f"Ion{i}={el}" for i, el in enumerate(elements, 1)]
    lines += ["[Ranges]", f"Number={len(ranges)}"]
    for i, r in enumerate(ranges.ranges, 1):
        known = all(el in ELEMENTS for el, _ in r.composition)
        atoms = " ".join(f"{el}:{n}" for el, n in r.composition) if known else f"Name:{r.ion}"
        vol = f" Vol:{r.volume:.5f}" if r.volume is not None else ""
        color = f" Color:{r.color}" if r.color else ""
        lines.append(f"Range{i}={r.lower:.4f} {r.upper:.4f}{vol} {atoms}{color}")
    return "\n".join(lines) + "\n"


def write_rrng(path: str | os.PathLike, ranges: RangeTable, overwrite: bool = False) -> Path:
    """Write an IVAS RRNG range file atomically."""
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text(format_rrng(ranges))
    return Path(path)
