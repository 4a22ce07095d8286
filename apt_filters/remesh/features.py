"""Sharp features of a triangle mesh: patches, feature curves and corners.

A feature edge is an edge whose dihedral angle exceeds a threshold, or a boundary edge.
Faces joined across non-feature edges form *patches*; patches smaller than ``min_area`` are
merged into a neighbour, which removes the spurious "features" around the noisy normals of
marching-cubes slivers. The feature edges are the edges between two different patches, the
boundary edges, and the sharp creases inside a patch (:func:`_inner_creases`: where the patches
on the two sides of a crease join through a gap, as at the rounded corners of a refined cuboid,
the crease is kept as a curve that may end inside its patch). With ``bridge=True``, gaps in a crease are bridged before patches
are formed: where a sharp bend is spread over two edges under the threshold (dual contouring with
estimated Hermite normals), the crease has gaps through which the patches on its two sides join.
A hysteresis closes them: *weak* edges, whose dihedral angle exceeds ``BRIDGE_FRACTION`` of the
threshold and whose bend over a window of two faces (:func:`window_cos`) exceeds the threshold,
become creases where they connect to a crease through weak edges. Where the bend is spread over
two edges that both pass, the two parallel creases cut out a strip one face wide; patches without
an interior vertex are merged into a neighbour whatever their area.
Off by default: on the refined, bumpy surfaces of the pipeline it turns noise creases into
features (the 10M `many` surfaces: 5 -> 71 curves, spheres among them, Hausdorff to the input 0.302
-> 0.351 nm). Feature curves are chains of such edges between *corners*, the vertices where three
or more feature curves meet (or closed loops without a corner).

Peak memory: a few integer arrays of 3 x the number of faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from apt_filters.remesh._arrays import unique
from apt_filters.core.mesh import TriMesh

BRIDGE_FRACTION = 0.5  # a weak (bridging) edge bends by at least this fraction of the feature angle
STRIP_ROUNDS = 5  # rounds of merging strips (patches without an interior vertex) when bridging


@dataclass
class Features:
    """Feature structure of an input mesh.

    Attributes
    ----------
    patch : (m,) int64
        Patch id of every input face, 0 .. n_patches-1.
    corners : (c,) int64
        Input vertex ids of the corners (pinned generators).
    curves : list of (k_i,) int64
        Ordered input vertex ids of each feature curve; a closed loop repeats its first vertex
        at the end. An open curve starts and ends at corners.
    curve_patches : list of (j_i,) int64
        Patches on either side of each curve (one for a boundary curve).
    corner_patches : list of (j_i,) int64
        Patches around each corner.
    boundary_curve : (n_curves,) bool
        Which curves lie on the open boundary of the surface.
    edge : (e,) bool
        Which input edges (:attr:`apt_filters.core.mesh.Topology.edge_vertices`) lie on a feature
        curve: the borders between patches, the open boundary and the creases kept inside a patch.
    """

    patch: np.ndarray
    corners: np.ndarray
    curves: list
    curve_patches: list
    corner_patches: list
    boundary_curve: np.ndarray
    edge: np.ndarray

    @property
    def n_patches(self) -> int:
        return int(self.patch.max()) + 1 if len(self.patch) else 0


def _merge_small_patches(patch: np.ndarray, areas: np.ndarray, pair: np.ndarray, lengths: np.ndarray,
                         min_area: float, force: np.ndarray | None = None,
                         keep: np.ndarray | None = None) -> np.ndarray:
    """Merge every patch smaller than ``min_area`` (and every patch id that ``force`` flags,
    whatever its area) into the neighbour it shares most border with; a flagged patch is a
    target only where a patch has no other neighbour, and a flagged patch goes into a small
    one only where it has no larger neighbour. Edges flagged in ``keep`` (e,) are no shared
    border: a small patch bounded only by them stays."""
    force = np.zeros(patch.max() + 1, bool) if force is None else force
    inner = pair[:, 1] >= 0
    if keep is not None:
        inner &= ~keep
    for _ in range(20):
        pa, pb = patch[pair[inner, 0]], patch[pair[inner, 1]]
        cross = pa != pb
        if not cross.any():
            break
        n = patch.max() + 1
        parea = np.where(force[:n], 0.0, np.bincount(patch, areas, minlength=n))  # forced: as if empty
        a = np.concatenate([pa[cross], pb[cross]])
        b = np.concatenate([pb[cross], pa[cross]])
        w = np.tile(lengths[inner][cross], 2)
        small = parea[a] < min_area
        w = np.where(force[b] | (force[a] & (parea[b] < min_area)), 1e-9 * w, w)
        if not small.any():
            break
        shared = sparse.coo_matrix((w[small], (a[small], b[small])), shape=(n, n)).tocsr()
        target = np.arange(n)
        rows = unique(a[small])
        best = np.asarray(shared[rows].argmax(axis=1)).ravel()
        # a small patch only moves into a larger one, so two small neighbours cannot swap
        grow = parea[best] >= parea[rows]
        target[rows[grow]] = best[grow]
        while True:  # follow chains of merges to their end
            nxt = target[target]
            if np.array_equal(nxt, target):
                break
            target = nxt
        if np.array_equal(target, np.arange(n)):
            break
        patch = target[patch]
    _, patch = np.unique(patch, return_inverse=True)
    return patch.ravel()


def _neighbours(pair: np.ndarray, half_edge: np.ndarray, m: int) -> np.ndarray:
    """(m, 3) the face across each edge of each face, -1 across a boundary edge."""
    own = np.repeat(np.arange(m), 3)
    return np.where(pair[half_edge, 0] == own, pair[half_edge, 1], pair[half_edge, 0]).reshape(m, 3)


def window_cos(pair: np.ndarray, half_edge: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(e,) per edge, the bend over a window of two faces as a cosine: the smallest cosine between
    the normal of one of its faces and the normal of a face next to the other one (1 on boundary
    edges; ``pair`` as :meth:`apt_filters.core.mesh.Topology.edge_pairs` gives it, ``half_edge`` (3m,) the
    edge of each half-edge, :attr:`~apt_filters.core.mesh.Topology.face_edge` flattened)."""
    nbr = _neighbours(pair, half_edge, len(normals))
    nbr = np.where(nbr >= 0, nbr, np.arange(len(normals))[:, None])
    a, b = pair[:, 0], np.maximum(pair[:, 1], 0)
    ca = np.einsum("eij,ej->ei", normals[nbr[a]], normals[b]).min(axis=1)
    cb = np.einsum("eij,ej->ei", normals[nbr[b]], normals[a]).min(axis=1)
    return np.where(pair[:, 1] >= 0, np.minimum(ca, cb), 1.0)


def side_cos(pair: np.ndarray, half_edge: np.ndarray, area_normals: np.ndarray) -> np.ndarray:
    """(e,) per edge, the turn across it over a window of two faces a side as a cosine: between the
    area-weighted mean normals of each of its faces with its other neighbours (1 on boundary edges;
    ``area_normals`` (m, 3) face normals scaled by twice the face area)."""
    padded = np.vstack([area_normals, np.zeros((1, 3))])  # row -1: no neighbour
    ring = area_normals + padded[_neighbours(pair, half_edge, len(area_normals))].sum(axis=1)  # with its neighbours
    a, b = pair[:, 0], np.maximum(pair[:, 1], 0)
    sa, sb = ring[a] - area_normals[b], ring[b] - area_normals[a]
    cos = np.einsum("ij,ij->i", sa, sb) / np.maximum(np.linalg.norm(sa, axis=1) * np.linalg.norm(sb, axis=1), 1e-300)
    return np.where(pair[:, 1] >= 0, cos, 1.0)


def _incidence(edges: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR vertex -> edge incidence: edges of vertex v are ``incident[start[v]:start[v + 1]]``."""
    ends = np.concatenate([edges[:, 0], edges[:, 1]])
    order = np.argsort(ends, kind="stable")
    return np.searchsorted(ends[order], np.arange(n_vertices + 1)), np.tile(np.arange(len(edges)), 2)[order]


def _grow_creases(edges: np.ndarray, n_vertices: int, crease: np.ndarray, weak: np.ndarray) -> np.ndarray:
    """``crease`` with the ``weak`` edges added that connect to a crease through weak edges (a
    hysteresis, as Canny's edge detector keeps weak edges joined to strong ones)."""
    both = crease | weak
    graph = sparse.coo_matrix((np.ones(both.sum()), (edges[both, 0], edges[both, 1])), shape=(n_vertices,) * 2)
    _, comp = connected_components(graph, directed=False)
    strong = np.zeros(comp.max() + 1, bool)
    strong[comp[edges[crease, 0]]] = True
    return crease | (weak & strong[comp[edges[:, 0]]])


def _strips(patch: np.ndarray, faces: np.ndarray, n_vertices: int, boundary_vertex: np.ndarray) -> np.ndarray:
    """(p,) bool: patches without an interior vertex (every vertex on another patch or on the open
    boundary): the one-face-wide strips that two parallel creases of a spread bend cut out."""
    per_vertex = sparse.coo_matrix((np.ones(faces.size), (faces.ravel(), np.repeat(patch, 3))),
                                   shape=(n_vertices, patch.max() + 1)).tocsr()
    border = (np.diff(per_vertex.indptr) > 1) | boundary_vertex  # duplicates summed: one entry per patch
    interior = np.bincount(np.repeat(patch, 3)[~border[faces.ravel()]], minlength=patch.max() + 1)
    return interior == 0


def _inner_creases(edges: np.ndarray, n_vertices: int, feature: np.ndarray, inner: np.ndarray,
                   window: np.ndarray, lengths: np.ndarray, reach: float) -> np.ndarray:
    """(e,) bool: the ``inner`` edges (creases inside a patch) that make curves.

    Chains of ``inner`` edges (joined at vertices) are kept where they are at least ``reach`` (nm,
    the target edge) long in all, and where they touch a ``feature`` edge or turn by more than the
    threshold over the wider window on one of their edges (``window`` (e,) bool: :func:`side_cos`).
    The output's edges cannot follow a shorter crease; and a crease continues along itself, where a
    lone edge of a coarse curved surface (a marching-cubes gyroid at 1 nm: 41° across one edge,
    31° over two faces a side) only bends, and the bend fades over the window.
    """
    graph = sparse.coo_matrix((np.ones(inner.sum()), (edges[inner, 0], edges[inner, 1])), shape=(n_vertices,) * 2)
    comp = connected_components(graph, directed=False)[1]
    length = np.bincount(comp[edges[inner, 0]], lengths[inner], minlength=comp.max() + 1)
    joined = np.zeros(comp.max() + 1, bool)
    joined[comp[edges[feature].ravel()]] = True
    joined[comp[edges[inner & window, 0]]] = True
    chain = comp[edges[:, 0]]
    return inner & joined[chain] & (length[chain] >= reach)


def _median_edge(edges: np.ndarray, n_vertices: int, lengths: np.ndarray) -> np.ndarray:
    """(e,) the median edge length (nm) of each edge's connected component."""
    graph = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_vertices,) * 2)
    comp = connected_components(graph, directed=False)[1][edges[:, 0]]
    order = np.lexsort((lengths, comp))
    first = np.searchsorted(comp[order], np.arange(comp.max() + 1))
    last = np.searchsorted(comp[order], np.arange(comp.max() + 1), side="right") - 1
    median = 0.5 * (lengths[order][(first + last) // 2] + lengths[order][(first + last + 1) // 2])
    return median[comp]


def _walk_curves(edges: np.ndarray, n_vertices: int, corner: np.ndarray) -> list[np.ndarray]:
    """Split the feature-edge graph into chains between corners and closed loops."""
    if len(edges) == 0:
        return []
    start, incident = _incidence(edges, n_vertices)
    used = np.zeros(len(edges), bool)
    curves = []

    def walk(v: int, e: int) -> list[int]:
        path = [v]
        while True:
            used[e] = True
            v = int(edges[e, 1] if edges[e, 0] == v else edges[e, 0])
            path.append(v)
            if corner[v]:
                return path
            nxt = [x for x in incident[start[v]:start[v + 1]] if not used[x]]
            if not nxt:
                return path  # closed loop back at its start
            e = int(nxt[0])

    for v in np.flatnonzero(corner):
        for e in incident[start[v]:start[v + 1]]:
            if not used[e]:
                curves.append(np.array(walk(int(v), int(e))))
    for e in range(len(edges)):
        if not used[e]:
            curves.append(np.array(walk(int(edges[e, 0]), e)))
    return curves


def _apexes(mesh: TriMesh, threshold: float, spacing: float, on_feature: np.ndarray) -> np.ndarray:
    """(v,) bool: apexes of cones off the feature curves (``on_feature`` (v,) bool).

    The angle deficit of a vertex (2π less the face angles around it) is the Gaussian curvature
    it holds: π/2 at a cube's corner, hundredths on a smooth surface. Summed over clusters of
    vertices joined by edges shorter than ``spacing`` (nm) or by faces under 1 % of the mean
    face area (marching cubes' zero-area slivers give one vertex a deficit of π and its
    neighbour -π; coincident vertices split one fan in two), it is that of the surface there; where it exceeds ``threshold`` (radians) in
    magnitude, the cluster's vertex of largest deficit is an apex. The pipeline's refinement
    sharpens a cuboid's corners without creases around them that pass the feature angle, and
    leaves spikes; the remesh at 0.5 nm cut such apexes 0.2-0.23 nm short. As corners they stay.
    """
    p = mesh.vertices[mesh.faces]
    # each corner's edges to the next and the previous corner, made in place and the corners' points freed (with
    # the rolled copies, the edge lengths' own differences and the areas' cross products, these were the largest
    # holders of a fine input's remesh: 360 bytes a face at the peak, of the box-sphere-plate's 800)
    u = np.roll(p, -1, axis=1)
    u -= p
    w = np.roll(p, 1, axis=1)
    w -= p
    del p
    normal = np.cross(u, w)
    angle = np.arctan2(np.linalg.norm(normal, axis=2), np.einsum("fki,fki->fk", u, w))
    del w
    area = 0.5 * np.linalg.norm(normal[:, 0], axis=1)  # corner 0's cross product is the face's normal
    del normal
    # a face with two coincident vertices has no angles there: give its three corners π in all
    # (they fall in one cluster below, so only the sum matters)
    angle += (np.pi - angle.sum(axis=1, keepdims=True)) / 3
    deficit = 2 * np.pi - np.bincount(mesh.faces.ravel(), angle.ravel(), minlength=mesh.n_vertices)
    del angle
    # corner k's edge u runs along the half-edge (k, k + 1)
    short = (np.linalg.norm(u, axis=2) < spacing) | (area < 0.01 * area.mean())[:, None]
    del u
    half = np.stack([mesh.faces, np.roll(mesh.faces, -1, axis=1)], axis=2)  # (f, 3, 2)
    join = half[short]
    graph = sparse.coo_matrix((np.ones(len(join)), (join[:, 0], join[:, 1])), shape=(mesh.n_vertices,) * 2)
    cluster = connected_components(graph, directed=False)[1]
    total = np.abs(np.bincount(cluster, deficit))
    order = np.lexsort((-np.abs(deficit), cluster))
    first = order[np.r_[True, cluster[order][1:] != cluster[order][:-1]]]
    # a cluster that touches a feature curve is that curve's corner or bend, already kept
    free = np.bincount(cluster, on_feature) == 0
    apex = np.zeros(mesh.n_vertices, bool)
    apex[first[(total[cluster[first]] > threshold) & free[cluster[first]]]] = True
    return apex


def _rim_turns(vertices: np.ndarray, rim: np.ndarray, threshold: float, spacing: float) -> np.ndarray:
    """(v,) bool: open-rim vertices where the rim turns by more than ``threshold`` (radians).

    Marching cubes leaves the rim of an open surface (the specimen's edge) as a zigzag of
    vertices on grid edges; a curve through it in chords of the target edge cut its teeth and
    sat 0.9-1.2 edge from the input's rim (gyroid and tilted sheet at half-voxel edges). As
    corners, the turning vertices keep the rim where it was. Of two turning vertices closer than
    ``spacing`` (nm) along the rim, the one turning less is left out (a triangle that small
    would only make slivers; the rim moves by less than ``spacing``).
    """
    corner = np.zeros(len(vertices), bool)
    if len(rim) == 0:
        return corner
    ends = np.concatenate([rim, rim[:, ::-1]])  # (v, neighbour) both ways
    ends = ends[np.argsort(ends[:, 0], kind="stable")]
    count = np.bincount(ends[:, 0], minlength=len(vertices))
    first = np.r_[0, np.cumsum(count)[:-1]]
    v = np.flatnonzero(count == 2)
    a, b = ends[first[v], 1], ends[first[v] + 1, 1]
    u, w = vertices[v] - vertices[a], vertices[b] - vertices[v]
    cos = np.einsum("ij,ij->i", u, w) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300)
    turn = np.full(len(vertices), -1.0)
    turn[v] = np.arccos(np.clip(cos, -1.0, 1.0))
    corner = turn > threshold
    short = rim[np.linalg.norm(vertices[rim[:, 0]] - vertices[rim[:, 1]], axis=1) < spacing]
    both = short[corner[short].all(axis=1)]
    corner[np.where(turn[both[:, 0]] < turn[both[:, 1]], both[:, 0], both[:, 1])] = False
    return corner


def detect(mesh: TriMesh, angle: float = 40.0, min_area: float = 0.0, bridge: bool = False,
           miss: float = np.inf) -> Features:
    """Find patches, feature curves and corners of ``mesh``.

    Parameters
    ----------
    angle : float
        Dihedral angle in degrees above which an edge is a feature (``>= 180`` disables features,
        boundaries stay).
    min_area : float
        Patches smaller than this (nm²) are merged into their neighbour.
    bridge : bool
        Join the gaps of creases whose bend is spread over two edges (see the module docstring).
    miss : float
        Small patches are never merged across a sharp crease that a chord could miss by more than
        this (nm): θ·min(h, √min_area)/2 for a turn θ between faces h high over the crease (the
        miss of a triangle with angles of 30-90°, :func:`apt_filters.remesh.remesh.crease_shrink`);
        slivers' noisy normals, with h near 0, never pass. Such creases inside a patch are kept as
        curves (:func:`_inner_creases`). Infinite: every small patch merges, and only the borders
        between patches are curves.
    """
    faces = mesh.faces
    top = mesh.topology
    edges, half_edge, counts, pair = top.edge_vertices, top.face_edge.ravel(), top.edge_faces, top.edge_pairs()
    normals = mesh.face_normals()
    manifold = counts == 2
    cos = np.ones(len(edges))
    cos[manifold] = np.einsum("ij,ij->i", normals[pair[manifold, 0]], normals[pair[manifold, 1]])
    degenerate = (np.linalg.norm(normals[pair[:, 0]], axis=1) == 0) | (np.linalg.norm(normals[pair[:, 1]], axis=1) == 0)
    threshold = np.radians(angle)
    crease = manifold & ~degenerate & (cos < np.cos(threshold))
    if bridge:
        weak = (manifold & ~degenerate & ~crease & (cos < np.cos(BRIDGE_FRACTION * threshold))
                & (window_cos(pair, half_edge, normals) < np.cos(threshold)))
        crease = _grow_creases(edges, len(mesh.vertices), crease, weak)
    smooth = manifold & ~crease
    graph = sparse.coo_matrix((np.ones(smooth.sum()), (pair[smooth, 0], pair[smooth, 1])),
                              shape=(len(faces), len(faces)))
    _, patch = connected_components(graph, directed=False)
    lengths = np.linalg.norm(mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]], axis=1)
    manifold_pair = np.where(manifold[:, None], pair, -1)
    boundary = counts == 1
    boundary_vertex = np.zeros(len(mesh.vertices), bool)
    boundary_vertex[edges[boundary].ravel()] = True
    unstripped, a, b = patch, pair[:, 0], np.maximum(pair[:, 1], 0)
    for _ in range(STRIP_ROUNDS if bridge else 0):  # a merge can leave a new strip beside the old one
        strips = _strips(patch, faces, len(mesh.vertices), boundary_vertex)
        if not strips.any():
            break
        patch = _merge_small_patches(patch, mesh.face_areas(), manifold_pair, lengths, min_area, strips)
    stripped = (unstripped[a] != unstripped[b]) & (patch[a] == patch[b])
    # creases a chord could miss by more than ``miss`` (the chamfer facets at a refined cuboid's
    # corners: creases of 65-118°, cut 0.27-0.31 edge deep once merged away) are never merged across
    twice_area = np.linalg.norm(mesh.face_normals(normalize=False), axis=1)
    height = np.minimum(twice_area[pair[:, 0]], twice_area[np.maximum(pair[:, 1], 0)]) / np.maximum(lengths, 1e-300)
    theta = np.arccos(np.clip(cos, -1.0, 1.0))
    kept = crease & (theta * np.minimum(height, np.sqrt(min_area)) > 2.0 * miss)
    patch = _merge_small_patches(patch, mesh.face_areas(), manifold_pair, lengths, min_area, keep=kept)
    feature = boundary | (manifold & (patch[pair[:, 0]] != patch[np.maximum(pair[:, 1], 0)]))
    # sharp creases inside a patch (where the patches on their two sides join through a gap, as
    # at a refined cuboid's rounded corners) are kept as curves all the same, by the rule above;
    # not those of the strips merged away when bridging (one curve stands for a spread bend there),
    # nor where the remesh refines the input (its median edge over √2 target edges, faces over twice
    # the output's): curve generators a target edge apart fall between the input's vertices and
    # cut the teeth of its coarse creases (a marching-cubes plate's rim at 1 nm, target 0.5: given
    # back with one seed of four, against none)
    inner = kept & ~feature & ~stripped
    window = side_cos(pair, half_edge, mesh.face_normals(normalize=False)) < np.cos(threshold)
    inner &= _median_edge(edges, len(mesh.vertices), lengths) <= np.sqrt(2.0 * min_area)
    feature |= _inner_creases(edges, len(mesh.vertices), feature, inner, window, lengths, np.sqrt(min_area))
    fedges = edges[feature]
    degree = np.bincount(fedges.ravel(), minlength=len(mesh.vertices))
    corner = (degree >= 3) | (degree == 1) | _rim_turns(mesh.vertices, edges[boundary], threshold,
                                                         0.25 * np.sqrt(min_area))
    # a circular cone whose sides meet at the feature angle across its apex holds 2π(1 - cos(angle/2))
    cone = 2 * np.pi * (1 - np.cos(threshold / 2))
    corner |= _apexes(mesh, cone, 0.25 * np.sqrt(min_area), (degree > 0) | boundary_vertex)
    curves = _walk_curves(fedges, len(mesh.vertices), corner)
    # patches beside each curve, from one of its edges
    fidx = np.flatnonzero(feature)
    lookup = dict(zip(map(tuple, fedges.tolist()), fidx.tolist()))
    curve_patches, is_boundary = [], []
    for c in curves:
        e = lookup[tuple(sorted((int(c[0]), int(c[1]))))]
        f = pair[e][pair[e] >= 0]
        curve_patches.append(unique(patch[f]))
        is_boundary.append(bool(boundary[e]))
    corners = np.flatnonzero(corner)
    vf = sparse.coo_matrix((np.ones(faces.size), (faces.ravel(), np.repeat(patch, 3))),
                           shape=(len(mesh.vertices), patch.max() + 1)).tocsr()
    corner_patches = [vf.indices[vf.indptr[v]:vf.indptr[v + 1]] for v in corners]
    return Features(patch, corners, curves, curve_patches, corner_patches, np.array(is_boundary, bool), feature)
