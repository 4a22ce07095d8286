"""Maps on the surface: where along an interface a solute segregates, with errors.

For each solute and each vertex of a surface, the local Gibbsian excess (detected atoms per nm²)
and each phase's plateau composition next to the surface, from the ions near a patch of the
surface around the vertex, with standard errors; a chi-square test says whether the map varies
more than counting noise.

Method
------
Each ion within ``max_distance`` of the surface gets its exact signed distance and closest point
(:class:`~apt_filters.core.distance.SurfaceDistance`; counted positive inside), is binned like the
proxigram (bin centre s, ``bin_width``) and split over the three corners of its closest triangle
by the barycentric weights of its closest point, so that a vertex receives the ions of the area
it owns (a third of its triangles, the area the map divides by). Ions beyond the rim of an open
surface are left out (``keep_edge``), as the proxigram does. Per vertex and region — the two
plateau windows ``inner <= |s| <= max_distance`` and the two halves of the interface region
``|s| < inner`` — the moments ``sum N``, ``sum N s``, ``sum N s²``, ``sum n``, ``sum n s`` are
kept (N atoms, n the solute's atoms).

A vertex's patch is the set of vertices of the same object within a Euclidean radius R whose
normals face the same way (positive dot product: a thin plate's far side is not the same
interface), gathered by cells of R/4 (:func:`patch_sums`). Summing the moments over the patch
gives exactly what
:func:`~apt_filters.analysis.excess.excess_of_profile` would see on the patch's own proxigram:
plateaus fitted as straight lines over the windows (slope kept only where significant), the
excess counted against them in ``|s| < inner``, divided by the patch's area. The same definition
as the per-object excess, so the area-weighted mean of the map is the object's excess within its
error. Whether a plateau is a line or a constant is decided once per object (its slope significant
at 2 standard errors, from all its ions) and every patch of the object fits the same form: a patch
deciding from its own few ions would keep the noise slopes that pass the test and extrapolate them
to the surface with errors that ignore the selection (pre-test estimation; it made the errors
2-5 % small and the uniformity test fire too often). The levels' binomial variance is counted at the
object's window fraction for the same reason: a patch's own count of a trace element makes its
error small where the count fluctuated low. The counting variance of the excess is Poisson, ``(1 - c)² n + c² (N - n)`` on each side
(c the plateau level): solute and other atoms are drawn independently, as the atoms a detector
samples are; the plateaus add their fitted variance.

R grows from twice the median edge length by factors of sqrt(2) until the excess's predicted
standard error falls to the stated level or the patch holds the vertex's whole (facing) object;
the prediction scales the object's error by the patch's plateau-window atoms, not by its own
solute counts, which would select patches whose solute fluctuated low (:func:`_window_atoms`); the
error stated per vertex is the patch's own. The level
is ``max_error`` if given, else per object and solute the larger of ``relative_error`` times the
object's |excess| and the error a patch of 1/``min_patches`` of the object would have: a map
resolves at least ``min_patches`` patches of an object whose excess is barely measurable, and
finer ones where there is more to see. Composition maps (``c_in``, ``c_out``: the inside and
outside plateau levels at the surface) use the same patches as their solute's excess.

Significance: each object is cut into disjoint patches of the map's median patch area (farthest
point seeds, each vertex to the nearest seed facing its way); their excesses and the errors
uniform segregation predicts for them give ``chi² = sum (Gamma_k - mean_w)² / sigma_k²`` (mean_w
weighted by 1 / sigma_k²), ``K - 1`` degrees of freedom, and the p-value of uniform segregation.
Patches are independent: no ion is counted in two.

References
----------
Hellman, Vandenbroucke, Rüsing, Isheim, Seidman (2000) Microsc. Microanal. 6, 437 (proxigram);
Krakauer & Seidman (1993) Phys. Rev. B 48, 6724 (excess); Felfer, Scherrer, Demeulemeester,
Vandervorst, Cairney (2015) Ultramicroscopy 159, 438 (excess per surface element); Peng et al.
(2019) Microsc. Microanal. 25, 389 (interface-resolved excess and composition).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np
from numba import njit, prange

from apt_filters.analysis.excess import levels_from_moments, reference_counts
from apt_filters.analysis.proxigram import face_objects
from apt_filters.core.atomic import atomic_output
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh, vertex_normals
from apt_filters.core.triangle import closest_on_triangle
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable

UNITS = "detected atoms/nm²"
MIN_COUNTS = 10.0
"""Atoms of the solute a patch's interface region must hold (counted or expected from its plateaus)
before its error is believed: the Poisson error of fewer is not Gaussian (none: an error of 0)."""
_MATRIX, _PRECIPITATE, _BETWEEN_OUT, _BETWEEN_IN = range(4)
"""Regions of a vertex's moments: outside and inside plateau windows, outside and inside halves of |s| < inner."""


@dataclass
class ObjectMapStats:
    """One solute's map over one object, and the test of uniform segregation.

    Attributes
    ----------
    object_id : int
    area : float
        nm².
    excess, excess_sigma : float
        The object's excess from all its ions (the map's definition), detected atoms/nm².
    c_in, c_out : float
        The object's plateau fractions at its surface, inside and outside, from all its ions.
    map_mean : float
        Area-weighted mean of the map over the object's vertices.
    map_p5, map_p95 : float
        5th and 95th area-weighted percentiles of the map.
    target_sigma : float
        Error level the patches were grown to reach, detected atoms/nm².
    median_sigma, median_radius : float
        Median standard error and patch radius (nm) over the object's vertices.
    n_patches : int
        Disjoint patches of the test.
    chi2, dof, p_value : float
        Chi-square of the disjoint patches against their weighted mean, its degrees of
        freedom (patches - 1) and the p-value of uniform segregation (NaN below two patches).
    spread : float
        Standard deviation of the excess between patches beyond counting noise (method of
        moments, 0 if the noise explains it all), detected atoms/nm².
    """

    solute: str
    object_id: int
    area: float
    excess: float
    excess_sigma: float
    c_in: float
    c_out: float
    map_mean: float
    map_p5: float
    map_p95: float
    target_sigma: float
    median_sigma: float
    median_radius: float
    n_patches: int
    chi2: float
    dof: int
    p_value: float
    spread: float


@dataclass
class SoluteMap:
    """Per-vertex maps of one solute (NaN where a vertex has no patch: unused or no plateau ions).

    Attributes
    ----------
    excess, excess_sigma : (n,) float64
        Local excess and its standard error, detected atoms per nm².
    c_in, c_in_sigma, c_out, c_out_sigma : (n,) float64
        Plateau fractions at the surface inside (positive distances) and outside, with errors.
    radius, area : (n,) float64
        Patch radius (nm) and area (nm²).
    target : (n,) float64
        The error level the vertex's patch was grown to reach.
    patch : (n,) int64
        Disjoint patch of the significance test (-1 for unused vertices).
    patch_excess, patch_sigma : (k,) float64
        Excess and error of each disjoint patch.
    objects : list of ObjectMapStats
    """

    solute: str
    excess: np.ndarray
    excess_sigma: np.ndarray
    c_in: np.ndarray
    c_in_sigma: np.ndarray
    c_out: np.ndarray
    c_out_sigma: np.ndarray
    radius: np.ndarray
    area: np.ndarray
    target: np.ndarray
    patch: np.ndarray
    patch_excess: np.ndarray
    patch_sigma: np.ndarray
    objects: list[ObjectMapStats] = field(default_factory=list)


@dataclass
class SurfaceMaps:
    """Maps of every solute on one surface (see the module docstring).

    Attributes
    ----------
    maps : dict solute -> SoluteMap
    vertex_object : (n,) int64
        Object of each vertex (-1: in no triangle).
    vertex_area : (n,) float64
        Area each vertex owns (a third of its triangles'), nm².
    window_nm : (inner, outer)
    vertices, normals : (n, 3) float64
        Vertex positions (nm) and unit normals the patches were made of.
    """

    maps: dict[str, SoluteMap]
    vertex_object: np.ndarray
    vertex_area: np.ndarray
    window_nm: tuple[float, float]
    vertices: np.ndarray
    normals: np.ndarray

    def patch_average(self, values: np.ndarray, solute: str) -> tuple[np.ndarray, np.ndarray]:
        """Area-weighted means of a per-vertex field ``values`` (n,) over each vertex's own patch of
        ``solute``'s map (n,), and over each disjoint patch of its test (k,): what the map and the
        patches would read if ``values`` were the truth."""
        m = self.maps[solute]
        weighted = np.stack([np.asarray(values, dtype=np.float64) * self.vertex_area, self.vertex_area], axis=1)
        per_vertex = np.full(len(self.vertex_area), np.nan)
        for r in np.unique(m.radius[np.isfinite(m.radius)]):
            q = np.flatnonzero(m.radius == r)
            sums = patch_sums(self.vertices, self.normals, self.vertex_object, weighted, q, r)
            per_vertex[q] = sums[:, 0] / sums[:, 1]
        ok = m.patch >= 0
        n = len(m.patch_excess)
        per_patch = np.bincount(m.patch[ok], weighted[ok, 0], n) / np.bincount(m.patch[ok], weighted[ok, 1], n)
        return per_vertex, per_patch

    def vertex_scalars(self) -> dict[str, np.ndarray]:
        """PLY vertex properties: ``excess_<El>``, ``excess_<El>_sigma`` (detected atoms/nm²),
        ``c_in_<El>``, ``c_out_<El>`` and their ``_sigma`` (fractions), ``patch_radius_<El>`` (nm)."""
        out = {}
        for el, m in self.maps.items():
            out |= {f"excess_{el}": m.excess, f"excess_{el}_sigma": m.excess_sigma, f"c_in_{el}": m.c_in,
                    f"c_in_{el}_sigma": m.c_in_sigma, f"c_out_{el}": m.c_out, f"c_out_{el}_sigma": m.c_out_sigma,
                    f"patch_radius_{el}": m.radius}
        return out

    def rows(self) -> list[dict]:
        """One row per solute and object: :class:`ObjectMapStats` as a dict (None where not finite, for JSON)."""
        return [{k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in vars(s).items()}
                for m in self.maps.values() for s in m.objects]

    def most_significant(self) -> str | None:
        """The solute whose map varies most significantly (smallest p-value over its objects; then
        the largest object excess in errors), the one shown as vertex quality."""
        def key(el):
            stats = self.maps[el].objects
            p = min((s.p_value for s in stats if np.isfinite(s.p_value)), default=1.0)
            z = max((abs(s.excess) / s.excess_sigma for s in stats if s.excess_sigma > 0), default=0.0)
            return (p, -z)
        return min(self.maps, key=key, default=None)

    def limits(self, solute: str, object_id: int | None = None) -> tuple[float, float]:
        """Colour range of a map from its data: the area-weighted 2nd and 98th percentiles over the
        surface, or over one object."""
        values = self.maps[solute].excess
        ok = np.isfinite(values) & (self.vertex_area > 0)
        if object_id is not None:
            ok &= self.vertex_object == object_id
        if not ok.any():
            return (0.0, 1.0)
        lo, hi = _weighted_quantiles(values[ok], self.vertex_area[ok], [0.02, 0.98])
        return (lo, hi) if hi > lo else (lo - 1.0, hi + 1.0)

    def plot(self, path: str | os.PathLike, mesh: TriMesh, solute: str, object_id: int, title: str | None = None,
             overwrite: bool = False, max_faces: int = 60_000) -> Path:
        """PNG of ``solute``'s excess map on one object of ``mesh`` (the mesh the maps were made on).

        Two views: an interface that faces one way on average (an open one) face-on and obliquely
        from behind; a closed object from two opposite sides. The colours span the object's own
        area-weighted 2nd-98th percentiles, in detected atoms/nm² on the colour bar; vertices
        without a patch are grey. The title states the object's excess with its error, the map's
        5th-95th percentiles and the test of uniform segregation in words.
        """
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib import colormaps
        from matplotlib.colors import Normalize
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        m = self.maps[solute]
        [stats] = [s for s in m.objects if s.object_id == object_id] or [None]
        mine = np.flatnonzero(face_objects(mesh) == object_id)
        if stats is None or not len(mine):
            raise AptFiltersError(f"no {solute} map on object {object_id}")
        faces = mesh.faces[mine[:: max(1, len(mine) // max_faces)]]
        with warnings.catch_warnings():  # a face without any patched corner stays NaN (grey)
            warnings.simplefilter("ignore", RuntimeWarning)
            value = np.nanmean(m.excess[faces], axis=1)
        norm = Normalize(*self.limits(solute, object_id))
        colors = colormaps["viridis"](norm(np.nan_to_num(value, nan=norm.vmin)))
        colors[~np.isfinite(value)] = (0.6, 0.6, 0.6, 1.0)
        tris = mesh.vertices[faces]
        lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
        centre, half = (lo + hi) / 2, max((hi - lo).max() / 2, 1e-6)
        # the area-weighted mean normal: about 0 for a closed object, about 1 for a flat interface
        areal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]).sum(axis=0)
        facing = np.linalg.norm(areal) / max(np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0],
                                                                      tris[:, 2] - tris[:, 0]), axis=1).sum(), 1e-300)
        if facing > 0.3:
            normal = areal / np.linalg.norm(areal)
            elev = float(np.degrees(np.arcsin(np.clip(normal[2], -1, 1))))
            azim = float(np.degrees(np.arctan2(normal[1], normal[0])))
            # face-on, and tilted 50° towards the horizon to show its relief
            tilt = elev - 50.0 if elev > 0 else elev + 50.0
            views = (("face-on", elev, azim), ("tilted 50°", tilt, azim))
        else:
            views = (("front", 20.0, -60.0), ("back", -20.0, 120.0))
        fig = plt.figure(figsize=(10, 4.6), dpi=110)
        for k, (name, elev, azim) in enumerate(views):
            ax = fig.add_subplot(1, 2, k + 1, projection="3d")
            ax.set_proj_type("ortho")
            # the faces' own colour as edges: no seams between triangles
            ax.add_collection3d(Poly3DCollection(tris, facecolors=colors, edgecolors=colors, linewidths=0.2))
            for axis, i in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), range(3)):
                axis(centre[i] - half, centre[i] + half)
            ax.set_box_aspect((1, 1, 1))
            for i, (label, ticks) in enumerate(((ax.set_xlabel, ax.set_xticks), (ax.set_ylabel, ax.set_yticks),
                                                (ax.set_zlabel, ax.set_zticks))):
                # an axis seen end-on has its ticks piled up: left unlabelled
                seen = np.array([np.cos(np.radians(elev)) * np.cos(np.radians(azim)),
                                 np.cos(np.radians(elev)) * np.sin(np.radians(azim)), np.sin(np.radians(elev))])
                if abs(seen[i]) > 0.9:
                    ticks([])
                else:
                    label(f"{'xyz'[i]} (nm)")
            ax.view_init(elev=elev, azim=azim)
            ax.set_title(f"{name} (elevation {elev:.0f}°, azimuth {azim % 360:.0f}°)", fontsize=8, pad=16)
        if not np.isfinite(stats.p_value):
            verdict = "too few patches to test whether it is uniform"
        elif stats.p_value < 0.05:
            verdict = (f"varies more than counting noise (uniform segregation: "
                       f"p {'< 1e-6' if stats.p_value < 1e-6 else f'= {stats.p_value:.2g}'})")
        else:
            verdict = f"consistent with uniform segregation (p = {stats.p_value:.2g})"
        fig.suptitle(title or (f"{solute} excess on object {object_id} ({stats.area:.0f} nm²): "
                               f"{stats.excess:.3g} ± {stats.excess_sigma:.2g} {UNITS}\nmap {stats.map_p5:.3g} to "
                               f"{stats.map_p95:.3g} (5th-95th percentile) over {stats.n_patches} independent "
                               f"patches; {verdict}"), fontsize=9)
        bar = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap="viridis"), ax=fig.axes, shrink=0.7, pad=0.06)
        bar.set_label(f"{solute} excess ({UNITS})")
        # the size of counting noise on the same scale: the map's mean ± its median standard error
        bar.ax.errorbar([0.5], [stats.map_mean], yerr=[stats.median_sigma], color="red", capsize=4, lw=1.5)
        bar.ax.set_xlabel("red: a patch's\n±1 SE", color="red", fontsize=7)
        with atomic_output(path, overwrite) as tmp:
            fig.savefig(tmp, format="png", bbox_inches="tight")
        plt.close(fig)
        return Path(path)


def _weighted_quantiles(values: np.ndarray, weights: np.ndarray, q) -> list[float]:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return [float(values[order][min(np.searchsorted(cum, p * cum[-1]), len(cum) - 1)]) for p in q]


@njit(cache=True, error_model="numpy")
def _accumulate(points, face, faces, vertices, region, s, atoms, out):
    """Add each ion's moments to the corners of its closest triangle, by the barycentric weights of
    its closest point. out: (n_vertices, 4, 3 + 2 E) over regions; atoms (N, E + 1), last = all atoms."""
    n_el = atoms.shape[1] - 1
    for i in range(points.shape[0]):
        f = face[i]
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        _, u, w, _ = closest_on_triangle(points[i, 0], points[i, 1], points[i, 2],
                                         vertices[a, 0], vertices[a, 1], vertices[a, 2],
                                         vertices[b, 0], vertices[b, 1], vertices[b, 2],
                                         vertices[c, 0], vertices[c, 1], vertices[c, 2])
        r, si, total = region[i], s[i], atoms[i, n_el]
        for v, weight in ((a, 1.0 - u - w), (b, u), (c, w)):
            t = weight * total
            out[v, r, 0] += t
            out[v, r, 1] += t * si
            out[v, r, 2] += t * si * si
            for e in range(n_el):
                x = weight * atoms[i, e]
                out[v, r, 3 + e] += x
                out[v, r, 3 + n_el + e] += x * si


@njit(cache=True, parallel=True, error_model="numpy")
def _ball_sums(points, normals, obj, values, qpoints, qnormals, qobj, radius, origin, dims, skeys, order):
    """(Q, K) sums of ``values`` (n, K) of the items of the same object within ``radius`` nm of each
    query whose normals face its way; items bucketed in cells of ``radius`` (sorted cell keys
    ``skeys`` of the items ``order``)."""
    out = np.zeros((qpoints.shape[0], values.shape[1]))
    r2 = radius * radius
    for j in prange(qpoints.shape[0]):
        px, py, pz = qpoints[j, 0], qpoints[j, 1], qpoints[j, 2]
        cx = int(np.floor((px - origin[0]) / radius))
        cy = int(np.floor((py - origin[1]) / radius))
        cz = int(np.floor((pz - origin[2]) / radius))
        for ix in range(max(cx - 1, 0), min(cx + 2, dims[0])):
            for iy in range(max(cy - 1, 0), min(cy + 2, dims[1])):
                for iz in range(max(cz - 1, 0), min(cz + 2, dims[2])):
                    key = (ix * dims[1] + iy) * dims[2] + iz
                    lo = np.searchsorted(skeys, key)
                    hi = np.searchsorted(skeys, key, side="right")
                    for k in range(lo, hi):
                        v = order[k]
                        if obj[v] != qobj[j]:
                            continue
                        dx, dy, dz = points[v, 0] - px, points[v, 1] - py, points[v, 2] - pz
                        if dx * dx + dy * dy + dz * dz > r2:
                            continue
                        facing = (normals[v, 0] * qnormals[j, 0] + normals[v, 1] * qnormals[j, 1]
                                  + normals[v, 2] * qnormals[j, 2])
                        if facing <= 0:
                            continue
                        for c in range(values.shape[1]):
                            out[j, c] += values[v, c]
    return out


PATCH_CELLS = 4
"""A patch of radius R sums cells of R / PATCH_CELLS (see :func:`patch_sums`)."""


def patch_sums(points: np.ndarray, normals: np.ndarray, obj: np.ndarray, values: np.ndarray, queries: np.ndarray,
               radius: float, cells: int | None = PATCH_CELLS) -> np.ndarray:
    """(Q, K) sums of per-vertex ``values`` (n, K) over the patch of radius ``radius`` nm of each
    vertex in ``queries`` (Q,).

    The patch: vertices of the same object ``obj`` (n,) within the radius whose unit ``normals``
    (n, 3) have a positive dot product with the query's. With ``cells``, vertices are first grouped
    by cubic cells of ``radius / cells``, object and the axis their normal is closest to (with its
    sign), and a group is in the patch when its mean position is within the radius and its mean
    normal faces the query's: the boundary of the patch moves by up to half a cell, its cost no
    longer grows with the vertices in it (about ``pi cells²`` groups per patch). ``cells=None``:
    vertex by vertex.
    """
    points = np.asarray(points, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    queries = np.asarray(queries, dtype=np.int64)
    q_points, q_normals, q_obj = points[queries], normals[queries], obj[queries]
    if cells:
        axis = np.argmax(np.abs(normals), axis=1)
        facing = 2 * axis + (normals[np.arange(len(normals)), axis] < 0)
        cell = np.floor((points - points.min(axis=0)) / (radius / cells)).astype(np.int64)
        _, group = np.unique(np.column_stack([cell, obj, facing]), axis=0, return_inverse=True)
        group = group.ravel()
        n = int(group.max()) + 1
        size = np.bincount(group, minlength=n)
        points = np.stack([np.bincount(group, points[:, c], n) / size for c in range(3)], axis=1)
        normals = np.stack([np.bincount(group, normals[:, c], n) for c in range(3)], axis=1)
        values = np.stack([np.bincount(group, values[:, c], n) for c in range(values.shape[1])], axis=1)
        group_obj = np.empty(n, np.int64)
        group_obj[group] = obj
        obj = group_obj
    lo = points.min(axis=0)
    dims = (np.floor((points.max(axis=0) - lo) / radius) + 1).astype(np.int64)
    cell = np.floor((points - lo) / radius).astype(np.int64)
    keys = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    order = np.argsort(keys, kind="stable")
    return _ball_sums(points, normals, obj, np.ascontiguousarray(values), q_points, q_normals, q_obj, float(radius),
                      lo, dims, keys[order], order)


def _evaluate(stats: np.ndarray, area: np.ndarray, k: int, n_el: int,
              like: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, ...]:
    """Excess (per nm²), its error, the inside and outside levels with errors of element k, the
    larger of its counted and reference atoms in the interface region, the excess count's
    variance from counting in that region and from the plateau fits, which plateaus were fitted
    as lines and the plateau windows' mean fractions ((..., 2) each: outside, inside), from summed
    moments ``stats`` (..., 4, 3 + 2 E) over ``area`` (...) nm².

    ``like``: the object's (lines, window fractions), each (..., 2), for a patch of it: fit those
    plateaus as lines and the others as constants, and count the levels' binomial variance at the
    object's fractions (:func:`excess_maps`). None: keep a slope where it is significant and
    count at the window's own fraction, as the proxigram's excess does.
    """
    count, var_counts, var_levels, expected, kept, means, levels = 0.0, 0.0, 0.0, 0.0, [], [], []
    for side, (r, window) in enumerate(((_BETWEEN_OUT, _MATRIX), (_BETWEEN_IN, _PRECIPITATE))):
        w = stats[..., window, :]
        given = {} if like is None else {"slope_sigmas": np.where(like[0][..., side], 0.0, np.inf),
                                         "fraction": like[1][..., side]}
        total, n = stats[..., r, 0], stats[..., r, 3 + k]
        with np.errstate(invalid="ignore", divide="ignore"):  # empty windows: NaN levels
            lv = levels_from_moments(w[..., 0], w[..., 1], w[..., 2], w[..., 3 + k], w[..., 3 + n_el + k], **given)
            means.append(w[..., 3 + k] / w[..., 0])
            ref, var_ref = reference_counts(total, stats[..., r, 1], *lv)
        c = lv[0]
        count = count + n - ref
        expected = expected + np.maximum(n, ref)
        var_counts = var_counts + (1 - c) ** 2 * n + c ** 2 * (total - n)
        var_levels = var_levels + var_ref
        kept.append(lv[1] != 0)
        levels.append(lv)
    out_level, in_level = levels
    with np.errstate(invalid="ignore", divide="ignore"):
        return (count / area, np.sqrt(np.maximum(var_counts + var_levels, 0.0)) / area, in_level[0],
                np.sqrt(in_level[2]), out_level[0], np.sqrt(out_level[2]), expected, var_counts,
                np.maximum(var_levels, 0.0),  # a quadratic form >= 0 that rounding can take below 0
                np.stack(kept, axis=-1), np.stack(means, axis=-1))


def _farthest_seeds(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of k farthest-point seeds of ``points`` (N, 3), from the first point."""
    seeds = [0]
    d = np.linalg.norm(points - points[0], axis=1)
    for _ in range(k - 1):
        seeds.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(points - points[seeds[-1]], axis=1))
    return np.array(seeds)


def _disjoint_patches(points, normals, obj, vertex_area, patch_area) -> np.ndarray:
    """(n,) disjoint patch of each vertex: per object, round(area / patch_area) farthest-point
    seeds, each vertex to the nearest of its 4 nearest seeds facing its way (else the nearest)."""
    from scipy.spatial import cKDTree

    label = np.full(len(points), -1, np.int64)
    next_label = 0
    for o in np.unique(obj[obj >= 0]):
        idx = np.flatnonzero(obj == o)
        k = int(np.clip(np.rint(vertex_area[idx].sum() / patch_area[o]), 1, len(idx)))
        seeds = idx[_farthest_seeds(points[idx], k)]
        _, near = cKDTree(points[seeds]).query(points[idx], k=min(4, k))
        near = near.reshape(len(idx), -1)
        facing = np.einsum("ijk,ik->ij", normals[seeds][near], normals[idx]) > 0
        pick = np.where(facing.any(axis=1), np.argmax(facing, axis=1), 0)
        label[idx] = next_label + near[np.arange(len(idx)), pick]
        next_label += k
    return label


def excess_maps(*, mesh: TriMesh, ions: IonTable | Iterable[IonTable], ranges: RangeTable,
                solutes: list[str] | None = None, bin_width: float = 0.1, max_distance: float = 3.0,
                inner: float = 1.0, keep_edge: bool = False, relative_error: float = 0.25,
                max_error: float | None = None, min_patches: int = 8, chunk: int = 1 << 22) -> SurfaceMaps:
    """Excess and plateau-composition maps of ``solutes`` on ``mesh``, with errors and significance.

    Parameters
    ----------
    mesh : TriMesh
        Surface, normals out of the region above the iso-value (open or closed); objects are
        ``face_scalars["object_id"]`` or its connected components, as in the proxigram.
    ions : IonTable or iterable of IonTable
        Ions (processed ``chunk`` at a time) or consecutive chunks of them.
    ranges : RangeTable
        Ranging and decomposition: an element's counts are its decomposed atoms over all atoms.
    solutes : list of str, optional
        Elements to map (default: every element of the range table).
    bin_width, max_distance, inner : float
        Proxigram bins (nm), half range (nm; the outer edge of the plateau windows) and the inner
        edge of the plateau windows: the per-object excess's definitions (defaults 0.1, 3, 1).
    keep_edge : bool
        Keep ions beyond the rim of an open surface (left out by default, as in the proxigram).
    relative_error, max_error, min_patches
        Error level each vertex's patch is grown to reach (module docstring): ``max_error``
        detected atoms/nm², or the larger of ``relative_error`` x |object excess| and the error of
        1/``min_patches`` of the object.
    chunk : int
        Ions per chunk; memory about 60 bytes per ion of a chunk plus about 200 + 130 E bytes per
        vertex for E solutes (the distance search's own structures aside).

    Returns
    -------
    SurfaceMaps
    """
    if bin_width <= 0 or max_distance <= 0 or not 0 <= inner < max_distance:
        raise AptFiltersError(f"need bin width > 0 and 0 <= inner ({inner}) < max distance ({max_distance}) nm")
    if not (relative_error > 0 and min_patches >= 1 and (max_error is None or max_error > 0)):
        raise AptFiltersError("relative_error and max_error must be > 0 and min_patches >= 1")
    if mesh.n_faces == 0:
        raise AptFiltersError("the mesh has no triangles")
    elements = list(ranges.elements)
    solutes = elements if solutes is None else list(solutes)
    for el in solutes:
        if el not in elements:
            raise AptFiltersError(f"{el!r} is not an element of the range file ({', '.join(elements)})")
    cols = [elements.index(el) for el in solutes]
    n_el = len(solutes)

    n_bins = int(round(2 * max_distance / bin_width))
    centers = -max_distance + bin_width * (np.arange(n_bins) + 0.5)
    # the windows and the interface region of :func:`excess_of_profile`, by bin centre
    region_of_bin = np.where(centers <= -inner, _MATRIX,
                             np.where(centers >= inner, _PRECIPITATE, np.where(centers < 0, _BETWEEN_OUT, _BETWEEN_IN)))
    surface = SurfaceDistance(mesh, reach=max_distance)
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    per_ion = np.concatenate([ranges.element_matrix()[:, cols], ranges.element_matrix().sum(axis=1, keepdims=True)],
                             axis=1).astype(np.float64)
    stats = np.zeros((mesh.n_vertices, 4, 3 + 2 * n_el))
    parts = ((ions.subset(slice(a, a + chunk)) for a in range(0, len(ions), chunk))
             if isinstance(ions, IonTable) else ions)
    for part in parts:
        points = np.asarray(part.positions, dtype=np.float32)
        sd = surface.query(points, max_distance=max_distance)
        inside = -sd.distance  # positive inside the region above the iso-value, as the proxigram bins
        keep = (inside >= -max_distance) & (inside < max_distance)
        if not keep_edge:
            keep &= ~sd.on_boundary
        kept = np.flatnonzero(keep)
        species = ranges.ion_index(np.asarray(part.mz)[kept])
        kept, species = kept[species >= 0], species[species >= 0]
        bins = np.minimum(((inside[kept] + max_distance) / bin_width).astype(np.int64), n_bins - 1)
        _accumulate(points[kept].astype(np.float64), sd.face[kept], faces, vertices, region_of_bin[bins],
                    centers[bins], per_ion[species], stats)

    # vertex geometry: owned area, unit normal, object
    face_area = mesh.face_areas()
    vertex_area = np.bincount(faces.ravel(), np.repeat(face_area / 3, 3), minlength=mesh.n_vertices)
    normals = vertex_normals(vertices, faces)
    labels = face_objects(mesh)
    object_ids, face_slot = np.unique(labels, return_inverse=True)
    obj = np.full(mesh.n_vertices, -1, np.int64)
    obj[faces.ravel()] = np.repeat(face_slot, 3)
    n_obj = len(object_ids)
    used = obj >= 0

    # per object: its excess from all its ions, and the error level of its patches
    flat = np.concatenate([stats.reshape(mesh.n_vertices, -1), vertex_area[:, None]], axis=1)
    per_object = np.stack([np.bincount(obj[used], flat[used, c], minlength=n_obj)
                           for c in range(flat.shape[1])], axis=1)
    object_area = per_object[:, -1]
    object_fit = [_evaluate(per_object[:, :-1].reshape(n_obj, 4, -1), object_area, k, n_el) for k in range(n_el)]
    # whether a plateau has a gradient is decided once per object, from all its ions, and its
    # levels' errors counted at the object's fractions (module docstring)
    like = [(f[9], f[10]) for f in object_fit]
    object_window = _window_atoms(per_object)
    object_var = np.array([f[7] for f in object_fit])  # counting in the interface region
    object_counts = np.array([f[6] for f in object_fit])
    target = np.empty((n_el, n_obj))
    for k in range(n_el):
        gamma, sigma = object_fit[k][:2]
        floor = sigma * np.sqrt(min_patches)
        target[k] = max_error if max_error is not None else np.fmax(relative_error * np.abs(gamma), floor)

    # adaptive patches: grow each vertex's radius until every solute's error reaches its level
    diameter = np.linalg.norm(np.stack([_group_max(obj[used], vertices[used, c], n_obj)
                                        + _group_max(obj[used], -vertices[used, c], n_obj) for c in range(3)], axis=1),
                              axis=1)
    edges = np.linalg.norm(vertices[faces] - vertices[np.roll(faces, 1, axis=1)], axis=2)
    radius = 2.0 * float(np.median(edges))
    results = np.full((n_el, 6, mesh.n_vertices), np.nan)
    chosen_radius = np.full((n_el, mesh.n_vertices), np.nan)
    chosen_area = np.full((n_el, mesh.n_vertices), np.nan)
    done = np.zeros((n_el, mesh.n_vertices), bool)
    done[:, ~used] = True
    while not done.all():
        active = np.flatnonzero(~done.all(axis=0))
        sums = patch_sums(vertices, normals, obj, flat, active, radius)
        last = radius >= diameter[obj[active]]
        for k in range(n_el):
            todo = ~done[k, active]
            fit = _evaluate(sums[:, :-1].reshape(len(active), 4, -1), sums[:, -1], k, n_el,
                            tuple(x[obj[active]] for x in like[k]))
            share = _window_atoms(sums) / object_window[obj[active]]
            predicted = np.sqrt(object_var[k, obj[active]] * share + fit[8]) / sums[:, -1]
            counted = object_counts[k, obj[active]] * share >= MIN_COUNTS
            reached = todo & (((predicted <= target[k, obj[active]]) & counted) | last)
            idx = active[reached]
            results[k][:, idx] = np.array([f[reached] for f in fit[:6]])
            chosen_radius[k, idx] = radius
            chosen_area[k, idx] = sums[reached, -1]
            done[k, idx] = True
        radius *= np.sqrt(2.0)

    maps = {}
    for k, el in enumerate(solutes):
        gamma, sigma, c_in, s_in, c_out, s_out = results[k]
        ok = used & np.isfinite(gamma)
        patch_area = np.array([np.median(chosen_area[k, ok & (obj == o)]) if (ok & (obj == o)).any()
                               else object_area[o] for o in range(n_obj)])
        patch = _disjoint_patches(vertices, normals, obj, vertex_area, patch_area)
        n_patch = int(patch.max()) + 1
        patch_stats = np.stack([np.bincount(patch[used], flat[used, c], minlength=n_patch)
                                for c in range(flat.shape[1])], axis=1)
        patch_object = np.zeros(n_patch, np.int64)
        patch_object[patch[used]] = obj[used]
        p_fit = _evaluate(patch_stats[:, :-1].reshape(n_patch, 4, -1), patch_stats[:, -1], k, n_el,
                          tuple(x[patch_object] for x in like[k]))
        p_gamma, p_sigma = p_fit[:2]
        # the errors uniform segregation predicts for each patch (not its own counts: see _window_atoms)
        p_null = (np.sqrt(object_var[k, patch_object] * _window_atoms(patch_stats) / object_window[patch_object]
                          + p_fit[8]) / patch_stats[:, -1])
        m = SoluteMap(el, gamma, sigma, c_in, s_in, c_out, s_out, chosen_radius[k], chosen_area[k],
                      np.where(used, target[k, np.maximum(obj, 0)], np.nan), patch, p_gamma, p_sigma)
        for o in range(n_obj):
            mine = ok & (obj == o)
            if not mine.any():
                continue
            w = vertex_area[mine]
            p5, p95 = _weighted_quantiles(gamma[mine], w, [0.05, 0.95])
            chi2, dof, p_value, spread = _uniformity(p_gamma[patch_object == o], p_null[patch_object == o])
            m.objects.append(ObjectMapStats(
                el, int(object_ids[o]), float(object_area[o]), float(object_fit[k][0][o]), float(object_fit[k][1][o]),
                float(object_fit[k][2][o]), float(object_fit[k][4][o]),
                float(np.sum(w * gamma[mine]) / w.sum()), p5, p95, float(target[k, o]), float(np.median(sigma[mine])),
                float(np.median(chosen_radius[k, mine])), int(np.count_nonzero(patch_object == o)), chi2, dof,
                p_value, spread))
        maps[el] = m
    return SurfaceMaps(maps, np.where(used, object_ids[np.maximum(obj, 0)], -1), vertex_area, (inner, max_distance),
                       vertices, normals)


def _window_atoms(sums: np.ndarray) -> np.ndarray:
    """Atoms in both plateau windows of summed moments (..., 4 (3 + 2 E) + 1).

    A patch's counting error is predicted from the object's per window atom: window atoms measure
    how many ions the patch holds (local density, geometry) but are independent of the solute
    counted in its interface region. Choosing patches (or weighting them) by their own counted
    errors would select those whose solute fluctuated low, and bias the map low. The plateau fits'
    share of the error is the patch's own (from its windows only: a slope kept in a small patch
    makes its level, extrapolated to the surface, several times less certain than the object's).
    """
    width = (sums.shape[-1] - 1) // 4
    return sums[..., _MATRIX * width] + sums[..., _PRECIPITATE * width]


def _group_max(group: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """(n,) largest of ``values`` in each group (``-inf`` where empty)."""
    out = np.full(n, -np.inf)
    np.maximum.at(out, group, values)
    return out


def _uniformity(gamma: np.ndarray, sigma: np.ndarray) -> tuple[float, int, float, float]:
    """Chi-square of independent estimates against their inverse-variance weighted mean:
    (chi², degrees of freedom, p-value, spread beyond the errors)."""
    from scipy.stats import chi2 as chi2_dist

    ok = np.isfinite(gamma) & np.isfinite(sigma) & (sigma > 0)
    gamma, sigma = gamma[ok], sigma[ok]
    if len(gamma) < 2:
        return float("nan"), 0, float("nan"), float("nan")
    w = 1.0 / sigma ** 2
    mean = np.sum(w * gamma) / w.sum()
    chi2 = float(np.sum(w * (gamma - mean) ** 2))
    dof = len(gamma) - 1
    spread = float(np.sqrt(max(np.var(gamma, ddof=1) - np.mean(sigma ** 2), 0.0)))
    return chi2, dof, float(chi2_dist.sf(chi2, dof)), spread


__all__ = ["ObjectMapStats", "SoluteMap", "SurfaceMaps", "UNITS", "excess_maps", "patch_sums"]
