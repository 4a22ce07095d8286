"""Each object's smoothness chosen from held-out ions (issue 9), against the truth of synthetic specimens.

The cross-validation (``apt_filters.refine.crossval``) never sees the truth; here every candidate it could
have chosen is compared with the true surface, and its choice must be (nearly) the best of them.
"""

import numpy as np
import pytest

from apt_filters.core.checks import folded_pairs
from apt_filters.core.mesh import split_components, topology
from apt_filters.refine import RefineParams, refine_surface
from apt_filters.refine.band import adjacency
from apt_filters.refine.composition import ion_atoms
from apt_filters.truth import counting_floor, match_objects, surface_error
from apt_filters.refine.crossval import CANDIDATES, basis_size, object_harmonics
from apt_filters.refine.spectral import low_pass
from apt_filters.refine.surface import _low_passed, umbrella
from apt_filters.synth import generate, preset
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
    topo = topology(faces, sphere.n_vertices)
    out, held = _low_passed(placed, target, faces, topo.face_pairs, umbrella(adjacency(faces, sphere.n_vertices)))
    assert len(folded_pairs(out, faces)) == 0
    assert held == 0
    off = np.abs(np.linalg.norm(out, axis=1) - radius)
    assert off.max() < 0.15, off.max()
    # away from the relaxed ring, the smooth shape is taken as it is
    assert np.count_nonzero(np.linalg.norm(out - target, axis=1) > 1e-12) < 0.1 * sphere.n_vertices
