"""The ions near a surface, selected in one streamed pass over the ion table and reused by every later step.

Refinement, the proxigram, the object table and the excess all need the ions within a few nm of
one surface (and of that surface after small moves). :func:`select_near` reads the positions
``chunk`` rows at a time (a memory-mapped table of 10^8-10^9 ions is read once, in bounded
memory) and keeps those within ``reach`` of the mesh by the exact signed distance
(:class:`~apt_filters.core.distance.SurfaceDistance`). A coarse grid of the surface's reach comes
first (:class:`ReachGrid`): the distance is 1-Lipschitz, so the exact distance of each cell's centre
bounds every ion of the cell by its distance to the centre, and only the ions the bounds cannot
place on one side of ``reach`` are searched (all those within reach when their distances are asked
for). The result, :class:`NearSurface`, answers later questions
from memory: :meth:`NearSurface.within` gives the ions within a smaller reach of a moved mesh,
complete as long as the mesh has moved less than the slack between the two reaches.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numba import njit, prange

from apt_filters.core.distance import SurfaceDistance, _threads_for
from apt_filters.core.mesh import TriMesh

CHUNK = 1 << 21
"""Rows of the ion table read at a time (about 30 bytes each while a chunk is searched)."""


@dataclass
class NearSurface:
    """Ions within ``reach`` nm of a mesh, with their signed distances to it.

    Attributes
    ----------
    rows : (b,) int64
        Rows of the ions in the table they were selected from, increasing (None when selected ``lean``).
    positions : (b, 3) float64
        Their positions, nm (None when selected ``lean``).
    distance : (b,) float32
        Signed distance to the mesh they were selected against (nm, positive along the normals,
        :mod:`apt_filters.core.distance`).
    face : (b,) int64
        Triangle holding each ion's closest point (int32 when selected ``lean``).
    reach : float
        Selection distance, nm.
    anchor : (n, 3) float64
        The mesh's vertices at selection.
    carried : tuple of arrays
        The selected rows of the columns given as ``carry`` to :func:`select_near` (e.g. m/z).
    on_boundary : (b,) bool
        Whether an ion's closest point is on the mesh's rim (an open surface's boundary edge or vertex,
        :attr:`~apt_filters.core.distance.SignedDistance.on_boundary`): it lies beyond the rim, not across the
        surface, so its side is no phase's (False where no distance was searched).
    """

    rows: np.ndarray | None
    positions: np.ndarray | None
    distance: np.ndarray
    face: np.ndarray
    reach: float
    anchor: np.ndarray
    carried: tuple = ()
    on_boundary: np.ndarray | None = None

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
        if self.positions is None:
            raise ValueError("a lean selection keeps no positions to measure again")
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


FAR, WITHIN, SEARCH = 0, 1, 2
"""What :meth:`ReachGrid.classify` says of an ion: outside the shell (proved), inside it (proved), or to be
searched (the bound straddles one of its distances)."""

CORE = 3
"""A coarse cell's state when every point of it is within ``inner`` of the mesh (proved): its ions are all to be
searched whatever their fine cell, so its fine centres are not measured."""

MAX_CELLS = 1 << 22
"""Most fine cells of a :class:`ReachGrid` (4 bytes each); the cell grows beyond :data:`ION_CELL` to stay under."""

ION_CELL = 0.5
"""nm: edge of a reach-grid cell. A cell holds ~5 ions at the 40 ions/nm³ of a reconstruction, so the
centres cost a fifth of a search of every ion, while the ions the bound leaves undecided lie within
the distance to their centre (0.24 nm on average) of the reach."""

FAR_CELL = 1.0
"""nm: edge of the reach grid's cell where it only has to prove ions far, every kept ion being searched anyway
(:func:`select_near` with exact distances throughout): an eighth of the centres to measure for a few more ions
searched near the reach (refinement's selections of 0.7-2M ions: 9-25 % less CPU than at :data:`ION_CELL`); the
rows and distances are the same whatever the grid."""


@dataclass
class ReachGrid:
    """Distances (nm) from the centres of a two-level grid's cells to a mesh, to bound the ions' own.

    The unsigned distance is 1-Lipschitz: an ion ``r`` nm from a centre at distance ``d`` lies between
    ``d - r`` and ``d + r`` from the mesh. On a closed mesh the signed distance is continuous too, so an
    ion within ``|d|`` of a centre lies on the centre's side. The grid decides, for the shell of
    unsigned distances (``inner``, ``reach``], which ions lie in it (and on which side) and which outside.

    Attributes
    ----------
    origin : (3,) float64
        Corner of cell (0, 0, 0), nm.
    cell : float
        Fine cell edge, nm (coarse cells: twice that).
    state : (nx, ny, nz) int8
        Per coarse cell: :data:`FAR` (every point outside the shell), :data:`WITHIN` (every point inside it),
        :data:`CORE` (every point nearer than ``inner``: searched), :data:`SEARCH` (its eight fine cells were
        measured).
    coarse : (nx, ny, nz) float32
        Signed distance of each coarse centre (NaN beyond the reach and half the cell's diagonal).
    fine : (2 nx, 2 ny, 2 nz) float32
        Signed distance of each fine centre of the coarse cells in state :data:`SEARCH` (NaN elsewhere and
        beyond the reach and half the cell's diagonal).
    reach, inner : float
        nm.

    Notes
    -----
    The grid covers the mesh's bounding box grown by the reach and a coarse cell; a point outside it is
    farther than the reach from every triangle. Memory: 4.6 bytes per fine cell, at most :data:`MAX_CELLS`.
    """

    origin: np.ndarray
    cell: float
    state: np.ndarray
    coarse: np.ndarray
    fine: np.ndarray
    reach: float
    inner: float = 0.0

    @classmethod
    def of(cls, engine: SurfaceDistance, reach: float, inner: float = 0.0, cell: float = ION_CELL) -> "ReachGrid":
        """The grid of ``engine``'s mesh for the shell (``inner``, ``reach``] nm (``cell`` nm, grown to at most
        :data:`MAX_CELLS`). Built coarse to fine: the coarse centres are measured first, and only the fine
        centres of the coarse cells their own bound leaves undecided (not those it proves nearer than ``inner``,
        whose ions the fine bound could not spare a search either)."""
        vertices = engine.mesh.vertices
        if not len(vertices) or not engine.mesh.n_faces:
            empty = np.zeros((0, 0, 0))
            return cls(np.zeros(3), 1.0, empty.astype(np.int8), empty.astype(np.float32), empty.astype(np.float32),
                       float(reach), float(inner))
        eps = _margin(reach)
        while True:
            coarse = 2.0 * cell
            lo = vertices.min(axis=0) - reach - coarse
            shape = np.ceil((vertices.max(axis=0) + reach + coarse - lo) / coarse).astype(np.int64)
            if 8 * np.prod(shape) <= MAX_CELLS:
                break
            cell *= 1.25
        half = coarse * np.sqrt(3.0) / 2
        axes = [lo[k] + coarse * (np.arange(shape[k]) + 0.5) for k in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        d = engine.query(centres, max_distance=reach + half).distance.reshape(tuple(shape))
        a = np.abs(d)
        within = (a + half < reach - eps) & ((a - half > inner + eps) if inner > 0 else True)
        state = np.full(tuple(shape), SEARCH, np.int8)
        state[np.isnan(a) | (a - half > reach + eps)] = FAR
        state[within] = WITHIN
        if inner > 0:
            state[a + half < inner - eps] = CORE
        measured = np.repeat(np.repeat(np.repeat(state == SEARCH, 2, 0), 2, 1), 2, 2)
        fine = np.full(tuple(2 * shape), np.nan, np.float32)
        centres = lo + cell * (np.column_stack(np.nonzero(measured)) + 0.5)
        fine[measured] = engine.query(centres, max_distance=reach + cell * np.sqrt(3.0) / 2).distance
        return cls(lo, float(cell), state, d, fine, float(reach), float(inner))

    def classify(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Verdicts (k,) int8 on points (k, 3) nm: :data:`FAR`, :data:`WITHIN` or :data:`SEARCH`; and (k,) int8
        the side (+1 along the normals, -1 against, 0 unknown) of those :data:`WITHIN` a shell with ``inner`` > 0
        (meaningful on a closed mesh only)."""
        out, side = np.empty(len(points), np.int8), np.zeros(len(points), np.int8)
        with _threads_for(len(points)):
            _classify(np.ascontiguousarray(points), self.origin, self.cell, self.state, self.coarse, self.fine,
                      self.reach, self.inner, _margin(self.reach), out, side)
        return out, side


def _margin(reach: float) -> float:
    """nm by which a bound must clear the shell's distances: far above float32 rounding, so that an ion whose
    distance is the reach itself stays undecided and is searched."""
    return 1e-4 * max(1.0, reach)


@njit(cache=True, error_model="numpy", parallel=True)
def _classify(points, origin, cell, state, coarse, fine, reach, inner, eps, out, side):
    nx, ny, nz = state.shape
    for i in prange(points.shape[0]):
        x = (np.float64(points[i, 0]) - origin[0]) / cell
        y = (np.float64(points[i, 1]) - origin[1]) / cell
        z = (np.float64(points[i, 2]) - origin[2]) / cell
        out[i] = FAR
        if not (0.0 <= x < 2 * nx and 0.0 <= y < 2 * ny and 0.0 <= z < 2 * nz):
            continue
        ix, iy, iz = int(x), int(y), int(z)
        s = state[ix // 2, iy // 2, iz // 2]
        if s == FAR:
            continue
        if s == CORE:
            out[i] = SEARCH
            continue
        if s == WITHIN:
            out[i] = WITHIN
            side[i] = 1 if coarse[ix // 2, iy // 2, iz // 2] > 0 else -1
            continue
        d = fine[ix, iy, iz]
        if np.isnan(d):
            continue
        r = cell * np.sqrt((x - ix - 0.5) ** 2 + (y - iy - 0.5) ** 2 + (z - iz - 0.5) ** 2)
        lower, upper = abs(d) - r, abs(d) + r
        if lower > reach + eps:
            continue
        out[i] = SEARCH
        if upper < reach - eps and (inner <= 0.0 or lower > inner + eps):
            out[i] = WITHIN
            side[i] = 0 if lower <= 0.0 else (1 if d > 0 else -1)


def select_near(positions: np.ndarray, mesh: TriMesh | SurfaceDistance, reach: float,
                chunk: int = CHUNK, *, also: Callable[[np.ndarray], np.ndarray] | None = None,
                carry: tuple[np.ndarray, ...] = (), distances: bool | float = True, lean: bool = False) -> NearSurface:
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
    distances : bool or float
        True: every selected ion's exact signed distance. False: only the selection is asked for; the
        ions a :class:`ReachGrid` proves within ``reach`` are kept unsearched (distance NaN, face -1, as
        those kept by ``also``), only those it leaves undecided (within about a cell of the reach) are
        searched. A float ``x`` < ``reach``: exact distances within ``x`` nm; on a closed mesh the ions the
        grid proves between ``x`` and ``reach`` get only their side (distance +-inf, face -1). The rows
        are the same in every case; in every case the ions the grid proves farther than ``reach`` are not
        searched.
    lean : bool
        Keep only what a pass over the selection with its measured distances reads (the proxigram's): distance,
        face (int32) and rim flag, not the rows nor the positions as float64 (carry the table's own positions to
        keep them in their dtype). :attr:`NearSurface.rows` and :attr:`NearSurface.positions` are then None, and
        :meth:`NearSurface.within` cannot be asked.

    Returns
    -------
    NearSurface
        Memory: 45 bytes per selected ion (9 when ``lean``), and those of the carried columns; while the result is
        joined, one column's chunks beside it.
    """
    engine = mesh if isinstance(mesh, SurfaceDistance) else SurfaceDistance(mesh, reach=reach)
    closed = engine.mesh.n_faces > 0 and not engine.topology.boundary_vertex.any()
    exact = reach if distances is True else 0.0 if distances is False else float(distances)
    # Beyond ``exact`` only the side is asked, which the grid's centres give on a closed mesh alone; where every
    # kept ion needs its exact distance the grid still spares the search of those it proves beyond the reach.
    side_only = 0 < exact < reach and closed
    unsearched = exact == 0 or side_only  # ions the grid proves within the reach are kept without a search
    grid = ReachGrid.of(engine, reach, inner=exact if side_only else 0.0, cell=ION_CELL if unsearched else FAR_CELL) \
        if engine.mesh.n_faces else None
    rows, points, dist, face = [np.zeros(0, np.int64)], [np.zeros((0, 3))], [np.zeros(0, np.float32)], \
        [np.zeros(0, np.int32 if lean else np.int64)]
    rim = [np.zeros(0, bool)]
    carried = [[np.zeros((0, *np.shape(c)[1:]), np.asarray(c[:0]).dtype)] for c in carry]
    for start in range(0, len(positions), chunk):
        part = np.asarray(positions[start:start + chunk])
        extra = None if also is None else also(part)
        if grid is None:  # a mesh without triangles: the search finds nothing, the ``also`` rows are kept
            kind, side = np.full(len(part), SEARCH, np.int8), np.zeros(len(part), np.int8)
        else:
            kind, side = grid.classify(part)
        # only the ions the grid does not prove beyond the reach (and those ``also`` keeps) are looked at further:
        # at 40 ions/nm³ most of a specimen's ions are far from any one surface
        look = np.flatnonzero(kind != FAR if extra is None else (kind != FAR) | extra)
        verdict = kind[look]
        search = np.flatnonzero(verdict == SEARCH if unsearched else verdict != FAR)
        sd = engine.query(part[look[search]], max_distance=reach)
        d, f = np.full(len(look), np.nan, np.float32), np.full(len(look), -1, np.int64)
        r = np.zeros(len(look), bool)
        d[search], f[search], r[search] = sd.distance, sd.face, sd.on_boundary
        within = verdict == WITHIN
        if grid is not None and grid.inner > 0:  # the shell's ions: only their side
            d[within] = side[look[within]] * np.float32(np.inf)
        near = within | (np.abs(d) <= reach)
        held = np.flatnonzero(near if extra is None else near | extra[look])
        keep, d, f, r = look[held], d[held], f[held], r[held]
        if not lean:
            rows.append(start + keep)
            points.append(part[keep].astype(np.float64))
        dist.append(d)
        face.append(f.astype(np.int32) if lean else f)
        rim.append(r)
        for column, out in zip(carry, carried):
            out.append(np.asarray(column[start:start + chunk])[keep])
    # column by column, each column's chunks let go once joined: the peak is the result and one column's chunks
    rows, points = (None, None) if lean else (_joined(rows), _joined(points))
    dist, face, rim = _joined(dist), _joined(face), _joined(rim)
    return NearSurface(rows, points, dist, face, float(reach), engine.mesh.vertices.copy(),
                       tuple(_joined(c) for c in carried), rim)


def _joined(parts: list[np.ndarray]) -> np.ndarray:
    """The arrays of ``parts`` concatenated; ``parts`` is emptied, so that they are freed as soon as joined."""
    out = np.concatenate(parts)
    parts.clear()
    return out
