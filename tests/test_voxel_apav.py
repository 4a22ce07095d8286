"""Agreement of the gaussian (AP Suite two-pass) fields with APAV's RangedGrid, the reference implementation.

APAV reflects mass at the grid's faces (scipy's default mode) and clips its first pass there,
while we pad; so the fields are compared where neither reaches: at least pass-1 + pass-2
radius + 1 voxels inside APAV's grid.
"""

import numpy as np
import pytest

from apt_filters.voxel import Grid, voxelize
from apt_filters.voxel.transfer import second_pass_radius, second_pass_sigma
from tests.voxel_helpers import random_ions, ranges

apav = pytest.importorskip("apav", reason="apav (reference RangedGrid) is not installed")


def apav_fields(table, rt, voxel, deloc):
    """APAV RangedGrid on the same ions; Roi built from arrays (its file readers need numpy < 2)."""
    from apav.analysis.spatial import RangedGrid

    coll = apav.RangeCollection([
        apav.Range("".join(f"{el}{n}" for el, n in r.composition), (r.lower, r.upper)) for r in rt.ranges
    ])
    roi = apav.Roi(table.positions.astype(np.float64), table.mz.astype(np.float64))
    with np.errstate(all="ignore"):
        grid = RangedGrid(roi, coll, bin_width=voxel, delocalization=np.asarray(deloc))
    ions = {i.hill_formula.split()[0]: v for i, v in grid.all_ionic_counts.items()}
    elements = {e.symbol: v for e, v in grid._elem_counts.items()}
    return grid.centers[0][:, 0, 0], grid.centers[1][0, :, 0], grid.centers[2][0, 0, :], ions, elements


def test_gaussian_fields_agree_with_apav_ranged_grid():
    voxel, deloc = 1.0, (3.0, 3.0, 1.5)
    # a non-integer lower corner: APAV adds a stray grid plane when its last x centre is an integer
    table = random_ions(40000, [0.3, 0.4, 0.45], [24.1, 22.2, 15.3], seed=9, names=("Cu", "CrO2", "O", "B"))
    rt = ranges()
    x, y, z, ref_ions, ref_elements = apav_fields(table, rt, voxel, deloc)
    reach = 1 + second_pass_radius(second_pass_sigma(voxel, deloc))
    start = np.array([x[0], y[0], z[0]])
    grid = Grid(tuple(start - reach * voxel), voxel, tuple(np.array([len(x), len(y), len(z)]) + 2 * reach + 1))
    core = tuple(slice(r + 1, n - r - 1) for r, n in zip(reach, (len(x), len(y), len(z))))  # APAV indices
    ours_core = tuple(slice(s.start + r, s.stop + r) for s, r in zip(core, reach))
    assert all(s.stop - s.start >= 4 for s in core)
    for species, ref in (("ions", ref_ions), ("elements", ref_elements)):
        f = voxelize(table, rt, grid=grid, kernel="gaussian", delocalization=deloc, species=species)
        for name, field in f.counts.items():
            a = ref[name][core]
            b = field.dense()[ours_core]
            assert a.min() > 0.1  # a filled interior: relative agreement is meaningful
            rel = np.max(np.abs(b - a) / a)
            assert rel < 1e-4, (species, name, rel)
