"""The signed distance of points to an oriented triangle mesh: the one engine every step uses.

Sign convention: a mesh's normals point OUT of the region above the iso-value, and a distance is
positive along them, i.e. outside that region (below the iso-value), negative inside. Steps that
report the other way (the proxigram plots distance positive inside, as AP Suite does) negate it.

The closest point on the surface comes from an exact search (:class:`TriangleGrid`: triangles
bucketed in a uniform grid; points visited block by block, each block listing once the non-empty
cells within range sorted by a lower bound; cells and triangles pruned by box and disk lower
bounds; Ericson's closest point on a triangle, :func:`apt_filters.core.triangle.closest_on_triangle`;
numba on all cores, float64). The sign comes from the angle-weighted pseudo-normal of the feature
(face, edge or vertex) on which the closest point lies (Bærentzen & Aanæs 2005,
doi:10.1109/TVCG.2005.49): provably right for any point of a closed manifold, including at sharp
edges and corners, and meaningful on open surfaces, unlike ray parity (which assumes a watertight
mesh).

Narrow band: with ``max_distance``, a point whose block (2 x 2 x 2 grid cells by default) has no
triangle within that distance is rejected at once (NaN) and the others are searched no farther
than ``max_distance``: the cost is proportional to the points near the surface. This band is
exact at the block level (conservative, no point within range is lost) and needs no separate
structure.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import numba
import numpy as np
from numba import njit, prange
from scipy import ndimage

from apt_filters.core.mesh import TriMesh
from apt_filters.core.triangle import closest_on_triangle

_PARALLEL_POINTS = 4096
"""Queries of fewer points (search plans of fewer blocks) run on the calling thread: waking numba's
other threads costs more (tens of ms per call on a loaded machine: a remesh's projections of a few
dozen points took 30-50 ms each, the plans of its patch grids 95 ms)."""


@contextmanager
def _threads_for(n: int):
    """numba's thread count set to 1 while ``n`` items are fewer than :data:`_PARALLEL_POINTS`."""
    threads = numba.get_num_threads()
    numba.set_num_threads(threads if n >= _PARALLEL_POINTS else 1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)

_CHUNK = 1 << 20
"""Points a query converts to float64 and searches at a time (24 MB)."""

_ROUNDING = 1e-12
"""Rounding of the search's distances and bounds relative to the largest coordinate (float64: ~100 x
its own error): a bound passes a triangle over only when it exceeds the best distance by this much,
so a triangle exactly as near as the best (a tie, :func:`_before`) is never lost to rounding."""

_PARTS = 4
"""Sub-cells per home edge by which a query orders its points within each home: the previous point's
closest face, which seeds each search, is then seldom far (a quarter less CPU than home order alone)."""

_RUN = 64
"""Consecutive triangles (in cell order) whose common box a search beyond the grid's rings tests
first (:attr:`TriangleGrid.run_boxes`): a run no nearer than the best so far is passed over whole."""

_REACH_CELL = 0.5
"""Smallest grid cell of an engine built for queries within a reach, as a fraction of that reach (homes of one
cell): the ions within 3-4 nm of a remeshed surface (0.5 nm edges), all searched, cost a quarter less CPU than
with cells of a quarter of the reach and homes of two cells (3M-ion pipeline run: `select_near` 1.72 -> 1.24 s
at 3 nm, 2.61 -> 1.93 s at 4 nm); the distances and faces are the same whatever the grid."""

_MAX_RING = 16
"""Cells the grid search reaches around a point when no ``max_distance`` bounds it."""

FACE, EDGE, VERTEX = 0, 1, 2
"""Feature of the closest point (``SignedDistance.feature``)."""

_BARY_EPS = 1e-5
"""Barycentric weight below which the closest point counts as lying on an edge/vertex.

Erring toward the lower-dimensional feature is safe: the edge (vertex) pseudo-normal gives the
right sign for a point whose closest point is inside an adjacent face, too.
"""


@dataclass
class PseudoNormals:
    """The normals that sign a distance (Bærentzen & Aanæs 2005), for one placement of the vertices.

    Attributes
    ----------
    face_normals : (m, 3) float64
        Unit face normals.
    edge_normals : (e, 3) float64
        Sum of the unit normals of the faces using each edge of :attr:`TriMesh.topology`.
    vertex_normals : (n, 3) float64
        Angle-weighted sum of incident unit face normals.
    corner_angles : (m, 3) float64
        Interior angle (radians) of each face at each of its corners.
    """

    face_normals: np.ndarray
    edge_normals: np.ndarray
    vertex_normals: np.ndarray
    corner_angles: np.ndarray

    @classmethod
    def of(cls, mesh: TriMesh) -> "PseudoNormals":
        top = mesh.topology
        nf = mesh.face_normals()
        corner_angles = _corner_angles(mesh.vertices, mesh.faces)
        edge_normals = _sum_rows(top.face_edge.ravel(), lambda k: np.repeat(nf[:, k], 3), len(top.edge_vertices))
        vertex_normals = _sum_rows(mesh.faces.ravel(), lambda k: (corner_angles * nf[:, k:k + 1]).ravel(),
                                   mesh.n_vertices)
        return cls(nf, edge_normals, vertex_normals, corner_angles)


def _sum_rows(index: np.ndarray, column, n: int) -> np.ndarray:
    """(n, 3) sums by ``index`` (k,) of the rows whose coordinate j ``column(j)`` gives ((k,) each; np.add.at, but
    faster), a coordinate at a time: (3m, 3) rows of a mesh's corners were 72 bytes per face."""
    return np.stack([np.bincount(index, column(k), minlength=n) for k in range(3)], axis=1)


def _corner_angles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m, 3) interior angles (radians) of ``faces`` (m, 3) over ``vertices`` (n, 3) at each of their corners,
    corner by corner: the (m, 3, 3) corner points, their two rolled differences and cross products were 457 bytes
    per face at their peak (now 177), an engine's build's peak."""
    out = np.empty(faces.shape)
    for k in range(3):
        p = vertices[faces[:, k]]
        a = vertices[faces[:, (k + 1) % 3]] - p
        b = vertices[faces[:, k - 1]] - p
        out[:, k] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    return out


@dataclass
class SignedDistance:
    """Exact signed distances of queried points.

    Attributes
    ----------
    distance : (N,) float32
        Signed distance in nm, positive outside the region above the iso-value (along the
        normals); NaN beyond a query's ``max_distance``.
    face : (N,) int64
        Triangle holding the closest point (-1 beyond ``max_distance``).
    feature : (N,) int8
        ``FACE``, ``EDGE`` or ``VERTEX``: where on that triangle the closest point lies.
    on_boundary : (N,) bool
        The closest point lies on a boundary edge or vertex of an open surface (the specimen
        edge): the point is beyond the surface's rim rather than across it.
    weights : (N, 3) float64 or None
        With ``closest=True``: barycentric weights of the closest point on ``face`` (corners 0,
        1, 2 of the mesh's face); :meth:`SurfaceDistance.closest` turns them into points.
    searched : int
        Points that needed a search (with ``max_distance``: those whose home block has a
        triangle within reach, the narrow band; otherwise all).
    """

    distance: np.ndarray
    face: np.ndarray
    feature: np.ndarray
    on_boundary: np.ndarray
    searched: int = 0
    weights: np.ndarray | None = None


class SurfaceDistance:
    """Signed-distance queries against one placement of a mesh (search grid and pseudo-normals built once).

    Parameters
    ----------
    mesh : TriMesh
        Oriented surface (normals out of the region above the iso-value); may be open. Its
        vertices are copied: a mesh that moves needs a new ``SurfaceDistance`` (the topology
        is cached on the mesh and reused).
    cell : float, optional
        Grid cell, nm (default: :meth:`TriangleGrid.build`, twice the median edge).
    reach : float, optional
        The ``max_distance`` queries will use, nm: the cell is then at least :data:`_REACH_CELL` of it and
        each home one cell (unless ``home`` is given), so that a search within reach visits tens of cells,
        not thousands (a 0.1 nm-edge sphere with a 3 nm reach: 16x faster, the same distances).
    home : int, optional
        Edge, in grid cells, of the blocks whose points share one list of rows to search (the
        visiting order); default 2, or 1 with ``reach``.

    Notes
    -----
    Memory: the grid (:class:`TriangleGrid`, about 170 bytes per triangle) plus 14 bytes per
    queried point for the results, and about 70 bytes per point of a million-point chunk (its float64
    copy in visiting order, the order, the keys and the chunk's results before they are put back).
    """

    def __init__(self, mesh: TriMesh, cell: float | None = None, home: int | None = None,
                 reach: float | None = None):
        self.mesh = mesh
        # kept, not looked up per query: the topology cache holds only the last few meshes (a remesh
        # queries dozens of patches in turn, and rebuilt each patch's topology on every query)
        self.topology = mesh.topology
        self.normals = PseudoNormals.of(mesh)
        self._vertices = np.array(mesh.vertices, dtype=np.float64)
        self._faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        bounded = reach is not None and np.isfinite(reach)
        self.grid = TriangleGrid.build(self._vertices, self._faces, cell,
                                       min_cell=reach * _REACH_CELL if bounded else 0.0)
        self.home = home if home is not None else 1 if bounded else 2

    def query(self, points: np.ndarray, max_distance: float | None = None, closest: bool = False) -> SignedDistance:
        """Exact signed distance of every point (N, 3) nm to the surface.

        Points are visited a million at a time (as float64), cell by cell and within each cell by
        its sub-cells, so that consecutive searches touch the same cells and start from a near
        face. Where faces are exactly as near (a closest point on a shared edge or corner), the
        face is the one of lowest centroid (x, then y, then z): no result depends on the order of
        the points or of the faces, nor on the grid. With
        ``max_distance`` (nm), points farther than that from the surface get a NaN distance and
        face -1, and the search never looks farther: a point whose cell has no triangle within
        range costs a few nanoseconds. Without it, a point more than ``_MAX_RING`` grid cells
        away from every triangle is finished by trying every triangle in turn (exact; runs of 64
        triangles and single triangles no nearer than the best so far are passed over by their box
        and disk bounds, but still slow on large meshes).
        With ``closest``, the barycentric weights of each closest point are kept too
        (``weights``, 24 more bytes per point).
        """
        n = len(points)
        out = SignedDistance(np.empty(n, np.float32), np.empty(n, np.int64), np.empty(n, np.int8), np.empty(n, bool),
                             weights=np.zeros((n if closest else 0, 3)))
        top, nrm = self.topology, self.normals
        signs = (self._vertices, self._faces, nrm.face_normals, top.face_edge, nrm.edge_normals, top.edge_faces,
                 nrm.vertex_normals, top.boundary_vertex)
        g = self.grid
        reach = np.inf if max_distance is None else float(max_distance)
        m = self.home
        offsets, bound, r, first, covered = g.offsets(min(reach, g.cell * float(min(g.shape.max(), _MAX_RING))), m)
        # homes beyond r cells of the grid hold no triangle within the plan's reach
        rim = -(-r // m)
        low, dims = np.full(3, -rim, np.int64), -(-g.shape // m) + 2 * rim
        extent = float(np.abs(g.triangles[:, :9]).max()) if len(g.triangles) else 0.0
        # float64 chunk by chunk: one compiled signature whatever the points' type, 24 bytes per point of a chunk;
        # the closest face does not depend on the order the points are visited in (:func:`_before`)
        for s in range(0, n, _CHUNK):
            part = np.asarray(points[s:s + _CHUNK])
            k = len(part)
            order, keys = _spatial_order(part, g.origin, m * g.cell, low, dims, _PARTS)
            # in visiting order: consecutive points lie close together in memory as in space
            part, keys = np.ascontiguousarray(part[order], dtype=np.float64), keys[order]
            # rounding of the distances and bounds of coordinates this large, far below any real tie's gap
            pad = _ROUNDING * max(extent, float(np.abs(part).max()), 1.0)
            # the results in visiting order, then each array put back in the points' order at once
            found = SignedDistance(np.empty(k, np.float32), np.empty(k, np.int64), np.empty(k, np.int8),
                                   np.empty(k, bool), weights=np.zeros((k if closest else 0, 3)))
            with _threads_for(k):
                out.searched += int(_signed_in_cells(part, keys, _blocks(keys, 256), low, dims, m, g.triangles,
                                                     g.face_id, g.origin, g.cell, g.shape, g.slot, g.start, g.tris,
                                                     g.boxes, g.run_boxes, offsets, bound, first, covered,
                                                     reach * reach * (1 + 1e-12), pad, *signs, found.distance,
                                                     found.face, found.feature, found.on_boundary, found.weights,
                                                     numba.get_num_threads()).sum())
            order += s
            out.distance[order], out.face[order], out.feature[order] = found.distance, found.face, found.feature
            out.on_boundary[order] = found.on_boundary
            if closest:
                out.weights[order] = found.weights
        if not closest:
            out.weights = None
        return out

    def nearest(self, points: np.ndarray, near: float, closest: bool = False) -> SignedDistance:
        """:meth:`query` without a distance limit, for points (N, 3) most of which lie within ``near``
        (nm) of the surface: those are searched no farther (a bounded search visits tens of cells
        instead of thousands), the others again without bound."""
        sd = self.query(points, max_distance=near, closest=closest)
        miss = np.flatnonzero(sd.face < 0)
        if len(miss):
            far = self.query(points[miss], closest=closest)
            sd.distance[miss], sd.face[miss], sd.feature[miss] = far.distance, far.face, far.feature
            sd.on_boundary[miss] = far.on_boundary
            if closest:
                sd.weights[miss] = far.weights
        return sd

    def closest(self, points: np.ndarray, near: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest points on the surface to ``points`` (N, 3) nm: positions (N, 3), faces (N,) and
        barycentric weights (N, 3) of the face's corners (exact, float64). ``near`` (nm): as
        :meth:`nearest`.
        """
        points = np.asarray(points, dtype=np.float64)
        sd = self.query(points, closest=True) if near is None else self.nearest(points, near, closest=True)
        corners = self._vertices[self._faces[sd.face]]
        return np.einsum("nk,nkj->nj", sd.weights, corners), sd.face, sd.weights


def mesh_distance(mesh: TriMesh, points: np.ndarray) -> np.ndarray:
    """(N,) float64 unsigned exact distance (nm) of points (N, 3) to the nearest triangle of ``mesh``."""
    return np.abs(SurfaceDistance(mesh).query(np.asarray(points, dtype=np.float64)).distance.astype(np.float64))


# --- exact closest-triangle search on a uniform grid (numba) -----------------------------------


@njit(cache=True, error_model="numpy", inline="always")
def _closest_on_triangle(px, py, pz, tri, t):
    """Squared distance of p to triangle ``t`` of the packed table ``tri`` (corners a, b, c in
    columns 0-8) and the weights (u, w) of b and c (:func:`apt_filters.core.triangle.closest_on_triangle`)."""
    d, u, w, _ = closest_on_triangle(px, py, pz, tri[t, 0], tri[t, 1], tri[t, 2], tri[t, 3], tri[t, 4], tri[t, 5],
                                     tri[t, 6], tri[t, 7], tri[t, 8])
    return d, u, w


@njit(cache=True, error_model="numpy")
def _bucket_triangles(tri, origin, cell, shape):
    """CSR lists of the triangles whose bounding box meets each grid cell, and per-cell boxes.

    Returns ``slot`` (cells,) int32 (-1 for an empty cell, else its row), ``start`` (rows + 1,)
    int64, ``tris`` int32 and ``boxes`` (rows, 6) float64: lower and upper corner of the part of
    the cell covered by its triangles' bounding boxes (padded by 1e-7 nm against rounding), a
    lower bound for the distance to anything in the cell.
    """
    m = tri.shape[0]
    n_cells = shape[0] * shape[1] * shape[2]
    span = np.empty((m, 6), np.int64)
    counts = np.zeros(n_cells, np.int64)
    for t in range(m):
        for k in range(3):
            a = min(tri[t, k], tri[t, 3 + k], tri[t, 6 + k])
            b = max(tri[t, k], tri[t, 3 + k], tri[t, 6 + k])
            span[t, k] = min(max(int(np.floor((a - origin[k]) / cell)), 0), shape[k] - 1)
            span[t, 3 + k] = min(max(int(np.floor((b - origin[k]) / cell)), 0), shape[k] - 1)
        for ix in range(span[t, 0], span[t, 3] + 1):
            for iy in range(span[t, 1], span[t, 4] + 1):
                for iz in range(span[t, 2], span[t, 5] + 1):
                    counts[(ix * shape[1] + iy) * shape[2] + iz] += 1
    slot = np.full(n_cells, -1, np.int32)
    n_rows = 0
    for c in range(n_cells):
        if counts[c] > 0:
            slot[c] = n_rows
            n_rows += 1
    start = np.zeros(n_rows + 1, np.int64)
    for c in range(n_cells):
        if counts[c] > 0:
            start[slot[c] + 1] = start[slot[c]] + counts[c]
    tris = np.empty(start[n_rows], np.int32)
    fill = start[:n_rows].copy()
    boxes = np.empty((n_rows, 6))
    boxes[:, :3] = np.inf
    boxes[:, 3:] = -np.inf
    pad = 1e-7
    for t in range(m):
        for ix in range(span[t, 0], span[t, 3] + 1):
            for iy in range(span[t, 1], span[t, 4] + 1):
                for iz in range(span[t, 2], span[t, 5] + 1):
                    r = slot[(ix * shape[1] + iy) * shape[2] + iz]
                    tris[fill[r]] = t
                    fill[r] += 1
                    idx = (ix, iy, iz)
                    for k in range(3):
                        a = min(tri[t, k], tri[t, 3 + k], tri[t, 6 + k])
                        b = max(tri[t, k], tri[t, 3 + k], tri[t, 6 + k])
                        lo = max(a, origin[k] + idx[k] * cell) - pad
                        hi = min(b, origin[k] + (idx[k] + 1) * cell) + pad
                        boxes[r, k] = min(boxes[r, k], lo)
                        boxes[r, 3 + k] = max(boxes[r, 3 + k], hi)
    return slot, start, tris, boxes


@njit(cache=True, error_model="numpy", parallel=True)
def _first_occupied(shape, slot, m, offsets, far):
    """(blocks,) int32: index of the first of ``offsets`` that leads from each block of m x m x m
    cells (offsets from its first cell) to a non-empty cell (``len(offsets)`` if none, or if
    ``far`` says so); the search starts there, the offsets before lead to empty cells only."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    bx, by, bz = far.shape
    first = np.full(bx * by * bz, offsets.shape[0], np.int32)
    for c in prange(bx * by * bz):
        hx, hy, hz = c // (by * bz), (c // bz) % by, c % bz
        if far[hx, hy, hz]:
            continue
        for k in range(offsets.shape[0]):
            ix, iy, iz = m * hx + offsets[k, 0], m * hy + offsets[k, 1], m * hz + offsets[k, 2]
            if 0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz and slot[(ix * ny + iy) * nz + iz] >= 0:
                first[c] = k
                break
    return first


@njit(cache=True, error_model="numpy", inline="always")
def _signed_one(px, py, pz, f, u, w, d2, vertices, faces, face_normals, face_edge, edge_normals, edge_faces,
                vertex_normals, boundary_vertex):
    """Signed distance, feature and rim flag of a point whose closest point on face ``f`` has the
    weights (u, w) of corners 1 and 2; ``d2`` its squared distance (< 0: from the points).

    The normal is the angle-weighted pseudo-normal of the feature holding the closest point: the
    face, the edge opposite a corner of weight below ``_BARY_EPS``, or the corner of largest
    weight when two are below it.
    """
    weights = (1.0 - u - w, u, w)
    n_small = 0
    k_small = 0
    k_big = 0
    for k in range(3):
        if weights[k] < _BARY_EPS:
            n_small += 1
            k_small = k
        if weights[k] > weights[k_big]:
            k_big = k
    rim = False
    if n_small == 0:
        feature = FACE
        nx, ny, nz = face_normals[f, 0], face_normals[f, 1], face_normals[f, 2]
    elif n_small == 1:
        feature = EDGE
        e = face_edge[f, (k_small + 1) % 3]  # the edge opposite corner k is half-edge k + 1
        nx, ny, nz = edge_normals[e, 0], edge_normals[e, 1], edge_normals[e, 2]
        rim = edge_faces[e] == 1
    else:
        feature = VERTEX
        v = faces[f, k_big]
        nx, ny, nz = vertex_normals[v, 0], vertex_normals[v, 1], vertex_normals[v, 2]
        rim = boundary_vertex[v]
    a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
    ox = px - (vertices[a, 0] + u * (vertices[b, 0] - vertices[a, 0]) + w * (vertices[c, 0] - vertices[a, 0]))
    oy = py - (vertices[a, 1] + u * (vertices[b, 1] - vertices[a, 1]) + w * (vertices[c, 1] - vertices[a, 1]))
    oz = pz - (vertices[a, 2] + u * (vertices[b, 2] - vertices[a, 2]) + w * (vertices[c, 2] - vertices[a, 2]))
    length = np.sqrt(d2) if d2 >= 0.0 else np.sqrt(ox * ox + oy * oy + oz * oz)
    # positive along the pseudo-normal, i.e. out of the region above the iso-value
    if ox * nx + oy * ny + oz * nz <= 0.0:
        length = -length
    return length, feature, rim


@njit(cache=True, error_model="numpy")
def _cell_keys(points, origin, cell, low, dims):
    """(N,) int64 flat index of the cell of each point in a block of ``dims`` cells starting at
    cell ``low`` (integer, per axis); ``prod(dims)`` for a point outside the block."""
    n = points.shape[0]
    outside = dims[0] * dims[1] * dims[2]
    keys = np.empty(n, np.int64)
    for i in range(n):
        key = 0
        for k in range(3):
            c = int(np.floor((np.float64(points[i, k]) - origin[k]) / cell)) - low[k]
            if c < 0 or c >= dims[k]:
                key = outside
                break
            key = key * dims[k] + c
        keys[i] = key
    return keys


@njit(cache=True)
def _counting_order(key, n_keys):
    """Stable order of integer ``key`` (N,) in [0, n_keys), by counting."""
    start = np.zeros(n_keys + 1, np.int64)
    for k in key:
        start[k + 1] += 1
    for k in range(n_keys):
        start[k + 1] += start[k]
    order = np.empty(len(key), np.int64)
    for i in range(len(key)):
        order[start[key[i]]] = i
        start[key[i]] += 1
    return order


@njit(cache=True)
def _within_cells(points, order, keys, origin, cell, low, dims, parts):
    """``order`` (points sorted by cell, :func:`_cell_keys`) sorted within each cell by its
    ``parts`` x ``parts`` x ``parts`` sub-cells (x, then y, then z; counting sort)."""
    n = order.shape[0]
    outside = dims[0] * dims[1] * dims[2]
    out = order.copy()
    sub = np.empty(n, np.int64)
    count = np.empty(parts * parts * parts + 1, np.int64)
    j = 0
    while j < n:
        key = keys[order[j]]
        e = j + 1
        while e < n and keys[order[e]] == key:
            e += 1
        if key != outside:
            corner = (key // (dims[1] * dims[2]) + low[0], (key // dims[2]) % dims[1] + low[1], key % dims[2] + low[2])
            count[:] = 0
            for q in range(j, e):
                s = 0
                for k in range(3):
                    c = int((np.float64(points[order[q], k]) - origin[k] - corner[k] * cell) / cell * parts)
                    s = s * parts + min(max(c, 0), parts - 1)
                sub[q] = s
                count[s + 1] += 1
            for c in range(parts * parts * parts):
                count[c + 1] += count[c]
            for q in range(j, e):
                out[j + count[sub[q]]] = order[q]
                count[sub[q]] += 1
        j = e
    return out


def _spatial_order(points: np.ndarray, origin: np.ndarray, cell: float, low: np.ndarray,
                   dims: np.ndarray, parts: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Order visiting ``points`` cell by cell (see :func:`_cell_keys`), within each cell by its
    ``parts``³ sub-cells, and the cell keys.

    A counting sort (linear time) when there are not many more cells than points (a sort of a few
    points, not a pass over a million empty cells, for the small queries of a remesh).
    """
    keys = _cell_keys(points, origin, cell, low, dims)
    n_keys = int(np.prod(dims)) + 1
    order = _counting_order(keys, n_keys) if n_keys <= 4 * len(points) else np.argsort(keys, kind="stable")
    return (_within_cells(points, order, keys, origin, cell, low, dims, parts) if parts > 1 else order), keys


@njit(cache=True)
def _blocks(keys, size):
    """Starts (and end) of the blocks of about ``size`` consecutive points (cell ``keys`` in
    visiting order) that split only between cells, so that each cell's list is built once."""
    n = keys.shape[0]
    starts = [0]
    for j in range(1, n):
        if j - starts[-1] >= size and keys[j] != keys[j - 1]:
            starts.append(j)
    starts.append(n)
    return np.array(starts, np.int64)


@njit(cache=True, error_model="numpy", inline="always")
def _beyond_disk(px, py, pz, tri, t, cut, root):
    """Whether the disk of triangle ``t`` (in its plane, about its centroid, radius to the farthest
    corner: columns 9-15 of ``tri``) proves p farther from it than ``root`` (nm; ``cut`` its square):
    strictly, so that a triangle as near as the best so far (an exact tie) is never passed over."""
    qx, qy, qz = px - tri[t, 9], py - tri[t, 10], pz - tri[t, 11]
    q2 = qx * qx + qy * qy + qz * qz
    rad = tri[t, 12]
    reach = root + rad
    if q2 > reach * reach:
        return True
    h = qx * tri[t, 13] + qy * tri[t, 14] + qz * tri[t, 15]
    h2 = h * h
    if h2 > cut:
        return True
    lateral2 = q2 - h2
    if lateral2 > rad * rad:
        lateral = np.sqrt(lateral2) - rad
        if h2 + lateral * lateral > cut:
            return True
    return False


@njit(cache=True, error_model="numpy", inline="always")
def _before(d, t, best, best_t, tri, face_id):
    """Whether triangle ``t`` (row of ``tri``) at squared distance ``d`` takes the place of the best so far,
    ``best_t`` at ``best``: it is nearer, or exactly as near (a tie: the closest point on a corner or an edge
    the two share) and its centroid is lower (x, then y, then z; the lower mesh face where two centroids are
    equal). The closest face is then the same whatever order the triangles are tried in."""
    if d != best:
        return d < best
    if best_t < 0:
        return True
    for k in range(9, 12):
        if tri[t, k] != tri[best_t, k]:
            return tri[t, k] < tri[best_t, k]
    return face_id[t] < face_id[best_t]


@njit(cache=True, error_model="numpy", inline="always")
def _cut(best, pad):
    """The pruning radius of the best squared distance so far, ``best`` + its rounding ``pad`` (nm), and its
    square: a bound must exceed it to pass over a triangle, so that no tie is lost to rounding."""
    root = np.sqrt(best) + pad
    return root, root * root


@njit(cache=True, error_model="numpy", inline="always")
def _box_gap2(px, py, pz, box, k):
    """Squared distance from p to the box ``box[k]`` (lower and upper corner)."""
    gx = max(box[k, 0] - px, 0.0, px - box[k, 3])
    gy = max(box[k, 1] - py, 0.0, py - box[k, 4])
    gz = max(box[k, 2] - pz, 0.0, pz - box[k, 5])
    return gx * gx + gy * gy + gz * gz


@njit(cache=True, error_model="numpy", inline="always")
def _nearer_in_row(px, py, pz, r, tri, face_id, start, tris, best, best_t, bu, bw, seen, mark, pad):
    """Closest of row ``r``'s triangles to p if before the best so far (``best`` squared nm; :func:`_before`).

    A triangle lies in every row its box meets (2.5 rows on average): ``seen[t] == mark`` says
    it was tried for this point already (mailboxing), and is set for those tried now. Lower
    bounds from the triangle's disk (:func:`_beyond_disk`) reject most triangles.
    """
    root, cut = _cut(best, pad)
    for s in range(start[r], start[r + 1]):
        t = tris[s]
        if seen[t] == mark:
            continue
        seen[t] = mark
        if _beyond_disk(px, py, pz, tri, t, cut, root):
            continue
        d, u, w = _closest_on_triangle(px, py, pz, tri, t)
        if _before(d, t, best, best_t, tri, face_id):
            best, best_t, bu, bw = d, t, u, w
            root, cut = _cut(best, pad)
    return best, best_t, bu, bw


def _run_boxes(triangles: np.ndarray) -> np.ndarray:
    """(ceil(m / _RUN), 6) box (lower, upper corner) of each run of :data:`_RUN` consecutive triangles
    (m, 16) (:attr:`TriangleGrid.triangles`), padded by 1e-7 nm against rounding."""
    corners = triangles[:, :9].reshape(-1, 3, 3)
    runs = -(-len(corners) // _RUN)
    low, high = np.full((runs * _RUN, 3), np.inf), np.full((runs * _RUN, 3), -np.inf)
    low[:len(corners)], high[:len(corners)] = corners.min(axis=1), corners.max(axis=1)
    return np.hstack([low.reshape(runs, _RUN, 3).min(axis=1) - 1e-7, high.reshape(runs, _RUN, 3).max(axis=1) + 1e-7])


@njit(cache=True, error_model="numpy", parallel=True)
def _signed_in_cells(points, keys, blocks, low, dims, m, tri, face_id, origin, cell, shape, slot, start,
                     tris, boxes, run_boxes, offsets, offset_bound, first, covered, limit, pad, vertices, faces,
                     face_normals, face_edge, edge_normals, edge_faces, vertex_normals, boundary_vertex, distance, face,
                     feature, rim, weights, n_workers):
    """Exact signed distances of ``points`` (N, 3) float64 given in visiting order, home by home (homes
    are blocks of m x m x m grid cells, ``keys`` their homes from :func:`_cell_keys` over the homes
    ``low`` + [0, ``dims``)), written to the output arrays in the same order (NaN, face -1 beyond
    ``limit``, squared nm); ``weights`` (N, 3) gets the closest points' barycentric weights unless it
    has no rows. The closest face is the first by :func:`_before` (distance, then centroid), whatever
    the order: every bound passes a triangle over only when it exceeds the best so far by ``pad`` nm
    (the rounding of these coordinates).

    ``n_workers`` workers (one per thread) take every ``n_workers``-th block of ``blocks``, each
    with its own mailbox (8 bytes per triangle). For each home, once: the non-empty grid rows
    reachable within ``limit`` (``offsets`` from the home's first cell, sorted by their lower
    bound ``offset_bound``), sorted by the distance from the home's box to the row's box; ``first``
    (homes tiling the grid) skips the offsets that lead to empty cells only. For each point: the previous point's
    closest triangle seeds an upper bound, the rows are visited in that order until their bound
    is farther than the best triangle so far, each row skipped when the point's own distance
    to its box is farther, its triangles pruned by disk bounds (:func:`_nearer_in_row`).
    ``covered``: squared distance within which the offsets reach every cell; a point whose
    nearest triangle is farther (and within ``limit``) is finished by trying every triangle in
    turn, passing over the runs of :data:`_RUN` triangles whose box (``run_boxes``) and the
    triangles whose disk is farther than the best so far.

    Returns (blocks,) int64: the points of each block whose home lists any row (the narrow
    band: the others cost a few nanoseconds each).
    """
    outside = dims[0] * dims[1] * dims[2]
    searched = np.zeros(blocks.shape[0] - 1, np.int64)

    n_off = offsets.shape[0]
    n_tri = tri.shape[0]
    for worker in prange(n_workers):
        tried = np.full(n_tri, -1, np.int64)  # mailbox: point that last tried each triangle
        gap = np.empty(n_off)
        rows = np.empty(n_off, np.int32)
        for b in range(worker, blocks.shape[0] - 1, n_workers):
            row_gap = np.empty(0)
            row_list = np.empty(0, np.int32)
            key_now = -1
            prev = -1
            for j in range(blocks[b], blocks[b + 1]):
                key = keys[j]
                px, py, pz = points[j, 0], points[j, 1], points[j, 2]
                best, best_t, bu, bw = limit, -1, 0.0, 0.0
                finished = False
                if key != outside:
                    if key != key_now:
                        key_now = key
                        hz = key % dims[2] + low[2]
                        hy = (key // dims[2]) % dims[1] + low[1]
                        hx = key // (dims[1] * dims[2]) + low[0]
                        cx, cy, cz = m * hx, m * hy, m * hz
                        lx, ly, lz = origin[0] + cx * cell, origin[1] + cy * cell, origin[2] + cz * cell
                        size = m * cell
                        k0 = 0
                        fx, fy, fz = (shape[0] + m - 1) // m, (shape[1] + m - 1) // m, (shape[2] + m - 1) // m
                        if 0 <= hx < fx and 0 <= hy < fy and 0 <= hz < fz:
                            k0 = first[(hx * fy + hy) * fz + hz]
                        n_rows = 0
                        for k in range(k0, n_off):
                            if offset_bound[k] >= limit:
                                break
                            ix, iy, iz = cx + offsets[k, 0], cy + offsets[k, 1], cz + offsets[k, 2]
                            if ix < 0 or iy < 0 or iz < 0 or ix >= shape[0] or iy >= shape[1] or iz >= shape[2]:
                                continue
                            r = slot[(ix * shape[1] + iy) * shape[2] + iz]
                            if r < 0:
                                continue
                            gx = max(boxes[r, 0] - lx - size, 0.0, lx - boxes[r, 3])
                            gy = max(boxes[r, 1] - ly - size, 0.0, ly - boxes[r, 4])
                            gz = max(boxes[r, 2] - lz - size, 0.0, lz - boxes[r, 5])
                            g = gx * gx + gy * gy + gz * gz
                            if g < limit:
                                gap[n_rows] = g
                                rows[n_rows] = r
                                n_rows += 1
                        by_gap = np.argsort(gap[:n_rows])
                        row_gap = gap[:n_rows][by_gap]
                        row_list = rows[:n_rows][by_gap]
                    searched[b] += row_list.shape[0] > 0
                    if prev >= 0:
                        tried[prev] = j
                        d, u, w = _closest_on_triangle(px, py, pz, tri, prev)
                        if _before(d, prev, best, best_t, tri, face_id):
                            best, best_t, bu, bw = d, prev, u, w
                    cut = _cut(best, pad)[1]
                    for q in range(row_list.shape[0]):
                        if row_gap[q] > cut:
                            finished = True
                            break
                        r = row_list[q]
                        if _box_gap2(px, py, pz, boxes, r) <= cut:
                            best, best_t, bu, bw = _nearer_in_row(px, py, pz, r, tri, face_id, start, tris, best,
                                                                  best_t, bu, bw, tried, j, pad)
                            cut = _cut(best, pad)[1]
                root, cut = _cut(best, pad)
                if not finished and cut >= covered:
                    # every triangle in turn; those the runs' boxes and the disks prove farther than the best so far
                    # are passed over (the same closest face as measuring all)
                    for c in range(run_boxes.shape[0]):
                        if _box_gap2(px, py, pz, run_boxes, c) > cut:
                            continue
                        for t in range(c * _RUN, min((c + 1) * _RUN, n_tri)):
                            if _beyond_disk(px, py, pz, tri, t, cut, root):
                                continue
                            d, u, w = _closest_on_triangle(px, py, pz, tri, t)
                            if _before(d, t, best, best_t, tri, face_id):
                                best, best_t, bu, bw = d, t, u, w
                                root, cut = _cut(best, pad)
                if best_t < 0:
                    distance[j], face[j], feature[j], rim[j] = np.nan, -1, FACE, False
                    continue
                prev = best_t
                f = face_id[best_t]
                face[j] = f
                if weights.shape[0] > 0:
                    weights[j, 0], weights[j, 1], weights[j, 2] = 1.0 - bu - bw, bu, bw
                distance[j], feature[j], rim[j] = _signed_one(
                    px, py, pz, f, bu, bw, best, vertices, faces, face_normals, face_edge, edge_normals, edge_faces,
                    vertex_normals, boundary_vertex)
    return searched


@dataclass
class TriangleGrid:
    """Triangles bucketed in a uniform grid, for exact closest-triangle queries.

    Attributes
    ----------
    origin : (3,) float64
        Corner of cell (0, 0, 0), nm.
    cell : float
        Cell edge, nm.
    shape : (3,) int64
        Cells along x, y, z.
    slot, start, tris, boxes
        Triangle lists (rows of ``triangles``) of the non-empty cells (see ``_bucket_triangles``).
    run_boxes : (ceil(m / _RUN), 6) float64
        Lower and upper corner of the triangles of each run of :data:`_RUN` consecutive rows of
        ``triangles`` (padded by 1e-7 nm against rounding): a search beyond the rings passes over
        the runs that cannot hold a nearer triangle.
    triangles : (m, 16) float64
        Triangles in cell order: corners (9), then the disk holding the triangle: centroid (3),
        radius (nm, to the farthest corner), unit normal (3, zero if degenerate).
    face_id : (m,) int64
        Mesh face of each row of ``triangles``.

    Notes
    -----
    Memory: 136 bytes per triangle, 4 bytes per (triangle, cell) pair, 56 bytes per non-empty
    cell and 4 bytes per cell of the mesh's bounding box, plus 4 bytes per home block for each
    search plan (:meth:`offsets`; 8 bytes per cell while it is built): 38 MB (+0.3 MB per plan)
    for 230k triangles in a 58 nm box with 0.76 nm cells. While it is built, about 120 bytes per
    triangle more (a 15k-face sphere: 156 bytes per triangle kept, 272 at the peak).
    """

    origin: np.ndarray
    cell: float
    shape: np.ndarray
    slot: np.ndarray
    start: np.ndarray
    tris: np.ndarray
    boxes: np.ndarray
    run_boxes: np.ndarray
    triangles: np.ndarray
    face_id: np.ndarray
    _plans: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, vertices: np.ndarray, faces: np.ndarray, cell: float | None = None,
              max_cells: int = 1 << 23, min_cell: float = 0.0) -> "TriangleGrid":
        """Bucket triangles (m, 3) of ``vertices`` (n, 3) nm into cells of ``cell`` nm.

        The default cell is twice the median edge (a few triangles per cell), at least ``min_cell``;
        it grows until the bounding box holds at most ``max_cells`` cells.
        """
        # Built a corner at a time, straight into the table: (m, 3, 3) corner arrays and their sorted copies were
        # 300 bytes per triangle of temporaries, twice what the grid keeps (the peak of a remesh's check).
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        if cell is None:
            edges = np.empty(faces.shape)
            for k in range(3):
                edges[:, k] = np.linalg.norm(vertices[faces[:, k]] - vertices[faces[:, k - 1]], axis=1)
            cell = max(2.0 * float(np.median(edges)), float(min_cell))
            del edges
        cell = max(float(cell), 1e-6 * float(np.max(hi - lo)), 1e-9)
        while np.prod(np.floor((hi - lo) / cell) + 1) > max_cells:
            cell *= 1.25
        shape = (np.floor((hi - lo) / cell) + 1).astype(np.int64)
        centre = (vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]) / 3
        # triangles stored in cell order, so that those a query visits lie together in memory
        c = np.floor((centre - lo) / cell).astype(np.int64)
        face_id = np.argsort((c[:, 0] * shape[1] + c[:, 1]) * shape[2] + c[:, 2], kind="stable")
        del c
        triangles = np.empty((len(faces), 16))
        for k in range(3):
            triangles[:, 3 * k:3 * k + 3] = vertices[faces[face_id, k]]
        triangles[:, 9:12] = centre[face_id]
        del centre
        a, b, c = triangles[:, 0:3], triangles[:, 3:6], triangles[:, 6:9]
        radius = np.maximum(np.maximum(np.linalg.norm(a - triangles[:, 9:12], axis=1),
                                       np.linalg.norm(b - triangles[:, 9:12], axis=1)),
                            np.linalg.norm(c - triangles[:, 9:12], axis=1))
        # radius padded so that rounding never rejects the triangle holding the closest point
        triangles[:, 12] = radius * (1 + 1e-9) + 1e-9
        normal = np.cross(b - a, c - a)
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        triangles[:, 13:16] = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
        del radius, normal, length
        slot, start, tris, boxes = _bucket_triangles(triangles, lo, cell, shape)
        return cls(lo, cell, shape, slot, start, tris, boxes, _run_boxes(triangles), triangles, face_id)

    def offsets(self, reach: float, m: int = 1) -> tuple[np.ndarray, np.ndarray, int, np.ndarray, float]:
        """Search plan from blocks of m x m x m cells for distances up to ``reach`` nm (cached).

        Returns the cell offsets (k, 3) from a block's first cell to the cells within reach of
        the block, nearest first, their squared lower bounds (k,) nm² for any point of the
        block, the reach in cells r, the first offset that leads from each block to a non-empty
        cell (blocks,) int32 (blocks tile the grid from cell 0), and the squared distance the
        offsets cover.
        """
        key = (float(reach), int(m))
        if key not in self._plans:
            r = int(np.ceil(reach / self.cell)) + 1
            axis = np.arange(-r, r + m)
            o = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
            gap = np.maximum(np.maximum(o - m, -o - 1), 0) * self.cell
            bound = (gap ** 2).sum(axis=1)
            covered = (r * self.cell) ** 2  # an offset outside the cube has a gap >= r cells
            keep = bound < covered
            key_order = np.lexsort(((o[keep] ** 2).sum(axis=1), bound[keep]))
            offsets = o[keep][key_order].astype(np.int64)
            # A listed offset leads less than r + sqrt(3) cells (centre to centre) from some cell
            # of the block; blocks whose cells are all farther than that from any non-empty cell
            # (Euclidean distance transform) need no scan: all their offsets are empty.
            gap = ndimage.distance_transform_edt(self.slot.reshape(tuple(self.shape)) < 0)
            blocks = -(-self.shape // m)
            padded = np.full(blocks * m, np.inf)
            padded[:gap.shape[0], :gap.shape[1], :gap.shape[2]] = gap
            nearest = padded.reshape(blocks[0], m, blocks[1], m, blocks[2], m).min(axis=(1, 3, 5))
            with _threads_for(nearest.size):
                first = _first_occupied(self.shape, self.slot, m, offsets, nearest >= r + np.sqrt(3.0))
            self._plans[key] = (offsets, bound[keep][key_order], r, first, covered)
        return self._plans[key]
