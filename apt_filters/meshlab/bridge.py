"""TriMesh <-> pymeshlab ``Mesh`` / ``MeshSet``, keeping per-vertex and per-face values.

Layout in MeshLab terms (what the GUI shows):

- one vertex scalar (by default ``"value"``, the interpolated field) becomes the *vertex
  quality*, so MeshLab's quality colour map and histogram work at once;
- every other vertex scalar becomes a custom per-vertex scalar attribute of the same name;
- the face scalar ``"object_id"`` (if present) becomes the *face quality*; every face scalar
  is also kept as a custom per-face attribute (float64 in MeshLab, cast back on return);
- vertex scalars named ``red``, ``green``, ``blue`` (and optionally ``alpha``), in [0, 1],
  are the vertex colour (MeshLab keeps 8 bits per channel).

pymeshlab offers no way to list custom attributes, so :class:`AttributeNames` records what
was put in and is handed back to :func:`from_pymeshlab`. Memory: one copy of the arrays
(pymeshlab copies on construction and on read-out).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pymeshlab

from apt_filters.core.atomic import atomic_output
from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.mesh import TriMesh

COLOR_KEYS = ("red", "green", "blue", "alpha")
"""Vertex scalars that together are the vertex colour (floats in [0, 1])."""

OBJECT_ID = "object_id"


@dataclass(frozen=True)
class AttributeNames:
    """Which TriMesh scalars went where in a pymeshlab mesh.

    Attributes
    ----------
    quality : str or None
        Vertex scalar stored as MeshLab vertex quality.
    vertex : tuple of (name, dtype str)
        Vertex scalars stored as custom attributes (colour channels excluded).
    face : tuple of (name, dtype str)
        Face scalars stored as custom attributes.
    colors : tuple of str
        Colour channels present (subset of :data:`COLOR_KEYS`, in that order).
    """

    quality: str | None
    vertex: tuple[tuple[str, str], ...]
    face: tuple[tuple[str, str], ...]
    colors: tuple[str, ...]

    @classmethod
    def of(cls, mesh: TriMesh, quality: str | None = "value") -> "AttributeNames":
        """Layout for ``mesh``; ``quality`` falls back to the first non-colour vertex scalar."""
        scalars = {k: v for k, v in mesh.vertex_scalars.items() if k not in COLOR_KEYS}
        if quality not in scalars:
            quality = next(iter(scalars), None)
        colors = tuple(k for k in COLOR_KEYS if k in mesh.vertex_scalars)
        if colors and colors[:3] != COLOR_KEYS[:3]:
            raise ValueError(f"vertex colour needs red, green and blue scalars, got {colors}")
        return cls(
            quality=quality,
            vertex=tuple((k, np.asarray(v).dtype.str) for k, v in scalars.items() if k != quality),
            face=tuple((k, np.asarray(v).dtype.str) for k, v in mesh.face_scalars.items()),
            colors=colors,
        )


def _color_matrix(mesh: TriMesh, colors: tuple[str, ...]) -> np.ndarray:
    rgba = np.ones((mesh.n_vertices, 4))
    for i, key in enumerate(colors):
        rgba[:, i] = mesh.vertex_scalars[key]
    return np.clip(rgba, 0.0, 1.0)


def to_pymeshlab(mesh: TriMesh, quality: str | None = "value") -> tuple[pymeshlab.Mesh, AttributeNames]:
    """Convert a :class:`TriMesh` to a ``pymeshlab.Mesh``.

    Parameters
    ----------
    mesh : TriMesh
        Vertices (n, 3) nm, faces (m, 3), named scalars.
    quality : str or None
        Vertex scalar to store as vertex quality (see :meth:`AttributeNames.of`).

    Returns
    -------
    pymeshlab.Mesh, AttributeNames
        The mesh and the layout to pass back to :func:`from_pymeshlab`.
    """
    names = AttributeNames.of(mesh, quality)
    kwargs: dict[str, np.ndarray] = {}
    if names.quality is not None:
        kwargs["v_scalar_array"] = np.asarray(mesh.vertex_scalars[names.quality], dtype=np.float64)
    if OBJECT_ID in mesh.face_scalars:
        kwargs["f_scalar_array"] = np.asarray(mesh.face_scalars[OBJECT_ID], dtype=np.float64)
    if names.colors:
        kwargs["v_color_matrix"] = _color_matrix(mesh, names.colors)
    m = pymeshlab.Mesh(mesh.vertices, mesh.faces.astype(np.int32), **kwargs)
    for name, _ in names.vertex:
        m.add_vertex_custom_scalar_attribute(np.asarray(mesh.vertex_scalars[name], dtype=np.float64), name)
    for name, _ in names.face:
        m.add_face_custom_scalar_attribute(np.asarray(mesh.face_scalars[name], dtype=np.float64), name)
    return m, names


def to_meshset(mesh: TriMesh, label: str = "iso-surface", quality: str | None = "value",
               meshset: pymeshlab.MeshSet | None = None) -> tuple[pymeshlab.MeshSet, AttributeNames]:
    """Add ``mesh`` to ``meshset`` (a new one by default) as the current mesh.

    The MeshSet's filter script is cleared only when a new MeshSet is made; adding a mesh
    records no filter, so a chain applied next records exactly its own filters.
    """
    m, names = to_pymeshlab(mesh, quality)
    ms = pymeshlab.MeshSet() if meshset is None else meshset
    ms.add_mesh(m, label)
    return ms, names


def from_pymeshlab(m: pymeshlab.Mesh | pymeshlab.MeshSet, names: AttributeNames | None = None) -> TriMesh:
    """Convert a ``pymeshlab.Mesh`` (or a MeshSet's current mesh) back to a :class:`TriMesh`.

    Parameters
    ----------
    m : pymeshlab.Mesh or pymeshlab.MeshSet
    names : AttributeNames, optional
        Layout from :func:`to_pymeshlab`. Without it, vertex quality comes back as
        ``"value"``, face quality as ``"object_id"`` (int64) and vertex colour as
        ``red``/``green``/``blue``/``alpha``; custom attributes cannot be discovered.
    """
    if isinstance(m, pymeshlab.MeshSet):
        m = m.current_mesh()
    if not m.is_compact():
        m.compact()
    vertex: dict[str, np.ndarray] = {}
    face: dict[str, np.ndarray] = {}
    if names is None:
        if m.has_vertex_scalar():
            vertex["value"] = m.vertex_scalar_array().copy()
        if m.has_face_scalar():
            face[OBJECT_ID] = np.rint(m.face_scalar_array()).astype(np.int64)
        colors = COLOR_KEYS if m.has_vertex_color() else ()
    else:
        if names.quality is not None:
            vertex[names.quality] = m.vertex_scalar_array().copy()
        for name, dtype in names.vertex:
            vertex[name] = _cast(m.vertex_custom_scalar_attribute_array(name), dtype)
        for name, dtype in names.face:
            face[name] = _cast(m.face_custom_scalar_attribute_array(name), dtype)
        colors = names.colors
    if colors:
        rgba = m.vertex_color_matrix()
        for i, key in enumerate(colors):
            vertex[key] = rgba[:, i].copy()
    return TriMesh(m.vertex_matrix().copy(), m.face_matrix().astype(np.int64), vertex, face)


def _cast(values: np.ndarray, dtype: str) -> np.ndarray:
    dt = np.dtype(dtype)
    return np.rint(values).astype(dt) if dt.kind in "iub" else values.astype(dt)


def save_current_mesh(ms: pymeshlab.MeshSet, path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Save ``ms``'s current mesh atomically, in the format of ``path``'s extension."""
    with atomic_output(path, overwrite) as tmp:
        try:
            ms.save_current_mesh(str(tmp))
        except pymeshlab.PyMeshLabException as exc:
            raise AptFiltersError(f"cannot write mesh: {exc}", path) from exc
    return Path(path)


def load_mesh(path: str | os.PathLike) -> pymeshlab.MeshSet:
    """A new MeshSet holding the mesh file ``path`` (any format pymeshlab reads)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("mesh file not found", path)
    ms = pymeshlab.MeshSet()
    cwd = os.getcwd()
    try:
        ms.load_new_mesh(str(path))
    except pymeshlab.PyMeshLabException as exc:
        raise InputError(f"cannot read mesh: {exc}", path) from None
    finally:
        # pymeshlab leaves the process inside the file's folder when a load fails.
        os.chdir(cwd)
    ms.clear_filter_script()
    return ms


def read_mesh(path: str | os.PathLike) -> TriMesh:
    """Read a triangle mesh file (PLY, OBJ, STL, OFF, anything MeshLab reads) as a :class:`TriMesh`.

    Vertex quality comes back as the vertex scalar ``"value"`` and face quality as
    ``"object_id"`` (see :func:`from_pymeshlab`); winding is kept as in the file.
    """
    ms = load_mesh(path)  # held here: a Mesh is a view into its MeshSet
    mesh = from_pymeshlab(ms.current_mesh())
    if mesh.n_faces == 0:
        raise InputError("no triangles could be read from the mesh", path)
    if not np.all(np.isfinite(mesh.vertices)):
        raise InputError("mesh has non-finite vertex coordinates", path)
    return mesh
