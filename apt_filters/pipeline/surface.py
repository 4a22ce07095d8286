"""Iso-surfaces as the pipeline draws them, also for pymeshlab scripts.

:func:`contour_surface` turns voxelized fields into the raw iso-surface of one species (or
of the atomic density); :func:`add_iso_surface` runs voxelize -> contour -> clean chain ->
CVT remesh on ions and adds the result to a ``pymeshlab.MeshSet``, the way a MeshLab user's
script would call one step.
"""

from __future__ import annotations

import os

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.io import IonTable, RangeTable


def field_values(fields, species: str, iso: float, basis=None) -> np.ndarray:
    """Dense (nx, ny, nz) field to contour: the concentration of ``species`` (a fraction; in ``basis``, default
    the voxelization's) or, for ``species == ""``, the atomic density (atoms/nm³); refused when ``iso`` is
    outside its range."""
    field = fields.concentration(species, basis) if species else fields.density()
    values = field.dense()
    finite = values[np.isfinite(values)]
    if not len(finite) or not finite.min() < iso < finite.max():
        lo, hi = (finite.min(), finite.max()) if len(finite) else (np.nan, np.nan)
        what = f"{species} concentration" if species else "atomic density"
        raise AptFiltersError(f"iso-value {iso:g} is outside the {what} range {lo:.4g}..{hi:.4g}: no surface")
    return values


def contour_surface(fields, mask: np.ndarray, species: str, iso: float, method: str = "dc",
                    close: bool = False, basis=None) -> TriMesh:
    """The iso-surface of ``species`` at ``iso`` (its concentration in ``basis``, default the voxelization's)
    by dual contouring (``"dc"``) or marching cubes (``"mc"``), open where it meets the specimen edge
    (``mask`` False) unless ``close``."""
    from apt_filters.contour import dual_contouring, marching_cubes

    values = field_values(fields, species, iso, basis)
    contour = dual_contouring if method == "dc" else marching_cubes
    mesh = contour(values, iso, spacing=fields.grid.voxel, origin=fields.grid.origin, mask=mask, close=close)
    if mesh.n_faces == 0:
        raise AptFiltersError(f"the {species or 'density'} iso-surface at {iso:g} has no triangles inside the specimen")
    return mesh


def add_iso_surface(ms, ions: IonTable, ranges: RangeTable, species: str, iso: float, *, voxel: float = 1.0,
                    kernel: str = "gaussian", delocalization=(3.0, 3.0, 1.5), method: str = "dc",
                    edge_length: float | None = None, clean_script: str | os.PathLike | None = None,
                    label: str | None = None) -> TriMesh:
    """Add the cleaned, remeshed iso-surface of ``species`` at ``iso`` to the MeshSet ``ms``.

    Parameters
    ----------
    ms : pymeshlab.MeshSet
        Receives the surface as a new current mesh (vertex quality = the field value).
    ions, ranges : IonTable, RangeTable
    species : str
        Element whose concentration is contoured (``""``: atomic density, atoms/nm³).
    iso : float
        Fraction (or atoms/nm³).
    voxel, kernel, delocalization, method
        As for ``apt-filters run`` (nm; 3 sigma per axis).
    edge_length : float, optional
        CVT target edge in nm (default half a voxel); 0 skips remeshing.
    clean_script : path, optional
        Where the clean chain's ``.mlx`` is saved.
    label : str, optional
        Mesh label in the MeshSet (default e.g. ``"Al 15 at.%"``).

    Returns
    -------
    TriMesh
        The surface as added.
    """
    from apt_filters.meshlab.bridge import to_meshset
    from apt_filters.meshlab.chains import apply_chain
    from apt_filters.remesh import remesh
    from apt_filters.voxel import inside_mask, voxelize

    fields = voxelize(ions, ranges, kernel=kernel, delocalization=delocalization, voxel=voxel)
    mesh = contour_surface(fields, inside_mask(fields).dense(), species, iso, method)
    mesh, _ = apply_chain(mesh, "clean", script=clean_script, overwrite=True)
    edge = voxel / 2 if edge_length is None else edge_length
    if edge > 0:
        mesh = remesh(mesh, edge_length=edge).mesh
    to_meshset(mesh, label or (f"{species} {100 * iso:g} at.%" if species else f"density {iso:g}"), meshset=ms)
    return mesh
