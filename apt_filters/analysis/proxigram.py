"""Proximity histograms (Hellman et al. 2000): composition against signed distance to an iso-surface.

Every ion within ``max_distance`` of the surface gets its exact signed distance
(:mod:`apt_filters.core.distance`), reported positive inside the region above the iso-value
(the engine's sign negated, as AP Suite plots proxigrams). Ions
are binned by that distance, per object (the connected piece of surface holding the closest
point, or ``face_scalars["object_id"]``), and counted per ion species; element counts follow
from the range table's decomposition (CrO2 = 1 Cr + 2 O).

Ions whose closest point lies on the boundary of an open surface (the rim where the surface
leaves the specimen) are beyond the surface's edge, not across it: they are left out by default,
as AP Suite's "exclude edge polygons" does.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable

import numpy as np

from apt_filters.core.atomic import atomic_output, atomic_write_text
from apt_filters.core.distance import PseudoNormals, SurfaceDistance
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.core.nearby import NearSurface
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable

POOLED = -1
"""Object id of the profile pooled over all objects."""


@dataclass
class Proxigram:
    """Ion counts per distance bin and object.

    Attributes
    ----------
    edges : (b + 1,) float64
        Bin edges in nm (signed distance, positive inside the region above the iso-value).
    ions, elements : list of str
        Ion species and elements of the range table.
    element_matrix : (n_ions, n_elements) int64
        Atoms of each element per ion.
    colors : dict
        Ion -> ``"RRGGBB"`` (or None) from the range file.
    object_ids : (k,) int64
        Object of each profile (``POOLED`` for a pooled one).
    counts : (k, b, n_ions) int64
        Ranged ions per object, bin and species.
    unranged : (k, b) int64
        Unranged ions per object and bin (not in any concentration).
    areas : (k,) float64
        Surface area of each object, nm².
    shell_volumes : (k, b) float64
        Volume of each distance shell, nm³ (see :func:`shell_volumes`).
    n_ions, n_candidates, n_rim : int
        Ions read, ions in the narrow band (searched: their block of the search grid has a
        triangle within range), ions within range whose closest point is on the rim of an open
        surface.
    rim_kept : bool
        Whether the rim ions are counted (``keep_edge``) or left out (default).
    iso_value : float or None
        Iso-value of the surface (fraction), marked on plots.
    """

    edges: np.ndarray
    ions: list[str]
    elements: list[str]
    element_matrix: np.ndarray
    colors: dict[str, str | None]
    object_ids: np.ndarray
    counts: np.ndarray
    unranged: np.ndarray
    areas: np.ndarray
    shell_volumes: np.ndarray
    n_ions: int = 0
    n_candidates: int = 0
    n_rim: int = 0
    rim_kept: bool = False
    iso_value: float | None = None

    @property
    def centers(self) -> np.ndarray:
        """(b,) bin centres, nm."""
        return 0.5 * (self.edges[1:] + self.edges[:-1])

    def species(self, kind: str = "element") -> list[str]:
        """Names along the last axis of :meth:`species_counts` for ``kind`` "element" or "ion"."""
        return self.elements if kind == "element" else self.ions

    def species_counts(self, kind: str = "element") -> np.ndarray:
        """(k, b, s) counts: ions per species (``kind="ion"``) or decomposed atoms per element."""
        if kind == "ion":
            return self.counts
        if kind == "element":
            return self.counts @ self.element_matrix
        raise ValueError(f"kind must be 'ion' or 'element', not {kind!r}")

    def counts_of(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Counts (k, b) of one element or ion species and the matching totals (k, b).

        An element name counts decomposed atoms over all atoms; otherwise the ion species counts
        ions over all ranged ions.
        """
        for kind in ("element", "ion"):
            names = self.species(kind)
            if name in names:
                counts = self.species_counts(kind)
                return counts[:, :, names.index(name)], counts.sum(axis=2)
        raise AptFiltersError(f"species {name!r} is neither an element ({', '.join(self.elements)}) "
                              f"nor an ion ({', '.join(self.ions)}) of the range file")

    def concentration(self, kind: str = "element") -> tuple[np.ndarray, np.ndarray]:
        """Fractions (k, b, s) and their binomial errors sqrt(c (1 - c) / N); NaN in empty bins."""
        counts = self.species_counts(kind).astype(np.float64)
        total = counts.sum(axis=2, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = counts / total
            return c, np.sqrt(c * (1.0 - c) / total)

    def atom_density(self) -> np.ndarray:
        """(k, b) detected atoms per nm³ of each shell (NaN where the shell volume is 0)."""
        atoms = self.species_counts("element").sum(axis=2)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.shell_volumes > 0, atoms / self.shell_volumes, np.nan)

    def pooled(self) -> "Proxigram":
        """One profile summed over all objects (areas and shell volumes add up)."""
        return replace(self, object_ids=np.array([POOLED]), counts=self.counts.sum(axis=0, keepdims=True),
                       unranged=self.unranged.sum(axis=0, keepdims=True), areas=self.areas.sum(keepdims=True),
                       shell_volumes=self.shell_volumes.sum(axis=0, keepdims=True))

    def crop(self, extent: float) -> "Proxigram":
        """The bins within ``[-extent, extent)`` nm: the counts a proxigram over that range holds (each
        ion's distance does not depend on the range; a distance on a bin edge may round to the other bin
        in float32), when ``extent`` falls on a bin edge."""
        keep = (self.edges[:-1] >= -extent - 1e-9) & (self.edges[1:] <= extent + 1e-9)
        if keep.all():
            return self
        first, last = np.flatnonzero(keep)[[0, -1]]
        return replace(self, edges=self.edges[first:last + 2], counts=self.counts[:, keep],
                       unranged=self.unranged[:, keep], shell_volumes=self.shell_volumes[:, keep])

    def table(self) -> tuple[list[str], np.ndarray]:
        """CSV header and rows (one per object and bin): counts, fractions, errors, densities."""
        k, b = self.counts.shape[:2]
        c_el, e_el = self.concentration("element")
        c_ion, e_ion = self.concentration("ion")
        header = (["object", "distance_nm", "bin_lo_nm", "bin_hi_nm", "n_ions", "n_unranged"]
                  + [f"n_{s}" for s in self.ions] + ["n_atoms"] + [f"atoms_{e}" for e in self.elements]
                  + [f"c_{e}" for e in self.elements] + [f"err_{e}" for e in self.elements]
                  + [f"c_ion_{s}" for s in self.ions] + [f"err_ion_{s}" for s in self.ions]
                  + ["shell_volume_nm3", "atom_density_nm-3"])
        atoms = self.species_counts("element")
        columns = [np.repeat(self.object_ids, b), np.tile(self.centers, k), np.tile(self.edges[:-1], k),
                   np.tile(self.edges[1:], k), self.counts.sum(axis=2).ravel(), self.unranged.ravel(),
                   *self.counts.reshape(k * b, -1).T, atoms.sum(axis=2).ravel(), *atoms.reshape(k * b, -1).T,
                   *c_el.reshape(k * b, -1).T, *e_el.reshape(k * b, -1).T,
                   *c_ion.reshape(k * b, -1).T, *e_ion.reshape(k * b, -1).T,
                   self.shell_volumes.ravel(), self.atom_density().ravel()]
        return header, np.column_stack(columns)

    def write_csv(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write :meth:`table` as CSV, atomically; concentrations as fractions, 6 significant digits."""
        header, rows = self.table()
        n_int = 6 + len(self.ions) + 1 + len(self.elements)  # object .. atoms_* columns are counts
        lines = [",".join(header)]
        for row in rows:
            ints = (f"{int(v)}" for v in row[:1])
            floats = (f"{v:.6g}" for v in row[1:4])
            counts = (f"{int(v)}" for v in row[4:n_int])
            rest = ("" if np.isnan(v) else f"{v:.6g}" for v in row[n_int:])
            lines.append(",".join([*ints, *floats, *counts, *rest]))
        return atomic_write_text(path, "\n".join(lines) + "\n", overwrite)

    def plot(self, path: str | os.PathLike, overwrite: bool = False, title: str | None = None,
             windows: tuple[float, float] | None = None) -> Path:
        """PNG of the pooled profile: ion species (range-file colours) and elements, in at.%, with errors;
        ``windows`` (inner, outer nm) shades the plateau windows."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        pooled = self if len(self.object_ids) == 1 else self.pooled()
        fig, axes = plt.subplots(2, 1, figsize=(7, 8), sharex=True)
        for ax, kind in zip(axes, ("ion", "element")):
            c, err = pooled.concentration(kind)
            for j, name in enumerate(pooled.species(kind)):
                color = self.colors.get(name)  # an element takes the colour of its single-atom ion
                ax.errorbar(pooled.centers, 100 * c[0, :, j], yerr=100 * err[0, :, j], label=name, lw=1,
                            ms=2, marker="o", capsize=1.5, color=f"#{color}" if color else None)
            ax.axvline(0.0, color="k", ls="--", lw=0.8, label="iso-surface")
            if windows is not None:
                for lo, hi in ((-windows[1], -windows[0]), (windows[0], windows[1])):
                    ax.axvspan(lo, hi, color="0.9", zorder=0, label="plateau windows" if lo > 0 else None)
            if self.iso_value is not None:
                ax.axhline(100 * self.iso_value, color="grey", ls=":", lw=0.8, label=f"iso = {100 * self.iso_value:g} at.%")
            ax.set_ylabel(f"{'ion' if kind == 'ion' else 'atomic'} concentration (%)")
            ax.legend(fontsize=7, ncol=2)
        axes[1].set_xlabel("distance to iso-surface (nm), positive inside")
        axes[0].set_title(title or f"proxigram, {len(self.object_ids)} object(s), area {pooled.areas[0]:.4g} nm²")
        fig.tight_layout()
        with atomic_output(path, overwrite) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
        plt.close(fig)
        return Path(path)


def face_objects(mesh: TriMesh) -> np.ndarray:
    """(m,) int64 object id per face: ``face_scalars["object_id"]`` or connected components."""
    if "object_id" in mesh.face_scalars:
        return np.asarray(mesh.face_scalars["object_id"]).astype(np.int64)
    return mesh.face_components()


def curvature_integrals(mesh: TriMesh, normals: PseudoNormals, labels: np.ndarray,
                        n_objects: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area, integrated mean curvature and integrated Gaussian curvature per object.

    Discrete forms: mean curvature ``M = 1/2 sum |e| theta_e`` over interior edges (signed
    dihedral angle, positive where the surface bends away from its normal), Gaussian curvature
    ``K = sum (2 pi - angle sum)`` over interior vertices. Returns three (n_objects,) arrays.
    """
    topology = mesh.topology
    areas = np.bincount(labels, mesh.face_areas(), minlength=n_objects)
    interior = np.flatnonzero(topology.edge_faces == 2)  # the edges of topology.face_pairs, in order
    f1, f2 = topology.face_pairs.T
    n1, n2 = normals.face_normals[f1], normals.face_normals[f2]
    centroid = mesh.vertices[mesh.faces].mean(axis=1)
    convex = np.einsum("ij,ij->i", n1, centroid[f2] - centroid[f1]) < 0
    theta = np.arccos(np.clip(np.einsum("ij,ij->i", n1, n2), -1, 1)) * np.where(convex, 1, -1)
    length = np.linalg.norm(np.diff(mesh.vertices[topology.edge_vertices[interior]], axis=1)[:, 0], axis=1)
    mean = np.bincount(labels[f1], 0.5 * length * theta, minlength=n_objects)
    angle_sum = np.bincount(mesh.faces.ravel(), normals.corner_angles.ravel(), minlength=mesh.n_vertices)
    vertex_label = np.zeros(mesh.n_vertices, dtype=np.int64)
    vertex_label[mesh.faces.ravel()] = np.repeat(labels, 3)
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[mesh.faces.ravel()] = True
    interior_vertex = used & ~topology.boundary_vertex
    gauss = np.bincount(vertex_label[interior_vertex], 2 * np.pi - angle_sum[interior_vertex], minlength=n_objects)
    return areas, mean, gauss


def shell_volumes(edges: np.ndarray, area: np.ndarray, mean: np.ndarray, gauss: np.ndarray) -> np.ndarray:
    """(k, b) volumes of the shells between signed distances ``edges`` (nm) for k objects.

    Steiner's formula: the parallel surface at outward offset t has area ``A + 2 M t + K t²``;
    the signed distance s is positive inside, so t = -s and the shell [s1, s2] has volume
    ``A (s2 - s1) - M (s2² - s1²) + K (s2³ - s1³) / 3`` (clamped at 0). Exact for planes,
    spheres and, outside, any convex body (cube included); an approximation where offsets
    fold (inside a cube's corners, beyond a radius of curvature) and near an open rim.
    """
    s1, s2 = edges[:-1][None, :], edges[1:][None, :]
    v = (area[:, None] * (s2 - s1) - mean[:, None] * (s2 ** 2 - s1 ** 2)
         + gauss[:, None] * (s2 ** 3 - s1 ** 3) / 3.0)
    return np.maximum(v, 0.0)


def compute_proxigram(ions: IonTable | Iterable[IonTable], ranges: RangeTable, mesh: TriMesh, bin_width: float = 0.1,
                      max_distance: float = 3.0, keep_edge: bool = False, iso_value: float | None = None,
                      chunk: int = 1 << 22, measured: NearSurface | None = None) -> Proxigram:
    """Proxigram of ``ions`` across ``mesh``, per object.

    Parameters
    ----------
    ions : IonTable or iterable of IonTable
        Ions, processed ``chunk`` at a time, or consecutive chunks of them (such as
        :func:`apt_filters.io.iter_ion_chunks` yields, for files larger than memory).
    ranges : RangeTable
        Ranging and decomposition.
    mesh : TriMesh
        Iso-surface, normals out of the region above the iso-value; open or closed.
    bin_width, max_distance : float
        Bin width and half range in nm: bins cover [-max_distance, max_distance).
    keep_edge : bool
        Keep ions whose closest point lies on the rim of an open surface (left out by default).
    iso_value : float, optional
        Iso-value (fraction), only recorded for the plot.
    chunk : int
        Ions per chunk of an ``IonTable``. Peak memory about 60 bytes x chunk size (250 MB at the
        default 4 M; the ions themselves not counted) plus the search grid (about 40 MB for 230k
        triangles, :class:`~apt_filters.core.distance.TriangleGrid`), independent of the
        number of ions.
    measured : NearSurface, optional
        The signed distances of ``ions`` (an ``IonTable``) to ``mesh``, row for row, exact wherever within
        ``max_distance`` (:func:`~apt_filters.core.nearby.select_near` with exact distances over a reach of
        at least ``max_distance``, the selection ``ions`` came from): not measured again. Ties between
        equidistant faces of one object may resolve to another face, which no count sees.

    Returns
    -------
    Proxigram
        One profile per object, objects in increasing id.
    """
    if bin_width <= 0 or max_distance <= 0:
        raise AptFiltersError(f"bin width ({bin_width}) and range ({max_distance}) must be positive")
    if mesh.n_faces == 0:
        raise AptFiltersError("the mesh has no triangles", None)
    n_bins = int(round(2 * max_distance / bin_width))
    edges = np.linspace(-max_distance, max_distance, n_bins + 1)
    if measured is not None and (not isinstance(ions, IonTable) or len(measured.distance) != len(ions)
                                 or measured.reach < max_distance):
        raise AptFiltersError(f"the measured distances cover {len(measured.distance):,} ions to "
                              f"{measured.reach:g} nm; the proxigram asks for these {len(ions):,} to {max_distance:g}")
    surface = SurfaceDistance(mesh, reach=max_distance)
    labels = face_objects(mesh)
    object_ids, face_slot = np.unique(labels, return_inverse=True)
    n_obj, n_ion = len(object_ids), len(ranges.ions)
    counts = np.zeros(n_obj * n_bins * (n_ion + 1), dtype=np.int64)
    n_candidates = n_edge = 0
    n_ions = 0
    parts = ((ions.subset(slice(a, a + chunk)) for a in range(0, len(ions), chunk))
             if isinstance(ions, IonTable) else ions)
    start = 0
    for part in parts:
        n_ions += len(part)
        if measured is None:
            sd = surface.query(np.asarray(part.positions, dtype=np.float32), max_distance=max_distance)
            distance, face, rim = sd.distance, sd.face, sd.on_boundary  # NaN beyond: not kept
            n_candidates += sd.searched
        else:
            rows = slice(start, start + len(part))
            distance, face, rim = measured.distance[rows], measured.face[rows], measured.on_boundary[rows]
            n_candidates += int(np.count_nonzero(np.abs(distance) <= max_distance))
        start += len(part)
        inside = -distance  # positive inside the region above the iso-value
        keep = (inside >= -max_distance) & (inside < max_distance)
        n_edge += int(np.count_nonzero(keep & rim))
        if not keep_edge:
            keep &= ~rim
        kept = np.flatnonzero(keep)
        species = ranges.ion_index(np.asarray(part.mz)[kept]) + 1
        bins = np.minimum(((inside[kept] + max_distance) / bin_width).astype(np.int64), n_bins - 1)
        slot = (face_slot[face[kept]] * n_bins + bins) * (n_ion + 1) + species
        counts += np.bincount(slot, minlength=len(counts))
    counts = counts.reshape(n_obj, n_bins, n_ion + 1)
    area, mean, gauss = curvature_integrals(mesh, surface.normals, face_slot, n_obj)
    return Proxigram(edges=edges, ions=ranges.ions, elements=ranges.elements,
                     element_matrix=ranges.element_matrix(), colors=ranges.ion_colors(),
                     object_ids=object_ids, counts=counts[:, :, 1:], unranged=counts[:, :, 0], areas=area,
                     shell_volumes=shell_volumes(edges, area, mean, gauss), n_ions=n_ions,
                     n_candidates=n_candidates, n_rim=n_edge, rim_kept=keep_edge,
                     iso_value=iso_value)
