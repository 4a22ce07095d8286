"""Connected components of a contoured mesh, labelled closed / open at the specimen edge."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from apt_filters.core.mesh import TriMesh


def label_components(mesh: TriMesh) -> np.ndarray:
    """(m,) int64 component id per face (faces connected through shared vertices)."""
    if mesh.n_faces == 0:
        return np.zeros(0, dtype=np.int64)
    f = mesh.faces
    rows = np.concatenate([f[:, 0], f[:, 1]])
    cols = np.concatenate([f[:, 1], f[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(mesh.n_vertices,) * 2)
    _, vertex_label = connected_components(graph, directed=False)
    _, face_label = np.unique(vertex_label[f[:, 0]], return_inverse=True)
    return face_label.astype(np.int64)


@dataclass
class Component:
    """One connected surface.

    Attributes
    ----------
    id : int
        Value of ``face_scalars["component"]``.
    status : str
        ``"closed"`` (watertight, inside the specimen), ``"open_at_edge"`` (has boundary
        loops where it meets the specimen edge or the box) or ``"closed_proxy"`` (closed
        only by caps that ``close=True`` added at the edge).
    n_faces : int
    area : float
        nm², caps included.
    volume : float
        Enclosed volume in nm³ (NaN when open).
    n_boundary_edges : int
    """

    id: int
    status: str
    n_faces: int
    area: float
    volume: float
    n_boundary_edges: int


def component_table(mesh: TriMesh) -> list[Component]:
    """Per-component summary of a mesh from :func:`marching_cubes` or :func:`dual_contouring`."""
    labels = mesh.face_scalars.get("component")
    if labels is None:
        labels = label_components(mesh)
    caps = mesh.face_scalars.get("at_edge", np.zeros(mesh.n_faces, dtype=bool))
    out = []
    for cid in range(int(labels.max()) + 1 if len(labels) else 0):
        sel = labels == cid
        sub = TriMesh(mesh.vertices, mesh.faces[sel])
        n_boundary = len(sub.boundary_edges())
        if n_boundary:
            status, volume = "open_at_edge", float("nan")
        else:
            status = "closed_proxy" if caps[sel].any() else "closed"
            volume = sub.signed_volume()
        out.append(Component(cid, status, int(sel.sum()), sub.area(), volume, n_boundary))
    return out
