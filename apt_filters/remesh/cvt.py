"""Lloyd iterations towards a feature-aware centroidal Voronoi tessellation of a surface.

Generators are of three kinds: *corners* (pinned on input corners), *curve* generators (on a
feature curve, moving only along it: 1D Lloyd on its arc length) and *patch* generators (free
on one patch, projected back onto it after each centroid step). A sample of patch ``p`` may
only belong to a generator of ``p`` or of a curve or corner bounding ``p``, so Voronoi cells
never straddle a sharp edge and the dual mesh has edges along every feature curve.

Peak memory: the labels of the samples and a few arrays of the number of generators (the
candidate table: 10 int64 per generator and group it may serve).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from apt_filters.remesh._arrays import isin
from apt_filters.core.mesh import TriMesh
from apt_filters.remesh.features import Features
from apt_filters.remesh.sampling import Samples, chunk_length, sample_point

CORNER, CURVE, PATCH = 0, 1, 2
# Patch generators move this many times the way to their centroid (over-relaxed Lloyd). Against
# plain Lloyd (1.0) on the test shapes, 1.7 reached a lower CVT energy (30k torus 1491 against
# 1509), in 15-20 instead of 23-26 steps on the sharp shapes, and raised mean Q by 0.002-0.008;
# 1.4 gained less. The labels still equal a full search.
OVER_RELAXATION = 1.7
_AREA_PER_VERTEX = np.sqrt(3.0) / 2.0  # area per vertex of an equilateral mesh of edge 1


@dataclass
class Generators:
    """Generator positions (n, 3) nm, their kind (CORNER/CURVE/PATCH) and owner (corner/curve/patch id)."""

    positions: np.ndarray
    kind: np.ndarray
    owner: np.ndarray
    arc: np.ndarray  # arc-length parameter of curve generators (nan otherwise)


@dataclass
class LloydResult:
    generators: Generators
    labels: np.ndarray  # (f,) generator of every sample
    energy: list = field(default_factory=list)  # CVT energy per iteration (nm^4)


class _Curve:
    """A polyline feature curve resampled densely for 1D Lloyd steps: arc lengths ``t`` every ``step`` (nm) or
    less, at whose points (``at(t)``) :meth:`weigh` takes the density (asked for all curves at once by
    :func:`initialise`: a KD-tree query per curve was a tenth of the remesh on bumpy surfaces' hundreds of
    noise creases)."""

    def __init__(self, points: np.ndarray, closed: bool, step: float):
        seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        self.points, self.s, self.closed, self.length = points, s, closed, s[-1]
        n = max(int(np.ceil(self.length / step)), 2)
        self.t = np.linspace(0.0, self.length, n + 1)

    def weigh(self, rho: np.ndarray) -> None:
        """The measure and mass tables from the density ``rho`` (len(t),) at ``at(t)``."""
        closed = self.closed
        size = 0.5 * (rho[1:] ** 0.25 + rho[:-1] ** 0.25) * np.diff(self.t)
        self.size = np.concatenate([[0.0], np.cumsum(size)])  # edge-count measure, edges ∝ rho^-1/4
        t, r = self.t, rho
        if closed:  # three periods, so that a cell may reach past either end
            t = np.concatenate([self.t[:-1] - self.length, self.t[:-1], self.t + self.length])
            r = np.concatenate([rho[:-1], rho[:-1], rho])
        mid = 0.5 * (r[1:] + r[:-1]) * np.diff(t)
        self.table_t = t
        self.m0 = np.concatenate([[0.0], np.cumsum(mid)])
        self.m1 = np.concatenate([[0.0], np.cumsum(mid * 0.5 * (t[1:] + t[:-1]))])

    def at(self, t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, self.s, self.points[:, k]) for k in range(3)], axis=1)

    def initial(self, edge: float) -> np.ndarray:
        """Arc positions of the free generators, evenly spaced in the density's edge measure."""
        # a loop, or a curve from a corner back to it, needs two generators besides the corner to stay a ring
        ring = self.closed or np.array_equal(self.points[0], self.points[-1])
        n = max(int(round(self.size[-1] / edge)), 3 if ring else 1)
        u = np.linspace(0.0, self.size[-1], n + 1)
        t = np.interp(u, self.size, self.t)
        return t[:-1] if self.closed else t[1:-1]


class _CurveSteps:
    """The tables of all ``curves`` (:class:`_Curve`) packed end to end (CSR), with the generators of each
    (``ids``: (n_curves,) lists of generator ids), for :func:`_curve_steps`: one compiled pass over every
    curve per Lloyd step (a 1D step per curve in Python was a third of Lloyd's time on the pipeline's
    refined cubes, with about 80 curves)."""

    def __init__(self, curves: list, ids: list):
        def packed(arrays, dtype=np.float64, shape=(0,)):
            ptr = np.r_[0, np.cumsum([len(a) for a in arrays])].astype(np.int64)
            return ptr, (np.concatenate(arrays).astype(dtype) if arrays else np.empty(shape, dtype))

        self.gen_ptr, self.gen_ids = packed(ids, np.int64)
        self.point_ptr, self.s = packed([c.s for c in curves])
        self.points = np.concatenate([c.points for c in curves]) if curves else np.empty((0, 3))
        self.table_ptr, self.table_t = packed([c.table_t for c in curves])
        self.m0 = packed([c.m0 for c in curves])[1]
        self.m1 = packed([c.m1 for c in curves])[1]
        self.length = np.array([c.length for c in curves], np.float64)
        self.closed = np.array([c.closed for c in curves], np.bool_)

    def step(self, arc: np.ndarray, positions: np.ndarray) -> None:
        """One 1D Lloyd step of every curve's generators: ``arc`` (n,) and ``positions`` (n, 3) updated in place."""
        _curve_steps(arc, positions, self.gen_ptr, self.gen_ids, self.point_ptr, self.s, self.points,
                     self.table_ptr, self.table_t, self.m0, self.m1, self.length, self.closed)


@njit(cache=True)
def _curve_steps(arc, positions, gen_ptr, gen_ids, point_ptr, s, points, table_ptr, table_t, m0, m1, length, closed):
    """A 1D Lloyd step on arc length along every curve c: its generators ``gen_ids[gen_ptr[c]:gen_ptr[c + 1]]``
    move to the centroid of their arc cells (between midpoints to the neighbours; open curve ends are fixed
    corners, a loop's cells wrap) under the density's mass tables ``m0``, ``m1`` (cumulative ∫ρ dt, ∫ρt dt at
    ``table_t``), then to their point on the polyline (``points`` at arc lengths ``s``)."""
    # Element loops instead of fancy indexing and np.where: the same arithmetic, without numba's advanced
    # indexing, which made this the costliest compile of a fresh install's pipeline (alone, cold: 9.7 -> 6.2 s CPU).
    for c in range(len(length)):
        g0, n = gen_ptr[c], gen_ptr[c + 1] - gen_ptr[c]
        if n == 0:
            continue
        unsorted = np.empty(n)
        for j in range(n):
            unsorted[j] = arc[gen_ids[g0 + j]]
        rank = np.argsort(unsorted)
        order = np.empty(n, np.int64)
        ext = np.empty(n + 2)
        for j in range(n):
            order[j] = gen_ids[g0 + rank[j]]
            ext[j + 1] = unsorted[rank[j]]
        if closed[c]:
            ext[0], ext[n + 1] = ext[n] - length[c], ext[1] + length[c]
        else:
            ext[0], ext[n + 1] = 0.0, length[c]
        lo, hi = 0.5 * (ext[:-2] + ext[1:-1]), 0.5 * (ext[1:-1] + ext[2:])
        t = table_t[table_ptr[c]:table_ptr[c + 1]]
        q0, q1 = m0[table_ptr[c]:table_ptr[c + 1]], m1[table_ptr[c]:table_ptr[c + 1]]
        mass = np.interp(hi, t, q0) - np.interp(lo, t, q0)
        new = np.interp(hi, t, q1) - np.interp(lo, t, q1)
        for j in range(n):
            new[j] = new[j] / max(mass[j], 1e-300) if mass[j] > 0 else ext[j + 1]
        if closed[c]:
            new = np.mod(new, length[c])
        for j in range(n):
            arc[order[j]] = new[j]
        ss, p = s[point_ptr[c]:point_ptr[c + 1]], points[point_ptr[c]:point_ptr[c + 1]]
        for k in range(3):
            at = np.interp(new, ss, np.ascontiguousarray(p[:, k]))
            for j in range(n):
                positions[order[j], k] = at[j]


class PatchSurfaces:
    """Closest points of ``mesh`` restricted to one patch per point.

    One closest-point engine (:class:`apt_filters.core.distance.SurfaceDistance`) over the whole
    mesh answers most queries exactly: when a point's closest face lies on the patch asked for,
    it is also the closest face of that patch. Only the other points (near a crease, or in a
    pocket where another patch is closer) ask an engine of their patch alone, built when first
    needed. (An engine per patch, built up front, was a tenth of the remesh's time and memory on
    bumpy surfaces, which have hundreds of small patches.)

    ``patch`` (f,) is the patch of every face of ``mesh``.
    """

    def __init__(self, mesh: TriMesh, patch: np.ndarray):
        from apt_filters.core.distance import SurfaceDistance
        from apt_filters.remesh.walk import face_neighbours

        self.mesh, self.patch, self.whole = mesh, patch, SurfaceDistance(mesh)
        self._order = np.argsort(patch, kind="stable")
        self._bounds = np.searchsorted(patch[self._order], np.arange(int(patch.max(initial=-1)) + 2))
        self._own: dict = {}
        self._faces = np.ascontiguousarray(mesh.faces, np.int64)
        self._vertices = np.ascontiguousarray(mesh.vertices, np.float64)
        neighbour = face_neighbours(self._faces, mesh.n_vertices)
        neighbour[(neighbour >= 0) & (patch[neighbour] != patch[:, None])] = -1  # walks stay on their patch
        self._neighbour = neighbour
        self._one = np.arange(mesh.n_faces + 1)

    def closest(self, points: np.ndarray, patches: np.ndarray, near: float | None = None,
                hint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) closest point on patch ``patches[i]`` (n,) to each of ``points`` (n, 3) nm, and (n,) its
        face; ``near`` (nm): how far most points are expected to be (the search's first reach).
        ``hint`` (n,): a face of that patch near each point (-1: none), from which the closest face is
        found by walking (:func:`apt_filters.remesh.walk.walk_closest`) instead of searched for: for
        points that moved a fraction of an edge since their face was found."""
        from apt_filters.remesh.walk import walk_closest

        out = np.empty((len(points), 3))
        face = np.full(len(points), -1, np.int64)
        if hint is not None:
            walk = np.flatnonzero(hint >= 0)
            walk = walk[self.patch[hint[walk]] == patches[walk]]
            face[walk], _, out[walk] = walk_closest(self._vertices, self._faces, self._neighbour, self._one, self._one,
                                                    hint[walk], np.ascontiguousarray(points[walk], np.float64))
        search = np.flatnonzero(face < 0)
        step = chunk_length(self.mesh.n_faces)  # the engines' temporaries, a chunk of points at a time
        for start in range(0, len(search), step):
            block = search[start:start + step]
            out[block], face[block], _ = self.whole.closest(points[block], near)
            wrong = block[self.patch[face[block]] != patches[block]]
            for p in np.unique(patches[wrong]).tolist():
                sel = wrong[patches[wrong] == p]
                out[sel], local, _ = self._of(p).closest(points[sel], near)
                face[sel] = self._order[self._bounds[p] + local]
        return out, face

    def _of(self, p: int):
        if p not in self._own:
            from apt_filters.core.distance import SurfaceDistance

            faces = self.mesh.faces[self._order[self._bounds[p]:self._bounds[p + 1]]]
            used, local = np.unique(faces, return_inverse=True)
            self._own[p] = SurfaceDistance(TriMesh(self.mesh.vertices[used], local.reshape(-1, 3)))
        return self._own[p]


def _initial_patch_points(samples: Samples, faces: np.ndarray, count: int, seed: int) -> np.ndarray:
    """``count`` evenly spread points among the samples of the input ``faces`` (a patch's): voxel down-sampling,
    then a random subset."""
    if count <= 0:
        return np.empty((0, 3))
    rng = np.random.default_rng(seed)
    size = np.sqrt(samples.face_area[faces].sum() / count)
    lat = samples.lattice
    args = (lat.vertices, lat.faces, lat.centroid, np.asarray(faces, np.int64))
    origin = _samples_min(*args)
    for _ in range(6):
        down = _voxel_means(args, origin, size, max(samples.chunk // samples.per_face, 1))
        if len(down) >= count:
            break
        size *= 0.8 * np.sqrt(max(len(down), 1) / count)
    if len(down) < count:  # a patch too small to hold them apart: take samples at random
        down = samples.points(samples.of_faces(faces))
    chosen = down[rng.choice(len(down), size=count, replace=False)]
    return chosen[_spatial_order(chosen, size)]


@njit(nogil=True, cache=True)
def _samples_min(vertices, faces, centroid, mine):
    """(3,) smallest coordinates (nm) of the samples of input faces ``mine`` (made face by face, as in
    :func:`_lloyd_pass`)."""
    low, point = np.full(3, np.inf), np.empty(3)
    per_face = len(centroid)
    for f in mine:
        for j in range(per_face):
            sample_point(vertices, faces, centroid, f * per_face + j, point)
            for k in range(3):
                low[k] = min(low[k], point[k])
    return low


def _voxel_means(args: tuple, origin: np.ndarray, size: float, step: int) -> np.ndarray:
    """Mean (nm) of the samples of input faces ``args[3]`` in each occupied cube of side ``size`` (nm) counted
    from ``origin`` (3,), no sample below it (voxel down-sampling), in lexicographic order of the cubes: one
    compiled pass over the samples, made face by face, with only the cubes held (about as many as generators).
    Sums are taken per ``step`` input faces, then over those, in their order: the sums (and means) of the numpy
    form this replaced, which materialised the samples a chunk at a time, bit for bit (a numpy pass per chunk of
    a few hundred samples was a tenth of the remesh's CPU on the 2 nm spheres)."""
    cells, total, count = _cube_sums(*args, origin, size, step)
    order = np.lexsort(cells.T[::-1])
    return total[order] / count[order, None]


@njit(nogil=True, cache=True)
def _cube_sums(vertices, faces, centroid, mine, origin, size, step):
    """Occupied cubes (k, 3) int64 (first-seen order), the sums (k, 3) of their samples' coordinates and their
    sample counts (k,) float64, for :func:`_voxel_means`: each cube's sum is taken per ``step`` input faces,
    starting at 0 and in sample order, then the parts are added in their order (what ``np.bincount`` over each
    chunk and then over the chunks' sums gave)."""
    slot = np.full(64, -1, np.int64)  # open-addressing hash table: cube -> its row, -1 free
    n = 0
    cells, total, part = np.empty((16, 3), np.int64), np.empty((16, 3)), np.empty((16, 3))
    count, stamp = np.empty(16), np.empty(16, np.int64)  # stamp: the last part that touched the cube
    touched = np.empty(16, np.int64)  # the cubes the present part touched
    per_face = len(centroid)
    point = np.empty(3)
    c = -1
    for start in range(0, len(mine), step):
        n_touched = 0
        for f in mine[start:start + step]:
            for j in range(per_face):
                sample_point(vertices, faces, centroid, f * per_face + j, point)
                x = np.int64(np.floor((point[0] - origin[0]) / size))
                y = np.int64(np.floor((point[1] - origin[1]) / size))
                z = np.int64(np.floor((point[2] - origin[2]) / size))
                # neighbouring samples mostly share a cube: the last one's first, then the table
                if c < 0 or cells[c, 0] != x or cells[c, 1] != y or cells[c, 2] != z:
                    c = _cube_row(x, y, z, slot, cells, n)
                    if c == n:  # a new cube
                        if n == len(cells):  # grown by doubling
                            cells, total, part = _doubled(cells), _doubled(total), _doubled(part)
                            count, stamp = _doubled(count), _doubled(stamp)
                        cells[c, 0], cells[c, 1], cells[c, 2] = x, y, z
                        total[c], part[c], count[c], stamp[c] = 0.0, 0.0, 0.0, -1
                        n += 1
                        if 2 * n > len(slot):  # at most half full: short probes
                            slot = _rehashed(cells, n, 2 * len(slot))
                if stamp[c] != start:
                    stamp[c] = start
                    if n_touched == len(touched):
                        touched = _doubled(touched)
                    touched[n_touched] = c
                    n_touched += 1
                for k in range(3):
                    part[c, k] += point[k]
                count[c] += 1.0
        for i in range(n_touched):
            c2 = touched[i]
            for k in range(3):
                total[c2, k] += part[c2, k]
                part[c2, k] = 0.0
    return cells[:n].copy(), total[:n].copy(), count[:n].copy()


@njit(nogil=True, cache=True, inline="always")
def _cube_row(x, y, z, slot, cells, n):
    """Row of cube (x, y, z) among the ``n`` rows of ``cells`` (k, 3), found in the open-addressing hash table
    ``slot`` (a power of two of rows, -1 free), or ``n`` where it is new (then entered in the table as row
    ``n``)."""
    mask = len(slot) - 1
    # Fibonacci hashing of the cube's coordinates: the top bits of the product, spread even for cubes on a plane
    h = np.int64(((np.uint64(x) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(y)) * np.uint64(0x9E3779B97F4A7C15)
                  + np.uint64(z)) * np.uint64(0x9E3779B97F4A7C15) >> np.uint64(32)) & mask
    while slot[h] >= 0:
        r = slot[h]
        if cells[r, 0] == x and cells[r, 1] == y and cells[r, 2] == z:
            return r
        h = (h + 1) & mask
    slot[h] = n
    return n


@njit(nogil=True, cache=True)
def _rehashed(cells, n, size):
    """A hash table of ``size`` (a power of two) slots holding the first ``n`` rows of ``cells``
    (:func:`_cube_row`'s)."""
    slot = np.full(size, -1, np.int64)
    for r in range(n):
        _cube_row(cells[r, 0], cells[r, 1], cells[r, 2], slot, cells, r)
    return slot


@njit(nogil=True, cache=True)
def _doubled(a):
    """``a`` in an array twice as long (along its first axis), the rest uninitialised."""
    out = np.empty((2 * len(a),) + a.shape[1:], a.dtype)
    out[:len(a)] = a
    return out


def _spatial_order(points: np.ndarray, cell: float) -> np.ndarray:
    """Order of ``points`` (n, 3) along a Z-order curve of cells of size ``cell``: neighbours end up
    near each other in memory, which the compiled passes over generators and samples need (in
    random order the candidate refresh of 160k generators took twice as long)."""
    if len(points) == 0:
        return np.arange(0)
    q = np.floor((points - points.min(axis=0)) / cell).astype(np.int64)
    q = np.minimum(q, (1 << 20) - 1)
    key = np.zeros(len(points), np.int64)
    for bit in range(20):
        for axis in range(3):
            key |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.argsort(key, kind="stable")


def initialise(mesh: TriMesh, features: Features, samples: Samples, edge: float, density: np.ndarray,
               vertex_density, seed: int = 0) -> tuple[Generators, list]:
    """Place generators: corners, evenly spaced curve generators, evenly spread patch generators.

    ``density`` (m,) is the density ρ ≥ 1 on each input face; edges scale as ρ^-1/4, so a patch gets
    ∫ρ^1/2 dA / (√3/2 L²) vertices, less the strip that its curve generators' cells take.
    """
    pos, kind, owner, arc = [mesh.vertices[features.corners]], [np.full(len(features.corners), CORNER)], \
        [np.arange(len(features.corners))], [np.full(len(features.corners), np.nan)]
    border = np.zeros(features.n_patches)
    curves = [_Curve(mesh.vertices[c], is_loop(c, features.corners), edge / 8) for c in features.curves]
    if curves:
        rho = vertex_density(np.vstack([curve.at(curve.t) for curve in curves]))
        for curve, r in zip(curves, np.split(rho, np.cumsum([len(curve.t) for curve in curves])[:-1])):
            curve.weigh(r)
    for i, curve in enumerate(curves):
        t = curve.initial(edge)
        pos.append(curve.at(t))
        kind.append(np.full(len(t), CURVE))
        owner.append(np.full(len(t), i))
        arc.append(t)
        border[features.curve_patches[i]] += curve.size[-1]
    order = np.argsort(features.patch, kind="stable")
    bounds = np.searchsorted(features.patch[order], np.arange(features.n_patches + 1))
    for p in range(features.n_patches):
        mine = order[bounds[p]:bounds[p + 1]]
        measure = (samples.face_area[mine] * np.sqrt(density[mine])).sum()
        free = (measure - 0.5 * _AREA_PER_VERTEX * edge * border[p]) / (_AREA_PER_VERTEX * edge**2)
        count = int(round(free)) if border[p] > 0 else max(int(round(free)), 4)
        count = min(max(count, 0), len(mine) * samples.per_face)
        pts = _initial_patch_points(samples, mine, count, seed + p)
        pos.append(pts)
        kind.append(np.full(len(pts), PATCH))
        owner.append(np.full(len(pts), p))
        arc.append(np.full(len(pts), np.nan))
    gens = Generators(np.vstack(pos), np.concatenate(kind), np.concatenate(owner), np.concatenate(arc))
    return gens, curves


def is_loop(curve: np.ndarray, corners: np.ndarray) -> bool:
    """Whether a feature curve (input vertex ids) is a closed loop: back at its start, which is no corner. A
    curve from a corner back to it is open, its two ends that corner: as a loop, its first generator sat on
    the corner itself (two output vertices at one point, faces without area)."""
    return bool(len(curve) > 2 and curve[0] == curve[-1] and not isin(curve[:1], corners)[0])


def allowed(features: Features, gens: Generators) -> list[np.ndarray]:
    """Generators that each sample group may belong to.

    Group ``p`` holds the samples of patch ``p``: its own generators and those of the curves
    and corners around it. Group ``n_patches + p`` holds the samples of ``p`` that touch a
    feature curve: only curve and corner generators, so that consecutive generators on a curve
    always have adjacent cells and the curve becomes a chain of mesh edges.
    """
    n = features.n_patches
    rim = [[] for _ in range(n)]
    for g_kind, lists in ((CORNER, features.corner_patches), (CURVE, features.curve_patches)):
        for i, patches in enumerate(lists):
            ids = np.flatnonzero((gens.kind == g_kind) & (gens.owner == i))
            for p in patches:
                rim[p].append(ids)
    rim = [np.concatenate(r) if r else np.empty(0, np.int64) for r in rim]
    full = [np.concatenate([rim[p], np.flatnonzero((gens.kind == PATCH) & (gens.owner == p))]) for p in range(n)]
    return full + [r if len(r) else f for r, f in zip(rim, full)]


def sample_groups(mesh: TriMesh, samples: Samples, features: Features) -> np.ndarray:
    """(f,) int32 group of each sample for :func:`allowed`: its patch, plus ``n_patches`` where its
    refined face touches a feature curve or the open boundary (a refined vertex on an input vertex
    or edge between two patches, on a crease kept inside a patch, or on the rim)."""
    top = mesh.topology
    lo = np.full(mesh.n_vertices, np.iinfo(np.int64).max)
    hi = np.full(mesh.n_vertices, -1)
    np.minimum.at(lo, mesh.faces.ravel(), np.repeat(features.patch, 3))
    np.maximum.at(hi, mesh.faces.ravel(), np.repeat(features.patch, 3))
    on_curve = (lo != hi) | top.boundary_vertex
    on_curve[top.edge_vertices[features.edge].ravel()] = True  # creases kept inside a patch too
    flag = samples.vertex_flags(on_curve, features.edge)
    return samples.groups(flag, features.patch, features.n_patches)


# Up to this many reference points, _knn compares every pair in a compiled loop instead of building a
# KD-tree: bumpy surfaces have hundreds of small patches, and a tree per patch's group cost more in calls
# than in search (the same neighbours, nearest first).
_BRUTE_KNN = 32


def _knn(reference: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    """(q, k) indices of the k nearest reference points, nearest first (scipy KD-tree; open3d's gave the same
    indices at the same speed; up to ``_BRUTE_KNN`` reference points every pair compared)."""
    if len(reference) <= _BRUTE_KNN:
        return _brute_knn(np.ascontiguousarray(reference, np.float64), np.ascontiguousarray(queries, np.float64), k)
    from scipy.spatial import cKDTree

    return cKDTree(reference).query(queries, k)[1].astype(np.int64).reshape(len(queries), k)


@njit(cache=True)
def _brute_knn(reference, queries, k):
    """:func:`_knn` by comparing every pair: (q, k) int64, the lower index first among equal distances."""
    out = np.empty((len(queries), k), np.int64)
    best = np.empty(k)
    for i in range(len(queries)):
        n = 0
        for j in range(len(reference)):
            d = (queries[i, 0] - reference[j, 0]) ** 2 + (queries[i, 1] - reference[j, 1]) ** 2 \
                + (queries[i, 2] - reference[j, 2]) ** 2
            n = _keep_nearest(best, out[i], n, d, j)
    return out


@njit(nogil=True, cache=True)
def _keep_nearest(best, ids, n, d, h):
    """Candidate ``h`` at squared distance ``d`` inserted into the ``n`` nearest so far (``best`` (k,) ascending,
    ``ids`` (k,) theirs; a later candidate at an equal distance goes after): the new count, at most k."""
    k = len(best)
    if n == k and d >= best[k - 1]:
        return n
    pos = min(n, k - 1)
    while pos > 0 and best[pos - 1] > d:
        best[pos] = best[pos - 1]
        ids[pos] = ids[pos - 1]
        pos -= 1
    best[pos] = d
    ids[pos] = h
    return min(n + 1, k)


class _Candidates:
    """Where each sample may look for its nearest generator, given its previous one.

    Samples of group ``g`` whose generator was ``c`` look at the ``k`` generators of
    ``allowed[g]`` nearest to ``c``. A generator may be allowed in several groups (curve and
    corner generators border two or more patches), so its rows are found through a small CSR
    table (``slot_*``: for each generator, its groups and its row in the table).
    """

    def __init__(self, allowed: list, n_generators: int, k: int):
        self.allowed, self.k = allowed, k
        sizes = np.array([len(ids) for ids in allowed])
        self.offset = np.r_[0, np.cumsum(sizes)]
        self.row_generator = np.concatenate(allowed) if len(allowed) else np.empty(0, np.int64)
        self.row_group = np.repeat(np.arange(len(allowed)), sizes)
        order = np.argsort(self.row_generator, kind="stable")
        self.slot_group, self.slot_row = self.row_group[order], order
        self.slot_ptr = np.r_[0, np.cumsum(np.bincount(self.row_generator, minlength=n_generators))]
        self._table, self._built, self._spacing = None, None, 0.0

    def table(self, positions: np.ndarray) -> np.ndarray:
        """(rows, k) global generator ids, -1 padded: the k nearest allowed generators of each slot.

        Built once with KD-trees (one per distinct allowed list). Afterwards, once some
        generator has moved more than a quarter of the generator spacing since the last update,
        each row is refreshed from its old row and its old neighbours' rows
        (:func:`_refresh_table`): the new k nearest are among the old 2-ring. (A KD-tree over
        160k generators costs about a second; rebuilt every step it was a third of the Lloyd
        time of a 200k-face input.) On the test shapes and the 30k torus the final labels
        equal a full search.
        """
        if self._table is not None:
            if np.sqrt(((positions - self._built) ** 2).sum(axis=1).max()) > 0.25 * self._spacing:
                self._table = _refresh_table(self._table, self.row_generator, self.row_group, self.slot_ptr,
                                             self.slot_group, self.slot_row, positions)
                self._built = positions.copy()
            return self._table
        out = np.full((self.offset[-1], self.k), -1, np.int64)
        done = {}
        for g, ids in enumerate(self.allowed):
            if len(ids) == 0:
                continue
            if id(ids) not in done:  # a patch without curves shares its list between its two groups
                kk = min(self.k, len(ids))
                done[id(ids)] = ids[_knn(positions[ids], positions[ids], kk)]
            rows = done[id(ids)]
            out[self.offset[g]:self.offset[g + 1], :rows.shape[1]] = rows
        near = out[:, 1] >= 0
        self._spacing = float(np.median(np.linalg.norm(positions[out[near, 1]] - positions[out[near, 0]], axis=1))) \
            if near.any() else 0.0
        self._table, self._built = out, positions.copy()
        return out


@njit(nogil=True, cache=True)
def _row_of(c, group, slot_ptr, slot_group, slot_row):
    for s in range(slot_ptr[c], slot_ptr[c + 1]):
        if slot_group[s] == group:
            return slot_row[s]
    return -1


@njit(nogil=True, cache=True)
def _refresh_table(table, row_generator, row_group, slot_ptr, slot_group, slot_row, positions):
    """New k nearest of every row's generator among its old neighbours and their old neighbours (same group)."""
    rows, k = table.shape
    out = np.full((rows, k), -1, np.int64)
    stamp = np.full(len(positions), -1, np.int64)
    best_d = np.empty(k)
    for r in range(rows):
        c = row_generator[r]
        n_best = 0
        for j in range(-1, k):
            g = c if j < 0 else table[r, j]
            if g < 0:
                break
            rg = _row_of(g, row_group[r], slot_ptr, slot_group, slot_row)
            for i in range(-1, k):
                h = g if i < 0 else table[rg, i]
                if h < 0:
                    break
                if stamp[h] == r:
                    continue
                stamp[h] = r
                d = (positions[h, 0] - positions[c, 0]) ** 2 + (positions[h, 1] - positions[c, 1]) ** 2 \
                    + (positions[h, 2] - positions[c, 2]) ** 2
                n_best = _keep_nearest(best_d, out[r], n_best, d, h)
    return out


@njit(nogil=True, cache=True)
def _lloyd_pass(lattice, face_weight, group, labels, positions, slot_ptr, slot_group, slot_row, table):
    """Nearest candidate generator of every sample, and the cells' weighted mass, first moments and energy.

    One pass over the samples (made face by face from ``lattice``, :meth:`Lattice.args`; weight
    ``face_weight`` of their input face) with no temporaries of their size: ``labels`` (f,) int32,
    each sample's previous generator, become the new ones in place; returns mass (n,), moments (n, 3)
    and energy (sum of w·d²).
    """
    n = len(positions)
    vertices, faces, centroid = lattice[0], lattice[1], lattice[6]
    mass = np.zeros(n)
    moment = np.zeros((n, 3))
    energy = 0.0
    point = np.empty(3)
    last_c, last_g, row = -1, -1, -1
    for i in range(len(labels)):
        sample_point(vertices, faces, centroid, i, point)
        c = labels[i]
        # a sample's row (its previous generator's, in its group) looked up once a run: an input face's samples
        # mostly share both (looked up for every sample, the search was a third of this pass's CPU)
        if c != last_c or group[i] != last_g:
            last_c, last_g = c, group[i]
            row = _row_of(c, last_g, slot_ptr, slot_group, slot_row)
        best, arg = np.inf, c
        for j in range(table.shape[1]):
            g = table[row, j]
            if g < 0:
                break
            d = (point[0] - positions[g, 0]) ** 2 + (point[1] - positions[g, 1]) ** 2 \
                + (point[2] - positions[g, 2]) ** 2
            if d < best:
                best, arg = d, g
        labels[i] = arg
        w = face_weight[i // len(centroid)]
        mass[arg] += w
        moment[arg, 0] += w * point[0]
        moment[arg, 1] += w * point[1]
        moment[arg, 2] += w * point[2]
        energy += w * best
    return mass, moment, energy


def assign(points: np.ndarray, group: np.ndarray, positions: np.ndarray, allowed: list) -> np.ndarray:
    """Nearest allowed generator of every sample point, per group (KD-tree of each group's generators)."""
    labels = np.full(len(points), -1)
    order = np.argsort(group, kind="stable")
    bounds = np.searchsorted(group[order], np.arange(len(allowed) + 1))
    for g, ids in enumerate(allowed):
        sel = order[bounds[g]:bounds[g + 1]]
        if len(sel) and len(ids):
            labels[sel] = ids[_knn(positions[ids], points[sel], 1)[:, 0]]
    return labels


@njit(cache=True)
def _run_starts(group, per_face):
    """(r,) int64 first sample of every run of samples of one input face (``per_face`` consecutive
    samples) and one group."""
    count = 0
    for i in range(len(group)):
        if i % per_face == 0 or group[i] != group[i - 1]:
            count += 1
    starts = np.empty(count, np.int64)
    count = 0
    for i in range(len(group)):
        if i % per_face == 0 or group[i] != group[i - 1]:
            starts[count] = i
            count += 1
    return starts


@njit(cache=True)
def _spread(starts, label, n):
    """(n,) int32: ``label[r]`` over the run of samples from ``starts[r]`` to the next start."""
    out = np.empty(n, np.int32)
    for r in range(len(starts)):
        out[starts[r]:starts[r + 1] if r + 1 < len(starts) else n] = label[r]
    return out


def _first_labels(samples: Samples, group: np.ndarray, positions: np.ndarray, allowed: list) -> np.ndarray:
    """A nearby allowed generator for every sample: the nearest one of the first sample of each run of
    samples with the same input face and group (refined faces are stored by input face), so the
    KD-tree answers one query per input face instead of one per sample; (f,) int32 and arrays of
    the runs' size only."""
    starts = _run_starts(group, samples.per_face)
    return _spread(starts, assign(samples.points(starts), group[starts], positions, allowed), len(group))


def lloyd(mesh: TriMesh, features: Features, samples: Samples, group: np.ndarray, gens: Generators,
          curves: list, density: np.ndarray, max_iter: int = 30, tol: float = 1e-4, k: int = 10,
          project_every: int = 3, near: float | None = None,
          surfaces: PatchSurfaces | None = None) -> LloydResult:
    """Lloyd iterations until the relative energy change is below ``tol`` or ``max_iter`` steps.

    Each step assigns every sample to the nearest of ``k`` candidates: the allowed generators
    nearest its previous generator (the new nearest generator is a Voronoi neighbour of the old
    one, since generators move little), and sums the cells' masses and moments in the same
    compiled pass. The first step starts from the nearest generator of one sample per input
    face (:func:`_first_labels`). On the test shapes and the 30k and 200k tori the final labels
    were identical to a full KD-tree search (previously every 5th step searched all generators
    for every sample). Patch generators move :data:`OVER_RELAXATION` times the way to their
    centroid and are projected back onto their patch every ``project_every`` steps (centroids
    sit off a curved surface by about L²/8R) and at the end; the returned labels belong to the
    returned positions. ``near`` (nm, about the edge length): how far a moved generator is
    expected to be from its patch (the projection's search reach; farther ones are found too).
    ``surfaces``: closest points on the patches (:class:`PatchSurfaces`), built here if not given.
    """
    surfaces = PatchSurfaces(mesh, features.patch) if surfaces is None else surfaces
    permitted = allowed(features, gens)
    candidates = _Candidates(permitted, len(gens.positions), k)
    w = samples.face_area * density / samples.per_face
    energy: list = []
    free = np.flatnonzero(gens.kind == PATCH)
    curve_steps = _CurveSteps(curves, [np.flatnonzero((gens.kind == CURVE) & (gens.owner == i))
                                       for i in range(len(curves))])
    labels = _first_labels(samples, group, gens.positions, permitted)

    hint = np.full(len(free), -1, np.int64)  # each free generator's face at the last projection, walked from

    def project():
        gens.positions[free], hint[:] = surfaces.closest(gens.positions[free], gens.owner[free], near, hint)

    on_surface = True
    for it in range(max_iter + 1):
        mass, moment, e = _lloyd_pass(samples.lattice.args(), w, group, labels, gens.positions, candidates.slot_ptr,
                                      candidates.slot_group, candidates.slot_row, candidates.table(gens.positions))
        energy.append(float(e))
        if it == max_iter or (it > 0 and abs(energy[-2] - energy[-1]) <= tol * energy[-1]):
            break
        has = mass > 0
        moved = np.flatnonzero(has & (gens.kind == PATCH))
        gens.positions[moved] += OVER_RELAXATION * (moment[moved] / mass[moved, None] - gens.positions[moved])
        on_surface = (it + 1) % project_every == 0
        if on_surface:
            project()
        curve_steps.step(gens.arc, gens.positions)
    if not on_surface:  # the last centroids were not projected: project, then label once more
        project()
        _lloyd_pass(samples.lattice.args(), w, group, labels, gens.positions, candidates.slot_ptr,
                    candidates.slot_group, candidates.slot_row, candidates.table(gens.positions))
    return LloydResult(gens, labels, energy)


def connect_cells(samples: Samples, labels: np.ndarray, group: np.ndarray, gens: Generators, n_patches: int,
                  cells: np.ndarray, dissolve: np.ndarray) -> np.ndarray:
    """Labels with the restricted Voronoi cells ``cells`` ((n,) bool over generators) made connected.

    A cell can reach across a fold or a thin neck of a bumpy surface in Euclidean distance and
    come out in pieces; its dual is then a vertex with several fans, or a hole. Each of those
    cells keeps its heaviest piece; the other pieces join the neighbouring cells they touch,
    ring by ring, as long as :func:`allowed` lets them (same patch; beside a curve, only curve
    and corner cells). Cells in ``dissolve`` ((n,) bool, a subset of ``cells``) give away all
    their pieces: their generators drop out of the mesh.

    ``samples`` is the refined mesh, ``labels`` (f,) the generator of each refined face,
    ``group`` (f,) their sample groups. Only the faces of ``cells`` and their neighbours are looked at.
    """
    from scipy import sparse
    from scipy.sparse.csgraph import connected_components

    from apt_filters.core.mesh import topology

    near = np.zeros(samples.n_vertices, bool)
    near[samples.corners(np.flatnonzero(cells[labels]))] = True
    sub = samples.touching(near)
    a, b = topology(samples.corners(sub), len(near)).face_pairs.T  # local ids: faces sub[a], sub[b] share an edge
    local = labels[sub]
    n = len(sub)
    same = local[a] == local[b]
    _, piece = connected_components(sparse.coo_matrix((np.ones(same.sum()), (a[same], b[same])), shape=(n, n)),
                                    directed=False)
    piece_label = np.empty(piece.max() + 1, np.int64)
    piece_label[piece] = local
    heaviest = np.lexsort((-np.bincount(piece, samples.weights(sub)), piece_label))
    first = np.r_[True, piece_label[heaviest][1:] != piece_label[heaviest][:-1]]
    orphan = (~isin(piece, heaviest[first]) & cells[local]) | dissolve[local]
    touch = orphan[a] | orphan[b]
    x, y = np.r_[a[touch], b[touch]], np.r_[b[touch], a[touch]]
    g = group[sub]
    while orphan.any():
        take = orphan[x] & ~orphan[y] & (g[x] % n_patches == g[y] % n_patches) \
            & ((g[x] < n_patches) | (gens.kind[local[y]] != PATCH))
        if not take.any():
            break
        local[x[take]] = local[y[take]]
        orphan[x[take]] = False
    labels = labels.copy()
    labels[sub] = local
    return labels
