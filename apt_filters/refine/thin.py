"""Objects thinner than the delocalization: drawn one octave finer, where the first contour thins them.

The first contour is drawn on fields smoothed by the delocalization kernel (AP Suite's 3 x 3 x 1.5 nm, a
Gaussian of sigma 1 x 1 x 0.5 nm). An object thinner than the kernel is averaged with the matrix around it:
a rod of radius r keeps ``1 - exp(-r² / 2 sigma²)`` of its contrast on its axis (0.41 at r = 1 nm), so at the
user's iso-value its contour is a thin tube inside it, sub-voxel slivers along it, or nothing. The refinement
grows a thin start to where the ions put the interface, but a sliver of a long rod grows into a ball.

So the same ions are voxelized again on the same grid with the kernel halved (one octave of scale space:
sigma 0.5 x 0.5 x 0.25 nm, 0.88 of a 1 nm rod's contrast on its axis), contoured at the same iso-value, and
its components tested by the speck rule (:func:`~apt_filters.refine.specks.remove_specks` on the finer fields:
its null is drawn at the finer scale, so the finer field's larger noise makes no object). A closed, real finer
component replaces the first contour's components it holds where every one of them lies wholly inside it and
is thinned by the coarse scale: its thickness ``V / A`` is less than half the finer component's (between two
scales an octave apart an object resolved at both keeps its thickness; one the coarse scale does not resolve
loses more than the scale ratio, or breaks into slivers along a rod).

The finer speck test costs a finer voxelization and contour per null draw and the exact distances of the ions
near every finer component; it is drawn only where some finer component may replace a coarse one by the rule
above (:func:`_may_replace`: bounding boxes and thicknesses), so that a specimen whose objects are all resolved
pays for one finer voxelization and contour. Its family stays every finer component.

Everything else keeps the first contour: resolved objects (their coarse contour is smoother and as close), a
finer component holding a resolved one (at low contrast the finer field's noise joins objects), and a finer
component holding none: at an iso-value near an object's own plateau the finer field's noise draws
significant blobs inside thick objects (the ``small`` preset at 20 at.% Al, its objects' composition: three
blobs of 4-20 nm³ in a 6 nm cube and a 3 nm sphere), which nothing in the contours tells from a thin object
the coarse scale missed. Such objects are not found.

References
----------
Lindeberg, T. (1994). Scale-space theory: a basic tool for analyzing structures at different scales. J. Appl.
Statist. 21, 225-270.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from apt_filters.contour import marching_cubes
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh, merge, split_components
from apt_filters.io import IonTable, RangeTable
from apt_filters.refine.specks import ALPHA, Specks, remove_specks
from apt_filters.voxel import ConcentrationBasis, voxelize

OCTAVE = 0.5
"""Ratio of the finer kernel to the first contour's (one octave of scale space)."""
HELD = 0.5
"""Share of a coarse component's vertices that lie inside a finer component holding it: a majority, not all
(counting noise lets a sliver's rim poke out of the finer contour: dev disc 37213's two slivers of a 1.31 nm disc
at 10 points of contrast lay 90 and 96 % inside it)."""


@dataclass
class ThinObjects:
    """What :func:`add_thin_objects` did.

    Attributes
    ----------
    delocalization : (3,) nm
        The finer kernel's delocalization.
    replaced : list of (float, float)
        (coarse, finer) volumes (nm³) of the components each finer one replaced (the coarse ones summed).
    tested : Specks or None
        The speck test of the finer contour's components (None where no finer component may replace a coarse
        one: not drawn).
    specks : Specks or None
        The first contour's speck test with each output component's p-value and z (``Specks.kept``, for
        :meth:`Specks.of`); the input's where nothing changed.
    """

    delocalization: tuple[float, float, float]
    replaced: list[tuple[float, float]] = field(default_factory=list)
    tested: Specks | None = field(default=None, repr=False)
    specks: Specks | None = field(default=None, repr=False)

    def describe(self) -> str:
        """One line for the run's log."""
        finer = "x".join(f"{d:g}" for d in self.delocalization)
        if not self.replaced:
            return f"no object too thin for the delocalization (checked at {finer} nm)"
        return f"{len(self.replaced)} object(s) too thin for the delocalization drawn again at {finer} nm"

    def as_dict(self) -> dict:
        return {"delocalization_nm": list(self.delocalization), "replaced_nm3": [list(r) for r in self.replaced]}


def _thickness(part: TriMesh) -> float:
    """nm: volume over area (a sphere's radius / 3, a rod's radius / 2, a plate's half-thickness)."""
    area = part.area()
    return abs(part.signed_volume()) / area if area > 0 else 0.0


def _thinned(thickness: np.ndarray, volume: np.ndarray, part: TriMesh) -> np.ndarray:
    """Whether coarse components of ``thickness`` (nm, :func:`_thickness`) and ``volume`` (nm³) are thinned by the
    coarse scale against the finer component ``part`` holding them: thinner than :data:`OCTAVE` of it, or of less
    than ``OCTAVE³`` of its volume. A resolved object's contour moves by less than the scale ratio between the two
    scales along each axis, so its volume by less than its cube (a sphere of radius 2 nm under AP Suite's kernel:
    0.51 of the finer contour's); a sliver of a disc the coarse scale thins has a thickness of its own size, not the
    disc's (dev disc 37219: 3.1 nm³ of a 1.36 nm thick disc whose finer contour holds 109 nm³, V / A 0.229 against
    the finer 0.418), so only its volume shows it."""
    return (np.asarray(thickness) < OCTAVE * _thickness(part)) | (np.abs(volume) < OCTAVE ** 3 * part.signed_volume())


def _may_replace(finer: list[TriMesh], points: list[np.ndarray], thickness: list[float], volume: list[float]
                 ) -> np.ndarray:
    """(f,) bool: the ``finer`` components that may replace coarse ones by the rule of :func:`add_thin_objects`.

    A necessary condition from bounding boxes and thicknesses alone, no distances: the component is closed (one
    ending at the specimen edge has no volume to compare: the coarse scale decides) and holds a coarse component
    :func:`_thinned` by the coarse scale (its ``thickness``, nm, and ``volume``, nm³); where it encloses its inside
    (positive volume), the bounding box of its vertices (grown by 1e-3 nm: a vertex found inside by a rounded
    distance) holds more than :data:`HELD` of the coarse component's vertices ``points`` (a point inside a closed
    surface lies in the hull of its vertices); a hole's inside (negative volume) is everything around it, so there
    thicknesses alone decide.
    The finer speck test, which costs a finer voxelization and contour per null draw and the exact distances of
    the ions near every finer component, is drawn only where one may.
    """
    if not points:
        return np.zeros(len(finer), bool)
    out = np.zeros(len(finer), bool)
    for j, part in enumerate(finer):
        if len(part.boundary_edges()):
            continue
        own = part.vertices[np.unique(part.faces)]
        lo, hi = own.min(axis=0) - 1e-3, own.max(axis=0) + 1e-3
        boxed = (np.array([np.mean(np.all((q >= lo) & (q <= hi), axis=1)) > HELD for q in points])
                 if part.signed_volume() > 0 else np.ones(len(points), bool))
        out[j] = bool(np.any(boxed & _thinned(thickness, volume, part)))
    return out


def add_thin_objects(mesh: TriMesh, specks: Specks | None = None, *, fields, mask: np.ndarray, ions: IonTable,
                     ranges: RangeTable, species: str, iso: float, basis: ConcentrationBasis | None = None,
                     alpha: float = ALPHA) -> tuple[TriMesh, ThinObjects]:
    """``mesh`` with the objects its scale thins drawn one octave finer (see the module docstring).

    Parameters
    ----------
    mesh : TriMesh
        The first contour of ``species`` at ``iso`` on ``fields``, specks removed.
    specks : Specks, optional
        Its speck test (:func:`~apt_filters.refine.specks.remove_specks`), completed with the finer components'
        p-values and z in ``ThinObjects.specks``.
    fields : voxel.Fields
        Its voxelization (Gaussian kernel; any other kernel is returned unchanged: it has no scale to halve).
    mask : (nx, ny, nz) bool
        Inside the specimen.
    ions, ranges : IonTable, RangeTable
    species : str
    iso : float
        Iso-value (fraction).
    basis : ConcentrationBasis, optional
        The basis of ``mesh`` (default ``fields.basis``).
    alpha : float
        Family-wise error rate of the finer components' speck test.

    Returns
    -------
    TriMesh, ThinObjects
        The surface (components relabelled) and what was replaced.
    """
    basis = fields.basis if basis is None else basis
    finer = tuple(OCTAVE * float(d) for d in fields.delocalization)
    report = ThinObjects(finer, specks=specks)
    if fields.kernel != "gaussian" or mesh.n_faces == 0:  # no scale to halve; nothing to replace
        return mesh, report
    fine = voxelize(ions, ranges, grid=fields.grid, kernel=fields.kernel, delocalization=finer, species=fields.kind,
                    basis=fields.basis, efficiency=fields.efficiency)
    values = fine.concentration(species, basis).dense()
    finite = values[np.isfinite(values)]
    if not len(finite) or not finite.min() < iso < finite.max():
        return mesh, report
    contour = marching_cubes(values, iso, spacing=fields.grid.voxel, origin=fields.grid.origin, mask=mask)
    if contour.n_faces == 0:
        return mesh, report
    coarse = split_components(mesh)
    points = [c.vertices[np.unique(c.faces)] for c in coarse]  # each component's own vertices
    thickness, volume = np.array([_thickness(c) for c in coarse]), np.array([c.signed_volume() for c in coarse])
    may = _may_replace(split_components(contour), points, thickness, volume)
    if not may.any():  # no finer component can replace a coarse one whatever its test says: none is drawn
        return mesh, report
    real, report.tested = remove_specks(contour, fields=fine, mask=mask, ions=ions, ranges=ranges, species=species,
                                        iso=iso, basis=basis, alpha=alpha)
    finer_parts = split_components(real) if real.n_faces else []
    may = may[~(report.tested.p_values > alpha)]  # of the real ones (the test removes whole components, in order)
    dropped, extra = set(), []
    for j, part in enumerate(finer_parts):
        if not may[j]:  # fails the bounds' necessary condition; an open one ends at the specimen edge
            continue
        # a coarse component lies in this one where most of its vertices are inside it (negative distance); one it
        # touches with fewer is another object's, and this one replaces nothing
        sd = SurfaceDistance(part).query(np.vstack(points))
        share = [float(flags.mean()) for flags in np.split(sd.distance < 0, np.cumsum([len(q) for q in points])[:-1])]
        held = [k for k, inside in enumerate(share) if inside > 0]
        if held and all(share[k] > HELD for k in held) and _thinned(thickness[held], volume[held], part).all():
            dropped.update(held)
            extra.append(j)
            report.replaced.append((float(sum(coarse[k].signed_volume() for k in held)), float(part.signed_volume())))
    if not extra:
        return mesh, report
    kept = [k for k in range(len(coarse)) if k not in dropped]
    out = merge([coarse[k] for k in kept] + [finer_parts[j] for j in extra])
    if specks is not None and specks.kept is not None:  # each output component's test, at the scale it came from
        first = specks.kept
        report.specks = replace(specks, kept=(out, np.concatenate([first[1][kept], report.tested.kept[1][extra]]),
                                              np.concatenate([first[2][kept], report.tested.kept[2][extra]])))
    return out, report
