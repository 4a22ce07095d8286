"""Plateau compositions of each object, and the per-object iso-value (midpoint of its plateaus)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh, topology, vertex_normals
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.band import Band, NearIons
from apt_filters.refine.composition import IonAtoms
from apt_filters.voxel import ConcentrationBasis

PLATEAU_WINDOW = (0.75, 3.0)
"""Default distances (nm) from the surface between which the plateaus are measured, each side.

Against a refined surface the inside plateau from 0.75 nm is biased by the surface's own noise (+0.6 at.%
Al with the refinement's own ions, +0.0 with an independent specimen's, gamma-prime seeds 1-5), but from
1.0 nm (the refinement's :data:`~apt_filters.refine.surface.REFINE_WINDOW`) a 3 nm sphere keeps ~30 % fewer
atoms inside and the reported plateau came out worse (seeds 1-3, worst / mean abs: 1.72 / 1.04 ->
2.33 / 1.40 at.%; on the TRUE surfaces 1.55 / 0.75 -> 2.73 / 1.09 at.%), so reporting keeps 0.75 nm."""

PLATEAU_PRIOR = 3000.0
"""Default weight (atoms) of the pooled plateaus of all objects in each object's own (shrinkage)."""


@dataclass
class ObjectLevels:
    """The two plateaus of one connected surface (one object), in the concentration basis.

    Attributes
    ----------
    component : int
        Component id (``face_scalars["component"]`` numbering of :meth:`TriMesh.face_components`).
    elements : list of str
        Basis elements.
    inside, outside : (k,) float64
        Fractions of each basis element between ``window`` nm inside / outside the surface
        (shrunk toward the pooled levels of all objects by ``prior`` atoms).
    n_inside, n_outside : float
        Basis atoms of this object counted in each plateau window.
    iso : float
        Midpoint of the iso species' two plateaus: where this object's surface belongs.
    """

    component: int
    elements: list[str]
    inside: np.ndarray
    outside: np.ndarray
    n_inside: float
    n_outside: float
    iso: float

    def as_dict(self) -> dict:
        return {"component": self.component, "iso": self.iso, "n_inside": self.n_inside, "n_outside": self.n_outside,
                "inside": dict(zip(self.elements, self.inside.tolist())),
                "outside": dict(zip(self.elements, self.outside.tolist()))}


def within_rim(band: Band, near: NearIons, mesh: TriMesh, reach: float) -> Band:
    """The ions of ``band`` whose closest point on ``mesh`` is not on its rim.

    An open surface (an interface that leaves the specimen, an object cut by its edge) has ions beyond its
    rim: their nearest vertex is a rim vertex and their offset along its normal says nothing about which
    side of the interface they are on, yet counted they enter a plateau window or the excess band as if
    across the surface (a spinodal's Si excess +14 % and its inside plateau 14 sigma low on the whole box).
    They are the ions whose exact closest surface point lies on a boundary edge or vertex
    (:attr:`~apt_filters.core.distance.SignedDistance.on_boundary`, as the proxigram leaves them out); a
    closed mesh keeps every ion.

    Parameters
    ----------
    band : Band
        Ions of ``near`` within ``reach`` of their nearest vertex of ``mesh``.
    near : NearIons
    mesh : TriMesh
        The surface ``band`` was measured against.
    reach : float, nm
    """
    if not len(mesh.boundary_edges()) or not len(band.index):
        return band
    rim = SurfaceDistance(mesh, reach=reach).query(near.positions[band.index], max_distance=reach).on_boundary
    return Band(band.index[~rim], band.vertex[~rim], band.distance[~rim])


def plateau_sums(band: Band, atoms: IonAtoms, components: np.ndarray, n_components: int,
                 window=PLATEAU_WINDOW) -> np.ndarray:
    """(n_components, 2, k) atoms of each basis element in each object's inside (0) and outside (1) window.

    Sums, so that the windows of separate ion sets (e.g. the two halves of :func:`refine_surface`'s
    cross-fit) add up before :func:`levels_from_sums`.

    An object with no ion ``window[0]`` deep (a rod or plate thinner than the delocalization, or a first contour
    that is a sliver of one) is measured from halfway to its deepest ion instead (:func:`inside_inner`).
    """
    inner, outer = window
    comp = components[band.vertex]
    a = atoms.atoms[band.index].astype(np.float64)
    window_of = np.full(len(comp), -1)  # 0: inside plateau window, 1: outside
    starts = inside_inner(band, comp, n_components, inner)
    window_of[(band.distance <= -starts[np.maximum(comp, 0)]) & (band.distance >= -outer)] = 0
    window_of[(band.distance >= inner) & (band.distance <= outer)] = 1
    use = (window_of >= 0) & (comp >= 0)
    key = 2 * comp[use] + window_of[use]
    per = np.stack([np.bincount(key, weights=a[use, e], minlength=2 * n_components) for e in range(a.shape[1])],
                   axis=1) if a.shape[1] else np.zeros((2 * n_components, 0))
    return per.reshape(n_components, 2, a.shape[1])


def inside_inner(band: Band, comp: np.ndarray, n_components: int, inner: float) -> np.ndarray:
    """(n_components,) nm: where each object's inside plateau window starts: ``inner``, or half its ``depth`` where
    no ion of it lies ``inner`` deep (``depth``: the largest distance inside its surface of the band's ions
    assigned to it; ``comp``: each ion's object, -1 none).

    An object whose half-thickness is under ``inner`` (a rod or plate thinner than the delocalization, or a first
    contour that is a sliver of one) would have no inside plateau at all, and its surface could not be moved.
    Its deeper half is the part of it least mixed with its interface; once it is grown to where the ions put
    its interface, its ions reach ``inner`` again where it is that thick.
    """
    depth = np.zeros(n_components)
    inside = (band.distance < 0) & (comp >= 0)
    np.maximum.at(depth, comp[inside], -band.distance[inside])
    return np.where(depth > inner, inner, 0.5 * depth)


def levels_from_sums(sums: np.ndarray, elements: list[str], species: str,
                     prior: float = PLATEAU_PRIOR) -> list[ObjectLevels]:
    """Each object's plateaus from its window sums (:func:`plateau_sums`), shrunk toward the pooled ones."""
    k = elements.index(species)
    out = []
    pooled = [sums[:, side].sum(axis=0) for side in (0, 1)] if len(sums) else []
    for c in range(len(sums)):
        inside, outside = sums[c, 0], sums[c, 1]
        n_in, n_out = inside.sum(), outside.sum()
        if prior > 0:
            # shrink toward the pooled levels: a small object's own plateau is mostly noise
            inside = inside + prior * pooled[0] / max(pooled[0].sum(), 1e-300)
            outside = outside + prior * pooled[1] / max(pooled[1].sum(), 1e-300)
        c_in = inside / inside.sum() if inside.sum() > 0 else np.full(len(inside), np.nan)
        c_out = outside / outside.sum() if outside.sum() > 0 else np.full(len(outside), np.nan)
        out.append(ObjectLevels(c, list(elements), c_in, c_out, float(n_in), float(n_out),
                                float(0.5 * (c_in[k] + c_out[k]))))
    return out


def plateaus(band: Band, atoms: IonAtoms, components: np.ndarray, n_components: int, species: str,
             window=PLATEAU_WINDOW, prior: float = PLATEAU_PRIOR) -> list[ObjectLevels]:
    """Plateaus of every component from ions already in a band (see :func:`object_levels`)."""
    return levels_from_sums(plateau_sums(band, atoms, components, n_components, window), atoms.elements, species,
                            prior)


def object_levels(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str,
                  basis: ConcentrationBasis = ConcentrationBasis(), window=PLATEAU_WINDOW,
                  prior: float = PLATEAU_PRIOR) -> list[ObjectLevels]:
    """Inside and outside plateaus of every connected surface of ``mesh``, and its midpoint iso-value.

    Ions are assigned to their nearest vertex and measured along its normal; the inside plateau
    is every ion between ``window[0]`` and ``window[1]`` nm inside, the outside one likewise. Ions beyond
    the rim of an open surface are not counted (:func:`within_rim`).
    An object with no ion ``window[0]`` deep is measured from halfway to its deepest ion (:func:`inside_inner`).

    Parameters
    ----------
    mesh : TriMesh
        Iso-surface (normals out of the region above iso).
    ions : IonTable
    ranges : RangeTable
    species : str
        The iso-surface element.
    basis : ConcentrationBasis
        Denominator of the fractions (e.g. ``exclude=("B",)`` for a segregant).
    window : (inner, outer) nm
    prior : float
        Atoms' worth of the pooled plateaus of all objects added to each object's own counts
        (shrinkage, empirical-Bayes style). A 3 nm sphere has ~1000 atoms in its inside window:
        its own plateau is uncertain by ~1.3 at.%, which moves its midpoint and its surface; a
        large object (many more atoms than ``prior``) keeps its own plateau, so objects of
        different phases stay apart once they are big enough to tell. 0: objects' own values.

    Returns
    -------
    list of ObjectLevels, one per component.
    """
    components = topology(mesh.faces, mesh.n_vertices).vertex_components
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    near = NearIons.select(ions, ranges, basis, vertices, mesh.faces, window[1] + 1.0)
    band = within_rim(near.band(vertices, vertex_normals(vertices, mesh.faces), window[1] + 1.0), near, mesh,
                      window[1] + 1.0)
    return plateaus(band, near.atoms, components, int(components.max()) + 1, species, window, prior)


def per_object_iso(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str,
                   basis: ConcentrationBasis = ConcentrationBasis(), window=PLATEAU_WINDOW,
                   prior: float = PLATEAU_PRIOR) -> np.ndarray:
    """(n_components,) iso-value of each object: the midpoint of its own inside and outside plateaus.

    Contour each object again at its value (e.g. with :func:`apt_filters.refine.recontour`) so that
    objects of different compositions are cut at the same relative height of their interfaces.
    """
    return np.array([lv.iso for lv in object_levels(mesh, ions, ranges, species, basis, window, prior)])
