"""The ions near a surface, selected in one streamed pass over the ion table and reused by every later step.

Refinement, the proxigram, the object table and the excess all need the ions within a few nm of
one surface (and of that surface after small moves). :func:`select_near` reads the positions
``chunk`` rows at a time (a memory-mapped table of 10^8-10^9 ions is read once, in bounded
memory) and keeps those within ``reach`` of the mesh by the exact signed distance
(:class:`~apt_filters.core.distance.SurfaceDistance`, whose narrow band rejects an ion far from
every triangle in a few nanoseconds). The result, :class:`NearSurface`, answers later questions
from memory: :meth:`NearSurface.within` gives the ions within a smaller reach of a moved mesh,
complete as long as the mesh has moved less than the slack between the two reaches.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh

CHUNK = 1 << 21
"""Rows of the ion table read at a time (about 30 bytes each while a chunk is searched)."""


@dataclass
class NearSurface:
    """Ions within ``reach`` nm of a mesh, with their signed distances to it.

    Attributes
    ----------
    rows : (b,) int64
        Rows of the ions in the table they were selected from, increasing.
    positions : (b, 3) float64
        Their positions, nm.
    distance : (b,) float32
        Signed distance to the mesh they were selected against (nm, positive along the normals,
        :mod:`apt_filters.core.distance`).
    face : (b,) int64
        Triangle holding each ion's closest point.
    reach : float
        Selection distance, nm.
    anchor : (n, 3) float64
        The mesh's vertices at selection.
    carried : tuple of arrays
        The selected rows of the columns given as ``carry`` to :func:`select_near` (e.g. m/z).
    """

    rows: np.ndarray
    positions: np.ndarray
    distance: np.ndarray
    face: np.ndarray
    reach: float
    anchor: np.ndarray
    carried: tuple = ()

    def moved(self, vertices: np.ndarray) -> float:
        """Largest move (nm) of a vertex of the same mesh since the selection."""
        if len(vertices) != len(self.anchor):
            return np.inf
        return float(np.sqrt(np.max(np.sum((vertices - self.anchor) ** 2, axis=1)))) if len(vertices) else 0.0

    def covers(self, mesh: TriMesh, reach: float, moved: float | None = None) -> bool:
        """Whether every ion within ``reach`` of ``mesh`` is among these.

        True when ``reach`` plus the farthest the surface has moved is within the selection's
        reach. ``moved`` (nm) bounds that move (the Hausdorff distance from the selected mesh);
        without it, ``mesh`` must be the selected mesh with moved vertices.
        """
        moved = self.moved(mesh.vertices) if moved is None else moved
        return reach + moved <= self.reach

    def within(self, mesh: TriMesh, reach: float, moved: float | None = None) -> tuple[np.ndarray, "SignedDistanceRows"]:
        """Indices into these ions of those within ``reach`` nm of ``mesh``, and their signed distances.

        Raises ``ValueError`` when the selection cannot vouch for completeness (:meth:`covers`).
        """
        if not self.covers(mesh, reach, moved):
            raise ValueError(f"ions were selected within {self.reach:g} nm; {reach:g} nm of a surface moved by "
                             f"{self.moved(mesh.vertices) if moved is None else moved:g} nm needs a new selection")
        sd = SurfaceDistance(mesh, reach=reach).query(self.positions, max_distance=reach)
        keep = np.flatnonzero(np.abs(sd.distance) <= reach)
        return keep, SignedDistanceRows(sd.distance[keep], sd.face[keep], sd.on_boundary[keep])


@dataclass
class SignedDistanceRows:
    """Signed distance (nm), closest face and rim flag of some selected ions (see :class:`NearSurface.within`)."""

    distance: np.ndarray
    face: np.ndarray
    on_boundary: np.ndarray


def select_near(positions: np.ndarray, mesh: TriMesh | SurfaceDistance, reach: float,
                chunk: int = CHUNK, *, also: Callable[[np.ndarray], np.ndarray] | None = None,
                carry: tuple[np.ndarray, ...] = ()) -> NearSurface:
    """The rows of ``positions`` within ``reach`` nm of a mesh, in one streamed pass.

    Parameters
    ----------
    positions : (N, 3) array, nm
        Ion positions; may be a memory map: one chunk is in memory at a time, besides the result.
    mesh : TriMesh or SurfaceDistance
        The surface (or its distance engine, to reuse a grid already built).
    reach : float
        Largest unsigned distance kept, nm.
    chunk : int
        Rows read at a time.
    also : callable, optional
        ``also(points)`` for a chunk's (k, 3) positions gives (k,) bool: further rows to keep beyond
        ``reach`` (their distance NaN and face -1), such as the ions inside closed objects.
    carry : tuple of arrays, optional
        Further columns of the same table (N rows each, e.g. m/z; memory maps too), read in the same
        pass: :attr:`NearSurface.carried` holds their selected rows.

    Returns
    -------
    NearSurface
        Memory: 48 bytes per selected ion, and those of the carried columns.
    """
    engine = mesh if isinstance(mesh, SurfaceDistance) else SurfaceDistance(mesh, reach=reach)
    rows, points, dist, face = [np.zeros(0, np.int64)], [np.zeros((0, 3))], [np.zeros(0, np.float32)], \
        [np.zeros(0, np.int64)]
    carried = [[np.zeros((0, *np.shape(c)[1:]), np.asarray(c[:0]).dtype)] for c in carry]
    for start in range(0, len(positions), chunk):
        part = np.asarray(positions[start:start + chunk])
        sd = engine.query(part, max_distance=reach)
        near = np.abs(sd.distance) <= reach
        keep = np.flatnonzero(near if also is None else near | also(part))
        rows.append(start + keep)
        points.append(part[keep].astype(np.float64))
        dist.append(sd.distance[keep])
        face.append(sd.face[keep])
        for column, out in zip(carry, carried):
            out.append(np.asarray(column[start:start + chunk])[keep])
    return NearSurface(np.concatenate(rows), np.concatenate(points), np.concatenate(dist), np.concatenate(face),
                       float(reach), engine.mesh.vertices.copy(), tuple(np.concatenate(c) for c in carried))
