"""Files the MeshLab GUI opens and shows well: iso-surfaces, ion point clouds, projects.

- :func:`write_ply`: binary little-endian PLY with vertex ``quality`` (the chosen scalar),
  vertex colour from a colour map of it, every other vertex scalar as a float property, and
  per face ``quality`` and ``object_id`` (MeshLab reads vertex/face quality and colour; the
  extra properties are for other tools and :func:`read_ply`).
- :func:`write_mesh`: OBJ, STL, OFF (or PLY) through pymeshlab, when asked for.
- :func:`write_ion_cloud`: ions as a coloured point cloud PLY, one colour per species
  (from the range file), subsampled to a size the GUI handles; the ratio is stated in the
  header comment and returned. :func:`write_ion_clouds`: several such layers in the same two passes.
- :func:`write_project`: a MeshLab project ``.mlp`` opening several files together.

Every file is written atomically and never replaces an existing one unless asked.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from apt_filters.core.atomic import atomic_write_bytes, atomic_write_text
from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.meshlab.bridge import COLOR_KEYS, OBJECT_ID, save_current_mesh, to_meshset

GUI_POINTS = 2_000_000
"""Default largest ion cloud written for the GUI (MeshLab stays interactive at this size)."""

UNRANGED_COLOR = (128, 128, 128)


def colormap_rgba(values: np.ndarray, cmap: str = "viridis", limits: tuple[float, float] | None = None) -> np.ndarray:
    """(n, 4) uint8 colours of ``values`` through a matplotlib colour map.

    ``limits`` defaults to the 1st and 99th percentiles, so a few outliers do not wash the
    map out; NaN maps to grey.
    """
    from matplotlib import colormaps

    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    if limits is None:
        limits = tuple(np.percentile(values[finite], [1, 99])) if finite.any() else (0.0, 1.0)
    lo, hi = limits
    t = np.clip((values - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
    rgba = colormaps[cmap](np.where(finite, t, 0.0), bytes=True)
    rgba[~finite] = (*UNRANGED_COLOR, 255)
    return rgba


def _ply_header(n_vertices: int, vertex_dtype: np.dtype, n_faces: int | None, face_dtype: np.dtype | None,
                comments: Sequence[str]) -> bytes:
    ply_types = {"f4": "float", "f8": "double", "u1": "uchar", "i4": "int", "u4": "uint"}
    lines = ["ply", "format binary_little_endian 1.0", *(f"comment {c}" for c in comments),
             f"element vertex {n_vertices}"]
    lines += [f"property {ply_types[vertex_dtype[n].str[1:]]} {n}" for n in vertex_dtype.names]
    if face_dtype is not None:
        lines.append(f"element face {n_faces}")
        for n in face_dtype.names:
            lines.append("property list uchar int vertex_indices" if n == "vertex_indices"
                         else f"property {ply_types[face_dtype[n].str[1:]]} {n}")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply(mesh: TriMesh, path: str | os.PathLike, quality: str | None = "value", cmap: str | None = "viridis",
              limits: tuple[float, float] | None = None, overwrite: bool = False,
              comments: Sequence[str] = ()) -> Path:
    """Write ``mesh`` as a binary PLY the MeshLab GUI shows coloured at once.

    Every vertex scalar is written as a float property under its own name, so any per-vertex
    map (a composition, an excess) plugs in by being a vertex scalar; ``quality`` picks the
    one MeshLab colours and shows as vertex quality.

    Parameters
    ----------
    mesh : TriMesh
        Vertices nm; scalars become properties (see module doc). Colour scalars
        (``red``... in [0, 1]) win over the colour map.
    quality : str or None
        Vertex scalar written as ``quality`` and coloured; falls back to the first scalar.
    cmap : str or None
        matplotlib colour map for the vertex colour; None writes no colour map (explicit
        colour scalars are still written).
    limits : (low, high), optional
        Colour-map range; default 1st-99th percentile.
    comments : sequence of str
        Extra header comments, e.g. what each property means and its unit.
    """
    scalars = {k: np.asarray(v) for k, v in mesh.vertex_scalars.items() if k not in COLOR_KEYS}
    if quality not in scalars:
        quality = next(iter(scalars), None)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    has_color = "red" in mesh.vertex_scalars or (cmap is not None and quality is not None)
    if has_color:
        fields += [(c, "u1") for c in COLOR_KEYS]
    if quality is not None:
        fields.append(("quality", "<f4"))
    reserved = {"x", "y", "z", "quality", *COLOR_KEYS}
    extra = [k for k in scalars if k not in reserved]  # the quality's scalar under its own name too
    fields += [(k, "<f4") for k in extra]
    v = np.empty(mesh.n_vertices, dtype=fields)
    v["x"], v["y"], v["z"] = mesh.vertices.T
    if has_color:
        if "red" in mesh.vertex_scalars:
            for c in COLOR_KEYS:
                v[c] = np.rint(255 * np.clip(mesh.vertex_scalars.get(c, np.ones(mesh.n_vertices)), 0, 1))
        else:
            rgba = colormap_rgba(scalars[quality], cmap, limits)
            for i, c in enumerate(COLOR_KEYS):
                v[c] = rgba[:, i]
    if quality is not None:
        v["quality"] = scalars[quality]
    for k in extra:
        v[k] = scalars[k]
    f_fields = [("vertex_indices_n", "u1"), ("vertex_indices", "<i4", (3,))]
    if OBJECT_ID in mesh.face_scalars:
        f_fields += [("quality", "<f4"), (OBJECT_ID, "<i4")]
    f = np.empty(mesh.n_faces, dtype=f_fields)
    f["vertex_indices_n"] = 3
    f["vertex_indices"] = mesh.faces
    if OBJECT_ID in mesh.face_scalars:
        f["quality"] = mesh.face_scalars[OBJECT_ID]
        f[OBJECT_ID] = mesh.face_scalars[OBJECT_ID]
    header_dtype = np.dtype([d for d in f_fields if d[0] != "vertex_indices_n"])
    comments = [*comments, f"apt-filters iso-surface; units nm; quality = {quality}"]
    header = _ply_header(mesh.n_vertices, v.dtype, mesh.n_faces, header_dtype, comments)
    return atomic_write_bytes(path, header + v.tobytes() + f.tobytes(), overwrite)


def write_mesh(mesh: TriMesh, path: str | os.PathLike, overwrite: bool = False, quality: str | None = "value") -> Path:
    """Write ``mesh`` in the format of ``path``'s extension: .ply (:func:`write_ply`), .obj, .stl, .off."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".ply":
        return write_ply(mesh, path, quality=quality, overwrite=overwrite)
    if ext not in {".obj", ".stl", ".off"}:
        raise AptFiltersError("mesh format must be .ply, .obj, .stl or .off", path)
    return save_current_mesh(to_meshset(mesh, quality=quality)[0], path, overwrite)


def _hex_rgb(color: str | None, fallback: tuple[int, int, int]) -> tuple[int, int, int]:
    if color is None:
        return fallback
    return tuple(int(color[i:i + 2], 16) for i in (0, 2, 4))


def species_colors(ranges: RangeTable) -> np.ndarray:
    """(n_ions + 1, 3) uint8: one RGB per ion species in ``ranges.ions`` order, last row unranged.

    Species without a colour in the range file get one from matplotlib's ``tab20``.
    """
    from matplotlib import colormaps

    tab = colormaps["tab20"].colors
    rows = [_hex_rgb(c, tuple(int(255 * x) for x in tab[i % len(tab)]))
            for i, c in enumerate(ranges.ion_colors().values())]
    return np.array(rows + [UNRANGED_COLOR], dtype=np.uint8)


@dataclass(frozen=True)
class CloudExport:
    """What :func:`write_ion_cloud` wrote."""

    path: Path
    n_written: int
    n_ions: int

    @property
    def ratio(self) -> float:
        """Fraction of the ions written (1 = all)."""
        return self.n_written / self.n_ions if self.n_ions else 1.0


CLOUD_CHUNK = 10_000_000
"""Ions ranged per chunk by :func:`write_ion_cloud` (about 20 bytes each while in flight)."""


_CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
                         ("quality", "<f4")])


def _pool(species: np.ndarray, include_unranged: bool, only: int | None = None) -> np.ndarray:
    """Chunk-local indices of the ions (``species``: their ion index, -1 unranged) eligible for a cloud:
    all ranged ions, unranged too if asked, or only the ion species of index ``only``."""
    if only is not None:
        return np.flatnonzero(species == only)
    return np.arange(len(species)) if include_unranged else np.flatnonzero(species >= 0)


def write_ion_cloud(ions: IonTable, ranges: RangeTable, path: str | os.PathLike, max_points: int = GUI_POINTS,
                    include_unranged: bool = False, seed: int = 0, overwrite: bool = False,
                    species: str | None = None) -> CloudExport:
    """Write ions as a coloured point-cloud PLY (x, y, z float32 nm; RGB by species; quality = species index).

    At most ``max_points`` ions, drawn uniformly without replacement (reproducible with
    ``seed``) and kept in file order; the header comment states the sampling ratio.
    ``species`` (an ion name of ``ranges``) writes that species only: one MeshLab layer per
    species, which the GUI shows and hides one by one (:func:`write_ion_clouds` writes them all in
    the same two passes). Two passes over chunks of :data:`CLOUD_CHUNK` ions: count the eligible
    ions per chunk, split the sample between chunks (multivariate hypergeometric, so the draw is
    uniform over all ions), then draw inside each chunk. Memory: one chunk's work arrays plus the
    written rows (19 bytes per point), whatever the number of ions.
    """
    return write_ion_clouds(ions, ranges, {species: (path, max_points)}, include_unranged=include_unranged,
                            seed=seed, overwrite=overwrite)[species]


def write_ion_clouds(ions: IonTable, ranges: RangeTable, layers: dict[str | None, tuple[str | os.PathLike, int]], *,
                     include_unranged: bool = False, seed: int = 0,
                     overwrite: bool = False) -> dict[str | None, CloudExport]:
    """Write several point clouds of ``ions`` in the same two streamed passes.

    ``layers`` maps an ion species of ``ranges`` (None: every ranged ion, unranged too with
    ``include_unranged``) to its file and its most points; each file is the one
    :func:`write_ion_cloud` writes for that species alone, with the same ``seed`` (each layer draws
    from its own generator, in the same order). Returns the exports by species.
    """
    for species, (_, max_points) in layers.items():
        if max_points < 1:
            raise AptFiltersError(f"max_points must be at least 1, got {max_points}")
        if species is not None and species not in ranges.ions:
            raise AptFiltersError(f"no ion {species!r} in the range file; ions: {', '.join(ranges.ions)}")
    only = {sp: None if sp is None else ranges.ions.index(sp) for sp in layers}
    chunks = [slice(i, i + CLOUD_CHUNK) for i in range(0, len(ions), CLOUD_CHUNK)]
    counts = {sp: np.zeros(len(chunks), dtype=np.int64) for sp in layers}
    for c, chunk in enumerate(chunks):
        species = ranges.ion_index(ions.mz[chunk])
        for sp in layers:
            counts[sp][c] = len(_pool(species, include_unranged, only[sp]))
    rngs = {sp: np.random.default_rng(seed) for sp in layers}
    take = {sp: counts[sp] if counts[sp].sum() <= n else rngs[sp].multivariate_hypergeometric(counts[sp], n)
            for sp, (_, n) in layers.items()}
    rows = {sp: [] for sp in layers}
    colors = species_colors(ranges)
    for c, chunk in enumerate(chunks):
        index = ranges.ion_index(ions.mz[chunk])
        positions = None
        for sp in layers:
            pool, k = _pool(index, include_unranged, only[sp]), take[sp][c]
            chosen = pool if k == len(pool) else np.sort(rngs[sp].choice(pool, size=k, replace=False))
            if positions is None and len(chosen):
                positions = np.asarray(ions.positions[chunk])
            part = np.empty(len(chosen), dtype=_CLOUD_DTYPE)
            if len(chosen):
                part["x"], part["y"], part["z"] = positions[chosen].T
            part["red"], part["green"], part["blue"] = colors[index[chosen]].T  # -1: unranged row
            part["quality"] = index[chosen]
            rows[sp].append(part)
    out = {}
    for sp, (path, _) in layers.items():
        v = np.concatenate(rows[sp]) if rows[sp] else np.empty(0, dtype=_CLOUD_DTYPE)
        n, n_pool = len(v), int(counts[sp].sum())
        what = f"{sp} ions" if sp is not None else "ions" if include_unranged else "ranged ions"
        comments = [f"apt-filters ion cloud; units nm; {n} of {n_pool} {what} (sampling ratio {n / max(n_pool, 1):.6g})",
                    "quality = species index: " + ", ".join(f"{i}={name}" for i, name in enumerate(ranges.ions))
                    + (", -1=unranged" if include_unranged else "")]
        header = _ply_header(n, v.dtype, None, None, comments)
        out[sp] = CloudExport(atomic_write_bytes(path, header + v.tobytes(), overwrite), n, n_pool)
    return out


POINTS_RENDERING = "0001" + "100100000" + "000000000" * 3 + "10000000000100011010110000010101"
"""How MeshLab (2020.09 and later) draws a point-cloud layer, in its own serialisation of the
rendering options (``MLRenderingData::serialize``, vcglib ``PerViewData``): primitive mask
(points only), per primitive the attributes used (points: position and vertex colour; no
normals), then the 32 view flags of ``MLPerViewGLOptions`` (MeshLab's defaults except
per-point shading off, so each ion shows its species colour unlit, and distance attenuation on)."""

POINT_SIZE = 2.0
"""Pixels per ion in MeshLab (its default is 3): small enough that the surfaces show through."""


_TILT = np.radians(20.0)
SIDE_VIEW = np.array([[1, 0, 0, 0], [0, np.sin(_TILT), np.cos(_TILT), 0], [0, -np.cos(_TILT), np.sin(_TILT), 0],
                      [0, 0, 0, 1]])
"""Layer transform that shows a specimen from the side, z (the analysis direction) up and tilted
20 degrees toward the viewer (so flat interfaces across the tip show as bands, not lines):
MeshLab opens looking down its z axis, which for a tip means looking through its whole length."""


def write_project(path: str | os.PathLike, meshes: Sequence[str | os.PathLike], labels: Sequence[str] | None = None,
                  overwrite: bool = False, visible: Sequence[bool] | None = None,
                  points: Sequence[bool] | None = None, transform: np.ndarray | None = None) -> Path:
    """Write a MeshLab project (.mlp) that opens ``meshes`` together (identity transforms).

    Mesh paths are stored relative to the project's folder when they lie under it, so the
    folder can be moved as a whole. ``labels`` name the layers in MeshLab's layer dialog;
    ``visible`` (default all) says which layers show when the project opens (MeshLab 2020.09
    and later read it; the others are one click away). Layers flagged in ``points`` are drawn
    as unlit points of :data:`POINT_SIZE` pixels in their vertex colours
    (:data:`POINTS_RENDERING`); MeshLab versions that do not read these options use their own.
    ``transform`` (4 x 4, default identity) is every layer's display matrix, e.g.
    :data:`SIDE_VIEW`; the files keep their coordinates.
    """
    path = Path(path)
    if path.suffix.lower() != ".mlp":
        raise AptFiltersError("a MeshLab project must end in .mlp", path)
    labels = [Path(m).stem for m in meshes] if labels is None else list(labels)
    visible = [True] * len(meshes) if visible is None else list(visible)
    points = [False] * len(meshes) if points is None else list(points)
    if not len(labels) == len(visible) == len(points) == len(meshes):
        raise AptFiltersError(f"{len(labels)} labels, {len(visible)} visibilities, {len(points)} point flags "
                              f"for {len(meshes)} meshes", path)
    matrix = np.eye(4) if transform is None else np.asarray(transform, dtype=np.float64)
    matrix_text = "\n" + " ".join(f"{v:g}" for v in matrix.ravel()) + " \n"
    root = ET.Element("MeshLabProject")
    group = ET.SubElement(root, "MeshGroup")
    base = path.parent.resolve()
    for mesh, label, shown, cloud in zip(meshes, labels, visible, points):
        mesh = Path(mesh).resolve()
        if not mesh.is_file():
            raise InputError("mesh of the project not found", mesh)
        name = mesh.relative_to(base).as_posix() if mesh.is_relative_to(base) else str(mesh)
        element = ET.SubElement(group, "MLMesh", idInFile="-1", visible="1" if shown else "0", label=label,
                                filename=name)
        ET.SubElement(element, "MLMatrix44").text = matrix_text
        if cloud:
            ET.SubElement(element, "RenderingOption", pointSize=f"{POINT_SIZE:g}").text = POINTS_RENDERING
    ET.SubElement(root, "RasterGroup")
    ET.indent(root, " ")
    text = "<!DOCTYPE MeshLabDocument>\n" + ET.tostring(root, encoding="unicode") + "\n"
    return atomic_write_text(path, text, overwrite)


_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4", "uint": "<u4",
              "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2",
              "int32": "<i4", "uint32": "<u4", "float32": "<f4", "float64": "<f8"}


def read_ply(path: str | os.PathLike) -> TriMesh:
    """Read a binary little-endian triangle PLY with all its vertex and face properties.

    For files written by :func:`write_ply` (and similar: scalar properties, one
    ``list uchar int|uint`` of 3 indices per face). Colours come back as ``red``... in
    [0, 1], vertex ``quality`` under the name stated in :func:`write_ply`'s header comment
    (else ``"quality"``), face properties as face scalars (``quality`` dropped when
    ``object_id`` holds the same).
    """
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise InputError("not a PLY file", path)
    lines = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise InputError("only binary little-endian PLY is read", path)
    elements: list[tuple[str, int, list]] = []
    quality_name = "quality"
    for line in lines:
        words = line.split()
        if words[:1] == ["comment"] and "quality =" in line and "iso-surface" in line:
            quality_name = line.rsplit("quality =", 1)[1].strip()
        elif words[:1] == ["element"]:
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"] and elements:
            if words[1] == "list":
                if words[2] not in ("uchar", "uint8") or _PLY_TYPES.get(words[3]) not in ("<i4", "<u4"):
                    raise InputError(f"unsupported face list {' '.join(words[2:4])}", path)
                elements[-1][2].extend([(f"{words[4]}_n", "u1"), (words[4], _PLY_TYPES[words[3]], (3,))])
            elif words[1] in _PLY_TYPES:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise InputError(f"unknown PLY type {words[1]}", path)
    arrays, offset = {}, end + len(b"end_header\n")
    for name, count, fields in elements:
        dtype = np.dtype(fields)
        if offset + count * dtype.itemsize > len(data):
            raise InputError(f"PLY truncated in element {name}", path)
        arrays[name] = np.frombuffer(data, dtype, count, offset)
        offset += count * dtype.itemsize
    v = arrays.get("vertex")
    if v is None:
        raise InputError("PLY has no vertices", path)
    f = arrays.get("face")
    faces = np.zeros((0, 3), np.int64)
    face_scalars = {}
    if f is not None:
        if np.any(f["vertex_indices_n"] != 3):
            raise InputError("PLY has faces that are not triangles", path)
        faces = f["vertex_indices"].astype(np.int64)
        face_scalars = {n: f[n].copy() for n in f.dtype.names if not n.startswith("vertex_indices")}
        if OBJECT_ID in face_scalars:
            face_scalars.pop("quality", None)
    vertex_scalars = {}
    for n in v.dtype.names:
        if n in ("x", "y", "z"):
            continue
        values = v[n] / 255.0 if n in COLOR_KEYS else v[n].astype(np.float64)
        vertex_scalars[quality_name if n == "quality" else n] = values
    return TriMesh(np.stack([v["x"], v["y"], v["z"]], axis=1), faces, vertex_scalars, face_scalars)
