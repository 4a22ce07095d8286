"""The inward bias of the refinement (issue 9): the profile distance must be measured to the mesh itself.

Measuring each ion's distance from its nearest vertex's tangent plane puts the interface inside any
convex mesh (the faces lie below the tangent plane: by ``rho * sin(theta / 2)`` across an edge of
dihedral ``theta``, by ``rho * h / 2R`` on a sphere), so the vertices walk inward from the truth; the
signed distance to the faces around the nearest vertex (``distance="mesh"``, the default) does not.
"""

import numpy as np
import pytest

from apt_filters.core.mesh import vertex_normals, topology
from apt_filters.contour import marching_cubes
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.refine import RefineParams, object_excess, refine_surface
from apt_filters.refine.band import NearIons
from apt_filters.synth import Cuboid, Sphere, generate
from apt_filters.synth.geometry import Box
from apt_filters.synth.presets import GAMMA, GAMMA_PRIME
from apt_filters.synth.specimen import Feature, Segregation, SpecimenSpec
from apt_filters.voxel import ConcentrationBasis

from tests.refine_starts import NO_B, speckless_start


def test_mesh_distance_is_the_exact_signed_distance_to_a_cube_and_the_tangent_one_is_not():
    cube = Cuboid((0.1, 0.2, 0.3), 6.0, rotation=31)
    mesh = cube.mesh(0.7)
    rng = np.random.default_rng(0)
    points = rng.uniform(-5, 5, (100_000, 3))
    ions = IonTable(points.astype(np.float32), np.full(len(points), 27.0, np.float32))
    ranges = RangeTable([Range(26.5, 27.5, (("Al", 1),))])
    near = NearIons.select(ions, ranges, ConcentrationBasis(), mesh.vertices, mesh.faces, 2.0)
    normals = vertex_normals(mesh.vertices, mesh.faces)
    exact = cube.sdf(near.positions)
    band = near.band(mesh.vertices, normals, 2.0, "mesh")
    # exact within the profiles' reach; deeper inside, the nearest vertex's faces need not hold the
    # nearest surface point (1 % of the ions 1-2 nm deep, which only count in the flat inside plateau)
    within = np.abs(exact[band.index]) < 1.0
    assert within.sum() > 40_000
    assert np.abs(band.distance - exact[band.index])[within].max() < 1e-9
    tangent = near.band(mesh.vertices, normals, 2.0, "tangent")
    q = np.abs((near.positions[tangent.index] - cube.center) @ cube.rotation) - 3.0
    at_edges = (np.abs(exact[tangent.index]) < 0.5) & ((q > -0.5).sum(axis=1) >= 2)
    # the tangent plane of an edge vertex lies outside both faces: ions there look inside (negative)
    assert np.mean(tangent.distance[at_edges] - exact[tangent.index][at_edges]) < -0.05


@pytest.fixture(scope="module")
def sharp_cube():
    """A 5 nm rotated cube, no blur, dense (340 atoms/nm³ detected), no B shell: a nearly noise-free profile;
    and marching cubes of its exact SDF at 1 nm (vertices on the truth) as the start."""
    cube = Cuboid((0.0, 0.0, -5.5), 5.0, rotation=7)
    spec = SpecimenSpec(Box((11.0, 11.0, 11.0)), GAMMA, (Feature(cube, GAMMA_PRIME, 0.2, (), "cube"),),
                        density=340.0, efficiency=1.0, blur=(0.0, 0.0), name="sharp cube")
    sp = generate(spec, seed=1)
    origin = np.array([-4.863, -4.709, -10.087])  # off the cube's symmetry
    n = 11
    grid = np.stack(np.meshgrid(*[origin[a] + np.arange(n) for a in range(3)], indexing="ij"), -1).reshape(-1, 3)
    start = marching_cubes(-cube.sdf(grid).reshape(n, n, n), 0.0, spacing=1.0, origin=origin)
    return cube, sp, start


def _edge_bias(cube, mesh):
    """Mean signed distance (nm) to the true cube of the vertices within 0.75 nm of an edge or corner."""
    q = np.abs((mesh.vertices - cube.center) @ cube.rotation) - cube.size / 2
    at_edges = (q > -0.75).sum(axis=1) >= 2
    return float(cube.sdf(mesh.vertices[at_edges]).mean())


def test_refinement_started_on_the_truth_keeps_cube_edges_with_the_mesh_distance(sharp_cube):
    cube, sp, start = sharp_cube
    # the profile distance alone: facets (which rebuild the edges from the faces' planes) off
    mesh = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B, RefineParams(facets=False)).mesh
    tangent = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B,
                             RefineParams(distance="tangent", facets=False)).mesh
    # measured: edges -0.028 nm in the start (marching cubes interpolates the SDF linearly across the
    # edge), -0.000 nm refined with the mesh distance, -0.024 nm with the tangent planes (the previous
    # code); volumes -1.5 % and -4.0 % (the rest is the chamfer of faces that cut across the edges). Since the
    # flat faces' sag is undone on the final surface (refine.blur.face_covariance), which lifts the faces across
    # the edges in both: +0.008 / -0.016 nm at the edges, volumes -1.1 % and -2.3 %
    assert abs(_edge_bias(cube, mesh)) < 0.015
    assert _edge_bias(cube, tangent) < _edge_bias(cube, mesh) - 0.015
    volume, tangent_volume = (m.signed_volume() / cube.volume() - 1 for m in (mesh, tangent))
    assert volume > -0.015 and tangent_volume < volume - 0.01


def test_contrast_weights_leave_out_elements_whose_plateaus_differ_only_by_noise():
    from apt_filters.refine.composition import contrast_weights

    elements = ["Al", "Cr", "Ni", "B"]
    inside, outside = np.array([0.20, 0.05, 0.7445, 0.0055]), np.array([0.10, 0.15, 0.745, 0.005])
    # B from ~11 atoms inside: 0.55 vs 0.50 at.% is noise, and B's interface shell would bias the crossing
    w = contrast_weights(inside, outside, elements, "Al", "contrast", 2000.0, 30000.0)
    assert w[0] > 0 > w[1] and w[2] == 0 and w[3] == 0
    exact = contrast_weights(inside, outside, elements, "Al", "contrast")  # plateaus known exactly: all count
    assert exact[3] > 0.05 and exact[2] != 0


def _rounded_start(cube, blur=1.0, fine=4):
    """Marching cubes (1 nm voxels) of the cube's indicator blurred by ``blur`` nm: corners and edges rounded
    as a delocalized field rounds them (the refinement's real start), volume -40 %."""
    from scipy.ndimage import gaussian_filter

    origin, n = np.array([-4.863, -4.709, -10.087]), 11
    axes = [origin[a] + np.arange(n * fine) / fine for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    inside = (cube.sdf(grid) < 0).reshape(n * fine, n * fine, n * fine).astype(float)
    return marching_cubes(gaussian_filter(inside, blur * fine)[::fine, ::fine, ::fine], 0.5, spacing=1.0,
                          origin=origin)


def _bias_by_feature(cube, mesh):
    """Mean signed distance (nm) to the true cube of the vertices within 0.75 nm of one face only (1), of two (2,
    an edge) or three (3, a corner)."""
    q = np.abs((mesh.vertices - cube.center) @ cube.rotation) - cube.size / 2
    near = (q > -0.75).sum(axis=1)
    d = cube.sdf(mesh.vertices)
    return {k: float(d[near == k].mean()) for k in (1, 2, 3)}


def test_refinement_brings_rounded_cube_edges_and_corners_out(sharp_cube):
    cube, sp, _ = sharp_cube
    start = _rounded_start(cube)
    # the iterations (and facets) alone: the cross-fit, the smoothness selection and the blur correction,
    # tested on their own elsewhere, would blur what this measures
    alone = dict(cross_fit=False, select_modes=False, blur=None)
    mesh = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B, RefineParams(**alone)).mesh
    full = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B, RefineParams(full_steps=12, **alone)).mesh
    bias, bias_full = _bias_by_feature(cube, mesh), _bias_by_feature(cube, full)
    # measured (noise-free, blur-free profile; start: edges -0.55 nm, volume -40 %): the defaults (4 full
    # steps, 6 smoothing passes at creases) -0.049 nm at the edges, -0.22 nm at the corners, volume -4.4 %,
    # area -13.4 %; 4 full steps, 10 passes everywhere -0.059, -0.24 nm, -5.1 %, -14.3 %; the code before
    # (3 full steps) -0.076, -0.265 nm, -5.6 %, -15.5 %; full steps throughout -0.025, -0.20 nm, -4.0 %,
    # -12.0 % (not the default: on noisy data they roughen 3 nm spheres). With every default step (session 6:
    # cross-fit, smoothness chosen by the held-out ions, blur estimated) -0.060, -0.23 nm, -3.8 %, -14.2 %
    assert bias[2] > -0.055 and bias[3] > -0.23
    assert mesh.signed_volume() / cube.volume() - 1 > -0.048
    assert mesh.area() / cube.area() - 1 > -0.14
    assert bias_full[2] > -0.04 and bias_full[3] > -0.22
    assert full.signed_volume() / cube.volume() - 1 > -0.045


def test_excess_plateaus_start_beyond_the_blurred_segregation_shell():
    """The solute's plateaus must not take in the tail of its own shell: measured from 0.75 nm they do
    (the B shell, sigma 0.25 nm with the 0.3/0.1 nm blur, holds ~3 % of the excess beyond 0.75 nm on
    each side), and the excess comes out low.

    A 6 nm sphere with a strong B shell (7,200 excess ions per specimen, Poisson noise ~1.2 %) measured
    against its TRUE surface, two specimens: mean excess error -1.91 % with the plateaus from 0.75 nm
    (the previous default; -2.3 and -1.5 %), +0.02 % from 1.0 nm (-0.4 and +0.4 %).

    The true sphere is triangulated at 0.2 nm (36k faces, within 0.0015 nm of the sphere): the specimen's own
    0.1 nm truth mesh (142k faces) gives the same errors within 0.04 points (-1.95 / +0.02 %) at 2.5x the cost."""
    errors = []
    for seed in (1, 2):
        shell = (Segregation("B", peak=0.3, sigma=0.25),)
        spec = SpecimenSpec(Box((20.0, 20.0, 20.0)), GAMMA, (Feature(Sphere((0, 0, -10), 6.0), GAMMA_PRIME, 0.2,
                                                                     shell, "sphere"),), efficiency=1.0, name="shell")
        sp = generate(spec, seed=seed)
        excess = object_excess(spec.features[0].shape.mesh(0.2), sp.ions, sp.ranges, "B")
        errors.append(excess[0].excess_ions / sp.truth["features"][0]["excess"]["B"]["excess_ions"] - 1)
    assert abs(np.mean(errors)) < 0.01, errors


def test_plateaus_the_refinement_uses_are_not_biased_by_the_surface_they_place():
    """Measured against the surface the same ions placed, an object's inside plateau reads high: where the
    surface moved out over an Al-rich fluctuation, ions of it near the window's inner edge enter the window,
    where it moved in over an Al-poor one they leave it. The cross-fit (``cross_fit=True``, the default since
    session 6) counts each half's ions against the other half's surface.

    Eight 3 nm gamma-prime spheres (B shell, efficiency 0.5), two specimens, the plateaus from 0.75 nm
    (where the selection is strong) and no prior, against the same ions' plateaus in the windows of the TRUE
    surfaces: mean inside Al error +0.42 / +0.46 at.% against the refined surface (``cross_fit=False``),
    +0.08 / -0.19 at.% cross-fitted (main e768678); per sphere sd 0.4-0.8 at.% (counting noise): the mean of both
    specimens' 16 spheres has sd ~0.16 at.%, one specimen's ~0.23 (too wide to tell 0 from +0.44: keep both)."""
    errors = {True: [], False: []}
    window = (0.75, 3.0)
    for seed in (1, 2):
        centres = [(x, y, z) for x in (-5.0, 5.0) for y in (-5.0, 5.0) for z in (-5.0, -15.0)]
        spec = SpecimenSpec(Box((20.0, 20.0, 20.0)), GAMMA,
                            tuple(Feature(Sphere(c, 3.0), GAMMA_PRIME, 0.2, (Segregation("B", peak=0.08, sigma=0.25),),
                                          f"sphere {i}") for i, c in enumerate(centres)), efficiency=0.5,
                            name="spheres")
        sp = generate(spec, seed=seed)
        start = speckless_start(sp)
        species, names = sp.ions.extra["species"], sp.truth["species"]
        counted = (species >= 0) & (species != names.index("B"))
        positions = sp.ions.positions.astype(np.float64)
        for cross_fit in (True, False):
            # the smoothness selection needs the cross-fit's halves
            result = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B,
                                    RefineParams(plateau_window=window, plateau_prior=0.0, cross_fit=cross_fit,
                                                 select_modes=cross_fit))
            components = topology(result.mesh.faces, result.mesh.n_vertices).vertex_components
            k = result.levels[0].elements.index("Al")
            assert len(result.levels) == len(centres)
            for i in range(len(centres)):
                sdf = sp.feature_sdf(i)
                c = np.bincount(components[np.abs(sdf(result.mesh.vertices)) < 0.7]).argmax()
                d = sdf(positions)
                truth = np.mean(species[counted & (d <= -window[0]) & (d >= -window[1])] == names.index("Al"))
                errors[cross_fit].append(100 * (result.levels[c].inside[k] - truth))
    assert abs(np.mean(errors[True])) < 0.15, errors[True]
    assert np.mean(errors[False]) > 0.25, errors[False]  # the selection the cross-fit removes
