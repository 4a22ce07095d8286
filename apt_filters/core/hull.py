"""The convex hull of the specimen (of its ions), exact and streamed: the one ion hull every step uses."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.spatial import ConvexHull, QhullError

ION_CHUNK = 4_000_000
"""Ions per chunk of a pass over the ions (12-16 bytes each while read)."""


def native_points(points: np.ndarray) -> np.ndarray:
    """Contiguous native float32/float64 (a no-copy view when already so), else float32: what
    the compiled kernels read (a big-endian memory map is converted chunk by chunk)."""
    dtype = points.dtype
    native = dtype.kind == "f" and dtype.itemsize in (4, 8) and dtype.isnative
    return np.ascontiguousarray(points, dtype=dtype if native else np.float32)


@dataclass(frozen=True)
class SpecimenHull:
    """Convex hull of the specimen (e.g. of its ions): half-spaces ``n . x + d <= 0`` inside."""

    equations: np.ndarray
    volume: float

    @classmethod
    def from_points(cls, points: np.ndarray, chunk: int = ION_CHUNK) -> "SpecimenHull":
        """Hull of (N, 3) points (nm) in two streamed passes over chunks of ``chunk`` points.

        Pass 1 finds the extreme points along :data:`_DIRECTIONS` among every
        :data:`HULL_SAMPLE`-th point; their hull lies inside the specimen's, so pass 2 keeps
        only the points on or outside it (a few per cent; points in grid cells wholly inside
        it are skipped without a test), and Qhull runs on those: the hull is exactly that of
        all points. Memory: one chunk
        converted to float32 (12 bytes/point) plus the kept points.
        """
        directions = _DIRECTIONS
        best = np.full(len(directions), -np.inf)
        arg = np.zeros(len(directions), dtype=np.int64)
        for start in range(0, len(points), chunk):  # a sample is enough: any points' hull lies inside
            _extremes(native_points(points[start:start + chunk:HULL_SAMPLE]), directions, best, arg, start, HULL_SAMPLE)
        extremes = np.asarray(points[np.unique(arg)], dtype=np.float64)
        try:
            inner = ConvexHull(extremes).equations
        except QhullError:  # the extremes are flat or too few: every point is a candidate
            inner = np.array([[0.0, 0.0, 0.0, 1.0]])
        deep = _DeepCells.build(inner, extremes.min(axis=0), extremes.max(axis=0), len(points))
        kept = [extremes]
        for start in range(0, len(points), chunk):
            block = native_points(points[start:start + chunk])
            keep = np.zeros(len(block), dtype=bool)
            _beyond(block, inner, HULL_TOLERANCE, deep.cells, deep.origin, 1.0 / deep.size, keep)
            kept.append(np.asarray(block[keep], dtype=np.float64))
        hull = ConvexHull(np.vstack(kept))
        return cls(hull.equations, float(hull.volume))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) distance (nm) of points (n, 3) to the hull's nearest facet plane, positive inside."""
        out = np.empty(len(points))
        _hull_distance(np.asarray(points, dtype=np.float64), self.equations, out)
        return out


HULL_SAMPLE = 8
"""Stride of the sample whose extremes give the inner hull of :meth:`SpecimenHull.from_points`."""

HULL_TOLERANCE = 1e-6
"""nm: points this close inside the inner hull of pass 1 are kept too (rounding of float32 input)."""


def _fibonacci_directions(n: int) -> np.ndarray:
    """(2n, 3) unit vectors spread over the sphere (Fibonacci lattice), each with its opposite."""
    z = 1.0 - (2.0 * np.arange(n) + 1.0) / n
    phi = np.arange(n) * math.pi * (3.0 - math.sqrt(5.0))
    d = np.column_stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z])
    return np.vstack([d, -d, np.eye(3), -np.eye(3)])


_DIRECTIONS = _fibonacci_directions(48)


@njit(cache=True, nogil=True)
def _extremes(points, directions, best, arg, offset, stride):  # pragma: no cover - compiled
    for i in range(points.shape[0]):
        x, y, z = float(points[i, 0]), float(points[i, 1]), float(points[i, 2])
        for k in range(directions.shape[0]):
            d = directions[k, 0] * x + directions[k, 1] * y + directions[k, 2] * z
            if d > best[k]:
                best[k] = d
                arg[k] = offset + i * stride


@dataclass(frozen=True)
class _DeepCells:
    """Cells of a coarse grid over the points' box that lie wholly inside a convex polytope
    (all 8 corners inside it): the points in them need no test against its facets."""

    cells: np.ndarray
    origin: np.ndarray
    size: float

    @classmethod
    def build(cls, equations: np.ndarray, lower: np.ndarray, upper: np.ndarray, n_points: int) -> "_DeepCells":
        n_cells = min(max(n_points // 16, 1), 1 << 22)  # ~16 points a cell, at most 4M cells
        size = max(float(np.prod(upper - lower) / n_cells) ** (1 / 3), 1e-9)
        shape = np.floor((upper - lower) / size).astype(int) + 1
        corners = np.stack(np.meshgrid(*[np.arange(n + 1) for n in shape], indexing="ij"), axis=-1)
        outside = np.zeros(corners.shape[:3], dtype=bool)
        no_cells = np.zeros((1, 1, 1), dtype=bool)
        _beyond(lower + corners.reshape(-1, 3) * size, equations, HULL_TOLERANCE, no_cells, lower, 0.0,
                outside.reshape(-1))
        inside = ~outside
        cells = np.ones(tuple(shape), dtype=bool)
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    cells &= inside[dx:dx + shape[0], dy:dy + shape[1], dz:dz + shape[2]]
        return cls(cells, lower, size)


@njit(cache=True, nogil=True)
def _beyond(points, equations, tol, deep, origin, inv, keep):  # pragma: no cover - compiled
    """Sets ``keep`` for points not deeper than ``tol`` inside the half-spaces ``equations``
    (f, 4), skipping points in ``deep`` cells (``inv`` = 1 / cell size; 0: no cells)."""
    nx, ny, nz = deep.shape
    for i in range(points.shape[0]):
        x, y, z = float(points[i, 0]), float(points[i, 1]), float(points[i, 2])
        cx = int(math.floor((x - origin[0]) * inv))
        cy = int(math.floor((y - origin[1]) * inv))
        cz = int(math.floor((z - origin[2]) * inv))
        if 0 <= cx < nx and 0 <= cy < ny and 0 <= cz < nz and deep[cx, cy, cz]:
            continue
        for f in range(equations.shape[0]):
            if equations[f, 0] * x + equations[f, 1] * y + equations[f, 2] * z + equations[f, 3] > -tol:
                keep[i] = True
                break


@njit(cache=True, nogil=True)
def _hull_distance(points, equations, out):  # pragma: no cover - compiled
    for i in range(points.shape[0]):
        worst = -np.inf
        for f in range(equations.shape[0]):
            v = equations[f, 0] * points[i, 0] + equations[f, 1] * points[i, 1] + equations[f, 2] * points[i, 2] \
                + equations[f, 3]
            worst = max(worst, v)
        out[i] = -worst
