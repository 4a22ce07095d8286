"""Each object's smoothness chosen from held-out ions (issue 9), against the truth of synthetic specimens.

The cross-validation (``apt_filters.refine.crossval``) never sees the truth; here every candidate it could
have chosen is compared with the true surface, and its choice must be (nearly) the best of them.
"""

from dataclasses import replace

import numpy as np
import pytest

from apt_filters.contour import marching_cubes
from apt_filters.core.checks import folded_pairs
from apt_filters.core.mesh import TriMesh, split_components, topology, vertex_normals
from apt_filters.refine import RefineParams, refine_surface
from apt_filters.refine.band import NearIons, adjacency
from apt_filters.refine.composition import ObjectScores, ion_atoms
from apt_filters.truth import counting_floor, match_objects, surface_error
from apt_filters.refine.crossval import (CANDIDATES, SCORED, HeldOutLoss, basis_size, cross_validated_modes,
                                         finer_candidates, mode_limit, object_harmonics)
from apt_filters.refine.spectral import low_pass
from apt_filters.refine.facets import Facet, Side, find_facets
from apt_filters.refine.surface import _finisher, _low_passed, _slabs_unflattened, _unclosed, umbrella
from apt_filters.synth import Capsule, Cuboid, Cylinder, generate, preset
from apt_filters.synth.geometry import Box
from apt_filters.synth.presets import GAMMA
from apt_filters.synth.specimen import Feature, SpecimenSpec
from apt_filters.synth.zoo import Ellipsoid
from apt_filters.voxel import ConcentrationBasis

from tests.proxigram_specimens import icosphere
from tests.refine_starts import NO_B, speckless_start


@pytest.fixture(scope="module", params=[1, 2])
def small(request):
    """The ``small`` preset (a rotated 6 nm cube, a 3 nm sphere, a layer; gamma-prime statistics) and its start."""
    sp = generate(preset("small"), seed=request.param)
    return sp, speckless_start(sp)


@pytest.fixture(scope="module")
def chosen(small):
    """The refinement with every default, which both tests judge (run once per seed)."""
    sp, start = small
    return refine_surface(start, sp.ions, sp.ranges, "Al", NO_B)


def test_the_modes_held_out_ions_choose_are_the_closest_to_the_true_sphere(small, chosen):
    sp, start = small
    # the same placement without the selection, finishing or blur: every candidate low-passed from it
    placed = refine_surface(start, sp.ions, sp.ranges, "Al", NO_B,
                            RefineParams(select_modes=False, facets=False, blur=None)).mesh
    sphere = next(i for i, f in enumerate(sp.truth["features"]) if f["name"].startswith("sphere"))
    tf, sdf = sp.truth["features"][sphere], sp.feature_sdf(sphere)
    parts = split_components(placed)
    component = match_objects(parts, [sdf])[0]
    bases = object_harmonics(placed.vertices, placed.faces, topology(placed.faces, placed.n_vertices).vertex_components,
                             [component], basis_size(max(CANDIDATES)))
    idx, basis = bases[component]

    def truth_error(vertices):
        mesh = type(placed)(vertices, placed.faces)
        part = split_components(mesh)[component]
        return surface_error(part, sdf, sp.meshes[sphere], tf["volume_nm3"], tf["area_nm2"])

    errors = {}
    for k in CANDIDATES:
        v = placed.vertices.copy()
        v[idx] = low_pass(placed.vertices[idx], basis, basis.cut(k))
        errors[k] = truth_error(v)
    errors[0] = truth_error(placed.vertices)
    k = chosen.modes.modes[component]
    best = min(e.mean_distance for e in errors.values())
    # the choice is within 15 % (+0.01 nm) of the best candidate's mean distance to the truth, and better than
    # keeping the refined shape; measured: the sphere keeps 4-9 modes, 0.07-0.09 nm against 0.14-0.16 as refined
    assert errors[k].mean_distance <= 1.15 * best + 0.01, (k, {m: round(e.mean_distance, 3) for m, e in errors.items()})
    assert errors[k].mean_distance < 0.8 * errors[0].mean_distance
    assert abs(errors[k].area_error) < abs(errors[0].area_error) + 0.01
    # the final sphere (low-passed, blur-corrected) against the truth
    final = split_components(chosen.mesh)[match_objects(split_components(chosen.mesh), [sdf])[0]]
    err = surface_error(final, sdf, sp.meshes[sphere], tf["volume_nm3"], tf["area_nm2"])
    assert err.mean_distance < 0.12 and err.hausdorff < 0.6


def test_the_offset_errors_the_refinement_reports_match_the_counting_floor(small, chosen):
    """The standard error each object gets from its own ions (``RefineResult.offset_errors``: its score profile,
    plateaus and width as measured, and its B peak's centre, the layer's offset fitted over the objects) against
    the Cramér-Rao floor computed with the truth (``counting_floor``: all element profiles and the B peak, one
    width pooled over the objects, the same unknown layer offset): the two models differ, so they agree to ~30 %
    rather than the data's being above the floor (measured: 1.01-1.14 of it, `small` seeds 1-2; from the score
    alone against the score's floor, 0.90-1.16)."""
    sp, _ = small
    result = chosen
    feats = [i for i, f in enumerate(sp.truth["features"]) if f["bounded"]]
    atoms = ion_atoms(sp.ions, sp.ranges, NO_B).atoms
    everything = ion_atoms(sp.ions, sp.ranges, ConcentrationBasis())
    floor = counting_floor([sp.feature_sdf(i) for i in feats], [sp.spec.features[i].shape.level_area for i in feats],
                           [sp.truth["features"][i]["volume_nm3"] for i in feats], sp.ions.positions, atoms,
                           marker=everything.atoms[:, everything.elements.index("B")])
    match = match_objects(split_components(result.mesh), [sp.feature_sdf(i) for i in feats])
    for fl, m in zip(floor, match):
        assert 0.75 * fl.offset < result.offset_errors[m] < 1.3 * fl.offset, (fl.offset, result.offset_errors[m])


def _judged(sp, rod, cube, inset, prism, rounded, inside):
    """``ModeSelection.facets`` of rod and cube (test below) for smooth surfaces ``inset`` nm inside the truth and
    the rod's prism of half-width ``prism`` radii, rounded by ``rounded`` of it; ``inside``: the objects' Al
    fraction."""
    radius, length, size = rod.radius, rod.length, cube.size[0]
    rounding = 0.8
    smooth = [Cylinder(rod.center, radius - inset, length - 2 * inset),
              Cuboid(cube.center, (size - 2 * inset - 2 * rounding,) * 3)]
    lo, hi, h = np.array([-8.0, -5.0, -16.0]), np.array([8.0, 5.0, -4.0]), 0.25
    shape = np.round((hi - lo) / h).astype(int) + 1
    grid = np.stack(np.meshgrid(*[lo[a] + h * np.arange(shape[a]) for a in range(3)], indexing="ij"), -1)
    sdf = np.minimum(smooth[0].sdf(grid.reshape(-1, 3)), smooth[1].sdf(grid.reshape(-1, 3)) - rounding)
    mesh = marching_cubes(-sdf.reshape(*shape), 0.0, spacing=h, origin=lo)
    vertices, faces = mesh.vertices, mesh.faces
    components = topology(faces, len(vertices)).vertex_components
    c_rod, c_cube = int(components[np.argmin(vertices[:, 0])]), int(components[np.argmax(vertices[:, 0])])

    def faceted(v):
        """The rod as a square prism of half-width ``prism`` radii rounded by ``rounded`` of it; the cube's rims
        moved along their normals onto its true faces."""
        out = v.copy()
        mine = components == c_rod
        p = v[mine] - rod.center
        theta = np.arctan2(p[:, 1], p[:, 0])
        a, c = prism * radius, rounded * prism * radius
        lo_t, hi_t = np.zeros(len(p)), np.full(len(p), 2 * a)
        for _ in range(40):  # along each direction, the rounded square's edge by bisection
            t = 0.5 * (lo_t + hi_t)
            q = np.abs(np.stack([t * np.cos(theta), t * np.sin(theta)], 1)) - (a - c)
            d = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0) - c
            lo_t, hi_t = np.where(d < 0, t, lo_t), np.where(d < 0, hi_t, t)
        p[:, :2] *= (0.5 * (lo_t + hi_t) / (radius - inset))[:, None]
        p[:, 2] *= length / (length - 2 * inset)
        out[mine] = p + rod.center
        mine = components == c_cube
        p, n = v[mine] - cube.center, vertex_normals(v, faces)[mine]
        with np.errstate(divide="ignore", invalid="ignore"):
            exit_ = np.where(np.abs(n) > 1e-9, (0.5 * size * np.sign(n) - p) / n, np.inf)
        out[mine] = v[mine] + np.where(exit_ > -1e-9, exit_, np.inf).min(axis=1)[:, None] * n
        return out

    near = NearIons.select(sp.ions, sp.ranges, NO_B, vertices, faces, SCORED + 1.0)
    held = [near.half(k, vertices) for k in (0, 1)]
    al = held[0].atoms.elements.index("Al")
    weights = np.zeros((2, len(held[0].atoms.elements)))
    weights[:, al] = 1.0
    scores = ObjectScores(np.ones(2, bool), weights, np.full(2, inside / 0.995), np.full(2, 0.10 / 0.995))
    selection = cross_validated_modes([vertices, vertices], faces, components, [0, 1], held, scores,
                                      np.full(2, 0.45),
                                      lambda k, kept: (lambda v: (faceted(v) if kept else v,)),
                                      faceted_objects={0, 1})
    return selection.facets[c_rod], selection.facets[c_cube]


def test_facets_must_pass_the_held_out_test_as_they_stand_and_at_fitted_sizes(monkeypatch):
    """A 1.5 nm rod offered facets loses them if the held-out ions reject them either as the candidates stand or
    with each candidate moved to the size the placing half's ions fit it to; a 4.5 nm cube keeps its true faces.
    Al 10 -> 50 at.%, the smooth surfaces' cube rounded by 0.8 nm. First the smooth surfaces 0.25 nm inside
    the truth (the rod 31 % small; refined thin rods come out ~10 % small) and the rod offered a sharp square
    prism of half-width 0.95 radii: the prism wins by its size as it stands (+1.3 SE: kept on main, as thin
    10005's rod kept a polyhedron 7 % large in volume and 13 % in area) and loses at fitted sizes (-1.6 SE).
    Then the smooth surfaces at the truth and the prism of 1.05 radii rounded by 0.6 of it: it loses as it
    stands (-6 SE) and ties at fitted sizes (+0.1 SE: kept by the sized test alone, as dev rod 3's 1.5 nm
    rod was, its area -2.8 -> +5.3 %). The sized test sizes each object's best candidate with facets and its best
    without them as they stand (over both halves): two size fits per half, not one per candidate (24)."""
    sized = []
    fitted_shift = HeldOutLoss.fitted_shift

    def counted(self, distance, only, n_comp, iterations=20):
        sized.append(fitted_shift(self, distance, only, n_comp, iterations))
        return sized[-1]

    monkeypatch.setattr(HeldOutLoss, "fitted_shift", counted)
    radius, length, size, inside = 1.5, 8.0, 4.5, 0.5
    rod, cube = Cylinder((-3.5, 0.0, -10.0), radius, length), Cuboid((3.5, 0.0, -10.0), (size,) * 3)
    phase = {"Ni": 0.945 - inside, "Al": inside, "Cr": 0.05, "B": 0.005}
    spec = SpecimenSpec(Box((16.0, 16.0, 20.0)), GAMMA, (Feature(rod, phase, 0.2, (), "rod"),
                                                         Feature(cube, phase, 0.2, (), "cube")),
                        efficiency=0.5, name="rod and cube")
    sp = generate(spec, seed=4)
    by_size = _judged(sp, rod, cube, 0.25, 0.95, 0.0, inside)
    # per half, the best with facets, then the best without: the smooth ones lie 0.25 nm inside the truth and
    # move out when sized
    assert len(sized) == 4 and np.all(sized[1] > 0.1) and np.all(sized[3] > 0.1), sized
    as_it_stands = _judged(sp, rod, cube, 0.0, 1.05, 0.6, inside)
    assert by_size == (False, True)
    assert not as_it_stands[0]


def test_a_low_passed_shape_that_folds_is_relaxed_in_place_not_held_at_the_rough_placement():
    """The modes stage's low-passed shape with a sliver turned over on it (as the 9-mode shape of held-out
    ``plate`` 10010's second plate had 23 folded pairs): the fold is relaxed where the smooth shape lies, and no
    vertex is left where the rough, inflated placement put it. Truth: every vertex of the smooth shape lies on a
    3 nm sphere; the placement lies 0.3 +- 0.24 nm outside it. Holding the folded sliver's vertices back at the
    placement (the fold guard's way) leaves them 0.3 nm out; the ring relaxed on the sphere stays within its
    sagitta (edge^2 / 2R ~ 0.04 nm per round)."""
    radius = 3.0
    sphere = icosphere(radius, 3)
    faces = sphere.faces
    rng = np.random.default_rng(0)
    placed = sphere.vertices * (1 + rng.normal(0.1, 0.08, sphere.n_vertices))[:, None]
    target = sphere.vertices.copy()
    # one vertex pushed along the sphere past a neighbour: the faces of its fan turn over
    v = int(faces[0, 0])
    j = int(faces[0, 1])
    moved = target[v] + 1.8 * (target[j] - target[v])
    target[v] = radius * moved / np.linalg.norm(moved)
    assert len(folded_pairs(target, faces)) > 0
    out, held = _low_passed(placed, target, faces, umbrella(adjacency(faces, sphere.n_vertices)))
    assert len(folded_pairs(out, faces)) == 0
    assert held == 0
    off = np.abs(np.linalg.norm(out, axis=1) - radius)
    assert off.max() < 0.15, off.max()
    # away from the relaxed ring, the smooth shape is taken as it is
    assert np.count_nonzero(np.linalg.norm(out - target, axis=1) > 1e-12) < 0.1 * sphere.n_vertices


def test_a_slab_its_low_pass_pressed_through_itself_is_finished_from_its_placement():
    """Exact truth: a plate 5 nm in radius and 2.25 nm thick, its two faces kept as a slab (side at its true radius),
    placed exactly, and a low-pass that pressed it through itself (its height scaled by -0.1: seen 10080's plate at
    the 4 modes chosen with its slab kept 9 % of its volume, and its slab finish made V -24 %, A +26 %). The slab is
    finished from its placement and gives the truth (V, A within 3 %); finished as the low-pass left it, its faces'
    cores are pulled across it and its area comes out 11 % high; a low-pass that only thinned it (x 0.85) is kept."""
    plate = Cylinder((0.0, 0.0, 0.0), 5.0, 2.25)
    mesh = plate.mesh(0.2)
    vertices, faces = mesh.vertices, mesh.faces
    topo = topology(faces, len(vertices))
    local = (vertices - plate.center) @ plate.rotation
    axis = plate.rotation[:, 2]
    normals = vertex_normals(vertices, faces)
    side = Side(plate.center, axis, plate.rotation[:, 0], plate.rotation[:, 1], np.full(64, plate.radius))
    everything = np.arange(len(vertices))
    found = [Facet(0, s * axis, plate.length / 2 + s * (plate.center @ axis), everything,
                   np.flatnonzero((normals @ (s * axis) > 0.95) & (np.hypot(local[:, 0], local[:, 1]) < 4.5)),
                   70.0, 0.0, side=side) for s in (1.0, -1.0)]
    squash = np.array([1.0, 1.0, 0.0])

    def pressed(scale):
        return plate.center + (local * squash + scale * local * (1 - squash)) @ plate.rotation.T

    finish = _finisher(found, faces, None)
    kept = _slabs_unflattened(pressed(-0.1), vertices, faces, topo.vertex_components, found)
    assert np.array_equal(kept, vertices)
    thinned = pressed(0.85)
    assert np.array_equal(_slabs_unflattened(thinned, vertices, faces, topo.vertex_components, found), thinned)
    good, bad = (TriMesh(finish(v)[0], faces) for v in (kept, pressed(-0.1)))
    assert abs(good.signed_volume() / plate.volume() - 1) < 0.03 and abs(good.area() / plate.area() - 1) < 0.03
    assert bad.area() / plate.area() - 1 > 0.08  # measured: +11.3 % (V -4.5 %)


def test_facets_that_do_not_close_their_object_must_win_the_held_out_test_not_merely_tie():
    """A lens at 4 points of contrast (an oblate spheroid, 5.5 x 5.5 x 1.5 nm semi-axes; Al 10 -> 14 at.%), its
    candidates the exact surface and what the facet stage makes of it with the two opposite "faces" a rough
    placement (0.3 nm normal noise) crowds its normals into (as held-out plate 10010's second plate kept two
    parallel faces on its 9-mode lens): their cores flattened onto planes fitted to the rough vertices, the
    volume 13 % low. Two facets that close nothing are no polyhedron; the held-out ions tie them with the exact
    lens (kept on main, where a tie keeps facets), so they are dropped."""
    inside = 0.14
    lens = Ellipsoid((0.0, 0.0, -8.0), (5.5, 5.5, 1.5))
    phase = {"Ni": 0.945 - inside, "Al": inside, "Cr": 0.05, "B": 0.005}
    spec = SpecimenSpec(Box((16.0, 16.0, 16.0)), GAMMA, (Feature(lens, phase, 0.2, (), "lens"),), efficiency=0.5,
                        name="lens")
    sp = generate(spec, seed=1)
    sphere = icosphere(1.0, 4)
    vertices, faces = sphere.vertices * lens.axes + lens.center, sphere.faces
    topo = topology(faces, len(vertices))
    rough = vertices + np.random.default_rng(0).normal(0.0, 0.3, len(vertices))[:, None] * vertex_normals(vertices,
                                                                                                           faces)
    found = find_facets(rough, faces)
    unclosed = _unclosed(found, rough, vertex_normals(rough, faces), topo.vertex_components)
    assert len(found) == 2 and unclosed == {0: 2}
    faceted = _finisher(found, faces, None)(vertices)[0]
    true_volume = sp.truth["features"][0]["volume_nm3"]
    assert abs(TriMesh(vertices, faces).signed_volume() / true_volume - 1) < 0.01
    assert abs(TriMesh(faceted, faces).signed_volume() / true_volume - 1) > 0.1
    near = NearIons.select(sp.ions, sp.ranges, NO_B, vertices, faces, SCORED + 1.0)
    held = [near.half(k, vertices) for k in (0, 1)]
    weights = np.zeros((1, len(held[0].atoms.elements)))
    weights[:, held[0].atoms.elements.index("Al")] = 1.0
    scores = ObjectScores(np.ones(1, bool), weights, np.full(1, inside / 0.995), np.full(1, 0.10 / 0.995))
    selection = cross_validated_modes([vertices, vertices], faces, topo.vertex_components, [0], held, scores,
                                      np.full(1, 0.45),
                                      lambda k, kept: _finisher(found if kept else [], faces, None),
                                      faceted_objects={0}, unclosed=unclosed)
    assert selection.facets == {0: False}


def test_a_polyhedron_whose_ions_refused_its_planes_is_judged_like_facets_that_close_nothing():
    """Seen rod 10179's 5.4 nm capsule (R 1.7 nm): the whole surface closed it by eight strips and caps whose joint
    fit to its ions found something else (fit_to_ions gave the vertices' planes back; so did each half's six), and
    the held-out ions tied the halves' square prisms with the smooth rod (+0.29 / -0.94 SE), so it kept the prism:
    area +35.9 %, Hausdorff 1.92 nm. Planes its ions refuse are no polyhedron, so such an object must win by the
    margin of facets that close nothing; planes the ions' fit holds leave the rule as it was."""
    rod = Capsule((0.0, 0.0, 0.0), 1.7, 5.4)
    mesh = rod.mesh(0.25)
    normals = vertex_normals(mesh.vertices, mesh.faces)
    components = np.zeros(len(mesh.vertices), dtype=np.int64)
    none = np.zeros(0, dtype=np.int64)
    box = [Facet(0, s * axis, float(extent), none, none, 10.0, 0.1)
           for axis, extent in zip(np.eye(3), (1.7, 1.7, 2.7 + 1.7)) for s in (1.0, -1.0)]
    assert _unclosed(box, mesh.vertices, normals, components) == {}
    assert _unclosed(box, mesh.vertices, normals, components, box) == {0: 6}  # the fit gave the planes back
    assert _unclosed(box, mesh.vertices, normals, components, [replace(f, fitted=True) for f in box]) == {}


def test_a_smooth_capsule_keeps_no_strips_of_facets_the_held_out_ions_prefer_only_within_their_number():
    """A capsule like development rod 10039's second rod (radius 1.8 nm, axis 11 nm; Al 10 -> 31 at.% over a 0.93
    nm tanh interface) refined with every default. Its rough halves crowd their normals into 5-6 strips round its
    axis (no plane of the truth); the whole's five strips close nothing, and the held-out ions prefer the halves'
    prisms by 2.01 and 1.51 SE: kept on main (one standard error), which turned the capsule into a pentagonal prism
    (area +5.0 %, volume -10.2 %). Five planes must win by 1.86 SE in both tests (``unclosed_margin``): no facets,
    area +0.1 %, volume -10.6 % (the start's and the levels' error, not the facets')."""
    inside = 0.31
    rod = Capsule((0.0, 0.0, -13.0), 1.8, 11.0)
    phase = {"Ni": 0.945 - inside, "Al": inside, "Cr": 0.05, "B": 0.005}
    spec = SpecimenSpec(Box((14.0, 14.0, 26.0)), GAMMA, (Feature(rod, phase, 0.93, (), "rod"),), efficiency=0.57,
                        name="capsule")
    sp = generate(spec, seed=3)
    result = refine_surface(speckless_start(sp, iso=0.5 * (inside + 0.10)), sp.ions, sp.ranges, "Al", NO_B)
    assert result.facets == 0
    area = result.mesh.area() / sp.truth["features"][0]["area_nm2"] - 1
    assert abs(area) < 0.02, area


def test_a_plates_rims_go_out_to_its_sharp_edges_where_its_two_faces_are_kept():
    """A 5 nm plate 2.5 nm thick (contrast 0.75, the faces kept on main too): the refinement rounds its rims by ~1 nm
    and pushes the short side between them out; the side placed by the ions against the faces (``facets.slab_fit``)
    and the rims put on the prism of the faces and the side give the truth back (measured: rims -0.169 -> -0.003 nm,
    the side's middle +0.073 -> -0.006 nm, area -7.3 -> +0.3 %, volume -1.8 -> +0.9 %)."""
    plate = Cylinder((0.3, -0.2, -7.0), 5.0, 2.5, rotation=11)
    phase = {"Ni": 0.095, "Al": 0.85, "Cr": 0.05, "B": 0.005}
    spec = SpecimenSpec(Box((16.0, 16.0, 14.0)), GAMMA, (Feature(plate, phase, 0.2, (), "plate"),), efficiency=0.5,
                        name="plate")
    sp = generate(spec, seed=1)
    result = refine_surface(speckless_start(sp, iso=0.475), sp.ions, sp.ranges, "Al", NO_B)
    assert result.facets == 2
    part = max(split_components(result.mesh), key=lambda p: p.n_faces)
    centres = part.vertices[part.faces].mean(axis=1)
    local = (centres - plate.center) @ plate.rotation
    rho, height = np.hypot(local[:, 0], local[:, 1]), np.abs(local[:, 2])
    # a face's nearest point on the truth: on a flat more than 0.5 nm from the rim, on the side more than 0.5 nm
    # from either rim, or on a rim's band
    rim = (rho > plate.radius - 0.5) & (height > plate.length / 2 - 0.5)
    side = (rho > plate.radius - 0.5) & ~rim
    area, distance = part.face_areas(), plate.sdf(centres)
    offset = {k: float(np.average(distance[sel], weights=area[sel])) for k, sel in (("rim", rim), ("side", side))}
    assert abs(offset["rim"]) < 0.05 and abs(offset["side"]) < 0.05, offset
    assert abs(part.area() / plate.area() - 1) < 0.03
    assert abs(part.signed_volume() / plate.volume() - 1) < 0.03


def test_a_thin_disc_is_offered_the_modes_that_hold_its_rim_a_sphere_only_those_it_had():
    """Exact shapes. ``mode_limit`` is ``A^3 / (pi V^2)``: 36 on a sphere (a fine icosphere within 0.2 %), so a
    sphere is offered CANDIDATES alone; on a disc 1.8 nm thick and 6 nm in radius the exact cylinder's 195.3
    (its 0.6 nm mesh within 0.5 %), offered 64, 100 and 144 modes as well. Those modes hold its rim: the disc
    low-passed to 36 modes loses 11 % of its area (its rim rounded off), to 100 modes 5 % (measured on the
    0.5 nm mesh: -11.1 and -4.6 %; 144 modes -3.7 %)."""
    sphere = icosphere(3.0, 4)
    assert abs(mode_limit(sphere.vertices, sphere.faces) / 36 - 1) < 2e-3
    assert finer_candidates(CANDIDATES, mode_limit(sphere.vertices, sphere.faces)) == CANDIDATES
    disc = Cylinder((0.0, 0.0, 0.0), 6.0, 1.8)
    exact = disc.area() ** 3 / (np.pi * disc.volume() ** 2)
    mesh = disc.mesh(0.6)
    assert abs(mode_limit(mesh.vertices, mesh.faces) / exact - 1) < 5e-3 and abs(exact - 195.29) < 0.01
    assert finer_candidates(CANDIDATES, exact) == CANDIDATES + (64, 100, 144)
    basis = object_harmonics(mesh.vertices, mesh.faces, np.zeros(mesh.n_vertices, int), [0], basis_size(100))[0][1]
    area = {k: TriMesh(low_pass(mesh.vertices, basis, basis.cut(k)), mesh.faces).area() / disc.area() - 1
            for k in (36, 100)}
    assert area[36] < -0.09 and abs(area[100]) < 0.06, area
