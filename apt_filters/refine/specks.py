"""The speck rule: a connected surface is an object only where its ions say so, at a stated significance.

A component of an iso-surface is *real* when the ions on the two sides of it differ in the iso
species' fraction by more than counting noise allows, tested over all components at once with a
family-wise error rate ``alpha`` (default 0.001); the others are specks, reported and removed.

Why the ions are split. A component is found *because* the delocalized field of the same ions crosses
the iso-value there: the ions inside a noise blob are, by construction, the ones whose fluctuation made
it, and a test on them is biased (on a zoo specimen with a 4-point contrast, 0.49 efficiency, noise blobs
reached z = 5-6.5 against their surroundings, a genuine 185 nm³ object z = 9.7). So the selection and the
test use different ions (data splitting, Cox 1975): the even and the odd rows of the ion table are
voxelized apart on the same grid and contoured at the same iso-value; each half's components are tested
with the *other* half's ions, which did not shape them, so under the null (no object, a homogeneous
phase) the test's p-value is uniform.

The test of one half-component: the other half's atoms within ``reach`` nm of its surface (signed
distance, :mod:`apt_filters.core.distance`), split into the side above the iso-value (``d < 0``) and
the side below; conditional on the totals, the atoms of the iso species on the side above are
hypergeometric under the null (Fisher's exact test, one-sided: more on the side above). The p-values
of all half-components of both halves are adjusted together by Holm's step-down method (Holm 1979:
family-wise error rate ``alpha`` over every component tested, so that a low-contrast field with
thousands of blobs does not yield objects by chance; uniformly more powerful than Bonferroni). A
component of the full surface takes the smallest adjusted p-value of the half-components within one
voxel of its vertices (the same object seen in either half), and is a speck when that exceeds
``alpha``, or when no half-component is near it (a blob neither half reproduces).

Why ``alpha = 0.001`` family-wise: a run reports its objects as found, and a user reads each as
physical; one spurious object in a thousand specimens is the error rate of a claim made without
qualification (3.1 sigma one-sided), while a genuine 2 nm-radius sphere at a 4-point contrast still
passes (its ions give z ~ 6 per half). ``reach = 2`` nm: the interior of every object whose reality
is in question (radius <= 2 nm) and the matrix within the delocalization's reach around it.

References
----------
Cox, D. R. (1975). A note on data-splitting for the evaluation of significance levels. Biometrika 62, 441-444.
Holm, S. (1979). A simple sequentially rejective multiple test procedure. Scand. J. Statist. 6, 65-70.
Fisher, R. A. (1922). On the interpretation of chi-square from contingency tables. J. R. Statist. Soc. 85, 87-94.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.contour import marching_cubes
from apt_filters.core.distance import SurfaceDistance
from apt_filters.core.mesh import TriMesh
from apt_filters.core.nearby import select_near
from apt_filters.io import IonTable, RangeTable
from apt_filters.refine.composition import ion_atoms
from apt_filters.voxel import ConcentrationBasis, voxelize

ALPHA = 1e-3
"""Family-wise error rate of the speck test (see the module docstring)."""

REACH = 2.0
"""nm each side of a component's surface whose ions are tested."""

NULL_DRAWS = 2
"""Noise specimens drawn to calibrate the test (each a voxelization and a contour of all the ions)."""

MIN_NULL = 20
"""Noise components needed to estimate the null's centre and spread; with fewer, noise rarely draws a
component at this iso-value and the statistic's own null, N(0, 1), is used."""


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
        Holm-adjusted (family-wise) p-value of every component of the input (1 where no half-component
        reproduces it).
    z : (c,) float
        The normal score of the unadjusted one-sided p-value behind each ``p_values`` entry (0 where none).
    tested : int
        Half-components tested (both halves): the size of the family.
    alpha : float
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
        """(adjusted p-value, z) of each component of ``mesh`` (e.g. the finished surface): those of the
        half-components within ``tolerance`` nm of its vertices, the smallest p-value; (1, 0) where none is."""
        return _match(mesh, [] if self.kept is None else [self.kept], tolerance)


def holm(p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error rate over all ``p``), monotone, at most 1."""
    p = np.asarray(p, dtype=np.float64)
    order = np.argsort(p, kind="stable")
    m = len(p)
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(np.maximum.accumulate((m - np.arange(m)) * p[order]), 1.0)
    return adjusted


def side_z(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str, basis: ConcentrationBasis,
           reach: float = REACH, mz: np.ndarray | None = None) -> np.ndarray:
    """(c,) two-sample z of each component of ``mesh``: the ``species`` fraction of the atoms within ``reach`` nm
    on the side above the iso-value (signed distance < 0) against those on the side below (pooled binomial
    variance; 0 where a side is empty). ``mz`` replaces the ions' own mass-to-charge (a null draw)."""
    labels = mesh.face_components()
    n_comp = int(labels.max()) + 1 if len(labels) else 0
    near = select_near(ions.positions, mesh, reach)
    mz = np.asarray(ions.mz if mz is None else mz)[near.rows]
    atoms = ion_atoms(IonTable(near.positions, mz), ranges, basis)
    total, mine = atoms.total.astype(np.float64), atoms.atoms[:, atoms.elements.index(species)].astype(np.float64)
    comp, above = labels[near.face], near.distance < 0

    def count(w):
        return np.bincount(comp, weights=w, minlength=n_comp)

    n_up, k_up, n_all, k_all = count(total * above), count(mine * above), count(total), count(mine)
    n_down, k_down = n_all - n_up, k_all - k_up
    pooled = k_all / np.maximum(n_all, 1.0)
    var = pooled * (1 - pooled) * (1 / np.maximum(n_up, 1.0) + 1 / np.maximum(n_down, 1.0))
    diff = k_up / np.maximum(n_up, 1.0) - k_down / np.maximum(n_down, 1.0)
    return np.where((n_up > 0) & (n_down > 0) & (var > 0), diff / np.sqrt(np.where(var > 0, var, 1.0)), 0.0)


def _match(mesh: TriMesh, halves, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    labels = mesh.face_components()
    n_comp = int(labels.max()) + 1 if len(labels) else 0
    best_p, best_z = np.ones(n_comp), np.zeros(n_comp)
    vertex_comp = np.zeros(mesh.n_vertices, dtype=np.int64)
    vertex_comp[mesh.faces.ravel()] = np.repeat(labels, 3)
    for half, p, z in halves:
        if half.n_faces == 0:
            continue
        sd = SurfaceDistance(half, reach=tolerance).query(mesh.vertices, max_distance=tolerance)
        close = np.abs(sd.distance) <= tolerance
        pairs = np.unique(np.column_stack([vertex_comp[close], half.face_components()[sd.face[close]]]), axis=0)
        order = np.lexsort((p[pairs[:, 1]], pairs[:, 0]))  # per component, its most significant half first
        first = order[np.r_[True, np.diff(pairs[order, 0]) > 0]] if len(order) else order
        c, h = pairs[first, 0], pairs[first, 1]
        better = p[h] < best_p[c]
        best_p[c[better]], best_z[c[better]] = p[h[better]], z[h[better]]
    return best_p, best_z


def null_z(*, fields, mask: np.ndarray, ions: IonTable, ranges: RangeTable, species: str, iso: float,
           basis: ConcentrationBasis, draws: int = NULL_DRAWS, reach: float = REACH, seed: int = 0) -> np.ndarray:
    """The :func:`side_z` of every component that noise alone draws at ``iso``: ``draws`` specimens with the ions'
    own positions, each ion given the mass-to-charge of an ion drawn at random from those below the iso-value
    (the matrix: its voxel's fraction under ``iso``), voxelized, contoured and tested like the data."""
    c = fields.concentration(species, basis).dense()
    rng = np.random.default_rng(seed)
    mz = np.asarray(ions.mz)
    cell = np.rint((np.asarray(ions.positions, dtype=np.float64) - fields.grid.origin) / fields.grid.voxel)
    cell = np.clip(cell.astype(np.int64), 0, np.array(c.shape) - 1)
    below = c[cell[:, 0], cell[:, 1], cell[:, 2]] < iso  # NaN voxels (no atoms) are in neither phase
    pool = mz[below]
    out = [np.zeros(0)]
    if not len(pool):
        return out[0]
    for _ in range(draws):
        labels = pool[rng.integers(0, len(pool), len(mz))]
        noise = IonTable(ions.positions, labels)
        null_fields = voxelize(noise, ranges, grid=fields.grid, kernel=fields.kernel,
                               delocalization=fields.delocalization, species=fields.kind, basis=fields.basis)
        mesh = marching_cubes(null_fields.concentration(species, basis).dense(), iso, spacing=fields.grid.voxel,
                              origin=fields.grid.origin, mask=mask)
        if mesh.n_faces:
            out.append(side_z(mesh, noise, ranges, species, basis, reach))
    return np.concatenate(out)


def remove_specks(mesh: TriMesh, *, fields, mask: np.ndarray, ions: IonTable, ranges: RangeTable, species: str,
                  iso: float, basis: ConcentrationBasis | None = None, alpha: float = ALPHA,
                  reach: float = REACH) -> tuple[TriMesh, Specks]:
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
    z = side_z(mesh, ions, ranges, species, basis, reach) if n_comp else np.zeros(0)
    null = null_z(fields=fields, mask=mask, ions=ions, ranges=ranges, species=species, iso=iso, basis=basis,
                  reach=reach)
    centre, spread = (float(null.mean()), float(null.std(ddof=1))) if len(null) >= MIN_NULL else (0.0, 1.0)
    standard = (z - centre) / max(spread, 1.0)  # a null narrower than the statistic's own noise is not trusted
    p = holm(norm.sf(standard))
    specks = Specks([], [], [], p_values=p, z=standard, tested=n_comp, alpha=alpha, null=(centre, spread, len(null)))
    small = np.flatnonzero(p > alpha)
    for c in small:
        part = TriMesh(mesh.vertices, mesh.faces[labels == c])
        closed = len(part.boundary_edges()) == 0
        specks.ids.append(int(c))
        specks.volumes.append(part.signed_volume() if closed else float("nan"))
        specks.areas.append(part.area())
    keep_face = ~np.isin(labels, small)
    faces = mesh.faces[keep_face]
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[faces.ravel()] = True
    new_index = np.cumsum(used) - 1
    out = TriMesh(mesh.vertices[used], new_index[faces],
                  {k: v[used] for k, v in mesh.vertex_scalars.items()},
                  {k: v[keep_face] for k, v in mesh.face_scalars.items() if k != "component"})
    out.face_scalars["component"] = out.face_components()
    kept = np.flatnonzero(p <= alpha)
    specks.kept = (out, p[kept], standard[kept])
    return out, specks
