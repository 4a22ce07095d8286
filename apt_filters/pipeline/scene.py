"""The MeshLab scene of a run: what ``project.mlp`` opens, drawn to show the chemistry.

- Each iso-surface as ``meshes/<label>.ply``, its vertex quality the **local composition** of
  one species at the surface (:func:`vertex_composition`: at.% of that element among the atoms
  of the :data:`NEAREST_IONS` ranged ions nearest each vertex, molecular ions decomposed), and
  its vertex colour that quality through viridis with the range set from the data (1st-99th
  percentile). The species is the solute whose pooled excess is the most significant (|Γ| over
  its error), else the surface's own species (:func:`scene_species`). Every composition computed
  is also written as a vertex property ``at_pct_<element>``. A surface given a map in ``quality``
  (the run's excess map) shows that map as quality instead, with its own range.
- Surfaces above :data:`LOD_FACES` faces get a decimated copy (fast-simplification, boundary
  loops kept) as ``<label>_lod.ply``, shown when the project opens; the full-resolution mesh
  is the hidden layer beside it.
- The ions as one layer per ion species (``meshes/ions_<name>.ply``, the range file's colours),
  sampled for viewing (:func:`layer_quotas`: :data:`VIEW_POINTS` in all, shared equally between
  the species), so rare species show; species holding a quarter or more of the ranged ions (the
  matrix, :data:`MATRIX_FRACTION`) open hidden, so that an interface across the whole tip is not
  drawn over.
- ``legend.png``: the colour bar of each surface and the colour of each ion layer.

Memory: the ions near the surfaces (a k-d tree over them) and one block of vertices' neighbours.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit, prange

from apt_filters.core.mesh import TriMesh
from apt_filters.core.threads import available_cores
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable

NEAREST_IONS = 300
"""Ions whose atoms make each vertex's composition: a counting error of sqrt(c (1 - c) / N)
(about 1 at.% at 3 at.% for N atoms ~ 300) over a sphere of about 1.3 nm radius in a 50 %
efficient metal, about the reach of the voxel field."""

VIEW_POINTS = 12_000
"""Ions drawn in all ion layers: with MeshLab's default point size the surfaces stay visible."""

MATRIX_FRACTION = 0.25
"""Ion species holding at least this fraction of the ranged ions (the matrix) open hidden: drawn
in front of an interface that crosses the whole tip they hide it, and they say little about it.
Their layers are one click away."""

LOD_FACES = 500_000
"""Surfaces with more faces get a decimated level of detail shown first, with a fifth of this
many faces (100k: MeshLab turns such a mesh smoothly even with software OpenGL)."""

_ION_CHUNK = 4_000_000
_VERTEX_BLOCK = 20_000


def vertex_composition(*, vertices: np.ndarray, ions: IonTable, ranges: RangeTable, elements: list[str],
                       k: int = NEAREST_IONS, margin: float = 5.0) -> dict[str, np.ndarray]:
    """Composition (at.%) of each element of ``elements`` around each vertex, from its ``k`` nearest ranged ions.

    Parameters
    ----------
    vertices : (n, 3) float
        Points in nm.
    ions, ranges : IonTable, RangeTable
        The ions (read in chunks of 4M) and their ranging; molecular ions count their atoms.
    elements : list of str
        Elements of ``ranges`` to report.
    k : int
        Nearest ranged ions per vertex.
    margin : float
        Ions farther than this (nm) outside the vertices' bounding box are not searched.

    Returns
    -------
    dict
        Element -> (n,) float64 atoms of that element over all atoms of the ``k`` ions, in %;
        NaN for every vertex when no ion lies within reach.

    Notes
    -----
    Exact, and without a tree over every ion in the box: only the ranged ions within a reach of
    the vertices are kept (twice the radius of a ball holding ``k`` ions at their mean density, one
    streamed pass over a mask of cells), and a vertex whose ``k``-th nearest lies beyond the reach
    is asked again with twice the reach, until it spans the box.
    """
    from scipy.spatial import cKDTree

    vertices = np.asarray(vertices, dtype=np.float64)
    lo, hi = vertices.min(axis=0) - margin, vertices.max(axis=0) + margin
    matrix = ranges.element_matrix()[:, [ranges.elements.index(e) for e in elements]]
    atoms_per_ion = ranges.element_matrix().sum(axis=1)
    out = np.full((len(vertices), len(elements)), np.nan)
    todo = np.arange(len(vertices))
    reach = _first_reach(ions, ranges, lo, hi, k)
    while len(todo):
        # The k nearest ions of a vertex whose k-th lies within ``reach`` are all among the ions kept
        # (every ion within ``reach`` of a vertex is); the others are asked again with twice the reach,
        # until it spans the box and every ranged ion in it is kept.
        whole = reach >= np.linalg.norm(hi - lo)
        points, kinds = _ranged_near(ions, ranges, lo, hi, None if whole else (vertices[todo], reach))
        if len(points) == 0:
            if whole:
                break
            reach *= 2
            continue
        tree = cKDTree(points)
        kk = min(k, len(points))
        done = np.zeros(len(todo), dtype=bool)
        for start in range(0, len(todo), _VERTEX_BLOCK):
            block = todo[start:start + _VERTEX_BLOCK]
            dist, idx = tree.query(vertices[block], k=kk, workers=available_cores())
            dist, idx = dist.reshape(len(block), -1), idx.reshape(len(block), -1)
            ok = np.ones(len(block), dtype=bool) if whole else (dist[:, -1] <= reach) & (kk == k)
            # ions of each species per vertex, then atoms: (vertices, species) instead of (vertices, k, elements)
            counts = _kind_counts(idx, kinds, len(matrix))[ok]
            out[block[ok]] = 100 * (counts @ matrix) / (counts @ atoms_per_ion)[:, None]
            done[start:start + len(block)] = ok
        todo = todo[~done]
        reach *= 2
    return {e: out[:, j] for j, e in enumerate(elements)}


@njit(cache=True, nogil=True, parallel=True)
def _kind_counts(idx, kinds, n_kinds):  # pragma: no cover - compiled
    """(m, n_kinds) float64: how many of each row's ions ``idx`` (m, k) are of each kind (``kinds[idx]``)."""
    counts = np.zeros((idx.shape[0], n_kinds), np.float64)
    for i in prange(idx.shape[0]):
        for j in range(idx.shape[1]):
            counts[i, kinds[idx[i, j]]] += 1.0
    return counts


_CELLS_PER_REACH = 4
"""Mask cells per reach: finer cells keep fewer ions beyond the reach (at most one cell diagonal)."""

_MASK_CELLS = 1 << 24
"""Cells of the mask of the region near the vertices (16 MB): its cell is at least the box's volume
over this, so a large specimen's mask stays small (a coarser cell only keeps more ions)."""


def _first_reach(ions: IonTable, ranges: RangeTable, lo: np.ndarray, hi: np.ndarray, k: int) -> float:
    """nm: twice the radius of a ball holding ``k`` ranged ions at their mean density in the box ``lo``-``hi``
    (from a sample of about a million ions): within it, most vertices find their ``k`` nearest ions."""
    step = max(1, len(ions) // 1_000_000)
    pos = np.asarray(ions.positions[::step])
    inside = (ranges.ion_index(np.asarray(ions.mz[::step])) >= 0) & np.all((pos >= lo) & (pos <= hi), axis=1)
    density = max(int(inside.sum()) * step, 1) / float(np.prod(hi - lo))
    return 2.0 * (3.0 * k / (4.0 * np.pi * density)) ** (1.0 / 3.0)


def _ranged_near(ions: IonTable, ranges: RangeTable, lo: np.ndarray, hi: np.ndarray,
                 near: tuple[np.ndarray, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """Positions (float64) and ion indices of the ranged ions in the box ``lo``-``hi``; with ``near =
    (points, reach)`` only those in the cells within ``reach`` (Chebyshev, whole cells) of a point's
    cell: every ion within ``reach`` of a point, and a few farther. One pass over chunks."""
    from scipy.ndimage import maximum_filter

    mask, cell = None, 0.0
    if near is not None:
        points, reach = near
        cell = max(reach / _CELLS_PER_REACH, (float(np.prod(hi - lo)) / _MASK_CELLS) ** (1.0 / 3.0))
        dims = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
        mask = np.zeros(dims, dtype=bool)
        mask[tuple(np.minimum(((points - lo) // cell).astype(np.int64), dims - 1).T)] = True
        # |x - v| <= reach on an axis moves the cell index by ceil(reach / cell) at most
        mask = maximum_filter(mask, size=2 * int(np.ceil(reach / cell)) + 1)
    kept, kinds = [], []
    for start in range(0, len(ions), _ION_CHUNK):
        pos = np.asarray(ions.positions[start:start + _ION_CHUNK])  # float32 compares and shifts as its float64
        species = ranges.ion_index(ions.mz[start:start + _ION_CHUNK])
        keep = np.flatnonzero((species >= 0) & np.all((pos >= lo) & (pos <= hi), axis=1))
        if mask is not None:
            cells = np.minimum(((pos[keep] - lo) // cell).astype(np.int64), np.array(mask.shape) - 1)
            keep = keep[mask[tuple(cells.T)]]
        kept.append(pos[keep])
        kinds.append(species[keep])
    # the kept chunks stay in the table's float32 until joined: 12 bytes per kept ion fewer at the peak
    return np.concatenate(kept, dtype=np.float64), np.concatenate(kinds)


def scene_species(species: str, summary: list[dict]) -> str:
    """The element a surface is coloured by: the solute with the most significant pooled excess
    (largest |Γ| / error over the summary rows of :func:`apt_filters.pipeline.summary.surface_summary`),
    else ``species`` itself."""
    best, score = species, 0.0
    for row in summary:
        for solute, e in row["excess"].items():
            if e and e["gamma_atoms_nm2"] is not None and e["error"]:
                s = abs(e["gamma_atoms_nm2"]) / e["error"]
                if s > score:
                    best, score = solute, s
    return best


def layer_quotas(counts: dict[str, int], total: int = VIEW_POINTS) -> dict[str, int]:
    """Ions drawn per species: ``total`` shared equally between the species, a species with
    fewer ions than its share drawn whole and the rest shared among the others (water filling).

    The majority species (the matrix) thus becomes a light haze and the minority species stand
    out; each layer's label states how many of its ions it draws.
    """
    out, left = {}, total
    order = sorted(counts, key=counts.get)
    for i, s in enumerate(order):
        out[s] = min(counts[s], left // (len(order) - i))
        left -= out[s]
    return {s: out[s] for s in counts}


def _file_name(ion: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", ion).strip("_") or "ion"


@dataclass
class SceneSurface:
    """One surface of the scene: its label, element, the quantity it is coloured by and its range."""

    label: str
    element: str
    limits: tuple[float, float]
    files: list[str]
    quantity: str = ""


def write_scene(*, folder: Path, surfaces: dict[str, TriMesh], species: dict[str, str], ions: IonTable,
                ranges: RangeTable, quality: dict[str, tuple] | None = None, lod_faces: int = LOD_FACES,
                view_points: int = VIEW_POINTS, near: dict[str, IonTable] | None = None,
                counts: dict[str, int] | None = None) -> dict:
    """Write the scene into ``folder`` (meshes/, project.mlp, legend.png); returns what it wrote.

    Parameters
    ----------
    folder : Path
        Output folder; ``meshes/`` must exist.
    surfaces : dict
        Label -> mesh (nm) with face scalar ``object_id``.
    species : dict
        Label -> element the surface is coloured by (its local at.%, see :func:`vertex_composition`).
    ions, ranges : IonTable, RangeTable
        All the ions (sampled for the ion layers) and their ranging.
    quality : dict, optional
        Label -> (vertex scalar, (low, high), meaning): a map the surface already carries (the
        excess map of :mod:`apt_filters.analysis.maps`) shown as quality instead of the local at.%.
    lod_faces : int
        Meshes with more faces get a level of detail (:data:`LOD_FACES`).
    view_points : int
        Ions drawn over all ion layers (:data:`VIEW_POINTS`).
    near : dict, optional
        Label -> the ions near that surface (:func:`~apt_filters.pipeline.surface.analysis_ions`), from
        which its local composition is taken instead of ``ions``: the same wherever a vertex's
        :data:`NEAREST_IONS` nearest ions lie within the selection's reach of it (at APT densities they
        lie within about 1.5 nm).
    counts : dict, optional
        Ion species -> ions of that species in ``ions`` (the read step's summary; counted here if not given).

    Returns
    -------
    dict
        ``surfaces`` (label, element, colour range in at.%, files), ``ion_layers`` (ion, file,
        drawn, total) and ``legend`` (file name), JSON-ready.
    """
    from apt_filters.meshlab.decimation import decimate
    from apt_filters.meshlab.exports import SIDE_VIEW, colormap_rgba, write_ion_clouds, write_ply, write_project

    meshes_dir = folder / "meshes"
    layers, labels, visible, scene_surfaces = [], [], [], []
    for label, mesh in surfaces.items():
        element = species[label]
        elements = list(dict.fromkeys([element, *(e for e in species.values() if e in ranges.elements)]))
        comp = vertex_composition(vertices=mesh.vertices, ions=(near or {}).get(label, ions), ranges=ranges,
                                  elements=elements)
        mesh = mesh.copy()
        for e, values in comp.items():
            mesh.vertex_scalars[f"at_pct_{e}"] = values
        shown = f"{element} at.%"
        quality_name = f"at_pct_{element}"
        values = comp[element][np.isfinite(comp[element])]
        limits = tuple(float(x) for x in np.percentile(values, [1, 99])) if len(values) else (0.0, 100.0)
        meaning = f"{element} at.% among the {NEAREST_IONS} ranged ions nearest each vertex"
        if quality and label in quality:
            quality_name, limits, meaning = quality[label]
            shown = quality_name.replace("_", " ")
        note = [f"quality = {meaning} (colour map viridis {limits[0]:.3g} to {limits[1]:.3g})",
                *(f"at_pct_{e} = {e} at.% among the {NEAREST_IONS} ranged ions nearest each vertex" for e in comp)]
        full = write_ply(mesh, meshes_dir / f"{label}.ply", quality=quality_name, limits=limits, comments=note,
                         overwrite=True)
        files = [full.name]
        if mesh.n_faces > lod_faces:
            lod = decimate(mesh, 1 - (lod_faces // 5) / mesh.n_faces)
            lod_path = write_ply(lod, meshes_dir / f"{label}_lod.ply", quality=quality_name, limits=limits,
                                 comments=note, overwrite=True)
            layers += [lod_path, full]
            labels += [f"{label}: {shown} ({lod.n_faces:,} faces)",
                       f"{label} full resolution ({mesh.n_faces:,} faces)"]
            visible += [True, False]
            files.append(lod_path.name)
        else:
            layers.append(full)
            labels.append(f"{label}: {shown}")
            visible.append(True)
        scene_surfaces.append(SceneSurface(label, element, limits, files,
                                           quantity=f"{shown}\nnear the surface" if shown.endswith("at.%") else
                                           f"{shown}\n(detected atoms/nm², map)"))
    counts = _species_counts(ions, ranges) if counts is None else counts
    quotas = layer_quotas(counts, view_points)
    # every layer in the same two passes over the ions
    clouds = write_ion_clouds(ions, ranges, {ion: (meshes_dir / f"ions_{_file_name(ion)}.ply", quota)
                                             for ion, quota in quotas.items() if quota}, overwrite=True)
    ion_layers = []
    for ion, cloud in clouds.items():
        layers.append(cloud.path)
        labels.append(f"ions {ion} ({cloud.n_written:,} of {cloud.n_ions:,})")
        shown = cloud.n_ions < MATRIX_FRACTION * sum(counts.values())
        visible.append(shown)
        ion_layers.append({"ion": ion, "file": cloud.path.name, "drawn": cloud.n_written, "total": cloud.n_ions,
                           "color": "#" + "".join(f"{c:02x}" for c in _ion_color(ranges, ion)), "shown": shown})
    write_project(folder / "project.mlp", layers, labels, visible=visible, overwrite=True,
                  points=[p.name.startswith("ions_") for p in layers], transform=SIDE_VIEW)
    _legend(folder / "legend.png", scene_surfaces, ion_layers, colormap_rgba)
    return {"surfaces": [dataclasses.asdict(s) for s in scene_surfaces],
            "ion_layers": ion_layers, "legend": "legend.png",
            "nearest_ions": NEAREST_IONS}


def _species_counts(ions: IonTable, ranges: RangeTable) -> dict[str, int]:
    counts = np.zeros(len(ranges.ions), dtype=np.int64)
    for start in range(0, len(ions), _ION_CHUNK):
        index = ranges.ion_index(ions.mz[start:start + _ION_CHUNK])
        counts += np.bincount(index[index >= 0], minlength=len(ranges.ions))
    return {ion: int(c) for ion, c in zip(ranges.ions, counts)}


def _ion_color(ranges: RangeTable, ion: str) -> tuple[int, int, int]:
    from apt_filters.meshlab.exports import species_colors

    return tuple(int(c) for c in species_colors(ranges)[ranges.ions.index(ion)])


def _legend(path: Path, surfaces: list[SceneSurface], layers: list[dict], colormap_rgba) -> None:
    """A PNG beside the project: each surface's colour bar and each ion layer's colour."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from apt_filters.core.atomic import atomic_output

    rows = len(surfaces) + math.ceil(len(layers) / 3)
    fig = plt.figure(figsize=(6, 0.75 + 0.55 * rows), dpi=110)
    y = 1.0
    step = 1.0 / (rows + 1)
    fig.text(0.02, y - step * 0.6, "apt-filters scene (project.mlp)", fontsize=11, weight="bold")
    y -= step
    for s in surfaces:
        ax = fig.add_axes([0.38, y - step * 0.75, 0.58, step * 0.45])
        ramp = np.linspace(s.limits[0], s.limits[1], 256)
        ax.imshow(colormap_rgba(ramp, "viridis", s.limits)[None, :, :3], aspect="auto",
                  extent=(s.limits[0], s.limits[1], 0, 1))
        ax.set_yticks([])
        ax.tick_params(labelsize=8)
        fig.text(0.02, y - step * 0.6, f"{s.label}: {s.quantity}", fontsize=9, va="center")
        y -= step
    for i, layer in enumerate(layers):
        col, row = i % 3, i // 3
        x0, y0 = 0.02 + 0.33 * col, y - step * (row + 0.6)
        fig.patches.append(matplotlib.patches.Rectangle((x0, y0 - 0.02), 0.03, 0.04, color=layer["color"],
                                                        transform=fig.transFigure, figure=fig))
        fig.text(x0 + 0.045, y0, f"{layer['ion']}: {layer['drawn']:,} of {layer['total']:,} ions", fontsize=8,
                 va="center")
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
