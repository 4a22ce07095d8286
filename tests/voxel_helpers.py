"""Hand-made ions and ranges for the voxel tests (no dependency on the io readers)."""

import numpy as np

from apt_filters.io import IonTable, Range, RangeTable

MZ = {"Cu": 63.0, "CrO2": 42.0, "O": 16.0, "B": 11.0}
"""m/z (Da) of each test ion, well inside its range."""


def ranges() -> RangeTable:
    """Cu, CrO2 (molecular: Cr + 2 O), O, B; anything else is unranged."""
    return RangeTable([
        Range(62.5, 63.5, (("Cu", 1),)),
        Range(41.5, 42.5, (("Cr", 1), ("O", 2))),
        Range(15.5, 16.5, (("O", 1),)),
        Range(10.5, 11.5, (("B", 1),)),
    ])


def ions(positions, species) -> IonTable:
    """IonTable from positions (N, 3) nm and ion names (N,); "?" gives an unranged m/z."""
    mz = np.array([MZ.get(s, 100.0) for s in species], dtype=np.float32)
    return IonTable(np.asarray(positions, dtype=np.float32).reshape(-1, 3), mz)


def random_ions(n, lower, upper, seed=0, names=("Cu", "CrO2", "O", "B", "?")) -> IonTable:
    rng = np.random.default_rng(seed)
    pos = rng.uniform(lower, upper, (n, 3))
    return ions(pos, rng.choice(list(names), n))
