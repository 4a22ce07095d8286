"""Open surfaces with the defaults of ``apt-filters run``, against their exact truth.

A low-contrast curved interface crosses the whole box (its rim is where it leaves the specimen); Mg 9 -> 17 at.% at
detection efficiency 0.4 gives few ions per nm² of contrast, so each vertex's placement is noisy and the surface's
smoothness must come from the data (``refine.crossval.cross_validated_lengths``), with its rim held.

A wide interface at a low contrast (Mg 9 -> 13.5 at.% over a tanh width of 2.15 nm at efficiency 0.4): its gradient is
small against the counting noise's, and the contour of AP Suite's 3 x 3 x 1.5 nm delocalization folds into handles and
tunnels that no later step removes; drawn at the delocalization its noise allows (``voxel.noise``) it is one sheet.

A sphere cut by a side face of the specimen: its measured surface stops at the voxel mask, short of the face, so it
is open there, and the ions between its rim and the face are beyond the rim, on neither side of it. Counted in the
refinement's plateau windows they put the matrix into the object's inside level, whose midpoint then moves the
surface outward.
"""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.core.mesh import topology
from apt_filters.synth import Box
from apt_filters.synth.implicit import CutSphere, SphereInterface
from apt_filters.synth.specimen import Feature, SpecimenSpec
from apt_filters.voxel import ConcentrationBasis
from tests.near_side import defaults

MATRIX = {"Al": 0.78, "Mg": 0.09, "Cu": 0.13}
INSIDE = {"Al": 0.80, "Mg": 0.17, "Cu": 0.03}
WIDE_INSIDE = {"Al": 0.835, "Mg": 0.135, "Cu": 0.03}
CUT_MATRIX = {"Ni": 0.80, "Al": 0.09, "Cr": 0.11}
CUT_INSIDE = {"Ni": 0.42, "Al": 0.55, "Cr": 0.03}


def _offsets(mesh, shape, box) -> tuple[np.ndarray, np.ndarray]:
    """(areas, signed distances to ``shape``) of the faces of ``mesh`` 2 nm inside ``box``, as the zoo benchmark
    compares (the measured surface stops at the voxel mask)."""
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    inner = box.sdf(centroids) + 2.0 < 0
    return mesh.face_areas()[inner], shape.sdf(centroids[inner])


def _curved_interface(inside: dict, width: float, seed: int):
    """(shape, box, mesh, record) of a curved interface across the box from Mg 9 at.% to ``inside`` over a tanh
    ``width`` (nm) at efficiency 0.4, its ions drawn from ``seed``."""
    box = Box((16.0, 16.0, 18.0))
    shape = SphereInterface(box, (2.0, -1.5, -49.0), 40.0, convex=True)
    spec = SpecimenSpec(box, MATRIX, (Feature(shape, inside, width, (), "curved interface"),), efficiency=0.4,
                        blur=(0.25, 0.12), name="curved")
    mesh, record = defaults(spec, seed, "Mg", 0.5 * (MATRIX["Mg"] + inside["Mg"]))
    return shape, box, mesh, record


@pytest.fixture(scope="module")
def curved():
    return _curved_interface(INSIDE, 0.3, 4)


@pytest.fixture(scope="module")
def wide():
    return _curved_interface(WIDE_INSIDE, 2.15, 1)


@pytest.fixture(scope="module")
def cut():
    box = Box((16.0, 16.0, 18.0))
    # the centre 0.8 nm beyond the face x = 8: a cap 3.7 nm deep into the specimen
    shape = CutSphere((8.8, -1.0, -9.0), 4.5, (1.0, 0.0, 0.0), 8.0)
    spec = SpecimenSpec(box, CUT_MATRIX, (Feature(shape, CUT_INSIDE, 0.3, (), "edge 0"),), efficiency=0.5,
                        blur=(0.4, 0.07), name="cut sphere")
    mesh, record = defaults(spec, 5, "Al", 0.5 * (CUT_MATRIX["Al"] + CUT_INSIDE["Al"]))
    return shape, box, mesh, record


def test_a_low_contrast_curved_interface_is_placed_within_a_tenth_of_a_nanometre(curved):
    shape, box, mesh, record = curved
    assert record.noise_scale["factor"] == 1.0, record.noise_scale  # a sharp interface keeps the delocalization
    areas, d = _offsets(mesh, shape, box)
    mean = float(np.sum(areas * np.abs(d)) / areas.sum())
    assert mean <= 0.1, mean  # measured 0.073 (0.070 with the ions beyond the rim in the windows; 0.144 without the
    # smoothing of open surfaces)
    assert abs(float(np.sum(areas * d) / areas.sum())) < 0.05  # measured +0.014 (-0.004 with them)
    assert np.abs(d).max() < 1.0  # measured 0.48 (0.45)


def test_a_wide_low_contrast_interface_is_one_sheet_at_the_delocalization_its_noise_allows(wide):
    shape, box, mesh, record = wide
    t = mesh.topology
    # main: Euler characteristic -5, mean |d| 0.85 nm, mean signed -0.66 nm (seed 2: -8, 1.07, -0.79)
    assert (t.n_components, t.genus, t.boundary_loops) == (1, 0, 1), (t.n_components, t.genus, t.boundary_loops)
    assert record.noise_scale["factor"] > 1.0, record.noise_scale
    areas, d = _offsets(mesh, shape, box)
    assert float(np.sum(areas * np.abs(d)) / areas.sum()) < 0.35  # measured 0.20 (seed 3: 0.21; seed 2: 0.57)
    assert abs(float(np.sum(areas * d) / areas.sum())) < 0.25  # measured -0.14


def test_the_inside_level_of_an_object_cut_by_the_edge_holds_no_matrix(cut):
    shape, box, mesh, record = cut
    refined = record.refined
    assert len(refined.mesh.boundary_edges()), "the measured surface is open at the specimen edge"
    components = topology(refined.mesh.faces, refined.mesh.n_vertices).vertex_components
    level = refined.levels[int(np.argmax(np.bincount(components[components >= 0])))]
    k = level.elements.index("Al")
    sigma = np.sqrt(CUT_INSIDE["Al"] * (1 - CUT_INSIDE["Al"]) / level.n_inside)
    # 0.489 (-6.9 sigma of the window's count) with the ions beyond the rim in the windows; 0.547 without
    assert abs(level.inside[k] - CUT_INSIDE["Al"]) < 2 * sigma, (level.inside[k], sigma)


def test_an_object_cut_by_the_edge_is_not_placed_outward(cut):
    shape, box, mesh, record = cut
    areas, d = _offsets(mesh, shape, box)
    # +0.062 nm with the matrix in its inside window (its midpoint lowered); -0.060 without (-0.063 with the ions
    # beyond the rim measured from the cap continued, -0.020 with the cap's paraboloid fitted within 4 nm, whose rim
    # then gave a blur estimate). Over draws 5-12 the mean -0.031 -> -0.019 -> -0.014 (SE 0.009); with the true blur
    # given -0.0003 (SE 0.011): what is left is the curvature correction of a blur a lone cap does not give (its
    # step's slope of width^2 against tilt has a standard error of 0.05-0.16 nm^2 for a true 0.155). Not asserted
    assert float(np.sum(areas * d) / areas.sum()) < 0.03


def test_the_ions_beyond_a_caps_rim_are_measured_from_the_cap_continued():
    """Exact truth: ions on spheres ``delta`` off a 4.5 nm sphere's surface, beyond the rim of a cap of it (the
    surface an object cut by the specimen edge leaves). Measured to the mesh they count at their lateral distance to
    the rim edge, on the side of its tangent plane; measured from the cap continued (:func:`_tangent_beyond`) they
    are ``delta`` off, without reading them inward."""
    from apt_filters.core.mesh import TriMesh, vertex_normals
    from apt_filters.io.ions import IonTable
    from apt_filters.io.ranges import Range, RangeTable
    from apt_filters.refine.band import NearIons
    from apt_filters.refine.surface import _beyond_rim, _tangent_beyond
    from proxigram_specimens import icosphere

    radius, reach = 4.5, 4.0
    sphere = icosphere(radius, 4)
    faces = sphere.faces[sphere.vertices[sphere.faces].mean(axis=1)[:, 0] < 2.0]  # a cap, its rim at x ~ 2 nm
    vertices = np.asarray(sphere.vertices, dtype=np.float64)
    rng = np.random.default_rng(3)
    x = rng.uniform(2.3, 3.3, 3000)  # 0.3-1.3 nm past the rim along the sphere
    phi = rng.uniform(0, 2 * np.pi, len(x))
    delta = rng.choice([-0.3, 0.0, 0.3], len(x))
    ring = np.sqrt(radius ** 2 - x ** 2)
    points = np.column_stack([x, ring * np.cos(phi), ring * np.sin(phi)]) * ((radius + delta) / radius)[:, None]
    ions = IonTable(points.astype(np.float32), np.full(len(points), 27.0, np.float32))
    near = NearIons.select(ions, RangeTable([Range(26.5, 27.5, (("Al", 1),))]), ConcentrationBasis(), vertices,
                           faces, reach)
    normals = vertex_normals(vertices, faces)
    beyond = _beyond_rim(vertices, faces, near, reach, "mesh", None)
    assert len(TriMesh(vertices, faces).boundary_edges()) and beyond.mean() > 0.95
    band = near.band(vertices, normals, reach, "mesh")
    truth = delta[near.rows[band.index]]
    assert np.abs(band.distance - truth).mean() > 0.3  # to the mesh: off by their lateral distance
    continued = _tangent_beyond(band, beyond, near, vertices, normals, np.zeros(len(vertices), dtype=np.int64), reach)
    error = continued.distance - truth
    # measured: mean +0.024, max 0.082 nm (the paraboloid fitted within 4 nm of a 4.5 nm sphere bends a little more
    # than the sphere near the vertex). From the rim vertex's own normal and edge curvatures, read from the faces on
    # one side of it: mean -0.058 (inward), max 0.151
    assert abs(error.mean()) < 0.04 and np.abs(error).max() < 0.12, (error.mean(), np.abs(error).max())


def test_a_cut_caps_rim_is_not_placed_inward(cut):
    """Exact truth: the faces of the cut sphere's measured surface within 1 nm of its rim, where the ions beyond the
    rim enter the profiles."""
    shape, box, mesh, record = cut
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    rim = np.unique(mesh.boundary_edges().ravel())
    near_rim = np.linalg.norm(centroids[:, None, :] - mesh.vertices[rim][None], axis=2).min(axis=1) < 1.0
    areas = mesh.face_areas()[near_rim]
    signed = float(np.sum(areas * shape.sdf(centroids[near_rim])) / areas.sum())
    # measured -0.010 nm; -0.087 with the ions beyond the rim measured from the rim vertex's own normal and edge
    # curvatures. Draws 5-12: mean -0.031 (SE 0.013; 6 of 8 above -0.05), from -0.072 (SE 0.012; 2 of 8)
    assert signed > -0.05, signed
