"""Per-object statistics of an iso-surface: each connected component is one object.

For every component: status (``closed``; ``open`` at the specimen edge; ``proxy`` = open,
capped at its boundary loops to estimate a volume), surface area, signed volume (tetrahedra
sum, positive for outward normals), equivalent-sphere radius, sphericity
pi^(1/3) (6V)^(2/3) / A, centroid, oriented-bounding-box extents and aspect ratios, Euler
characteristic and genus, ions inside by species and the element composition inside
(the sign of the exact signed distance to the closed object, :mod:`apt_filters.core.distance`:
negative inside), and the distance to the specimen edge. The table also gives the object number density in the
analysed volume; objects that enclose no ion (marching-cubes specks) are dropped.

Units: nm, nm², nm³; compositions as fractions (at.% only in reports).
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Protocol

import numpy as np
from numba import njit, prange
from scipy import ndimage

from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_write_text
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.hull import ION_CHUNK, SpecimenHull, native_points
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.io.summary import range_edges

CAP = "cap"
"""Face scalar flagging faces that close a hole (non-zero), as the meshlab ``close`` chain sets it:
components with such faces are proxies and their area leaves those faces out."""

COUNT_VOXEL = 0.5
"""Edge (nm) of the label grid that sorts ions into objects; only ions in voxels that a
triangle's bounding box touches are tested against the surface itself."""

MAX_LABEL_VOXELS = 50_000_000
"""Largest label grid (int32: 200 MB); a larger union of object boxes coarsens the voxels."""


# --- the specimen ---------------------------------------------------------------------------

class Specimen(Protocol):
    """The analysed volume: its size and the distance of points to its edge."""

    volume: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) distance in nm from each (n, 3) point to the edge, positive inside."""


@dataclass(frozen=True)
class SpecimenMask:
    """Voxel mask of the specimen: ``mask[i, j, k]`` covers the voxel centred at
    ``origin + (i, j, k) * spacing`` (x, y, z order)."""

    mask: np.ndarray
    origin: tuple[float, float, float]
    spacing: float
    _edt: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        padded = np.pad(np.asarray(self.mask, dtype=bool), 1)  # beyond the array is outside
        # distance from a voxel centre to the nearest outside centre, less half a voxel: to the edge
        edt = ndimage.distance_transform_edt(padded, sampling=self.spacing)[1:-1, 1:-1, 1:-1]
        object.__setattr__(self, "_edt", edt - 0.5 * self.spacing)

    @property
    def volume(self) -> float:
        return float(np.count_nonzero(self.mask)) * self.spacing ** 3

    def distance(self, points: np.ndarray) -> np.ndarray:
        index = (np.asarray(points, dtype=np.float64) - np.asarray(self.origin)) / self.spacing
        return ndimage.map_coordinates(self._edt, index.T, order=1, mode="nearest")


# --- topology -----------------------------------------------------------------------------

def cap_boundaries(mesh: TriMesh) -> tuple[TriMesh, np.ndarray]:
    """Close every boundary loop with a fan to the loop's vertex centroid.

    Returns the capped mesh (input faces first) and the (m_cap,) loop index of each cap
    face. Exact for planar loops (a flat specimen edge); otherwise a proxy.
    """
    half = mesh.topology.boundary_half_edges
    n_loops, loop = mesh.topology.boundary_pieces
    if n_loops == 0:
        return mesh, np.zeros(0, dtype=np.int64)
    sums = np.zeros((n_loops, 3))
    np.add.at(sums, loop, mesh.vertices[half[:, 0]])
    centres = sums / np.bincount(loop, minlength=n_loops)[:, None]
    # the cap runs each boundary edge backwards, so orientation stays coherent
    caps = np.column_stack([half[:, 1], half[:, 0], mesh.n_vertices + loop])
    return TriMesh(np.vstack([mesh.vertices, centres]), np.vstack([mesh.faces, caps])), loop


# --- the table ------------------------------------------------------------------------------

@dataclass
class ObjectStats:
    """One object (connected component). Lengths nm, areas nm², volumes nm³.

    ``volume``, ``equivalent_radius``, ``sphericity`` are NaN for ``open`` objects;
    ``area`` is the iso-surface only (caps excluded), sphericity uses the closed
    (capped) area of a proxy. ``obb_extents`` are sorted longest first; ``aspect_ratios``
    = (middle / longest, shortest / longest). ``genus`` = (2 - chi - boundary_loops) / 2.
    ``edge_distance`` is the smallest distance of the object's vertices to the specimen edge
    (about 0 for objects cut by it; NaN without a specimen). ``n_ions`` is -1 when no ions
    were given; ``ion_counts`` has an ``unranged`` entry; ``composition`` is by element,
    molecular ions split into their atoms. ``volume_se`` and ``area_se`` are the counting
    errors of volume and area, ``p_value`` and ``z`` the speck test's family-wise p-value and
    score (:func:`counting_errors`; NaN where not measured).
    """

    object_id: int
    status: str
    n_faces: int
    area: float
    volume: float
    equivalent_radius: float
    sphericity: float
    centroid: tuple[float, float, float]
    obb_extents: tuple[float, float, float]
    aspect_ratios: tuple[float, float]
    euler_characteristic: int
    boundary_loops: int
    genus: float
    edge_distance: float = math.nan
    n_ions: int = -1
    ion_counts: dict[str, int] = field(default_factory=dict)
    composition: dict[str, float] = field(default_factory=dict)
    volume_se: float = math.nan
    area_se: float = math.nan
    p_value: float = math.nan
    z: float = math.nan


@dataclass
class ObjectTable:
    """All objects with the analysed volume (nm³) and the number density (nm⁻³)."""

    objects: list[ObjectStats]
    analysed_volume: float
    n_dropped: int

    @property
    def number_density(self) -> float:
        return len(self.objects) / self.analysed_volume if self.analysed_volume > 0 else math.nan

    def rows(self) -> list[dict[str, object]]:
        """Flat rows for CSV: vectors split into x/y/z columns, counts and fractions per species."""
        species = list(dict.fromkeys(k for o in self.objects for k in o.ion_counts))
        elements = list(dict.fromkeys(k for o in self.objects for k in o.composition))
        out = []
        for o in self.objects:
            row: dict[str, object] = {k: v for k, v in asdict(o).items()
                                      if k not in ("centroid", "obb_extents", "aspect_ratios", "ion_counts",
                                                   "composition")}
            row.update(zip(("centroid_x", "centroid_y", "centroid_z"), o.centroid))
            row.update(zip(("obb_long", "obb_mid", "obb_short"), o.obb_extents))
            row.update(zip(("aspect_mid_long", "aspect_short_long"), o.aspect_ratios))
            row.update({f"n_{s}": o.ion_counts.get(s, 0) for s in species})
            row.update({f"frac_{e}": o.composition.get(e, math.nan) for e in elements})
            out.append(row)
        return out

    def write_csv(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        rows = self.rows()
        buf = io.StringIO()
        buf.write(f"# objects {len(self.objects)}; analysed volume {self.analysed_volume:.6g} nm^3; "
                  f"number density {self.number_density:.6g} nm^-3; dropped (no ion inside) {self.n_dropped}\n")
        if rows:
            writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
        return atomic_write_text(path, buf.getvalue(), overwrite)

    def write_json(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        data = {"analysed_volume_nm3": self.analysed_volume, "number_density_per_nm3": self.number_density,
                "n_dropped": self.n_dropped, "objects": [asdict(o) for o in self.objects]}
        return atomic_write_text(path, jsontext.dumps(data, indent=1) + "\n", overwrite)



def _obb(part: TriMesh, areas: np.ndarray) -> np.ndarray:
    """Extents (longest first) along the principal axes of the surface (uniform area density).

    The covariance is exact for the triangulated surface (second moment of each triangle,
    A/12 (a a' + b b' + c c' + s s') with s = a + b + c), so it does not depend on how the
    surface is triangulated; a shape with equal principal moments (a cube) has no unique axes.
    """
    ref = part.vertices.mean(axis=0)
    v = part.vertices[part.faces] - ref
    s = v.sum(axis=1)
    total = areas.sum()
    if total <= 0:
        return np.zeros(3)
    second = (np.einsum("f,fki,fkj->ij", areas, v, v) + np.einsum("f,fi,fj->ij", areas, s, s)) / 12.0
    mean = (areas @ s) / (3.0 * total)
    _, axes = np.linalg.eigh(second / total - np.outer(mean, mean))
    proj = (part.vertices - ref) @ axes
    return np.sort(np.ptp(proj, axis=0))[::-1]


class _Shape:
    """One closed object for the point-in-object test: its signed distance and its box."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.triangles = vertices[faces]
        corners = self.triangles.reshape(-1, 3)
        self.lower, self.upper = corners.min(axis=0), corners.max(axis=0)
        mesh = TriMesh(vertices, faces)
        self.surface = SurfaceDistance(mesh)
        # a cavity's surface faces into the cavity (out of the region above the iso-value): what it
        # encloses lies along its normals
        self.enclosed_sign = 1.0 if mesh.signed_volume() < 0 else -1.0

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points the closed surface encloses, by the sign of their exact signed distance
        (the angle-weighted pseudo-normal at the closest point: exact for a closed manifold). The
        search has no limit, so every point is decided; those asked lie near the surface."""
        if not len(points):
            return np.zeros(0, dtype=bool)
        return self.surface.query(np.asarray(points, dtype=np.float64)).distance * self.enclosed_sign > 0


MULTI = np.iinfo(np.int32).min
"""Label of voxels that belong to, or are crossed by, more than one object."""


@dataclass
class _LabelGrid:
    """Voxels over the union of the objects' boxes: ``k + 1`` wholly inside object ``k`` only,
    ``-(k + 1)`` crossed by object ``k``'s surface only, :data:`MULTI` more than one object,
    0 outside every object. Voxel ``(i, j, k)`` covers ``origin + [i, i + 1) * voxel`` (x, y, z).
    ``encloses[k]``: whether object ``k`` encloses a region (else it has no label)."""

    labels: np.ndarray
    origin: np.ndarray
    voxel: float
    encloses: list[bool] = field(default_factory=list)

    @classmethod
    def build(cls, shapes: list[_Shape], voxel: float = COUNT_VOXEL) -> "_LabelGrid":
        lower = np.min([s.lower for s in shapes], axis=0) - voxel
        upper = np.max([s.upper for s in shapes], axis=0) + voxel
        voxel = max(voxel, float(np.prod(upper - lower) / MAX_LABEL_VOXELS) ** (1 / 3))
        labels = np.zeros(tuple(np.floor((upper - lower) / voxel).astype(int) + 1), dtype=np.int32)
        grid = cls(labels, lower, voxel)
        grid.encloses = [grid._add(k, shape) for k, shape in enumerate(shapes)]
        return grid

    def _add(self, k: int, shape: _Shape) -> bool:
        """Label object ``k``'s voxels; False (and nothing labelled) where its surface encloses no region."""
        lo = self._cell(shape.lower - LABEL_MARGIN)
        hi = self._cell(shape.upper + LABEL_MARGIN) + 1
        region = self.labels[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        crossed = np.zeros(region.shape, dtype=bool)
        corner = self.origin + lo * self.voxel
        _mark_boxes(shape.triangles.min(axis=1) - corner, shape.triangles.max(axis=1) - corner,
                    1.0 / self.voxel, LABEL_MARGIN, crossed)
        # The surface crosses no voxel left unmarked, so each face-connected region of unmarked voxels lies
        # wholly inside or wholly outside: the signed distance of a few voxel centres spread over each region
        # decides it. Centres of one region that disagree, or a region on the box's outermost voxels (which
        # reach beyond the object's box) judged inside, mean that the surface changes sides where it is not
        # crossed: it encloses no region (a cap through a wavy sheet across the specimen).
        regions, n_regions = ndimage.label(~crossed)
        flat = regions.ravel()
        order = np.argsort(flat, kind="stable")
        size = np.bincount(flat, minlength=n_regions + 1)
        start = np.cumsum(size) - size
        picks = start[1:, None] + (np.arange(REGION_SAMPLES) * (size[1:, None] - 1)) // (REGION_SAMPLES - 1)
        cells = np.column_stack(np.unravel_index(order[picks.ravel()], region.shape))
        votes = shape.inside(corner + (cells + 0.5) * self.voxel).reshape(n_regions, REGION_SAMPLES)
        region_inside = np.concatenate([[False], votes[:, 0]])
        border = np.concatenate([regions[[0, -1]].ravel(), regions[:, [0, -1]].ravel(), regions[:, :, [0, -1]].ravel()])
        if np.any(votes != votes[:, :1]) or region_inside[border].any():
            return False
        inside = region_inside[regions]
        free = region == 0
        region[crossed & free] = -(k + 1)
        region[inside & free] = k + 1
        region[(crossed | inside) & ~free] = MULTI
        return True

    def _cell(self, points: np.ndarray) -> np.ndarray:
        return np.clip(np.floor((points - self.origin) / self.voxel).astype(int), 0, np.array(self.labels.shape) - 1)

    def touched(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: points in a voxel inside or crossed by an object (all the ions any object may hold)."""
        out = np.empty(len(points), dtype=bool)
        _touched(np.ascontiguousarray(points), self.origin, self.voxel, self.labels, out)
        return out


REGION_SAMPLES = 8
"""Voxel centres, spread over each region of voxels no surface crosses, whose signed distances must agree."""

LABEL_MARGIN = 1e-3
"""nm added around each triangle's box when marking crossed voxels: covers the rounding of
float32 ion coordinates (about 1e-4 nm at 1000 nm), so a voxel not marked holds no ion that
could lie on the other side of the surface."""


@njit(cache=True, nogil=True, parallel=True)
def _touched(points, origin, voxel, labels, out):  # pragma: no cover - compiled
    nx, ny, nz = labels.shape
    for n in prange(points.shape[0]):
        i = np.floor((np.float64(points[n, 0]) - origin[0]) / voxel)
        j = np.floor((np.float64(points[n, 1]) - origin[1]) / voxel)
        k = np.floor((np.float64(points[n, 2]) - origin[2]) / voxel)
        out[n] = (0 <= i < nx and 0 <= j < ny and 0 <= k < nz) and labels[int(i), int(j), int(k)] != 0


@njit(cache=True, nogil=True)
def _mark_boxes(lower, upper, inv, margin, crossed):  # pragma: no cover - compiled
    nx, ny, nz = crossed.shape
    for t in range(lower.shape[0]):
        i0 = max(int(np.floor((lower[t, 0] - margin) * inv)), 0)
        j0 = max(int(np.floor((lower[t, 1] - margin) * inv)), 0)
        k0 = max(int(np.floor((lower[t, 2] - margin) * inv)), 0)
        i1 = min(int(np.floor((upper[t, 0] + margin) * inv)), nx - 1)
        j1 = min(int(np.floor((upper[t, 1] + margin) * inv)), ny - 1)
        k1 = min(int(np.floor((upper[t, 2] + margin) * inv)), nz - 1)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for k in range(k0, k1 + 1):
                    crossed[i, j, k] = True


@njit(cache=True, nogil=True)
def _label_pass(points, mz, edges, column_of_bin, labels, origin, inv, counts, found, codes,
                species):  # pragma: no cover - compiled
    """Counts the ions of voxels wholly inside one object by species column (``column_of_bin``
    of the ion's m/z bin in ``edges``); returns how many ions it left in ``found`` (their
    index), ``codes`` (their voxel's label) and ``species`` for the exact test."""
    nx, ny, nz = labels.shape
    n = 0
    for i in range(points.shape[0]):
        fx = (points[i, 0] - origin[0]) * inv
        fy = (points[i, 1] - origin[1]) * inv
        fz = (points[i, 2] - origin[2]) * inv
        if fx < 0 or fy < 0 or fz < 0 or fx >= nx or fy >= ny or fz >= nz:
            continue
        label = labels[int(fx), int(fy), int(fz)]
        if label == 0:
            continue
        column = column_of_bin[np.searchsorted(edges, mz[i], side="right")]
        if label > 0:
            counts[label - 1, column] += 1
        else:
            found[n] = i
            codes[n] = label
            species[n] = column
            n += 1
    return n


def _count_ions(ions: IonTable, ranges: RangeTable, shapes: list[tuple[np.ndarray, np.ndarray]],
                chunk: int = ION_CHUNK) -> np.ndarray:
    """(n_shapes, n_species + 1) ions inside each closed shape; last column unranged.

    One streamed pass over chunks of ions through a :class:`_LabelGrid`: an ion in a voxel
    wholly inside one object is counted at once; only ions in voxels that a surface crosses
    (or that several objects share) are tested by their signed distance, all together at the end.
    An ion inside nested objects counts for each. Memory: the grid (int32, at most
    :data:`MAX_LABEL_VOXELS`), a chunk's work arrays (20 bytes per ion), and 36 bytes per ion left
    to test.
    """
    n_species = len(ranges.ions)
    counts = np.zeros((len(shapes), n_species + 1), dtype=np.int64)
    if not shapes or not len(ions):
        return counts
    scenes = [_Shape(v, f) for v, f in shapes]
    grid = _LabelGrid.build(scenes)
    edges, species_of_bin = range_edges(ranges)
    column_of_bin = np.where(species_of_bin > 0, species_of_bin - 1, n_species)  # unranged: last column
    left: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for start in range(0, len(ions), chunk):
        points = native_points(ions.positions[start:start + chunk])
        found = np.empty(len(points), dtype=np.int64)
        codes = np.empty(len(points), dtype=np.int32)
        species = np.empty(len(points), dtype=np.int64)
        n = _label_pass(points, native_points(ions.mz[start:start + chunk]), edges, column_of_bin, grid.labels, grid.origin,
                        1.0 / grid.voxel, counts, found, codes, species)
        left.append((np.asarray(points[found[:n]], dtype=np.float64), species[:n], codes[:n]))
    points = np.vstack([p for p, _, _ in left])
    species = np.concatenate([s for _, s, _ in left])
    codes = np.concatenate([c for _, _, c in left])
    del left
    order = np.argsort(codes, kind="stable")
    bounds = np.searchsorted(codes[order], np.arange(-len(shapes), 1))  # code -(k + 1) at slot n - 1 - k
    multi = order[:np.searchsorted(codes[order], MULTI + 1)]
    for k, shape in enumerate(scenes):
        slot = len(shapes) - 1 - k
        mine = order[bounds[slot]:bounds[slot + 1]]
        near = multi[np.all((points[multi] >= shape.lower) & (points[multi] <= shape.upper), axis=1)]
        test = np.concatenate([mine, near])
        counts[k] += np.bincount(species[test[shape.inside(points[test])]], minlength=n_species + 1)
    return counts


def object_table(mesh: TriMesh, ions: IonTable | None = None, ranges: RangeTable | None = None,
                 specimen: Specimen | None = None, cap_open: bool = True) -> ObjectTable:
    """Statistics of every connected component of ``mesh``.

    Parameters
    ----------
    mesh : TriMesh
        Iso-surface, outward normals (nm).
    ions, ranges : IonTable, RangeTable, optional
        Ions to count inside each closed or proxy object; objects enclosing none are dropped.
        Any subset holding every ion :func:`ions_in_objects` selects gives the same counts (the
        pipeline passes the ions it selected once, :func:`~apt_filters.core.nearby.select_near`).
    specimen : SpecimenHull or SpecimenMask, optional
        The analysed volume, for edge distances and the number density; default: the convex
        hull of the ions (if given; pass it with a subset of the ions).
    cap_open : bool
        Cap open objects at their boundary loops and report them as ``proxy`` with a
        volume; otherwise they stay ``open`` without volume. Objects closed by faces flagged
        in the face scalar :data:`CAP` (the meshlab ``close`` chain) are ``proxy`` too. A capped
        object that encloses no region (its caps cross its surface, so that its signed distance
        changes sign without crossing it: an interface across the specimen capped by the plane of
        its rim) stays ``open``.

    Memory: a few copies of the face array, the label grid of :func:`_count_ions` and
    :data:`ION_CHUNK`-sized work arrays; the ions are read chunk by chunk (a memory-mapped
    table is never copied whole). Two streamed passes build the hull, one counts the ions.
    """
    if (ions is None) != (ranges is None):
        raise AptFiltersError("counting ions inside objects needs both the ions and the range table")
    if specimen is None and ions is not None and len(ions) >= 4:
        specimen = SpecimenHull.from_points(ions.positions)
    # every vertex's distance once (numba, no (n, facets) temporary); an object's is its smallest
    edge = specimen.distance(mesh.vertices) if specimen is not None else None
    objects: list[ObjectStats] = []
    shapes: list[tuple[np.ndarray, np.ndarray]] = []
    for part in _objects(mesh, cap_open):
        objects.append(_stats(part.object_id, part.surface, part.closed, part.status))
        shapes.append((part.closed.vertices, part.closed.faces))
        if edge is not None:
            objects[-1].edge_distance = float(edge[mesh.faces[part.own]].min())
    n_dropped = 0
    if ions is not None:
        countable = [i for i, o in enumerate(objects) if o.status != "open"]
        counts = _count_ions(ions, ranges, [shapes[i] for i in countable])
        matrix = ranges.element_matrix()
        for i, c in zip(countable, counts):
            o = objects[i]
            o.n_ions = int(c.sum())
            o.ion_counts = dict(zip(ranges.ions + ["unranged"], map(int, c)))
            atoms = c[:-1] @ matrix
            o.composition = dict(zip(ranges.elements, (atoms / atoms.sum()).tolist() if atoms.sum() else
                                     [math.nan] * len(atoms)))
        keep = [o for o in objects if o.status == "open" or o.n_ions > 0]
        n_dropped = len(objects) - len(keep)
        objects = keep
    volume = specimen.volume if specimen is not None else math.nan
    return ObjectTable(objects, volume, n_dropped)


def ions_in_objects(mesh: TriMesh, cap_open: bool = True) -> Callable[[np.ndarray], np.ndarray]:
    """Which points may lie inside an object of ``mesh``'s table: ``test(points)`` (n, 3) nm -> (n,) bool.

    True in every voxel of the table's label grid that lies inside or is crossed by a closed or capped
    object (:func:`object_table` with the same ``cap_open``): a superset of the ions the table counts, so
    that one streamed pass can select them beside the ions near the surface
    (:func:`~apt_filters.core.nearby.select_near`'s ``also``). Memory: the label grid.
    """
    closed = [(p.closed.vertices, p.closed.faces) for p in _objects(mesh, cap_open) if p.status != "open"]
    if not closed:
        return lambda points: np.zeros(len(points), dtype=bool)
    return _LabelGrid.build([_Shape(v, f) for v, f in closed]).touched


@dataclass
class _Part:
    """One object of a mesh: its id, the faces of its own iso-surface (``own``, rows of the mesh's faces),
    that surface, the same closed by its caps, and its status."""

    object_id: int
    own: np.ndarray
    surface: TriMesh
    closed: TriMesh
    status: str


def object_surfaces(mesh: TriMesh, *, cap_open: bool = True) -> dict[int, TriMesh]:
    """Each object of ``mesh`` (nm, outward normals) by its id in :func:`object_table`: its surface, closed by its
    caps where ``cap_open`` and it is cut by the specimen edge (the surface its volume is measured on)."""
    return {p.object_id: p.closed for p in _objects(mesh, cap_open)}


def _objects(mesh: TriMesh, cap_open: bool) -> list[_Part]:
    """The objects of ``mesh``, in increasing id: the face scalar ``object_id`` if given, else the components
    (the same numbering as the proxigram and excess)."""
    labels = (np.asarray(mesh.face_scalars["object_id"], dtype=np.int64) if "object_id" in mesh.face_scalars
              else mesh.face_components())
    ids, face_label = np.unique(labels, return_inverse=True)
    order = np.argsort(face_label, kind="stable")
    starts = np.searchsorted(face_label[order], np.arange(len(ids) + 1))
    is_cap = np.asarray(mesh.face_scalars.get(CAP, np.zeros(mesh.n_faces)), dtype=bool)
    parts = []
    for k in range(len(ids)):
        index = order[starts[k]:starts[k + 1]]
        capped = is_cap[index]
        own = index[~capped] if capped.any() and not capped.all() else index  # the iso-surface's faces
        whole = _submesh(mesh.vertices, mesh.faces[index])
        surface = whole if own is index else _submesh(mesh.vertices, mesh.faces[own])
        closed = cap_boundaries(whole)[0] if cap_open else whole
        status = "open" if len(closed.topology.boundary_half_edges) else ("closed" if closed is surface else "proxy")
        if status == "proxy" and not _LabelGrid.build([_Shape(closed.vertices, closed.faces)]).encloses[0]:
            closed, status = surface, "open"  # its caps cross its surface: no region to measure or count in
        parts.append(_Part(int(ids[k]), own, surface, closed, status))
    return parts


def counting_errors(table: ObjectTable, mesh: TriMesh, *, reference: TriMesh, offset_se: np.ndarray,
                    shape_se: np.ndarray | None = None, p_value: np.ndarray | None = None,
                    z: np.ndarray | None = None) -> None:
    """Fill each object's counting errors (and speck-test figures) in ``table``, in place.

    The counting error of an object's surface position is that of its mean offset along its normals,
    ``sigma_d`` (``offset_se``: the Fisher information of the ions' composition profile across it,
    :attr:`apt_filters.refine.RefineResult.offset_errors`). To first order an offset ``d`` changes the
    volume by ``A d`` and the area by ``(dA/dd) d`` (:func:`area_growth`, ``2 integral H dA``), so
    ``volume_se = A sigma_d`` and ``area_se = |dA/dd| sigma_d``. The volume error does not depend on how
    the offset noise is correlated along the surface: any smoothing of the displacements that keeps their
    area-weighted mean keeps the volume, and for independent patches of equal information per area
    ``sqrt(sum (A_i sigma_i)^2) = A / sqrt(I)`` as for the mean offset. The area error assumes the
    offset noise is common to the object (its low-passed shape, :mod:`apt_filters.refine.spectral`);
    higher modes add area only at second order.

    A faceted object's figures also carry the spread of a discrete decision: which facets its surface
    finds, and so which edges and corners are rebuilt sharp (a lath whose narrow faces are found on one
    draw of its ions and not on the next changes its area by several times ``|dA/dd| sigma_d``). Where
    ``shape_se`` holds it (:attr:`apt_filters.refine.RefineResult.shape_errors`, from the two cross-fit
    halves of the ions), each error is the larger of the two (:func:`size_errors`).

    Parameters
    ----------
    table : ObjectTable
        The objects of ``mesh`` (``object_id`` = its component numbering).
    mesh : TriMesh
        The measured surface.
    reference : TriMesh
        The surface ``offset_se`` describes, component by component (e.g. the refined surface before
        cleaning and remeshing); each object takes the component holding most of the reference vertices
        nearest to its own.
    offset_se : (c,) float, nm
        Per component of ``reference``; NaN where unknown.
    shape_se : (c, 2) float, nm³ and nm², optional
        Per component of ``reference``: volume and area errors from the halves; NaN where unknown.
    p_value, z : (k,) float, optional
        Per component of ``mesh`` (:meth:`apt_filters.refine.Specks.of`).
    """
    from scipy.spatial import cKDTree

    labels = (np.asarray(mesh.face_scalars["object_id"], dtype=np.int64) if "object_id" in mesh.face_scalars
              else mesh.face_components())
    vertex_object = np.full(mesh.n_vertices, -1, dtype=np.int64)
    vertex_object[mesh.faces.ravel()] = np.repeat(labels, 3)
    ref_comp = np.zeros(reference.n_vertices, dtype=np.int64)
    ref_comp[reference.faces.ravel()] = np.repeat(reference.face_components(), 3)
    nearest = ref_comp[cKDTree(reference.vertices).query(mesh.vertices)[1]] if reference.n_vertices else None
    for o in table.objects:
        if p_value is not None and o.object_id < len(p_value):
            o.p_value, o.z = float(p_value[o.object_id]), float(z[o.object_id])
        if nearest is None:
            continue
        mine = vertex_object == o.object_id
        votes = np.bincount(nearest[mine], minlength=len(offset_se))
        c = int(np.argmax(votes)) if votes.any() else -1
        se = float(offset_se[c]) if c >= 0 else math.nan
        halves = shape_se[c] if shape_se is not None and 0 <= c < len(shape_se) else (math.nan, math.nan)
        part = _submesh(mesh.vertices, mesh.faces[labels == o.object_id])
        o.volume_se, o.area_se = size_errors(part, se, halves, area=o.area)
        if o.status == "open":
            o.volume_se = math.nan


def size_errors(part: TriMesh, offset_se: float, halves=(math.nan, math.nan), area: float | None = None
                ) -> tuple[float, float]:
    """(volume_se nm³, area_se nm²) of one object: ``A sigma_d`` and ``|dA/dd| sigma_d`` (:func:`counting_errors`),
    each raised to the halves' spread ``halves`` (nm³, nm²) where that is larger (NaN: not known).

    Parameters
    ----------
    part : TriMesh
        The object's surface.
    offset_se : float, nm
        Counting error of its mean offset.
    halves : (2,) float, nm³ and nm²
    area : float, nm², optional
        Its area, if already measured (else ``part.area()``).
    """
    area = part.area() if area is None else area
    return (float(np.fmax(offset_se * area, halves[0])),
            float(np.fmax(offset_se * abs(area_growth(part)), halves[1])))


def area_growth(part: TriMesh) -> float:
    """dA/dd (nm): how fast the area of ``part`` grows as its surface moves ``d`` nm out along its normals.

    Steiner's formula for a polyhedral surface: the parallel surface at distance ``d`` has area
    ``A + d sum_e l_e theta_e + O(d^2)``, ``l_e`` each interior edge's length and ``theta_e`` its signed
    exterior dihedral angle (positive where convex); the discrete form of ``2 integral H dA`` (``8 pi r``
    for a sphere, ``6 pi a`` for a cube of edge ``a``, whose faces do not grow, its edges do).
    """
    top = part.topology
    if not len(top.face_pairs):
        return 0.0
    normals = part.face_normals()
    centres = part.vertices[part.faces].mean(axis=1)
    f1, f2 = top.face_pairs[:, 0], top.face_pairs[:, 1]
    n1, n2 = normals[f1], normals[f2]
    turn = np.arctan2(np.linalg.norm(np.cross(n1, n2), axis=1), np.einsum("ij,ij->i", n1, n2))
    sign = np.sign(np.einsum("ij,ij->i", centres[f2] - centres[f1], n2 - n1))
    edges = top.edge_vertices[top.edge_faces == 2]
    length = np.linalg.norm(part.vertices[edges[:, 0]] - part.vertices[edges[:, 1]], axis=1)
    return float(np.sum(length * sign * turn))

def _submesh(vertices: np.ndarray, faces: np.ndarray) -> TriMesh:
    used, local = np.unique(faces, return_inverse=True)
    return TriMesh(vertices[used], local.reshape(-1, 3))


def _stats(object_id: int, part: TriMesh, closed: TriMesh, status: str) -> ObjectStats:
    """Statistics of one component: ``part`` its iso-surface faces, ``closed`` the same with
    caps (or ``part`` itself when nothing was capped)."""
    n_loops = part.topology.boundary_pieces[0]
    chi = part.n_vertices - len(part.topology.edge_vertices) + part.n_faces
    areas = part.face_areas()
    face_centres = part.vertices[part.faces].mean(axis=1)
    volume = radius = sphericity = math.nan
    centroid = (areas @ face_centres) / areas.sum() if areas.sum() > 0 else part.vertices.mean(axis=0)
    if status != "open":
        ref = part.vertices.mean(axis=0)  # tetrahedra apex near the object: no cancellation far from 0
        v = closed.vertices[closed.faces] - ref
        tet = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])) / 6.0
        volume = float(tet.sum())
        if volume != 0:
            centroid = ref + (tet @ v.sum(axis=1)) / (4.0 * volume)
        if volume > 0:
            radius = (3.0 * volume / (4.0 * math.pi)) ** (1 / 3)
            sphericity = math.pi ** (1 / 3) * (6.0 * volume) ** (2 / 3) / closed.area()
    extents = _obb(part, areas)
    aspect = tuple(float(e / extents[0]) if extents[0] > 0 else math.nan for e in extents[1:])
    return ObjectStats(object_id, status, part.n_faces, float(areas.sum()), volume, radius, sphericity,
                       tuple(map(float, centroid)), tuple(map(float, extents)), aspect, int(chi), n_loops,
                       (2 - chi - n_loops) / 2)
