"""Edge adjacency and fold detection on indexed triangle meshes."""

from __future__ import annotations

import numpy as np


def face_pairs(faces: np.ndarray) -> np.ndarray:
    """(k, 2) pairs of faces that share an edge used by exactly two faces."""
    m = len(faces)
    if m == 0:
        return np.zeros((0, 2), dtype=np.int64)
    a, b = faces.reshape(-1), np.roll(faces, -1, axis=1).reshape(-1)
    key = np.minimum(a, b) * (int(faces.max()) + 1) + np.maximum(a, b)  # 1-D keys sort fast
    owner = np.repeat(np.arange(m), 3)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    two = counts[inverse] == 2
    order = np.argsort(inverse[two], kind="stable")
    return owner[two][order].reshape(-1, 2)


def unit_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def folded_pairs(vertices: np.ndarray, faces: np.ndarray, max_angle_deg: float = 120.0) -> np.ndarray:
    """(k, 2) edge-adjacent face pairs whose normals differ by more than ``max_angle_deg``.

    A fold is a triangle flipped against its neighbour; the default of 120° is beyond any
    dihedral the benchmark shapes have (their sharpest edges are 90°).
    """
    pairs = face_pairs(faces)
    n = unit_normals(vertices, faces)
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
