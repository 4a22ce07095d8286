"""Per-object statistics of an iso-surface: each connected component is one object.

For every component: status (``closed``; ``open`` at the specimen edge; ``proxy`` = open,
capped at its boundary loops to estimate a volume), surface area, signed volume (tetrahedra
sum, positive for outward normals), equivalent-sphere radius, sphericity
pi^(1/3) (6V)^(2/3) / A, centroid, oriented-bounding-box extents and aspect ratios, Euler
characteristic and genus, ions inside by species and the element composition inside
(vectorised point-in-closed-mesh test by ray parity, open3d ``RaycastingScene``), and the
distance to the specimen edge. The table also gives the object number density in the
analysed volume; objects that enclose no ion (marching-cubes specks) are dropped.

Units: nm, nm², nm³; compositions as fractions (at.% only in reports).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull

from apt_filters.core.atomic import atomic_write_text
from apt_filters.core.deps import open3d
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable

CAP = "cap"
"""Face scalar flagging faces that close a hole (non-zero), as the meshlab ``close`` chain sets it:
components with such faces are proxies and their area leaves those faces out."""

ION_CHUNK = 4_000_000
"""Ions tested per chunk; peak extra memory about 60 bytes per ion of a chunk (~240 MB)."""


# --- the specimen ---------------------------------------------------------------------------

class Specimen(Protocol):
    """The analysed volume: its size and the distance of points to its edge."""

    volume: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(n,) distance in nm from each (n, 3) point to the edge, positive inside."""


@dataclass(frozen=True)
class SpecimenHull:
    """Convex hull of the specimen (e.g. of its ions): half-spaces ``n . x + d <= 0`` inside."""

    equations: np.ndarray
    volume: float

    @classmethod
    def from_points(cls, points: np.ndarray, chunk: int = ION_CHUNK) -> "SpecimenHull":
        """Hull of (N, 3) points (nm), built chunk by chunk: the hull of the chunks' hull
        vertices is the hull of all points. Memory: one chunk as float64 (24 bytes/point)."""
        corners = np.empty((0, 3))
        for start in range(0, len(points), chunk):
            block = np.vstack([corners, np.asarray(points[start:start + chunk], dtype=np.float64)])
            corners = block[ConvexHull(block).vertices]
        hull = ConvexHull(corners)
        return cls(hull.equations, float(hull.volume))

    def distance(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        return -(p @ self.equations[:, :3].T + self.equations[:, 3]).max(axis=1)


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

def _boundary_half_edges(faces: np.ndarray) -> np.ndarray:
    """(k, 2) directed half-edges (a, b) of faces whose undirected edge is used once."""
    half = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    key = np.sort(half, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return half[counts[inverse.ravel()] == 1]


def _loops(half: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Boundary loops: their number and the loop of each boundary half-edge."""
    if len(half) == 0:
        return 0, np.zeros(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(half), dtype=np.int8), (half[:, 0], half[:, 1])), shape=(n_vertices,) * 2)
    _, label = connected_components(graph, directed=False)
    used, loop = np.unique(label[half[:, 0]], return_inverse=True)
    return len(used), loop.ravel()


def cap_boundaries(mesh: TriMesh) -> tuple[TriMesh, np.ndarray]:
    """Close every boundary loop with a fan to the loop's vertex centroid.

    Returns the capped mesh (input faces first) and the (m_cap,) loop index of each cap
    face. Exact for planar loops (a flat specimen edge); otherwise a proxy.
    """
    half = _boundary_half_edges(mesh.faces)
    n_loops, loop = _loops(half, mesh.n_vertices)
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
    molecular ions split into their atoms.
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
        return atomic_write_text(path, json.dumps(_nan_to_none(data), indent=1, allow_nan=False) + "\n", overwrite)


def _nan_to_none(value: object) -> object:
    """JSON has no NaN: undefined values become null."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, dict):
        return {k: _nan_to_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_nan_to_none(v) for v in value]
    return value


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


def _inside(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n,) bool: points inside the closed mesh (ray parity, majority of 3 rays)."""
    o3d = open3d()
    ref = vertices.mean(axis=0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor((vertices - ref).astype(np.float32)),
                        o3d.core.Tensor(faces.astype(np.uint32)))
    occ = scene.compute_occupancy(o3d.core.Tensor((points - ref).astype(np.float32)), nsamples=3)
    return occ.numpy().astype(bool)


def _count_ions(ions: IonTable, ranges: RangeTable, shapes: list[tuple[np.ndarray, np.ndarray]],
                chunk: int = ION_CHUNK) -> np.ndarray:
    """(n_shapes, n_species + 1) ions inside each closed shape; last column unranged.

    Ions go in chunks sorted by x; each shape tests only the ions in its bounding box.
    """
    n_species = len(ranges.ions)
    counts = np.zeros((len(shapes), n_species + 1), dtype=np.int64)
    boxes = [(v[f].reshape(-1, 3).min(axis=0), v[f].reshape(-1, 3).max(axis=0)) for v, f in shapes]
    for start in range(0, len(ions), chunk):
        pos = np.asarray(ions.positions[start:start + chunk], dtype=np.float64)
        species = ranges.ion_index(ions.mz[start:start + chunk])
        order = np.argsort(pos[:, 0], kind="stable")
        xs = pos[order, 0]
        for i, ((lo, hi), (v, f)) in enumerate(zip(boxes, shapes)):
            idx = order[np.searchsorted(xs, lo[0], "left"):np.searchsorted(xs, hi[0], "right")]
            p = pos[idx]
            idx = idx[np.all((p[:, 1:] >= lo[1:]) & (p[:, 1:] <= hi[1:]), axis=1)]
            if len(idx):
                s = species[idx[_inside(pos[idx], v, f)]]
                counts[i] += np.bincount(np.where(s < 0, n_species, s), minlength=n_species + 1)
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
    specimen : SpecimenHull or SpecimenMask, optional
        The analysed volume, for edge distances and the number density; default: the convex
        hull of the ions (if given).
    cap_open : bool
        Cap open objects at their boundary loops and report them as ``proxy`` with a
        volume; otherwise they stay ``open`` without volume. Objects closed by faces flagged
        in the face scalar :data:`CAP` (the meshlab ``close`` chain) are ``proxy`` too.

    Memory: a few copies of the face array, plus :data:`ION_CHUNK`-sized ion work arrays.
    """
    if (ions is None) != (ranges is None):
        raise AptFiltersError("counting ions inside objects needs both the ions and the range table")
    if specimen is None and ions is not None and len(ions) >= 4:
        specimen = SpecimenHull.from_points(ions.positions)
    # The same numbering as the proxigram and excess: the face scalar if given, else components.
    labels = (np.asarray(mesh.face_scalars["object_id"], dtype=np.int64) if "object_id" in mesh.face_scalars
              else mesh.face_components())
    ids, face_label = np.unique(labels, return_inverse=True)
    n_obj = len(ids)
    order = np.argsort(face_label, kind="stable")
    starts = np.searchsorted(face_label[order], np.arange(n_obj + 1))
    is_cap = np.asarray(mesh.face_scalars.get(CAP, np.zeros(mesh.n_faces)), dtype=bool)
    objects: list[ObjectStats] = []
    shapes: list[tuple[np.ndarray, np.ndarray]] = []
    for k in range(n_obj):
        index = order[starts[k]:starts[k + 1]]
        whole = _submesh(mesh.vertices, mesh.faces[index])
        surface = _submesh(mesh.vertices, mesh.faces[index[~is_cap[index]]]) \
            if is_cap[index].any() and not is_cap[index].all() else whole
        closed = cap_boundaries(whole)[0] if cap_open else whole
        status = "open" if len(_boundary_half_edges(closed.faces)) else ("closed" if closed is surface else "proxy")
        objects.append(_stats(int(ids[k]), surface, closed, status))
        shapes.append((closed.vertices, closed.faces))
        if specimen is not None:
            objects[-1].edge_distance = float(specimen.distance(surface.vertices).min())
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


def _submesh(vertices: np.ndarray, faces: np.ndarray) -> TriMesh:
    used, local = np.unique(faces, return_inverse=True)
    return TriMesh(vertices[used], local.reshape(-1, 3))


def _stats(object_id: int, part: TriMesh, closed: TriMesh, status: str) -> ObjectStats:
    """Statistics of one component: ``part`` its iso-surface faces, ``closed`` the same with
    caps (or ``part`` itself when nothing was capped)."""
    n_loops, _ = _loops(_boundary_half_edges(part.faces), part.n_vertices)
    n_edges = len(np.unique(np.sort(part.edges(), axis=1), axis=0))
    chi = part.n_vertices - n_edges + part.n_faces
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
