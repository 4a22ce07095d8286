"""The refinement's two final corrections (issue 9), against analytic surfaces and synthetic specimens.

- the reconstruction blur's curvature bias (``apt_filters.refine.blur``): a blurred interface's midpoint
  lies ``(1/2) tr(Sigma S)`` inside a convex surface;
- sharp edges and corners rebuilt where planar facets meet (``apt_filters.refine.facets``).
"""

import numpy as np
import pytest

from apt_filters.contour import marching_cubes
from apt_filters.refine import RefineParams, refine_surface
from apt_filters.refine.blur import blur_shift, shape_operator
from apt_filters.refine.facets import facet_steps, find_facets
from apt_filters.synth import Cuboid, Sphere, generate
from apt_filters.synth.geometry import Box
from apt_filters.synth.presets import GAMMA, GAMMA_PRIME
from apt_filters.synth.specimen import Feature, SpecimenSpec

from tests.refine_starts import NO_B, speckless_start


def _contour(sdf, lo, hi, spacing):
    """Marching cubes of ``-sdf`` (inside positive) on a grid over [lo, hi] (x, y, z extents may differ)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    shape = np.round((hi - lo) / spacing).astype(int) + 1
    axes = [lo[a] + spacing * np.arange(shape[a]) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return marching_cubes(-sdf(grid).reshape(*shape), 0.0, spacing=spacing, origin=lo)


def test_shape_operator_of_a_sphere_and_the_blur_shift_of_a_cylinder_along_x():
    r = 3.0
    sphere = _contour(lambda p: np.linalg.norm(p, axis=1) - r, (-4, -4, -4), (4, 4, 4), 0.2)
    normals = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    trace = np.trace(shape_operator(sphere.vertices, sphere.faces, normals), axis1=1, axis2=2)
    assert np.median(np.abs(trace * r / 2 - 1)) < 0.02  # sum of principal curvatures 2 / R
    # a cylinder of radius 2 along x (an asymmetric box, x longest): curvature only round the axis, in
    # y and z, so the shift is (1/2) sigma_t^2 / rho with sigma_t^2 = 0.09 sin^2 + 0.01 cos^2 at normal
    # (0, cos, sin): the depth sigma (z) must act where the tangent is along z, i.e. at the cylinder's sides
    rho, lateral, depth = 2.0, 0.3, 0.1
    cyl = _contour(lambda p: np.hypot(p[:, 1], p[:, 2]) - rho, (-6, -3, -3), (6, 3, 3), 0.2)
    shift, along = blur_shift(cyl, (lateral, depth))
    v = cyl.vertices
    middle = np.abs(v[:, 0]) < 4  # away from the open ends
    angle = np.arctan2(v[middle, 2], v[middle, 1])
    expected = 0.5 * (lateral ** 2 * np.sin(angle) ** 2 + depth ** 2 * np.cos(angle) ** 2) / rho
    # measured on this 0.2 nm marching-cubes mesh: mean 0.96 of the expected, correlation 0.92, normal along z
    # 0.92, along y 1.22 (spurious curvature along the axis of ~0.01/nm, times the lateral 0.09 nm^2)
    assert shift[middle].mean() == pytest.approx(expected.mean(), rel=0.06)
    assert np.corrcoef(shift[middle], expected)[0, 1] > 0.9
    top, side = np.abs(np.sin(angle)) > 0.95, np.abs(np.cos(angle)) > 0.95  # normal along z / along y
    assert shift[middle][top].mean() == pytest.approx(0.5 * lateral ** 2 / rho, rel=0.1)
    assert shift[middle][side].mean() == pytest.approx(0.5 * depth ** 2 / rho, rel=0.3)
    assert shift[middle][top].mean() > 6 * shift[middle][side].mean()  # x, y lateral; z depth
    # a plane has none
    plane = _contour(lambda p: p[:, 2] - 0.3, (-3, -3, -2), (3, 3, 2), 0.25)
    assert np.abs(blur_shift(plane, (lateral, depth))[0]).max() < 1e-9


def test_the_blur_shift_stays_within_its_first_order_range_where_the_mesh_crumples():
    """The shift is first order in the blur over the radius of curvature, so at most about the blur's sigma
    where the surface is an interface; a crumple of the mesh (faces collapsed to a point: a vertex's 1-ring
    shrunk to 2 % on a 3 nm sphere's 0.2 nm mesh) reads 1.4 nm. Seen on unseen thin 10033's rough rod after its
    harmonic low-pass: 13 vertices moved 1-4.5 nm out. The shift is held at the largest sigma there and is the
    sphere's own (sigma^2 / R, 0.03 nm) everywhere the crumple's smoothed normals do not reach."""
    from apt_filters.core.mesh import TriMesh

    r, lateral, depth = 3.0, 0.3, 0.1
    sphere = _contour(lambda p: np.linalg.norm(p, axis=1) - r, (-4, -4, -4), (4, 4, 4), 0.2)
    shift, _ = blur_shift(sphere, (lateral, depth))
    assert shift.max() < 0.5 * lateral  # 0.04 nm on this mesh: far below the clip
    v = sphere.vertices.astype(np.float64)
    top = int(np.argmax(v[:, 2]))
    ring = np.setdiff1d(np.unique(sphere.faces[(sphere.faces == top).any(axis=1)]), [top])
    v[ring] = v[top] + 0.02 * (v[ring] - v[top])
    crumpled, _ = blur_shift(TriMesh(v, sphere.faces), (lateral, depth))
    assert np.abs(crumpled).max() <= lateral
    far = np.linalg.norm(v - v[top], axis=1) > 1.0
    assert np.abs(crumpled[far] - shift[far]).max() < 1e-3  # the smoothed normals reach 1.3 nm, by 6e-4 nm


def _sphere_specimen(seed, blur):
    """A 3 nm gamma-prime sphere in a dense box, no segregant: the volume error is the profile's own."""
    spec = SpecimenSpec(Box((14.0, 14.0, 14.0)), GAMMA, (Feature(Sphere((0.3, -0.2, -7.1), 3.0), GAMMA_PRIME, 0.2, (),
                                                                  "sphere"),),
                        density=170.0, efficiency=1.0, blur=blur, name="blurred sphere")
    sp = generate(spec, seed=seed)
    return sp, speckless_start(sp)


def test_blur_correction_removes_the_curvature_bias_of_a_blurred_sphere():
    blur = (0.45, 0.45)
    errors = {False: [], True: []}
    for seed in (1, 2, 3):
        sp, start = _sphere_specimen(seed, blur)
        true_volume = sp.truth["features"][0]["volume_nm3"]
        for correct in (False, True):
            # profiles to +-2.5 nm: this blur's profile (width ~0.5 nm) cut at the default +-1.5 nm loses part of
            # its longer inside tail, which takes ~40 % of the curvature shift away on this dense specimen
            # (session 6: shift -4.2 % at +-1.5 nm, -7.1 % at +-2.5 nm, theory -6.75 %; at the gamma-prime
            # density the 1.5 nm window kept it: -7.5 % over 32 spheres)
            # facets off: a sphere keeps none; on these six specimens the surfaces are the same bit for bit with them
            # on, which only fits 5-8 candidate planes to the ions and drops them (6x the time)
            mesh = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B,
                                  RefineParams(half_width=2.5, blur=blur if correct else None, facets=False)).mesh
            errors[correct].append(mesh.signed_volume() / true_volume - 1)
    # theory: the midpoint lies sigma^2 / R = 0.0675 nm inside, -6.6 % of the volume. Measured (session 5, the
    # 1.5 nm window, plateaus against the surface itself): -5.9, -5.3, -2.9 % uncorrected, +0.8, +1.4, +3.9 %
    # corrected; session 6 (the 2.5 nm window, cross-fitted plateaus, smoothness chosen by held-out ions):
    # -7.3, -6.8, -5.0 % uncorrected, -0.7, -0.2, +1.7 % corrected
    # The flat faces' sag (start edges 0.47 nm after the subdivision, ~1.1 % of this sphere's volume) is undone in
    # both arms since session 34: uncorrected -5.3 -> -4.1 %, corrected +1.4 -> +2.6 % (seeds 1-3: +1.8, +2.2,
    # +3.9 %). The rest is outward on this dense specimen under a wide (0.45 nm) isotropic blur, which the sag hid;
    # the blur's own correction is the difference, at its theory
    uncorrected, corrected = np.mean(errors[False]), np.mean(errors[True])
    assert uncorrected < -0.035
    assert corrected - uncorrected == pytest.approx(3 * 0.0675 / 3.0 + 3 * (0.0675 / 3.0) ** 2, rel=0.15)
    assert abs(corrected) < abs(uncorrected)


def _rounded_box(rounding=1.0, rotation=27, spacing=0.3, noise=0.03, seed=0, size=(7.0, 6.0, 5.0)):
    box = Cuboid((0.2, -0.1, 0.3), size, rotation=rotation)
    inner = Cuboid(box.center, box.size - 2 * rounding, rotation=rotation)
    mesh = _contour(lambda p: inner.sdf(p) - rounding, (-6, -6, -6), (6, 6, 6), spacing)
    rng = np.random.default_rng(seed)
    mesh.vertices = mesh.vertices + rng.normal(0.0, noise, mesh.vertices.shape)
    return box, mesh


def test_facets_of_a_rounded_noisy_box_and_its_rebuilt_edges_and_corners():
    from apt_filters.truth import surface_error

    box, mesh = _rounded_box()
    # planes fitted to the 20° cones: the default 40° ones take in the start of the rims, which balances the
    # pillowed faces of refined surfaces but puts the planes of this clean fillet ~0.04 nm inside
    facets = find_facets(mesh.vertices, mesh.faces, fit_cap=20.0)
    assert len(facets) == 6
    axes = box.rotation.T  # rows: the box's local axes in the world frame
    for f in facets:
        k = np.argmax(np.abs(axes @ f.normal))
        assert abs(axes[k] @ f.normal) > np.cos(np.radians(1.0))
        assert abs(abs(f.offset - f.normal @ box.center) - box.size[k] / 2) < 0.05
    step, normals = facet_steps(mesh.vertices, mesh.faces, facets)
    sharp = type(mesh)(mesh.vertices + step[:, None] * normals, mesh.faces)
    before = surface_error(mesh, box.sdf, box.mesh(0.2), box.volume(), box.area())
    after = surface_error(sharp, box.sdf, box.mesh(0.2), box.volume(), box.area())
    # a 1 nm fillet: corners 0.73 nm in, volume -7.1 %, area -11.3 %; rebuilt (measured): Hausdorff 0.28 nm,
    # volume -1.1 %, area -2.3 %, what is left being the chamfer of the 0.3 nm triangles across the edges
    assert before.hausdorff > 0.7 and before.volume_error < -0.06 and before.area_error < -0.1
    assert after.hausdorff < 0.3 and abs(after.volume_error) < 0.015 and abs(after.area_error) < 0.03


def test_a_small_cube_is_faceted_where_its_faces_close_it():
    """A 5 nm cube rounded by 1.2 nm: each face's 20° cone holds ~11.5 nm², under ``min_area`` (12), but the
    six close the cube, so they count down to ``closed_area``; a 5.5 x 5 x 4.8 nm cuboid likewise, whose
    two largest pairs of faces (4 facets, not closing it) pass 12 nm² (``peak=inf``: without the search for
    crowded normals, which would find the faces as well)."""
    for size, at_min_area in (((5.0, 5.0, 5.0), 0), ((5.5, 5.0, 4.8), 4)):
        for seed in range(3):
            box, mesh = _rounded_box(rounding=1.2, seed=seed, size=size)
            assert len(find_facets(mesh.vertices, mesh.faces, closed_area=12.0, peak=np.inf)) == at_min_area
            facets = find_facets(mesh.vertices, mesh.faces)
            axes = box.rotation.T
            assert sorted(np.argmax(np.abs(axes @ f.normal)) for f in facets) == [0, 0, 1, 1, 2, 2]
            for f in facets:
                k = np.argmax(np.abs(axes @ f.normal))
                # measured (the cube): tilts 0.1-0.8°, planes 0.060-0.075 nm inside the true faces (the 40°
                # fit cone takes in the start of the 1.2 nm fillet)
                assert abs(axes[k] @ f.normal) > np.cos(np.radians(1.0))
                assert -0.1 < abs(f.offset - f.normal @ box.center) - box.size[k] / 2 < 0.0


def test_a_lath_rounded_off_on_its_narrow_faces_is_rebuilt_to_its_area():
    """Laths 2.5-2.9 nm thick with 1-1.2 nm fillets, as the refinement leaves them: their narrow faces are
    mostly fillet, and their 20° cones hold 6-12 nm², 2-4 % of the lath's area (a sphere's cone holds 3 %),
    so neither ``min_area`` nor ``share`` finds them; the normals still crowd there (1.9-3.5 times the
    area per solid angle of the ring around), which a smooth body's do not at its ends (an ellipsoid's
    long-axis poles 0.7-0.8, a capsule's caps 1.1). With all six facets the edges and corners are rebuilt:
    area within 2 % of the box (measured -0.2, -0.7 %; Hausdorff 0.30, 0.27 nm); with the two or four facets the
    first search finds, -13 to -16 % (Hausdorff 0.7-0.9 nm)."""
    from apt_filters.refine.facets import edge_and_corner_steps
    from apt_filters.truth import surface_error

    for size, rounding in (((2.9, 7.5, 12.0), 1.2), ((2.5, 5.0, 9.0), 1.0)):
        box = Cuboid((0.2, -0.1, 0.3), size, rotation=27)
        inner = Cuboid(box.center, box.size - 2 * rounding, rotation=27)
        mesh = _contour(lambda p: inner.sdf(p) - rounding, (-8, -8, -8), (8, 8, 8), 0.3)
        mesh.vertices = mesh.vertices + np.random.default_rng(0).normal(0.0, 0.03, mesh.vertices.shape)
        facets = find_facets(mesh.vertices, mesh.faces)
        axes = box.rotation.T
        assert sorted(np.argmax(np.abs(axes @ f.normal)) for f in facets) == [0, 0, 1, 1, 2, 2]
        step, normals = facet_steps(mesh.vertices, mesh.faces, facets)
        vertices = mesh.vertices + step[:, None] * normals
        vertices = vertices + edge_and_corner_steps(vertices, mesh.faces, facets)
        err = surface_error(type(mesh)(vertices, mesh.faces), box.sdf, box.mesh(0.2), box.volume(), box.area())
        assert abs(err.area_error) < 0.02 and err.hausdorff < 0.4


def test_smooth_elongated_bodies_are_not_closed_by_crowded_normals():
    """An ellipsoid's flat sides and a rod's strip of normals crowd too, but their ends do not: the search
    for crowded normals adds nothing that closes them (measured: the facets the first search finds, 0-2)."""
    from apt_filters.synth.shapes import Capsule

    rng = np.random.default_rng(1)
    for sdf in (lambda p: (np.linalg.norm(p / [1.8, 3.0, 5.0], axis=1) - 1.0) * 1.8,
                lambda p: (np.linalg.norm(p / [1.8, 5.0, 5.0], axis=1) - 1.0) * 1.8,
                Capsule((0.0, 0.0, 0.0), 1.5, 8.0, rotation=5).sdf):
        mesh = _contour(sdf, (-7, -7, -7), (7, 7, 7), 0.3)
        mesh.vertices = mesh.vertices + rng.normal(0.0, 0.03, mesh.vertices.shape)
        assert len(find_facets(mesh.vertices, mesh.faces)) <= 2


def test_the_rest_of_a_face_found_off_its_normal_is_not_a_second_facet():
    """Vertex normals of a small cube (areas in nm², as measured on a `many` 5 nm cube) whose +x face settled
    as a mode 30° off its normal (8.6 nm²) and left the rest (4.5 nm²) along it: the search for the -x
    facet's opposite meets that rest, which is not a seventh facet."""
    from apt_filters.refine.facets import _modes

    rng = np.random.default_rng(0)
    tilt = np.radians(30)
    clusters = [((0, 1, 0), 11.5), ((0, -1, 0), 11.5), ((-1, 0, 0), 10.2), ((0, 0, 1), 8.7), ((0, 0, -1), 8.4),
                ((np.cos(tilt), 0, np.sin(tilt)), 8.6), ((1, 0, 0), 4.5)]
    normals = np.concatenate([np.asarray(d, float) + rng.normal(0, np.radians(3.0), (60, 3)) for d, _ in clusters])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    areas = np.repeat([a / 60 for _, a in clusters], 60)
    modes = np.array([m[0] for m in _modes(normals, areas, np.cos(np.radians(20)), 0.06, 8.0, 0.5)])
    assert len(modes) == 6  # 7 before the rule
    assert (modes @ modes.T - 2 * np.eye(6)).max() < np.cos(np.radians(40))


def test_a_noisy_sphere_has_no_facets():
    rng = np.random.default_rng(2)
    for r in (2.5, 3.0, 6.0):
        mesh = _contour(lambda p: np.linalg.norm(p, axis=1) - r, (-r - 1,) * 3, (r + 1,) * 3, 0.3)
        mesh.vertices = mesh.vertices + rng.normal(0.0, 0.05, mesh.vertices.shape)
        assert find_facets(mesh.vertices, mesh.faces) == []


def test_refined_small_spheres_no_held_out_ions_judge_get_no_facets():
    """Eight 3 nm spheres refined without the cross-fit (no held-out ions to judge facets): their refined
    surfaces are lumpy, and the search for crowded normals closed every one with 6-7 facets (51 in all, fitted
    to their ions as polyhedra); the searches by area find none."""
    from apt_filters.synth.specimen import Segregation

    centres = [(x, y, z) for x in (-5.0, 5.0) for y in (-5.0, 5.0) for z in (-5.0, -15.0)]
    spec = SpecimenSpec(Box((20.0, 20.0, 20.0)), GAMMA,
                        tuple(Feature(Sphere(c, 3.0), GAMMA_PRIME, 0.2, (Segregation("B", peak=0.08, sigma=0.25),),
                                      f"sphere {i}") for i, c in enumerate(centres)), efficiency=0.5, name="spheres")
    sp = generate(spec, seed=1)
    result = refine_surface(speckless_start(sp), sp.ions, sp.ranges, "Al", NO_B,
                            RefineParams(cross_fit=False, select_modes=False))
    assert result.facets == 0


def test_open_surfaces_get_no_facets():
    """An interface that meets the specimen edge is left as it is, even where it is flat."""
    plane = _contour(lambda p: p[:, 2] - 0.3, (-6, -6, -3), (6, 6, 3), 0.3)
    box, closed = _rounded_box()
    both = type(plane)(np.concatenate([plane.vertices, closed.vertices + [0, 0, 20]]),
                       np.concatenate([plane.faces, closed.faces + plane.n_vertices]))
    facets = find_facets(both.vertices, both.faces)
    assert len(facets) == 6 and all(f.vertices.min() >= plane.n_vertices for f in facets)


def test_the_flat_faces_sag_is_undone_so_a_thin_rod_meshed_coarsely_keeps_its_volume():
    """Vertices exactly on a thin rod (radius 1.3 nm, axis 6 nm, like the zoo's thin rods) with the edges the
    placement leaves there (~0.6 nm: it stretches a thin object's start): the flat faces lie inside by
    ``e^2 / 8R`` on average (``face_covariance``), 5.2 % of the volume short here (zoo thin 10117's rod: vertices
    -0.011 nm, faces -0.046 nm, V -8.6 % at the place stage). The finishing moves every vertex out by its faces'
    sag, blur or none: the volume within 1 % of the exact capsule's (measured -0.7 %), the area within 1 % (+0.6 %);
    a plane does not move."""
    from apt_filters.core.mesh import TriMesh
    from apt_filters.refine.surface import _finisher
    from apt_filters.synth import Capsule

    rod = Capsule((0.0, 0.0, 0.0), 1.3, 6.0)
    mesh = _contour(rod.sdf, (-2, -2, -5), (2, 2, 5), 0.6)  # edges 0.61 nm on average
    v = mesh.vertices.astype(np.float64)
    axis = np.zeros_like(v)
    axis[:, 2] = np.clip(v[:, 2], -3.0, 3.0)
    v = axis + rod.radius * (v - axis) / np.linalg.norm(v - axis, axis=1, keepdims=True)  # exactly on the rod
    placed = TriMesh(v, mesh.faces)
    assert placed.signed_volume() / rod.volume() - 1 < -0.04  # the faces' sag
    finished = TriMesh(_finisher([], mesh.faces, None, sag=True)(v)[0], mesh.faces)
    assert abs(finished.signed_volume() / rod.volume() - 1) < 0.01
    assert abs(finished.area() / rod.area() - 1) < 0.01
    plane = _contour(lambda p: p[:, 2] - 0.3, (-3, -3, -2), (3, 3, 2), 0.45)
    flat = plane.vertices.astype(np.float64)
    assert np.abs(_finisher([], plane.faces, None, sag=True)(flat)[0] - flat).max() < 1e-9
