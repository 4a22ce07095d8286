"""Level-of-detail copies of big meshes with fast-simplification (quadric edge collapse).

Open surfaces (objects cut by the specimen edge) keep their boundary loops: every edge
touching a border vertex is left uncollapsed (``preserve_border``), so boundary vertices keep
their exact positions and the loops their exact shape; the tests check it. fast-simplification
keeps its mesh in C++ global state, so calls are serialised by a module lock. Vertex scalars
are carried over from the nearest input vertex. Memory: about 3x the mesh (input, the
library's copy, the k-d tree).
"""

from __future__ import annotations

import threading

import fast_simplification
import numpy as np
from scipy.spatial import cKDTree

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh

_LOCK = threading.Lock()


def decimate(mesh: TriMesh, target_reduction: float, aggressiveness: float = 7.0,
             preserve_boundary: bool = True) -> TriMesh:
    """Remove about ``target_reduction`` of the faces of ``mesh``.

    Parameters
    ----------
    mesh : TriMesh
        Input (n, 3) nm vertices, (m, 3) faces; not modified.
    target_reduction : float
        Fraction of faces to remove, in [0, 1): 0.9 keeps about 10 %.
    aggressiveness : float
        fast-simplification's ``agg``: higher is faster and coarser.
    preserve_boundary : bool
        Keep boundary loops exactly (no collapse touches a border vertex).

    Returns
    -------
    TriMesh
        Decimated mesh; vertex scalars from the nearest input vertex, face scalars dropped
        except ``object_id``, taken from the nearest input vertex's face.
    """
    if not 0.0 <= target_reduction < 1.0:
        raise AptFiltersError(f"target_reduction must be in [0, 1), got {target_reduction}")
    if mesh.n_faces == 0:
        return mesh.copy()
    with _LOCK:
        points, faces = fast_simplification.simplify(mesh.vertices, mesh.faces.astype(np.int32),
                                                     target_reduction=target_reduction, agg=aggressiveness,
                                                     preserve_border=preserve_boundary)
    points = np.asarray(points, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    used = np.unique(mesh.faces)
    nearest = used[cKDTree(mesh.vertices[used]).query(points)[1]]
    vertex = {k: np.asarray(v)[nearest] for k, v in mesh.vertex_scalars.items()}
    face = {}
    if "object_id" in mesh.face_scalars:
        # object ids are constant on a component, so any input face at a nearby vertex will do
        vertex_face = np.zeros(mesh.n_vertices, dtype=np.int64)
        vertex_face[mesh.faces.ravel()] = np.repeat(np.arange(mesh.n_faces), 3)
        face["object_id"] = np.asarray(mesh.face_scalars["object_id"])[vertex_face[nearest[faces[:, 0]]]]
    return TriMesh(points, faces, vertex, face)
