"""The ion table: what every reader returns and every later step consumes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class IonTable:
    """Reconstructed ions.

    Attributes
    ----------
    positions : (N, 3) float32
        x, y, z in nm.
    mz : (N,) float32
        Mass-to-charge ratio in Da.
    extra : dict[str, (N,) or (N, k) array]
        Optional further columns by name (EPOS: ``tof``, ``vdc``, ``vpulse``, ``det_x``,
        ``det_y``, ``delta_pulse``, ``multiplicity``; APT6: its section names).
    source : str or None
        The file the ions were read from, for messages and reports.
    """

    positions: np.ndarray
    mz: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        if self.positions.ndim != 2 or self.positions.shape[1] != 3:
            raise ValueError(f"positions must be (N, 3), got {self.positions.shape}")
        if self.mz.shape != (len(self.positions),):
            raise ValueError(f"mz must be ({len(self.positions)},), got {self.mz.shape}")
        for name, col in self.extra.items():
            if len(col) != len(self.positions):
                raise ValueError(f"column {name!r} has {len(col)} rows for {len(self.positions)} ions")

    def __len__(self) -> int:
        return len(self.mz)

    def subset(self, index: np.ndarray | slice) -> "IonTable":
        """Ions selected by a boolean mask, an index array or a slice (columns are copied)."""
        return IonTable(
            positions=np.ascontiguousarray(self.positions[index]),
            mz=np.ascontiguousarray(self.mz[index]),
            extra={k: np.ascontiguousarray(v[index]) for k, v in self.extra.items()},
            source=self.source,
        )

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) corners of the bounding box in nm, each (3,) float64."""
        return self.positions.min(axis=0).astype(np.float64), self.positions.max(axis=0).astype(np.float64)
