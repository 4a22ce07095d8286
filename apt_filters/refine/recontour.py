"""Contouring each object again at its own iso-value (the midpoint of its own plateaus)."""

from __future__ import annotations

import numpy as np

from apt_filters.contour import marching_cubes
from apt_filters.core.mesh import TriMesh, merge

MARGIN = 3
"""Voxels added around each object's bounding box for its own contour."""


def recontour(values: np.ndarray, isos: np.ndarray, mesh: TriMesh, spacing: float, origin, mask=None) -> TriMesh:
    """Marching cubes of each component of ``mesh`` again, at ``isos[component]``, in a box around it.

    Parameters
    ----------
    values : (nx, ny, nz) array
        The field ``mesh`` was contoured from (x, y, z order, NaN outside).
    isos : (n_components,) array
        One iso-value per component (:func:`~apt_filters.refine.levels.per_object_iso`); NaN keeps
        the component as it is.
    mesh : TriMesh
        Components labelled as :meth:`TriMesh.face_components` does.
    spacing : float, nm
    origin : (3,) nm
    mask : (nx, ny, nz) bool, optional

    Returns
    -------
    TriMesh
        The largest component of each object's new contour (whatever else its box holds, such
        as a neighbour or a speck, is left out), or the old component where the new contour is empty.
    """
    labels = mesh.face_components()
    origin = np.asarray(origin, dtype=np.float64)
    shape = np.array(values.shape)
    parts = []
    for c in range(int(labels.max()) + 1 if len(labels) else 0):
        faces = mesh.faces[labels == c]
        old = TriMesh(mesh.vertices, faces)
        if not np.isfinite(isos[c]):
            parts.append(old)
            continue
        pts = mesh.vertices[np.unique(faces)]
        lo = np.maximum(np.floor((pts.min(axis=0) - origin) / spacing).astype(int) - MARGIN, 0)
        hi = np.minimum(np.ceil((pts.max(axis=0) - origin) / spacing).astype(int) + MARGIN + 1, shape)
        box = tuple(slice(a, b) for a, b in zip(lo, hi))
        new = marching_cubes(values[box], float(isos[c]), spacing=spacing, origin=origin + lo * spacing,
                             mask=None if mask is None else mask[box])
        if new.n_faces == 0:
            parts.append(old)
            continue
        lab = new.face_scalars["component"]
        areas = np.bincount(lab, weights=new.face_areas())
        parts.append(TriMesh(new.vertices, new.faces[lab == int(np.argmax(areas))]))
    return merge(parts)

