"""Precipitates of a synthetic specimen measured against their truth: the figures refinement is judged by.

For a specimen of closed precipitates (the ``gamma-prime`` preset: cubes and spheres of one species, a
segregant shell), :func:`evaluate_precipitates` gives per true precipitate the surface's volume, area and
distance errors (:func:`~apt_filters.truth.surface_error`), the solute's excess per area and the
species' plateaus against the model, the counting floor of the volume and the count the object's own ions
hold (:func:`volume_floors`, :func:`counted_errors`), proxigram sign errors (:func:`sign_errors`) and
folded pairs. :func:`reference_surface` and :func:`per_object_start` are the surfaces such a comparison
starts from: the AP Suite-style iso-surface and the same contoured again per object at its own plateaus'
midpoint.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from apt_filters.core.checks import folded_pairs
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh, split_components
from apt_filters.refine import object_excess, remove_specks
from apt_filters.refine.composition import ion_atoms
from apt_filters.refine.levels import object_levels, per_object_iso
from apt_filters.refine.recontour import recontour
from apt_filters.truth.counting import counting_floor
from apt_filters.truth.specimen import counted_truths
from apt_filters.truth.surface import match_objects, surface_error
from apt_filters.voxel import ConcentrationBasis, inside_mask

SIGN_BAND = 2.0
"""Ions within this distance (nm) of a true surface are checked by :func:`sign_errors`."""


def reference_surface(*, fields, species: str, iso: float, basis) -> TriMesh:
    """The AP Suite-style iso-surface: marching cubes of ``species`` (fraction in ``basis``) at ``iso``, open
    at the specimen edge (density mask)."""
    from apt_filters.contour import marching_cubes

    c = fields.concentration(species, basis).dense()
    return marching_cubes(c, iso, spacing=fields.grid.voxel, origin=fields.grid.origin,
                          mask=inside_mask(fields).dense())


def per_object_start(*, specimen, fields, mesh: TriMesh, species: str, basis, iso: float):
    """``mesh`` (contoured at ``iso``) without specks, each object contoured again at its own plateaus' midpoint
    (in ``basis``).

    Returns (mesh, :class:`~apt_filters.refine.specks.Specks` removed)."""
    c = fields.concentration(species, basis).dense()
    clean, specks = remove_specks(mesh, fields=fields, mask=inside_mask(fields).dense(), ions=specimen.ions,
                                  ranges=specimen.ranges, species=species, iso=iso, basis=basis)
    isos = per_object_iso(clean, specimen.ions, specimen.ranges, species, basis)
    return recontour(c, isos, clean, fields.grid.voxel, fields.grid.origin, inside_mask(fields).dense()), specks


def winding_number(mesh: TriMesh, points: np.ndarray) -> np.ndarray:
    """(n,) winding number of the closed ``mesh`` around each point: 1 inside an outward-oriented surface,
    -1 inside an inward-oriented one, 0 outside.

    The solid angle of each triangle seen from the point (Van Oosterom & Strackee 1983,
    doi:10.1109/TBME.1983.325207), summed and divided by 4 pi. Independent of the signed-distance
    engine (no closest point, no normals), so it checks that engine's signs. Cost: points in the box of the
    mesh's vertices x faces; a point outside that box is outside the convex hull, where a closed surface's
    winding number is 0 (and any surface's below 1/2), and gets 0 without the sum.
    """
    points = np.asarray(points)
    corners = mesh.vertices[np.unique(mesh.faces)]
    box = np.flatnonzero(np.all((points >= corners.min(axis=0)) & (points <= corners.max(axis=0)), axis=1))
    out = np.zeros(len(points))
    out[box] = _winding(np.ascontiguousarray(mesh.vertices[mesh.faces], dtype=np.float64),
                        np.ascontiguousarray(points[box], dtype=np.float64))
    return out


@njit(cache=True, parallel=True)
def _winding(tri, points):  # pragma: no cover - compiled
    out = np.empty(points.shape[0])
    for i in prange(points.shape[0]):
        total = 0.0
        for t in range(tri.shape[0]):
            ax, ay, az = tri[t, 0, 0] - points[i, 0], tri[t, 0, 1] - points[i, 1], tri[t, 0, 2] - points[i, 2]
            bx, by, bz = tri[t, 1, 0] - points[i, 0], tri[t, 1, 1] - points[i, 1], tri[t, 1, 2] - points[i, 2]
            cx, cy, cz = tri[t, 2, 0] - points[i, 0], tri[t, 2, 1] - points[i, 1], tri[t, 2, 2] - points[i, 2]
            la = np.sqrt(ax * ax + ay * ay + az * az)
            lb = np.sqrt(bx * bx + by * by + bz * bz)
            lc = np.sqrt(cx * cx + cy * cy + cz * cz)
            det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
            den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la
                   + (cx * ax + cy * ay + cz * az) * lb)
            total += np.arctan2(det, den)
        out[i] = total / (2 * np.pi)
    return out


def sign_errors(mesh: TriMesh, points: np.ndarray) -> int:
    """Points whose signed distance (:mod:`apt_filters.core.distance`, negative inside) disagrees with the
    winding number (:func:`winding_number`) of the closed, outward-oriented ``mesh``; points within 1e-4 nm
    of it are not counted."""
    signed = SurfaceDistance(mesh).query(points).distance
    near = np.abs(signed) > 1e-4
    return int(np.sum(near & ((signed < 0) != (winding_number(mesh, points) > 0.5))))


def _within(points: np.ndarray, shape, reach: float) -> np.ndarray:
    """The ``points`` (n, 3) nm within ``reach`` nm of the surface of ``shape`` (a synth shape, exact SDF), in
    their order: the SDF is taken only in the shape's bounds widened past ``reach`` (beyond them a point is
    farther than ``reach``; the margin of 0.1 nm dwarfs rounding), a tenth of a specimen's ions per object."""
    bounds = shape.bounds()
    if bounds is not None:
        lo, hi = bounds[0] - reach - 0.1, bounds[1] + reach + 0.1
        points = points[np.all((points >= lo) & (points <= hi), axis=1)]
    return points[np.abs(shape.sdf(points)) < reach]


def volume_floors(specimen, *, species: str, marker: str) -> list:
    """Counting floor (:func:`~apt_filters.truth.counting_floor`) of each true precipitate, ``marker`` (the
    segregant) out of the basis and marking the interface, as the refinement reads it."""
    sp = specimen
    feats = [i for i, f in enumerate(sp.truth["features"]) if f["bounded"]]
    everything = ion_atoms(sp.ions, sp.ranges, ConcentrationBasis())
    atoms = ion_atoms(sp.ions, sp.ranges, ConcentrationBasis(exclude=(marker,))).atoms
    return counting_floor([sp.feature_sdf(i) for i in feats], [sp.spec.features[i].shape.level_area for i in feats],
                          [sp.truth["features"][i]["volume_nm3"] for i in feats], sp.ions.positions, atoms,
                          marker=everything.atoms[:, everything.elements.index(marker)])


def counted_errors(specimen, *, species: str, solute: str) -> list[dict]:
    """Per true precipitate: the ``solute`` excess (relative) and ``species`` inside plateau (at.%) errors against
    the model of what its own ions hold (:func:`~apt_filters.truth.specimen.counted_truths`, all species in the
    basis)."""
    sp = specimen
    elements, counts = counted_truths(sp.truth, sp.ions, sp.ranges)
    ks, kp = elements.index(solute), elements.index(species)
    return [{"excess": counts[i].excess_ions[ks] / tf["excess"][solute]["excess_ions"] - 1,
             "plateau_in": 100 * (counts[i].inside[kp] - tf["composition_inside"][species])}
            for i, tf in enumerate(sp.truth["features"]) if tf["bounded"]]


def evaluate_precipitates(specimen, mesh: TriMesh, *, species: str, solute: str, seed: int,
                          floor: list | None = None, count: list | None = None) -> list[dict]:
    """Per true precipitate of ``specimen``, the figures of ``mesh`` (specks removed, objects matched to it).

    Returns one dict per bounded true feature: ``found`` and, if found, relative ``volume`` and ``area`` errors,
    ``mean`` and ``hausdorff`` distances (nm), ``solute`` ``excess`` per own area and ``excess_count``
    (relative), ``plateau_in`` / ``plateau_out`` of ``species`` (at.%, absolute), ``sign_errors``, ``folds``,
    the volume ``floor`` (relative, 1 sd) and ``z`` (volume error in floors), the counted truth
    (``excess_counted``, ``plateau_in_counted``) and the errors beyond it (``excess_beyond``,
    ``plateau_in_beyond``). ``floor`` and ``count`` are :func:`volume_floors` and :func:`counted_errors` of the
    specimen (computed if not given).
    """
    sp = specimen
    feats = [i for i, f in enumerate(sp.truth["features"]) if f["bounded"]]
    floor = volume_floors(sp, species=species, marker=solute) if floor is None else floor
    count = counted_errors(sp, species=species, solute=solute) if count is None else count
    clean = mesh  # specks are removed where the surface is drawn; a component that matches nothing is not scored
    parts = split_components(clean)
    match = match_objects(parts, [sp.feature_sdf(i) for i in feats])
    excess_all = object_excess(clean, sp.ions, sp.ranges, solute)
    levels = object_levels(clean, sp.ions, sp.ranges, species, prior=0.0)
    k = levels[0].elements.index(species) if levels else 0
    pos = sp.ions.positions.astype(np.float64)
    rows = []
    for fi, m, fl, co in zip(feats, match, floor, count):
        tf = sp.truth["features"][fi]
        if m is None:
            rows.append({"name": tf["name"], "found": False})
            continue
        err = surface_error(parts[m], sp.feature_sdf(fi), sp.meshes[fi], tf["volume_nm3"], tf["area_nm2"], seed=seed)
        near = _within(pos, sp.spec.features[fi].shape, SIGN_BAND)
        excess = excess_all[m].ions_per_nm2 / tf["excess"][solute]["ions_per_nm2"] - 1
        plateau_in = 100 * (levels[m].inside[k] - tf["composition_inside"][species])
        rows.append({
            "name": tf["name"], "found": True, "volume": err.volume_error, "area": err.area_error,
            "mean": err.mean_distance, "hausdorff": err.hausdorff,
            "excess": excess, "excess_count": excess_all[m].excess_ions / tf["excess"][solute]["excess_ions"] - 1,
            "plateau_in": plateau_in,
            "plateau_out": 100 * (levels[m].outside[k] - tf["composition_outside"][species]),
            "sign_errors": sign_errors(parts[m], near),
            "folds": len(folded_pairs(parts[m].vertices, parts[m].faces)),
            "floor": fl.volume, "z": err.volume_error / fl.volume,
            "excess_counted": co["excess"], "plateau_in_counted": co["plateau_in"],
            "excess_beyond": (1 + excess) / (1 + co["excess"]) - 1, "plateau_in_beyond": plateau_in - co["plateau_in"],
        })
    return rows
