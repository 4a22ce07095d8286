"""Mesh sanity checks: folded face pairs, self-intersections, non-manifold vertices."""

from __future__ import annotations

import numpy as np

from apt_filters.core.mesh import face_normals, topology

SLACK = 1 + 1e-9  # balls that touch within rounding count as overlapping (triangles meeting at one point)
BOX_SLACK = 1e-9  # bounding boxes this close, as a share of the largest coordinate, count as meeting


def folded_pairs(vertices: np.ndarray, faces: np.ndarray, max_angle_deg: float = 120.0) -> np.ndarray:
    """(k, 2) edge-adjacent face pairs whose normals differ by more than ``max_angle_deg``.

    A fold is a triangle flipped against its neighbour; the default of 120° is beyond any
    dihedral the benchmark shapes have (their sharpest edges are 90°).
    """
    pairs = topology(faces, len(vertices)).face_pairs
    n = face_normals(vertices, faces)
    dots = np.einsum("ij,ij->i", n[pairs[:, 0]], n[pairs[:, 1]])
    return pairs[dots < np.cos(np.radians(max_angle_deg))]


def triangles_intersect(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) bool: whether triangles ``a[i]`` and ``b[i]`` ((k, 3, 3) arrays) share a point.

    Separating-axis test in float64: the two normals, the nine edge-edge cross products
    and the six in-plane edge normals (which separate coplanar triangles); the triangles
    intersect when no axis separates their projections. It runs only on the pairs whose bounding
    boxes meet: the mend's candidates (every face within a few edges, mend.crossing) meet in 1 of
    40 (22,334 pairs, 575 meeting, on a bumpy sheet; its crossing tests 0.18 -> 0.07 s). Boxes
    apart by more than ``BOX_SLACK`` of the largest coordinate hold triangles farther apart than
    that, which one of the 17 axes separates by as much (the closest points' direction is a
    normal or an edge-edge cross product), far above the projections' rounding.
    """
    lo_a, hi_a, lo_b, hi_b = a.min(axis=1), a.max(axis=1), b.min(axis=1), b.max(axis=1)
    slack = BOX_SLACK * np.maximum(np.abs(a).max(axis=(1, 2)), np.abs(b).max(axis=(1, 2)))[:, None]
    meet = np.flatnonzero(((lo_a <= hi_b + slack) & (lo_b <= hi_a + slack)).all(axis=1))
    out = np.zeros(len(a), dtype=bool)
    out[meet] = ~_separated(a[meet], b[meet])
    return out


def _separated(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) bool: whether one of :func:`triangles_intersect`'s 17 axes separates triangles ``a[i]`` and ``b[i]``
    ((k, 3, 3))."""
    ea, eb = np.roll(a, -1, axis=1) - a, np.roll(b, -1, axis=1) - b
    na, nb = np.cross(ea[:, 0], ea[:, 1]), np.cross(eb[:, 0], eb[:, 1])
    axes = [na[:, None], nb[:, None], np.cross(ea[:, :, None], eb[:, None, :]).reshape(-1, 9, 3),
            np.cross(na[:, None], ea), np.cross(nb[:, None], eb)]
    axes = np.concatenate(axes, axis=1)  # (k, 17, 3)
    pa, pb = np.einsum("kaj,kvj->kav", axes, a), np.einsum("kaj,kvj->kav", axes, b)
    separated = (pa.max(axis=2) < pb.min(axis=2)) | (pb.max(axis=2) < pa.min(axis=2))
    return separated.any(axis=1)


def touching_pairs(centre: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """(k, 2) int index pairs ``i < j`` of balls that overlap, ``|centre[i] - centre[j]| <= radius[i] + radius[j]``.

    Every pair of triangles that can share a point, with ``centre`` a point of each and ``radius`` its farthest
    corner from it. One search radius for all pairs would have to be twice the largest ball's, and one long sliver
    on a tangled surface then pairs every face with every other (a refined rod's grooved start: 19.6 M pairs and
    ~20 GB in the separating-axis test). So the balls are searched by size class (radii within a factor of two,
    from the median up): each class against itself and against every smaller class, each on its own reach; the
    result is exact, and the work scales with the overlapping pairs.

    Parameters
    ----------
    centre : (n, 3) float64
    radius : (n,) float64, >= 0
    """
    from scipy.spatial import cKDTree

    n = len(centre)
    if n < 2:
        return np.zeros((0, 2), dtype=np.intp)
    base = max(float(np.median(radius)), float(radius.max()) * 1e-12, 1e-300)
    size = np.maximum(np.ceil(np.log2(np.maximum(radius, base) / base)), 0).astype(int)  # radius <= base 2^size
    found = []
    for k in np.unique(size):
        top = base * 2.0 ** k
        here, below = np.flatnonzero(size == k), np.flatnonzero(size < k)
        found.append(here[cKDTree(centre[here]).query_pairs(2 * top * SLACK, output_type="ndarray")])
        if below.size:  # the smaller classes' radii are at most top / 2
            near = cKDTree(centre[below]).query_ball_point(centre[here], (radius[here] + top / 2) * SLACK)
            lengths = np.fromiter(map(len, near), dtype=np.intp, count=len(here))
            if lengths.sum():
                found.append(np.column_stack([np.repeat(here, lengths),
                                              below[np.concatenate([np.asarray(x, dtype=np.intp) for x in near])]]))
    pairs = np.sort(np.concatenate(found).reshape(-1, 2), axis=1)
    gap = np.linalg.norm(centre[pairs[:, 0]] - centre[pairs[:, 1]], axis=1)
    return pairs[gap <= (radius[pairs[:, 0]] + radius[pairs[:, 1]]) * SLACK]


def self_intersecting_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces that cross another face, not counting faces that share an edge.

    Candidates come from pymeshlab's ``compute_selection_by_self_intersections_per_face``
    (imported on first use; call it on world coordinates, nm, since its tolerances are
    absolute). That test also flags disjoint *coplanar* triangles (seen on the flat faces
    of dual-contoured boxes, 0.6 voxel apart), so every flagged face is confirmed by
    :func:`triangles_intersect` against the flagged faces near it that share no edge
    with it; both are shrunk by 1e-6 about their centroids first, so that faces meeting
    only at a shared vertex do not count.
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces.astype(np.int32)))
    ms.compute_selection_by_self_intersections_per_face()
    flagged = np.flatnonzero(ms.current_mesh().face_selection_array())
    out = np.zeros(len(faces), dtype=bool)
    if len(flagged) < 2:
        return out
    tri = vertices[faces[flagged]]
    centre = tri.mean(axis=1)
    tri = centre[:, None] + (1 - 1e-6) * (tri - centre[:, None])
    pairs = touching_pairs(centre, np.linalg.norm(tri - centre[:, None], axis=2).max(axis=1))
    f = faces[flagged]
    # in slices: the separating-axis test holds 17 axes per pair, and a tangled surface has many pairs
    for chunk in np.array_split(pairs, max(1, len(pairs) // 65536)):
        shared = (f[chunk[:, 0], :, None] == f[chunk[:, 1], None, :]).sum(axis=(1, 2))
        chunk = chunk[shared < 2]
        hit = chunk[triangles_intersect(tri[chunk[:, 0]], tri[chunk[:, 1]])]
        out[flagged[hit.reshape(-1)]] = True
    return out


def non_manifold_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) bool: vertices whose incident faces form more than one fan (pymeshlab's
    ``compute_selection_by_non_manifold_per_vertex``)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces.astype(np.int32)))
    ms.compute_selection_by_non_manifold_per_vertex()
    return ms.current_mesh().vertex_selection_array().astype(bool)


def non_manifold_vertex_count(vertices: np.ndarray, faces: np.ndarray) -> int:
    """Vertices whose incident faces form more than one fan (pymeshlab's ``get_topological_measures``)."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces.astype(np.int32)))
    return int(ms.get_topological_measures()["non_two_manifold_vertices"])
