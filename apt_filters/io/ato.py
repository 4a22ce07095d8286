"""ATO: the ion files of LAWATAP and the GPM Rouen tools (versions 3 and 5), memory-mapped.

No formal specification is published; the layout below is the one the public readers agree
on (3Depict, the NOMAD ``ifes_apt_tc_data_modeling`` reader, the GPM description of versions
3-5 deposited on Zenodo, record 8382828). All values are little-endian.

Version 3
    An 8-byte header: two uint32, the second the version (3). Then 56-byte records of 14
    float32: x, y, z (Å), m/z (Da), cluster id, pulse number, standing voltage (kV),
    time of flight (ns), detector x, y (cm), pulse voltage (kV), virtual voltage (kV),
    Fourier intensities R and I.
Version 5
    A 5000-byte header whose second uint32 is the version (5). Then 40-byte records: x, y as
    int16 in units of 0.01 nm, z as float32 (Å), m/z as float32 (Da) at byte 8; the
    remaining 28 bytes (times, voltages, detector coordinates) are not read: the public
    descriptions disagree on them.

Positions are converted to nm chunk by chunk as they are read (Å x 0.1; version 5 x, y x 0.01);
m/z is a plain strided view. Version 3's further fields become extra columns under the names in
:data:`ATO3_EXTRA`, in the file's units.
"""

from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np

from apt_filters.core.errors import InputError
from apt_filters.io.mapped import MappedIons, column, open_map

ATO_HEADER = {3: 8, 5: 5000}
"""Header bytes per version."""
ATO_RECORD = {3: 56, 5: 40}
"""Record bytes per version."""
ATO3_EXTRA = ("cluster_id", "pulse", "vdc", "tof", "det_x", "det_y", "vpulse", "vvirtual", "fourier_r", "fourier_i")
"""Names of the version-3 fields after x, y, z, m/z."""


class ScaledColumns:
    """(N, k) float32 columns computed from strided views of a map, each times a factor, on slicing.

    Stands where a reader expects a column view: ``shape``, ``dtype``, ``flags`` (never
    contiguous, so it is always converted) and slicing along the first axis.
    """

    def __init__(self, parts: list[tuple[np.ndarray, float]]):
        self.parts = parts
        self.shape = (len(parts[0][0]), len(parts))
        self.dtype = np.dtype(np.float32)
        self.flags = SimpleNamespace(c_contiguous=False)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, index) -> np.ndarray:
        out = np.empty((len(self.parts[0][0][index]), len(self.parts)), dtype=np.float32)
        for k, (view, factor) in enumerate(self.parts):
            np.multiply(view[index], factor, out=out[:, k], casting="unsafe")
        return out


def ato_version(path: str, size: int) -> int:
    """The version word of an ATO file (3 or 5), checked against the file size."""
    if size < 8:
        raise InputError(f"size {size} bytes is too small for an ATO header", path)
    with open(path, "rb") as fh:
        _, version = struct.unpack("<II", fh.read(8))
    if version not in ATO_HEADER:
        raise InputError(f"ATO version {version} is not supported (versions 3 and 5 are)", path)
    body = size - ATO_HEADER[version]
    record = ATO_RECORD[version]
    if body < 0 or body % record:
        raise InputError(f"size {size} bytes is not a {ATO_HEADER[version]}-byte ATO v{version} header and whole "
                         f"{record}-byte records ({max(body, 0) // record} records and {max(body, 0) % record} "
                         "bytes left over)", path)
    return version


def map_ato(path: str, size: int) -> MappedIons:
    """Map an ATO file: positions in nm (converted when sliced), m/z as a view, v3 extras as views."""
    version = ato_version(path, size)
    head, record = ATO_HEADER[version], ATO_RECORD[version]
    n = (size - head) // record
    if n == 0:
        raise InputError(f"ATO v{version} file holds no ions", path)
    mm = open_map(path, size)
    if version == 3:
        positions = ScaledColumns([(column(mm, n, "<f4", head + 4 * a, record), 0.1) for a in range(3)])
        extra = {name: column(mm, n, "<f4", head + 16 + 4 * k, record) for k, name in enumerate(ATO3_EXTRA)}
    else:
        positions = ScaledColumns([(column(mm, n, "<i2", head, record), 0.01),
                                   (column(mm, n, "<i2", head + 2, record), 0.01),
                                   (column(mm, n, "<f4", head + 4, record), 0.1)])
        extra = {}
    mz = column(mm, n, "<f4", head + (12 if version == 3 else 8), record)
    return MappedIons(path=path, fmt=f"ato{version}", mm=mm, positions=positions, mz=mz, extra=extra,
                      spans=[(head, record)])
