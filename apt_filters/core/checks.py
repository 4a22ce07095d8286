"""Mesh sanity checks: folded face pairs, self-intersections, non-manifold vertices."""

from __future__ import annotations

import numpy as np

from apt_filters.core.mesh import face_normals, topology


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
    intersect when no axis separates their projections.
    """
    ea, eb = np.roll(a, -1, axis=1) - a, np.roll(b, -1, axis=1) - b
    na, nb = np.cross(ea[:, 0], ea[:, 1]), np.cross(eb[:, 0], eb[:, 1])
    axes = [na[:, None], nb[:, None], np.cross(ea[:, :, None], eb[:, None, :]).reshape(-1, 9, 3),
            np.cross(na[:, None], ea), np.cross(nb[:, None], eb)]
    axes = np.concatenate(axes, axis=1)  # (k, 17, 3)
    pa, pb = np.einsum("kaj,kvj->kav", axes, a), np.einsum("kaj,kvj->kav", axes, b)
    separated = (pa.max(axis=2) < pb.min(axis=2)) | (pb.max(axis=2) < pa.min(axis=2))
    return ~separated.any(axis=1)


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
    from scipy.spatial import cKDTree

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
    reach = 2 * np.linalg.norm(tri - centre[:, None], axis=2).max()
    pairs = cKDTree(centre).query_pairs(reach, output_type="ndarray")
    f = faces[flagged]
    shared = (f[pairs[:, 0], :, None] == f[pairs[:, 1], None, :]).sum(axis=(1, 2))
    pairs = pairs[shared < 2]
    hit = pairs[triangles_intersect(tri[pairs[:, 0]], tri[pairs[:, 1]])]
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
