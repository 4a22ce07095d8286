"""Holes the specimen-edge clip cuts in closed objects: closed again where the ions say the object stops short.

Contouring leaves a surface open where its cells touch a voxel outside the specimen (``mask``,
:mod:`apt_filters.voxel.mask`), so that an object cut by the specimen's side keeps its rim and the refinement
treats it as an open surface (its rim held, low-passed at the length held-out ions choose). The mask's boundary
lies about a voxel inside the side, and near the side the delocalization kernel averages ions from one side
only, weighted toward the object: the first contour of a closed object whose surface comes within ~1.5 nm of
the side bulges toward it and reaches the mask there. The cells it would cross there emit nothing, and the
object enters the refinement with a hole, is refined as an open sheet and reported open (zoo sphere 10149:
a sphere of radius 1.96 nm 1.2 nm from the side, holed by a 4-vertex loop, placed at V -19.8 % and low-passed as
an open surface to -34.2 %; one of radius 4.28 nm 1.1 nm from the side holed likewise). Closed again, the
first ends at V -11.1 % (sigma 8.9; was -28.8 %).

The ions between a hole and the specimen's side tell the two apart. Of each hole's ions *beyond* it -- those
within its footprint (laterally within its radius plus :data:`LATERAL` of its centroid) and :data:`BEYOND` nm past
its plane along the outward normal of the cap that would close it (wound like the faces around it: out of the
region above the iso-value) -- the outer half (:data:`OUTER`), the layer at the side, holds the object's inside
phase where the object meets the side, and the matrix between its surface and the side where it stops short of
it. An object every hole of which holds the iso species below the iso-value there (with at least
:data:`MIN_ATOMS` atoms) is closed, each hole by a fan from its centroid (:func:`close_clipped`); the refinement
then places the caps with the rest of the object.

A hole is a boundary loop whose cap faces the specimen's outside: a grid point one or two voxels beyond its
centroid along the cap's normal lies outside the mask (the mask's boundary is the bulk count's threshold, not a
plane: zoo sphere 36106's hole 0.9 nm from the side had the grid point a voxel beyond it inside), the one a voxel
before it inside. An object with any other rim keeps all of them: the rim of a sheet across the specimen (an open
or curved interface) runs along the edge, but its centroid lies deep inside; the mouth of a tube of the phase
*below* the iso-value that leaves through the side (a bicontinuous structure) is a loop at the edge too, but its
cap faces back into the specimen.

Limitations: the test reads composition, not significance; at a contrast of a few points a small hole's ions
beyond can read either side of the iso-value by noise (a closed object then stays open, as before). An object
cut by the side over a cap shallower than half the layer beyond its hole reads as closed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.mesh import TriMesh, topology
from apt_filters.core.nearby import CHUNK
from apt_filters.io import IonTable, RangeTable
from apt_filters.refine.composition import ion_atoms
from apt_filters.remesh.repair import boundary_loops
from apt_filters.voxel import ConcentrationBasis, Grid

BEYOND = 2.0
"""nm past a hole's plane within which its ions beyond are taken: the hole lies on the mask's boundary, within about
a voxel (1 nm) of the side, so the layer the clip removed lies within it."""

OUTER = 0.5
"""Share of the ions beyond a hole that are read: the outer ones (farthest past its plane), the layer at the side. A
closed object's own surface lies within ~0.3 nm past the hole (the first contour's bulge toward the side: 0.21 nm on
zoo sphere 10149), the side 0.5-1.5 nm past it; all of them read the object's interface too (zoo sphere 10149's
obj 2: 0.114 within 1.5 nm against an iso-value of 0.120, the outer half 0.094, the matrix 0.093)."""

LATERAL = 0.5
"""nm beyond a loop's radius that its footprint reaches (a hole of one cell holds ~0.6 nm); wider where the data are
sparse (:func:`_least_reach`)."""

MIN_ATOMS = 20
"""Atoms (of the basis) in a hole's outer layer below which it keeps its rim (nothing past it: the specimen's side)."""


@dataclass
class Clipped:
    """What :func:`close_clipped` did.

    Attributes
    ----------
    loops : int
        Boundary loops tested: holes facing the specimen's outside, of objects with no other rim.
    closed : int
        Loops closed (the ions beyond every hole of their object below the iso-value).
    objects : int
        Objects (components) closed.
    fractions : list of float
        Each tested loop's iso-species fraction in its outer layer beyond (NaN: fewer than :data:`MIN_ATOMS` atoms).
    """

    loops: int = 0
    closed: int = 0
    objects: int = 0
    fractions: list = field(default_factory=list)

    def describe(self) -> str:
        """One line for the run's log."""
        if not self.loops:
            return "no closed object holed at the specimen side"
        return f"{self.objects} object(s) short of the specimen side closed ({self.closed} of {self.loops} holes)"


def close_clipped(mesh: TriMesh, *, mask: np.ndarray, grid: Grid, ions: IonTable, ranges: RangeTable, species: str,
                  iso: float, basis: ConcentrationBasis = ConcentrationBasis()) -> tuple[TriMesh, Clipped]:
    """Close the holes of each object of ``mesh`` whose rims are all holes the specimen mask cut short of the side,
    the ions beyond each holding ``species`` below ``iso`` (module docstring).

    Parameters
    ----------
    mesh : TriMesh
        The contour (normals out of the region above ``iso``), open where it met the specimen mask.
    mask : (nx, ny, nz) bool
        Inside the specimen (:func:`apt_filters.voxel.inside_mask`), on ``grid``.
    grid : voxel.Grid
    ions, ranges : IonTable, RangeTable
        The ions (read ``CHUNK`` rows at a time: a memory map is streamed once).
    species : str
    iso : float
        Fraction of ``species`` in ``basis`` (the contour's iso-value).
    basis : ConcentrationBasis
        The contour's concentration basis.

    Returns
    -------
    TriMesh, Clipped
        ``mesh`` with one vertex (at the hole's centroid) and a fan of faces added per closed hole, the scalars
        carried over; ``mesh`` itself where none is closed.
    """
    report = Clipped()
    # the cached topology the refinement reads next: a closed mesh (most runs) costs no table of its own here
    top = topology(mesh.faces, mesh.n_vertices) if mesh.n_faces else None
    if top is None or not len(top.boundary_half_edges):
        return mesh, report
    loops = [np.asarray(loop) for loop in boundary_loops(mesh.faces)]
    half = {tuple(e) for e in top.boundary_half_edges.tolist()}
    component = top.vertex_components
    vertices = mesh.vertices.astype(np.float64)
    frames, hole = [], []
    least = _least_reach(len(ions), float(mask.sum()) * grid.voxel ** 3)
    for loop in loops:
        centre = vertices[loop].mean(axis=0)
        # the cap's normal: its vector area, the loop run backward (the faces hold it forward, a -> b)
        n = -0.5 * np.cross(vertices[loop] - centre, vertices[np.roll(loop, -1)] - centre).sum(axis=0)
        n /= max(np.linalg.norm(n), 1e-12)
        rel = vertices[loop] - centre
        radius = np.linalg.norm(rel - np.outer(rel @ n, n), axis=1).max()
        frames.append((centre, n, max(radius + LATERAL, least)))
        # a vertex with two rims (a pinch) can break a walk: only loops that close on their own are holes
        hole.append(len(loop) >= 3 and (int(loop[-1]), int(loop[0])) in half
                    and any(_outside(centre + step * grid.voxel * n, mask, grid) for step in (1, 2))
                    and not _outside(centre - grid.voxel * n, mask, grid))
    # an object is closed again only where every loop of it is such a hole
    rimmed = {component[loop[0]] for loop, h in zip(loops, hole) if not h}
    keep = [k for k in range(len(loops)) if hole[k] and component[loops[k][0]] not in rimmed]
    loops, frames = [loops[k] for k in keep], [frames[k] for k in keep]
    report.loops = len(loops)
    if not loops:
        return mesh, report
    beyond = [[] for _ in loops]  # per loop: (height, atoms of species, atoms in the basis) of its ions beyond
    for start in range(0, len(ions), CHUNK):
        chunk = ions.subset(slice(start, start + CHUNK))
        positions = np.asarray(chunk.positions, dtype=np.float64)
        atoms = None
        for k, (centre, n, reach) in enumerate(frames):
            rel = positions - centre
            height = rel @ n
            near = (height > 0) & (height < BEYOND)
            near[near] = np.einsum("ij,ij->i", rel[near], rel[near]) - height[near] ** 2 < reach ** 2
            if not near.any():
                continue
            atoms = ion_atoms(chunk, ranges, basis) if atoms is None else atoms
            a = atoms.atoms[near]
            beyond[k].append(np.column_stack([height[near], a[:, atoms.elements.index(species)], a.sum(axis=1)]))
    counts = np.zeros((len(loops), 2))  # per loop, its outer layer's atoms of species and in the basis
    for k, parts in enumerate(beyond):
        if parts:
            h, own, total = np.vstack(parts).T
            outer = h >= np.quantile(h, 1 - OUTER)
            counts[k] = own[outer].sum(), total[outer].sum()
    fraction = counts[:, 0] / np.maximum(counts[:, 1], 1e-12)
    tested = counts[:, 1] >= MIN_ATOMS
    report.fractions = np.where(tested, fraction, np.nan).tolist()
    owner = np.array([component[loop[0]] for loop in loops])
    short = tested & (fraction < iso)
    shut = np.flatnonzero([short[owner == c].all() for c in owner])  # every hole of its object short of the side
    report.closed, report.objects = len(shut), len(np.unique(owner[shut]))
    if not len(shut):
        return mesh, report
    faces, first = [mesh.faces], []
    for i, k in enumerate(shut):
        loop = loops[k]
        # the loop runs along the faces' boundary half-edges (a -> b); the cap holds each as b -> a
        faces.append(np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), len(vertices) + i)]))
        first.append(np.flatnonzero(np.isin(mesh.faces, loop).any(axis=1))[0])
    # the caps carry the scalars of the faces around them (component, ...) and the loop's mean vertex values
    repeat = np.repeat(first, [len(loops[k]) for k in shut])
    closed = TriMesh(np.vstack([vertices, [vertices[loops[k]].mean(axis=0) for k in shut]]), np.vstack(faces),
                     {name: np.concatenate([v, [v[loops[k]].mean() for k in shut]])
                      for name, v in mesh.vertex_scalars.items()},
                     {name: np.concatenate([v, v[repeat]]) for name, v in mesh.face_scalars.items()})
    return closed, report


def _least_reach(n_ions: int, volume: float) -> float:
    """nm: the footprint radius whose outer layer (:data:`OUTER` of :data:`BEYOND`) holds twice :data:`MIN_ATOMS`
    ions at the specimen's mean density (``n_ions`` in the mask's ``volume``, nm³), so that a hole short of the side
    has enough to be tested (at 2 * MIN_ATOMS expected, fewer than MIN_ATOMS by chance 5e-4 of the time). A one-cell
    hole's footprint of ~1.1 nm holds that down to ~10 ions per nm³; zoo artefact 10186 (6.8 per nm³, efficiency
    0.46) held fewer than MIN_ATOMS beyond a 3-vertex hole 2 nm inside the side of its 37 nm³ object, which kept its
    rim and was refined as an open surface. Past the side there are no ions however wide the footprint."""
    density = n_ions / max(volume, 1e-12)
    return float(np.sqrt(2 * MIN_ATOMS / (np.pi * BEYOND * OUTER * max(density, 1e-12))))


def _outside(point: np.ndarray, mask: np.ndarray, grid: Grid) -> bool:
    """Whether the grid point nearest ``point`` lies outside ``mask`` (or off the grid)."""
    index = np.rint((point - np.asarray(grid.origin)) / grid.voxel).astype(np.int64)
    if (index < 0).any() or (index >= np.array(mask.shape)).any():
        return True
    return not mask[tuple(index)]
