"""Repair of the extracted triangulation: duplicates, over-full edges and holes.

The labelled refined mesh can report one restricted Voronoi vertex twice (a duplicate
triangle) or not at all (a cell touching a vertex twice), which leaves over-full edges or
small holes. Duplicates are dropped, over-full edges lose their worst triangles, and every
boundary loop that is not made only of boundary-curve generators is a hole and is closed
with the fan triangulation that maximises the smallest angle.
"""

from __future__ import annotations

import numpy as np

from apt_filters.contour.metrics import face_quality
from apt_filters.core.checks import non_manifold_vertices
from apt_filters.core.mesh import Topology, TriMesh, topology
from apt_filters.remesh._arrays import unique_rows
from apt_filters.remesh.extract import triangulate_polygon


def drop_duplicates(faces: np.ndarray) -> np.ndarray:
    """Keep the first of triangles with the same three vertices; drop triangles with repeated vertices."""
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    faces = faces[ok]
    first = unique_rows(np.sort(faces, axis=1))[1]
    return faces[np.sort(first)]


def trim_overfull_edges(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Remove the worst-shaped triangles on edges used by more than two, until none is."""
    for _ in range(10):
        e = np.sort(TriMesh(vertices, faces).edges(), axis=1)
        _, _, inverse, counts = unique_rows(e)
        over = counts[inverse.ravel()].reshape(-1, 3).max(axis=1) > 2
        if not over.any():
            break
        quality = face_quality(TriMesh(vertices, faces))[0].min(axis=1)
        # on each over-full edge, drop the worst of its triangles
        edge = inverse.ravel()
        face = np.repeat(np.arange(len(faces)), 3)
        sel = counts[edge] > 2
        worst = np.full(len(counts), np.inf)
        np.minimum.at(worst, edge[sel], quality[face[sel]])
        drop = np.zeros(len(faces), bool)
        drop[face[sel][quality[face[sel]] == worst[edge[sel]]]] = True
        faces = faces[~drop]
    return faces


def boundary_loops(faces: np.ndarray) -> list[list[int]]:
    """Boundary loops as vertex lists, following the boundary half-edges (a -> b) of the faces."""
    nxt = {}
    # not cached: the hole fill's faces change every round, and a cached table lived as long as they did (through
    # the next round's trim of over-full edges: 630 bytes per input face of a thin plate's remesh, at its peak)
    for a, b in Topology.of(faces, int(faces.max()) + 1).boundary_half_edges.tolist():
        nxt.setdefault(a, []).append(b)
    loops, seen = [], set()
    for a in list(nxt):
        if a in seen:
            continue
        loop, v = [], a
        while v not in seen and v in nxt:
            seen.add(v)
            loop.append(v)
            v = nxt[v][0]
        loops.append(loop)
    return loops


MAX_FILL_ROUNDS = 4


def close_holes(vertices: np.ndarray, faces: np.ndarray, on_boundary: np.ndarray, pinned: np.ndarray,
                sliver=None) -> np.ndarray:
    """Close every boundary loop most of whose vertices are not on a boundary curve (``on_boundary`` False),
    with no face that ``sliver`` forbids where it can (:func:`~apt_filters.remesh.extract.triangulate_polygon`).

    A loop mostly of boundary-curve generators is the input's open rim, even where a cell next
    to it took one of its places: filling it capped the rim of an open interface across a
    specimen tip (+29 % area on a bumpy tilted sheet, +457 % in the pipeline).
    """
    new = []
    for loop in boundary_loops(faces):
        if len(loop) < 3 or 2 * on_boundary[loop].sum() >= len(loop):
            continue
        new.extend(triangulate_polygon(loop[::-1], vertices, pinned, sliver))
    return np.vstack([faces, np.array(new, np.int64).reshape(-1, 3)]) if new else faces


def orient_coherently(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Make neighbouring faces agree (pymeshlab), keeping the orientation most faces had before.

    A hole fill next to a vertex with two boundary fans can come out reversed; re-orienting
    per component and then voting with the original faces fixes it without trusting either.
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertices, faces))
    ms.meshing_re_orient_faces_coherently()
    new = ms.current_mesh().face_matrix().astype(np.int64)
    if new.shape != faces.shape:  # pymeshlab changed more than orientation: keep ours
        return faces
    same = np.zeros(len(faces), bool)
    for shift in range(3):
        same |= (np.roll(new, shift, axis=1) == faces).all(axis=1)
    labels = TriMesh(vertices, new).face_components()
    flip_component = np.bincount(labels, ~same) > np.bincount(labels, same)
    return np.where(flip_component[labels][:, None], new[:, ::-1], new)


def defects(vertices: np.ndarray, faces: np.ndarray, on_boundary: np.ndarray) -> np.ndarray:
    """(n,) bool: generators where the extracted triangulation is not a closed, oriented 2-manifold.

    These are the ends of edges with more than two faces, of half-edges used twice (opposite
    orientations) and of boundary edges not on a boundary curve, and vertices with several
    fans: the marks of restricted Voronoi cells that are not topological disks.
    """
    faces = drop_duplicates(faces)
    bad = np.zeros(len(vertices), bool)
    if len(faces) == 0:
        return bad
    topo = topology(faces, len(vertices))
    undirected, counts = topo.edge_vertices, topo.edge_faces
    opened = (counts == 1) & ~on_boundary[undirected].all(axis=1)
    bad[undirected[(counts > 2) | opened].ravel()] = True
    # faces running an edge the same way (opposite orientations): not in the undirected topology; one sorted
    # key per half-edge (a unique_rows of the half-edges held ten arrays of their size: the remesh's peak
    # on the thin plate, whose output has 7.5 faces per input face)
    n = len(vertices)
    key = (faces * n + np.roll(faces, -1, axis=1)).ravel()
    key.sort()
    twice = key[1:][key[1:] == key[:-1]]
    bad[twice // n] = True
    bad[twice % n] = True
    return bad | non_manifold_vertices(vertices, faces)


def lone_generators(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: generators in ``faces`` with fewer than three distinct neighbours or fewer than three faces.

    No closed 2-manifold holds such a vertex inside it. A restricted Voronoi cell bordered by only two cells
    (a sliver squeezed between two generators of a feature curve) has a dual of two triangles on the same
    three vertices with opposite orientations; two small cells side by side on the border of two others
    (a retry of the bumpy gyroid, cells 0.07 nm apart) have a dual of two faces each, a flap on the edge
    between those two, which extraction makes again and the hole fill cannot close.
    """
    edges = unique_rows(np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1))[0]
    edges = edges[edges[:, 0] != edges[:, 1]]
    degree = np.bincount(edges.ravel(), minlength=n)
    n_faces = np.bincount(faces.ravel(), minlength=n)
    return (n_faces > 0) & ((degree < 3) | (n_faces < 3))


def restore_rim(vertices: np.ndarray, faces: np.ndarray, on_boundary: np.ndarray) -> np.ndarray:
    """``faces`` with a triangle for every generator of the open boundary (``on_boundary`` (n,) bool)
    that no face uses, on the output's rim edge it lies closest beside.

    A corner at the tip of a marching-cubes rim's tooth can have a cell of a few samples that
    meets its two neighbours along the rim only, never all three at one point: it has no dual
    triangle, and the rim cut the tooth (0.80 nm off the input's rim on the bumpy tilted sheet at
    0.5 nm edges). The rim edge (a, b) whose detour |ga| + |gb| - |ab| through the missing
    generator g is least gets the face (b, a, g), oriented as the face on (a, b).
    """
    used = np.zeros(len(vertices), bool)
    used[faces.ravel()] = True
    missing = np.flatnonzero(on_boundary & ~used)
    if len(missing) == 0 or len(faces) == 0:
        return faces
    rim = topology(faces, len(vertices)).boundary_half_edges
    rim = rim[on_boundary[rim].all(axis=1)]
    new = []
    for g in missing:
        if len(rim) == 0:
            break
        ga = np.linalg.norm(vertices[rim[:, 0]] - vertices[g], axis=1)
        gb = np.linalg.norm(vertices[rim[:, 1]] - vertices[g], axis=1)
        ab = np.linalg.norm(vertices[rim[:, 0]] - vertices[rim[:, 1]], axis=1)
        j = int(np.argmin(ga + gb - ab))
        if min(ga[j], gb[j]) == 0.0:  # on a vertex already there: no triangle to make
            continue
        a, b = rim[j]
        new.append((b, a, g))
        rim = np.vstack([np.delete(rim, j, axis=0), [[a, g], [g, b]]])
    return np.vstack([faces, np.array(new, np.int64).reshape(-1, 3)])


def fill_rim_notches(faces: np.ndarray, on_boundary: np.ndarray) -> np.ndarray:
    """``faces`` with the triangle (g, a, b) added wherever the output's rim runs a -> g -> b from a generator of
    the open boundary (``on_boundary`` (n,) bool) through one that is not and back to one that is, and no face
    holds the edge (a, b) yet.

    A patch cell can reach the rim between two rim generators whose cells do not meet there (two corners on
    neighbouring input rim vertices, pinned by a retry, with no curve generator between them): the rim then
    detours through the patch generator and cuts the input surface between it and the rim (the bumpy tilted
    sheet's main sheet: 0.21 nm off the input's rim, tolerance 0.125). The triangle covers that piece and the rim
    runs a -> b on the input's rim.
    """
    if len(faces) == 0:
        return faces
    top = topology(faces, len(on_boundary))
    rim = top.boundary_half_edges
    out_of = np.full(len(on_boundary), -1, np.int64)
    into = np.full(len(on_boundary), -1, np.int64)
    count = np.bincount(rim.ravel(), minlength=len(on_boundary))
    out_of[rim[:, 0]] = rim[:, 1]
    into[rim[:, 1]] = rim[:, 0]
    g = np.flatnonzero((count == 2) & ~on_boundary & (out_of >= 0) & (into >= 0))
    a, b = into[g], out_of[g]
    keep = on_boundary[a] & on_boundary[b] & (a != b)
    g, a, b = g[keep], a[keep], b[keep]
    absent = ~_has_rows(top.edge_vertices, np.sort(np.stack([a, b], 1), axis=1)) if len(g) else np.zeros(0, bool)
    g, a, b = g[absent], a[absent], b[absent]
    # two notches sharing a rim generator are filled one at a time (the first in id order)
    first = np.zeros(len(g), bool)
    seen = set()
    for i in range(len(g)):
        if a[i] not in seen and b[i] not in seen:
            first[i] = True
            seen.update((int(a[i]), int(b[i])))
    return np.vstack([faces, np.stack([g, a, b], 1)[first]])


def drop_rim_caps(vertices: np.ndarray, faces: np.ndarray, pinned: np.ndarray, max_angle: float = 150.0,
                  rounds: int = 4) -> np.ndarray:
    """``faces`` without the caps on the open rim: faces of three ``pinned`` generators with an angle over
    ``max_angle`` degrees at a vertex off the rim, the long edge across from it on the rim.

    The rim's counterpart of :func:`~apt_filters.remesh.optimize.flip_caps`: where the cell of a rim
    generator is squeezed between its two neighbours on a straight rim curve (a few samples wide), extraction
    can join the three into a face of no area whose long edge is the rim, which no flip reaches. Without the
    face the rim runs through the apex, as the curve does.
    """
    limit = np.radians(max_angle)
    for _ in range(rounds):
        top = topology(faces, len(vertices))
        rim = top.boundary_half_edges
        on_rim = np.zeros(len(vertices), bool)
        on_rim[rim.ravel()] = True
        cap = np.zeros(len(faces), bool)
        for k in range(3):  # apex k, the edge (k+1, k+2) across from it
            c, a, b = faces[:, k], faces[:, (k + 1) % 3], faces[:, (k + 2) % 3]
            u, w = vertices[a] - vertices[c], vertices[b] - vertices[c]
            angle = np.arctan2(np.linalg.norm(np.cross(u, w), axis=1), np.einsum("ij,ij->i", u, w))
            cap |= pinned[a] & pinned[b] & pinned[c] & (angle > limit) & ~on_rim[c] & _has_rows(rim, np.stack([a, b], 1))
        if not cap.any():
            break
        faces = faces[~cap]
    return faces


def _has_rows(table: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(k,) bool: which ``rows`` (k, 2) are rows of ``table`` (m, 2) (int ids)."""
    if len(table) == 0:
        return np.zeros(len(rows), bool)
    n = int(max(table.max(), rows.max())) + 1
    return np.isin(rows[:, 0] * n + rows[:, 1], table[:, 0] * n + table[:, 1])


def repair(vertices: np.ndarray, faces: np.ndarray, on_boundary: np.ndarray, pinned: np.ndarray,
           sliver=None) -> np.ndarray:
    """Duplicates, over-full edges, holes (:func:`close_holes`, ``sliver`` its), then the open boundary's lost
    generators; returns the new faces."""
    faces = drop_duplicates(faces)
    faces = trim_overfull_edges(vertices, faces)
    # A hole fill can add a third face to an edge (two holes sharing a vertex pair); trimming
    # it opens a smaller hole, so fill and trim until nothing changes.
    for _ in range(MAX_FILL_ROUNDS):
        filled = trim_overfull_edges(vertices, drop_duplicates(close_holes(vertices, faces, on_boundary, pinned, sliver)))
        if filled.shape == faces.shape and np.array_equal(filled, faces):
            break
        faces = filled
    del filled  # where the fill ended with nothing to add: a copy of faces, not held through the rim's steps
    # the faces before each of the rim's steps let go before the next: with their topology (cached while they
    # live) they were 1,000 bytes per input face of a thin plate's remesh, held through the re-orientation at its
    # peak
    faces = restore_rim(vertices, faces, on_boundary)
    faces = fill_rim_notches(faces, on_boundary)
    return orient_coherently(vertices, faces)
