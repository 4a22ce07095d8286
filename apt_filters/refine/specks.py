"""The speck rule: a connected surface is an object only where its ions say so, at a stated significance.

A component of an iso-surface is *real* when the ions on its two sides differ in the iso species'
fraction by more than noise does at this iso-value, tested over all components at once with a
family-wise error rate ``alpha`` (default 0.001); the others are specks, reported and removed. Size
plays no part: a 0.3 nm³ marching-cubes sliver of a 16 nm³ sphere at a 65-point contrast is kept
(nothing else at that iso-value comes from noise), a 13 nm³ blob at a 4-point contrast is not.

The statistic. For each component, the atoms within ``reach`` nm of its surface on the side above the
iso-value (exact signed distance ``-reach <= d < 0``, :mod:`apt_filters.core.distance`) are compared
with those from ``s`` to ``s + reach`` nm on the side below, ``s`` the kernel's standard deviation
(:func:`kernel_sigma`): the delocalization shrinks a small object's contour inside its true surface
by about ``s``, and a side below that started at the contour would hold the object's own rim (a 24 nm³
sphere at a 41-point contrast: z 3.1 without the gap, 5.2 with it). ``z`` is the two-sample binomial
score of the iso species' fraction above against below (:func:`side_z`).

Its null. A component is found *because* the delocalized field of the same ions crosses the
iso-value there, so for a component that noise drew, ``z`` is not standard normal: the ions inside
a noise blob are the ones whose fluctuation made it (on a zoo specimen with a 4-point contrast and
0.49 efficiency, noise blobs reached z = 3-6.5, a genuine 185 nm³ object 9.7). The null is therefore
drawn, not assumed (a randomisation test, as for cluster-finding parameters in APT: Stephenson et
al. 2007): each ion keeps its position and gets the mass-to-charge of an ion drawn at random from the
phase below the iso-value (ions in voxels whose fraction is under ``iso``), so the specimen keeps its
shape, density and matrix composition and loses every object; it is voxelized on the same grid with the
same kernel, contoured at the same iso-value, and every component noise draws there is scored like the
data's (:func:`null_z`). Their scores' mean and standard deviation are the null of one component
(the empirical null of Efron 2004), from :data:`NULL_DRAWS` draws, up to :data:`MAX_NULL_DRAWS` while
they hold some but fewer than :data:`MIN_NULL` components. Where noise draws no component at all at this
iso-value, the statistic's own null, N(0, 1), is used; a spread under 1 is not trusted (set to 1).

The family. The one-sided p-values ``P(Z > (z - centre) / spread)`` of all the components are adjusted
together by Holm's step-down method (Holm 1979; family-wise, uniformly more powerful than Bonferroni),
so that a low-contrast field with thousands of blobs does not yield objects by chance. A component is
a speck when its adjusted p-value exceeds ``alpha``.

Why ``alpha = 0.001`` family-wise: a run reports its objects as found and a user reads each as
physical, so a spurious object should be as rare as one per thousand specimens analysed (the usual
threshold for a claim made without qualification); on the held-out zoo draws the least significant
object of >= 30 nm³ (a 4-point contrast) stands 7.9 null spreads above the noise's centre, spheres of
15-24 nm³ 5.2-11 (benchmarks/results_object_errors.md).
``reach = 2`` nm: the interior of every object whose reality is in question (radius <= 2 nm) and the
matrix within the delocalization's reach around it.

Limitations: the null is the phase below the iso-value; noise holes in the phase above are scored
against it. Each draw costs a voxelization of all the ions and a contour.

References
----------
Efron, B. (2004). Large-scale simultaneous hypothesis testing: the choice of a null hypothesis.
J. Am. Statist. Assoc. 99, 96-104.
Holm, S. (1979). A simple sequentially rejective multiple test procedure. Scand. J. Statist. 6, 65-70.
Stephenson, L. T., Moody, M. P., Liddicoat, P. V., Ringer, S. P. (2007). New techniques for the analysis
of fine-scaled clustering phenomena within atom probe tomography (APT) data. Microsc. Microanal. 13,
448-463.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.contour import marching_cubes
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh, merge
from apt_filters.core.nearby import CHUNK, NearSurface, select_near
from apt_filters.io import IonTable, RangeTable
from apt_filters.refine.composition import ion_atoms
from apt_filters.voxel import ConcentrationBasis, voxelize

ALPHA = 1e-3
"""Family-wise error rate of the speck test (see the module docstring)."""

REACH = 2.0
"""nm each side of a component's surface whose ions are tested."""

NULL_DRAWS = 2
"""Noise specimens drawn at least to calibrate the test (each a voxelization and a contour of all the ions)."""

MAX_NULL_DRAWS = 4
"""Noise specimens drawn at most, while they hold some but fewer than :data:`MIN_NULL` components (none in
:data:`NULL_DRAWS` draws: noise draws no component at this iso-value, and more draws would not change that)."""

MIN_NULL = 20
"""Noise components wanted to estimate the null's centre and spread."""


@dataclass
class Specks:
    """What :func:`remove_specks` found.

    Attributes
    ----------
    ids : list of int
        Components of the input removed as specks.
    volumes, areas : list of float
        Their enclosed volumes (nm³, NaN where open) and areas (nm²).
    p_values : (c,) float
        Holm-adjusted (family-wise) p-value of every component of the input.
    z : (c,) float
        Each component's score in null spreads above the null's centre, ``(side_z - centre) / spread``.
    tested : int
        Components tested: the size of the family.
    alpha : float
    null : (centre, spread, components)
        The null of one component's :func:`side_z` and the noise components it was estimated from.
    kept : (TriMesh, (k,) float, (k,) float) or None
        The components kept, with their p-values and z (for :meth:`of`).
    """

    ids: list[int]
    volumes: list[float]
    areas: list[float]
    p_values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    z: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tested: int = 0
    alpha: float = ALPHA
    null: tuple[float, float, int] = (0.0, 1.0, 0)
    kept: tuple[TriMesh, np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def count(self) -> int:
        return len(self.ids)

    def of(self, mesh: TriMesh, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
        """(adjusted p-value, z) of each component of ``mesh`` (e.g. the finished surface): of the kept
        components within ``tolerance`` nm of its vertices, the one with the smallest p-value; (1, 0) where none
        is."""
        labels = mesh.face_components()
        n_comp = int(labels.max()) + 1 if len(labels) else 0
        best_p, best_z = np.ones(n_comp), np.zeros(n_comp)
        if self.kept is None or self.kept[0].n_faces == 0 or not n_comp:
            return best_p, best_z
        kept, p, z = self.kept
        vertex_comp = np.zeros(mesh.n_vertices, dtype=np.int64)
        vertex_comp[mesh.faces.ravel()] = np.repeat(labels, 3)
        sd = SurfaceDistance(kept, reach=tolerance).query(mesh.vertices, max_distance=tolerance)
        close = np.abs(sd.distance) <= tolerance
        pairs = np.unique(np.column_stack([vertex_comp[close], kept.face_components()[sd.face[close]]]), axis=0)
        np.minimum.at(best_p, pairs[:, 0], p[pairs[:, 1]])
        best = p[pairs[:, 1]] == best_p[pairs[:, 0]]  # the z of the most significant neighbour
        best_z[pairs[best, 0]] = z[pairs[best, 1]]
        return best_p, best_z


def holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error rate over all ``p``), monotone, at most 1."""
    p = np.asarray(p, dtype=np.float64)
    order = np.argsort(p, kind="stable")
    m = len(p)
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(np.maximum.accumulate((m - np.arange(m)) * p[order]), 1.0)
    return adjusted


def side_z(mesh: TriMesh, *, ions: IonTable, ranges: RangeTable, species: str, basis: ConcentrationBasis,
           reach: float = REACH, gap: float = 0.0, near: NearSurface | None = None,
           labels: np.ndarray | None = None) -> np.ndarray:
    """(c,) two-sample z of each component of ``mesh``: the ``species`` fraction of the atoms within ``reach`` nm
    on the side above the iso-value (signed distance in [-reach, 0)) against those on the side below, from
    ``gap`` to ``gap + reach`` nm (pooled binomial variance; 0 where a side is empty).

    ``labels``, optional: (f,) int, a part of the surface per face (default its components); each atom counts for
    the part of its nearest face.

    ``near``, optional: the ions of ``ions`` near this very ``mesh`` selected already
    (:func:`~apt_filters.core.nearby.select_near` to at least ``reach + gap`` nm, with exact distances and faces
    within ``reach + gap``, e.g. :func:`~apt_filters.refine.segregants.segregant_ions`); default: selected here.
    The counts are whole atoms, so the z is the same to the bit either way."""
    labels = mesh.face_components() if labels is None else np.asarray(labels)
    n_comp = int(labels.max()) + 1 if len(labels) else 0
    if near is None:
        near = select_near(ions.positions, mesh, reach + gap)
    elif near.reach < reach + gap or near.moved(mesh.vertices) != 0.0:
        raise ValueError(f"the ions were selected within {near.reach:g} nm of another mesh or too close to this one: "
                         f"the speck test needs {reach + gap:g} nm")
    within = np.flatnonzero(np.abs(near.distance) <= reach + gap)  # those of a wider selection: +-inf beyond
    rows = near.rows[within]
    atoms = ion_atoms(IonTable(near.positions[within], np.asarray(ions.mz)[rows]), ranges, basis)
    total, mine = atoms.total.astype(np.float64), atoms.atoms[:, atoms.elements.index(species)].astype(np.float64)
    comp, d = labels[near.face[within]], near.distance[within]
    up, down = (d < 0) & (d >= -reach), (d >= gap) & (d <= gap + reach)

    def count(w):
        return np.bincount(comp, weights=w, minlength=n_comp)

    n_up, k_up, n_down, k_down = count(total * up), count(mine * up), count(total * down), count(mine * down)
    pooled = (k_up + k_down) / np.maximum(n_up + n_down, 1.0)
    var = pooled * (1 - pooled) * (1 / np.maximum(n_up, 1.0) + 1 / np.maximum(n_down, 1.0))
    diff = k_up / np.maximum(n_up, 1.0) - k_down / np.maximum(n_down, 1.0)
    return np.where((n_up > 0) & (n_down > 0) & (var > 0), diff / np.sqrt(np.where(var > 0, var, 1.0)), 0.0)


def kernel_sigma(fields) -> float:
    """nm: the largest standard deviation of the voxelization's kernel (a Gaussian's delocalization is 3 sigma;
    the sawtooth and square kernels spread over about a voxel)."""
    return max(fields.delocalization) / 3.0 if fields.kernel == "gaussian" else fields.grid.voxel


def null_z(*, fields, mask: np.ndarray, ions: IonTable, ranges: RangeTable, species: str, iso: float,
           basis: ConcentrationBasis, reach: float = REACH, seed: int = 0) -> tuple[np.ndarray, int]:
    """The :func:`side_z` of every component that noise alone draws at ``iso``, and the specimens drawn: each
    keeps the ions' positions, each ion given the mass-to-charge of an ion drawn at random from those below the
    iso-value (the matrix: its voxel's fraction under ``iso``), voxelized, contoured and tested like the data;
    :data:`NULL_DRAWS` of them, up to :data:`MAX_NULL_DRAWS` while some but fewer than :data:`MIN_NULL` components."""
    c = fields.concentration(species, basis).dense()
    rng = np.random.default_rng(seed)
    pool = []  # chunk by chunk: no per-ion index arrays of a memory-mapped table in memory at once
    for start in range(0, len(ions), CHUNK):
        cell = np.rint((np.asarray(ions.positions[start:start + CHUNK], dtype=np.float64) - fields.grid.origin)
                       / fields.grid.voxel)
        cell = np.clip(cell.astype(np.int64), 0, np.array(c.shape) - 1)
        below = c[cell[:, 0], cell[:, 1], cell[:, 2]] < iso  # NaN voxels (no atoms) are in neither phase
        pool.append(np.asarray(ions.mz[start:start + CHUNK])[below])
    pool = np.concatenate(pool) if pool else np.zeros(0, np.float32)
    out = [np.zeros(0)]
    if not len(pool):
        return out[0], 0
    drawn = 0
    while drawn < NULL_DRAWS or (drawn < MAX_NULL_DRAWS and 0 < sum(map(len, out)) < MIN_NULL):
        drawn += 1
        labels = np.empty(len(ions), dtype=pool.dtype)
        for start in range(0, len(ions), CHUNK):
            labels[start:start + CHUNK] = pool[rng.integers(0, len(pool), min(CHUNK, len(ions) - start))]
        noise = IonTable(ions.positions, labels)
        null_fields = voxelize(noise, ranges, grid=fields.grid, kernel=fields.kernel,
                               delocalization=fields.delocalization, species=fields.kind, basis=fields.basis)
        mesh = marching_cubes(null_fields.concentration(species, basis).dense(), iso, spacing=fields.grid.voxel,
                              origin=fields.grid.origin, mask=mask)
        if mesh.n_faces:
            out.append(side_z(mesh, ions=noise, ranges=ranges, species=species, basis=basis, reach=reach,
                              gap=kernel_sigma(fields)))
    return np.concatenate(out), drawn


def remove_specks(mesh: TriMesh, *, fields, mask: np.ndarray, ions: IonTable, ranges: RangeTable, species: str,
                  iso: float, basis: ConcentrationBasis | None = None, alpha: float = ALPHA,
                  reach: float = REACH, near: NearSurface | None = None) -> tuple[TriMesh, Specks]:
    """``mesh`` without the components its ions do not show to be real (see the module docstring).

    Parameters
    ----------
    mesh : TriMesh
        Iso-surface of ``species`` at ``iso`` drawn from ``fields`` (normals out of the region above iso).
    fields : voxel.Fields
        The voxelization ``mesh`` was contoured from; the null specimens are voxelized on its grid with its
        kernel and delocalization.
    mask : (nx, ny, nz) bool
        Inside the specimen, as for ``mesh``.
    ions, ranges : IonTable, RangeTable
    species : str
        The iso-surface's element.
    iso : float
        Its iso-value (fraction).
    basis : ConcentrationBasis, optional
        The basis of the fractions (default ``fields.basis``); leave segregants out as for ``mesh``.
    alpha : float
        Family-wise error rate in (0, 1).
    reach : float, nm
        Ions tested each side of a component's surface.
    near : NearSurface, optional
        The ions near ``mesh`` selected already (:func:`side_z`), e.g. by the segregant search of the same mesh;
        default: selected here.

    Returns
    -------
    TriMesh, Specks
        The real components (unused vertices dropped, components relabelled) and what was removed, with
        every component's adjusted p-value and z.
    """
    from scipy.stats import norm

    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    basis = fields.basis if basis is None else basis
    labels = mesh.face_components()
    n_comp = int(labels.max()) + 1 if len(labels) else 0
    if not n_comp:
        return mesh, Specks([], [], [], alpha=alpha)
    z = side_z(mesh, ions=ions, ranges=ranges, species=species, basis=basis, reach=reach, gap=kernel_sigma(fields),
               near=near)
    null, _ = null_z(fields=fields, mask=mask, ions=ions, ranges=ranges, species=species, iso=iso, basis=basis,
                     reach=reach)
    centre = float(null.mean()) if len(null) else 0.0
    spread = max(float(null.std(ddof=1)) if len(null) > 1 else 1.0, 1.0)  # never narrower than a fixed surface's
    standard = (z - centre) / spread
    p = holm(norm.sf(standard))
    specks = Specks([], [], [], p_values=p, z=standard, tested=n_comp, alpha=alpha,
                    null=(centre, spread, len(null)))
    small = np.flatnonzero(p > alpha)
    for c in small:
        part = TriMesh(mesh.vertices, mesh.faces[labels == c])
        closed = len(part.boundary_edges()) == 0
        specks.ids.append(int(c))
        specks.volumes.append(part.signed_volume() if closed else float("nan"))
        specks.areas.append(part.area())
    keep_face = ~np.isin(labels, small)
    out = _faces_of(mesh, keep_face)
    original = np.zeros(out.face_scalars["component"].max() + 1 if out.n_faces else 0, dtype=np.int64)
    original[out.face_scalars["component"]] = labels[keep_face]  # the input component of each output one
    specks.kept = (out, p[original], standard[original])
    return out, specks


def _faces_of(mesh: TriMesh, keep_face: np.ndarray) -> TriMesh:
    """The faces ``keep_face`` of ``mesh``, unused vertices dropped, with their scalars and their components."""
    faces = mesh.faces[keep_face]
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[faces.ravel()] = True
    new_index = np.cumsum(used) - 1
    out = TriMesh(mesh.vertices[used], new_index[faces],
                  {k: v[used] for k, v in mesh.vertex_scalars.items()},
                  {k: v[keep_face] for k, v in mesh.face_scalars.items() if k != "component"})
    out.face_scalars["component"] = out.face_components()
    return out


@dataclass
class Lobes:
    """What :func:`trim_lobes` did.

    Attributes
    ----------
    level : float
        The parts' level: the iso-value plus the field's counting noise (fraction).
    tested : int
        Parts tested: those of the components that rise above ``level`` in more than one place.
    removed : int
        Parts removed as noise.
    volume : float
        nm³ of voxels removed with them.
    """

    level: float = float("nan")
    tested: int = 0
    removed: int = 0
    volume: float = 0.0

    def describe(self) -> str:
        return (f"{self.removed} of {self.tested} parts trimmed as noise ({self.volume:.0f} nm³)" if self.tested
                else "no part to trim")


def trim_lobes(mesh: TriMesh, specks: Specks, *, values: np.ndarray, fields, mask: np.ndarray, ions: IonTable,
               ranges: RangeTable, species: str, iso: float, basis: ConcentrationBasis | None = None,
               alpha: float = ALPHA, reach: float = REACH, contour=marching_cubes,
               near: NearSurface | None = None) -> tuple[TriMesh, Lobes]:
    """``mesh`` without the parts of its components that the ions do not show to be real: the speck test of
    :func:`remove_specks` applied to each part of a component instead of the whole.

    At low contrast, counting noise in the matrix crosses the iso-value beside an object and joins it: a lobe
    of the object's surface with no contrast of its own. The parts: where a component of the field above the
    iso-value rises above ``level``, the iso-value plus the field's counting noise (its standard deviation in the
    phase below the iso-value), in more than one place, each such place is a part's seed and every voxel of the
    component goes to the seed it reaches by the highest path (watershed by image foresting, Falcão et al.
    2004); two maxima that the field does not separate by more than its noise are one part. The statistic is
    :func:`side_z` on the faces of each part (an ion counts for the part of its nearest face), standardised by
    the noise components' null of the speck test (``specks.null``) and adjusted by Holm over every part tested.
    In each component the most significant part stays (whether the component is real is the speck test's
    question); any other part whose adjusted p-value exceeds ``alpha`` is removed: its voxels are reflected
    about the iso-value (``2 iso - c``, so the cut lies where the two parts' fields are equally far above it)
    and the component is contoured again.

    Parameters
    ----------
    mesh : TriMesh
        The iso-surface after :func:`remove_specks` (normals out of the region above iso).
    specks : Specks
        Its speck test (the null of one noise component).
    values : (nx, ny, nz) float
        The field ``mesh`` was contoured from (fraction; NaN where no atoms).
    fields : voxel.Fields
        Its voxelization (grid and kernel).
    mask : (nx, ny, nz) bool
        Inside the specimen, as for ``mesh``.
    ions, ranges : IonTable, RangeTable
    species : str
    iso : float
    basis : ConcentrationBasis, optional
        As for :func:`remove_specks`.
    alpha : float
        Family-wise error rate of the parts' test.
    reach : float, nm
        Ions tested each side of a part's surface.
    contour : callable
        How ``mesh`` was contoured: ``contour(values, iso, spacing=, origin=, mask=)``.
    near : NearSurface, optional
        The ions near ``mesh`` selected already, as for :func:`side_z`.

    Returns
    -------
    TriMesh, Lobes
        The surface (``mesh`` itself where nothing is removed) and what was done.

    References
    ----------
    Falcão, A. X., Stolfi, J., Lotufo, R. A. (2004). The image foresting transform: theory, algorithms, and
    applications. IEEE Trans. Pattern Anal. Mach. Intell. 26, 19-29.
    """
    from scipy import ndimage as ndi
    from scipy.stats import norm

    basis = fields.basis if basis is None else basis
    finite = mask & np.isfinite(values)
    noise = float(values[finite & (values < iso)].std()) if (finite & (values < iso)).any() else 0.0
    report = Lobes(level=iso + noise)
    if mesh.n_faces == 0 or not noise > 0:
        return mesh, report
    full = ndi.generate_binary_structure(3, 3)
    above = finite & (values >= iso)
    comp, _ = ndi.label(above, full)
    seeds, n_seeds = ndi.label(above & (values >= report.level), full)
    seed_comp = np.zeros(n_seeds + 1, dtype=np.int64)
    seed_comp[seeds[seeds > 0]] = comp[seeds > 0]
    per_comp = np.bincount(seed_comp[1:], minlength=comp.max() + 1)
    if not (per_comp > 1).any():
        return mesh, report
    # each voxel of a component to the seed it reaches by the highest path
    top = float(values[above].max())
    cost = np.full(values.shape, np.iinfo(np.uint16).max, dtype=np.uint16)
    cost[above] = np.rint((top - values[above]) / max(top - iso, 1e-12) * 60000).astype(np.uint16)
    part = ndi.watershed_ift(cost, seeds.astype(np.int32), structure=full)  # across the background only at its cost
    part[~above | (per_comp[comp] < 2)] = 0  # the background's marker, and components of one part: not tested
    # each face to the part of the voxel nearest its centroid that belongs to a part, in its own component
    _, near_comp = ndi.distance_transform_edt(comp == 0, return_indices=True)
    face_voxel = _nearest_voxel(mesh, near_comp, fields.grid)
    face_comp = comp[face_voxel]
    face_part = np.where(per_comp[face_comp] > 1,
                         part[_nearest_voxel(mesh, ndi.distance_transform_edt(part == 0, return_indices=True)[1],
                                             fields.grid)], 0)
    tested = np.zeros(n_seeds + 1, dtype=bool)
    tested[np.unique(face_part)] = True
    tested[0] = False
    tested &= per_comp[seed_comp] > 1
    report.tested = int(tested.sum())
    if report.tested < 2:
        return mesh, report
    z = side_z(mesh, ions=ions, ranges=ranges, species=species, basis=basis, reach=reach, gap=kernel_sigma(fields),
               labels=face_part, near=near)
    centre, spread, _ = specks.null
    z = np.concatenate([z, np.zeros(n_seeds + 1 - len(z))])
    p = np.ones(n_seeds + 1)
    p[tested] = holm(norm.sf((z[tested] - centre) / spread))
    best = np.full(comp.max() + 1, np.inf)
    np.minimum.at(best, seed_comp[tested], p[tested])
    removed = tested & (p > alpha) & (p > best[seed_comp])
    report.removed = int(removed.sum())
    if not report.removed:
        return mesh, report
    cut = removed[part]
    report.volume = float(cut.sum()) * fields.grid.voxel ** 3
    trimmed = values.copy()
    trimmed[cut] = 2 * iso - values[cut]
    again = contour(trimmed, iso, spacing=fields.grid.voxel, origin=fields.grid.origin, mask=mask)
    # the trimmed components contoured again; every other component as it was
    changed = np.zeros(comp.max() + 1, dtype=bool)
    changed[seed_comp[removed]] = True

    kept = _faces_of(mesh, ~changed[face_comp])
    # of the trimmed components contoured again, the pieces that overlap the surface that passed the speck test
    # (a speck joined to a component by a voxel's corner is not brought back)
    passed = np.zeros(values.shape, dtype=bool)
    passed[face_voxel] = changed[face_comp]
    again = _faces_of(again, changed[comp[_nearest_voxel(again, near_comp, fields.grid)]])
    pieces = again.face_components()
    overlap = np.bincount(pieces, weights=passed[_nearest_voxel(again, near_comp, fields.grid)],
                          minlength=pieces.max() + 1 if len(pieces) else 0)
    again = _faces_of(again, overlap[pieces] > 0)
    # and of those, the pieces that pass the speck test themselves (the cut leaves slivers of the removed parts)
    z = (side_z(again, ions=ions, ranges=ranges, species=species, basis=basis, reach=reach,
                gap=kernel_sigma(fields)) - centre) / spread
    new = _faces_of(again, (holm(norm.sf(z)) <= alpha)[again.face_components()])
    return merge([kept, new]), report


def _nearest_voxel(mesh: TriMesh, nearest: np.ndarray, grid) -> tuple[np.ndarray, ...]:
    """Index of each face's voxel: the labelled voxel nearest the voxel of its centroid (``nearest``: the indices
    of :func:`scipy.ndimage.distance_transform_edt` of the unlabelled voxels)."""
    cell = np.clip(np.rint((mesh.vertices[mesh.faces].mean(axis=1) - grid.origin) / grid.voxel).astype(np.int64),
                   0, np.array(nearest.shape[1:]) - 1)
    return tuple(nearest[:, cell[:, 0], cell[:, 1], cell[:, 2]])
