"""Chemistry of open surfaces: ions beyond an interface's rim count on neither side of it.

An interface that leaves the specimen is measured to the voxel mask, about a voxel short of the specimen's
edge; the ions in that strip are beyond the surface's rim, not across it. Exact truth: a plane whose mesh
stops 1 nm short of the ion box's sides, a segregant only in a thin layer at the plane, no segregant elsewhere.
"""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.refine import object_excess
from apt_filters.refine.levels import object_levels

RANGES = RangeTable([Range(26.5, 27.5, (("Al", 1),)), Range(55.0, 57.0, (("Fe", 1),)),
                     Range(10.5, 11.5, (("B", 1),))])
BOX, RIM = 20.0, 1.0


def _plane(spacing: float = 0.5) -> TriMesh:
    """z = 0 over [RIM, BOX - RIM]², normals +z (the Al-rich phase, above the iso-value, lies below)."""
    g = np.arange(RIM, BOX - RIM + 1e-9, spacing)
    n = len(g)
    x, y = np.meshgrid(g, g, indexing="ij")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a, b, c, d = (i * n + j).ravel(), ((i + 1) * n + j).ravel(), ((i + 1) * n + j + 1).ravel(), (i * n + j + 1).ravel()
    return TriMesh(vertices, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]))


def _ions(seed: int = 3) -> IonTable:
    """Al 30 % below the plane, 10 % above, the rest Fe; B only within 0.3 nm of the plane."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform((0.0, 0.0, -6.0), (BOX, BOX, 6.0), (400_000, 3))
    al = rng.random(len(pos)) < np.where(pos[:, 2] < 0, 0.3, 0.1)
    mz = np.where(al, 27.0, 56.0)
    layer = rng.uniform((0.0, 0.0, -0.3), (BOX, BOX, 0.3), (4_000, 3))
    return IonTable(np.vstack([pos, layer]).astype(np.float32), np.concatenate([mz, np.full(len(layer), 11.0)]))


def _under_the_mesh(p: np.ndarray) -> np.ndarray:
    return ((p[:, :2] >= RIM) & (p[:, :2] <= BOX - RIM)).all(axis=1)


def test_excess_of_an_open_plane_counts_only_the_ions_under_it():
    ions = _ions()
    mesh = _plane()
    e, = object_excess(mesh, ions, RANGES, "B")
    p = ions.positions.astype(np.float64)
    held = np.count_nonzero((ions.mz == 11.0) & _under_the_mesh(p))  # B has no plateau: its excess is its count
    area = (BOX - 2 * RIM) ** 2
    assert e.area == pytest.approx(area, rel=1e-9)
    assert e.excess_ions == pytest.approx(held, abs=1e-6)
    # counting the strip beyond the rim too would read (20 / 18)² = 1.23 times the excess per area


def test_plateaus_of_an_open_plane_count_only_the_ions_under_it():
    ions = _ions()
    lv, = object_levels(_plane(), ions, RANGES, "Al", prior=0.0)
    p = ions.positions.astype(np.float64)
    under = _under_the_mesh(p)
    inside = under & (p[:, 2] <= -0.75) & (p[:, 2] >= -3.0)
    outside = under & (p[:, 2] >= 0.75) & (p[:, 2] <= 3.0)
    assert lv.n_inside == np.count_nonzero(inside)
    assert lv.n_outside == np.count_nonzero(outside)
    k = lv.elements.index("Al")
    assert lv.inside[k] == pytest.approx(np.mean(ions.mz[inside] == 27.0), abs=1e-12)
