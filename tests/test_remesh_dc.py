"""Remesher on the issue's own inputs: the analytic shapes contoured by our dual contouring.

Voxel = 1 nm; Hermite normals from the analytic field's gradient. Quality targets of issue 6
against the input mesh, sharp features against the analytic truth. These judge the remesher's own
output (``verify=False``): with the check on, a component that the remesh moves by more than a
quarter edge is given back unchanged (tests/test_remesh_preserve.py), as the box minus sphere is
here (0.32 voxel where the dual contouring left a crease's bend split over two edges).
"""

import numpy as np
import pytest

from apt_filters.remesh import quality, remesh, verify
from apt_filters.truth.metrics import truth_edge_f1
from tests import remesh_shapes as shapes

EDGE = 1.0  # voxels


def edge_f1(mesh, name):
    """Edge F1 of ``mesh`` against the sharp edges of the analytic shape ``name`` (voxel 1 nm)."""
    return truth_edge_f1(mesh, [shapes.dc_shape(name)], 1.0)[0]


@pytest.fixture(scope="module")
def results():
    cache = {}

    def get(name):
        if name not in cache:
            mesh = shapes.dual_contoured(name)
            result = remesh(mesh, edge_length=EDGE, max_iter=20, verify=False)
            cache[name] = (mesh, result, quality.assess(result.mesh, mesh, 50_000))
        return cache[name]

    return get


@pytest.mark.parametrize("name", shapes.DC_SHAPES)
def test_triangle_quality(results, name):
    _, _, q = results(name)
    assert q.frac_ge_30 >= 0.995, q
    assert q.mean_q >= 0.9, q


# The rotated box missed (0.68 voxel) until the QEF's ties went to the point nearest the mass
# point: one dual-contouring vertex stood 0.56 voxel off the true box in a tent (now 0.18).
@pytest.mark.parametrize("name", ["sphere", "rotated_box", "cylinder", "torus"])
def test_hausdorff_to_input_below_0_3_voxel(results, name):
    _, _, q = results(name)
    assert q.hausdorff <= 0.3, q


def test_box_minus_sphere_missed_is_remeshed_again():
    """The box minus sphere's first remesh passes 0.32 voxel from the input where the sphere meets a box
    edge (two input vertices 0.24-0.30 voxel outside the truth; 0.28 before the cone apexes and the
    graded sizes): beyond a quarter edge. The check remeshes it again, finer there with the vertices it
    missed pinned, and that one holds: nothing is given back."""
    mesh = shapes.dual_contoured("box_minus_sphere")
    first = remesh(mesh, edge_length=EDGE, max_iter=20, verify=False)
    one = np.zeros(first.mesh.n_faces, np.int64)
    assert any("Hausdorff" in r for r in verify.check_components(mesh, first.mesh, mesh.face_components(), one,
                                                                  edge=EDGE)[0].reasons)
    result = remesh(mesh, edge_length=EDGE, max_iter=20)
    assert result.kept_input == 0
    c = result.checks[0]
    assert max(c.hausdorff_in_out, c.hausdorff_out_in) <= verify.HAUSDORFF_FRACTION * EDGE, c
    assert c.euler_out == c.euler_in and abs(c.area_change) <= verify.AREA_TOLERANCE, c


@pytest.mark.parametrize("name", shapes.DC_SHAPES)
def test_manifold_oriented_topology_preserved(results, name):
    mesh, result, q = results(name)
    topo = quality.topology(mesh)
    assert (q.non_manifold_edges, q.non_manifold_vertices, q.orientation_conflicts) == (0, 0, 0), q
    assert q.self_intersections == 0, q
    assert (q.components, q.boundary_loops, q.genus) == (topo.components, topo.boundary_loops, topo.genus), q
    assert result.mesh.signed_volume() * mesh.signed_volume() > 0


@pytest.mark.parametrize("name, curves, corners", [("rotated_box", 12, 8), ("cylinder", 2, 0)])
def test_feature_curves_found(results, name, curves, corners):
    _, result, _ = results(name)
    assert (result.n_curves, result.n_corners) == (curves, corners)


@pytest.mark.parametrize("name", ["rotated_box", "box_minus_sphere"])
def test_edge_f1_within_0_05_of_input(results, name):
    mesh, result, _ = results(name)
    before = edge_f1(mesh, name)
    assert before > 0.9  # the sharp edges are there to keep
    assert edge_f1(result.mesh, name) >= before - 0.05


# With the default ENO Hermite normals the bend at a rim is spread over two edges under 40 deg
# in places; with ``bridge_gaps`` the weak edges joined to a crease close its gaps (without: 6 of
# the 15 curves on the box minus sphere; the box's 12 since the contouring kink test, none before).
@pytest.fixture(scope="module")
def eno_results():
    cache = {}

    def get(name):
        if name not in cache:
            mesh = shapes.dual_contoured(name, exact_normals=False)
            result = remesh(mesh, edge_length=EDGE, max_iter=20, bridge_gaps=True, verify=False)
            cache[name] = (mesh, result, quality.assess(result.mesh, mesh, 50_000))
        return cache[name]

    return get


@pytest.mark.parametrize("name, curves, corners", [("rotated_box", 12, 8), ("cylinder", 2, 0),
                                                   ("box_minus_sphere", 15, 10)])
def test_eno_feature_curves_found(eno_results, name, curves, corners):
    _, result, _ = eno_results(name)
    assert (result.n_curves, result.n_corners) == (curves, corners)


@pytest.mark.parametrize("name", ["rotated_box", "cylinder", "box_minus_sphere"])
def test_eno_triangle_quality_and_manifold(eno_results, name):
    mesh, result, q = eno_results(name)
    assert q.frac_ge_30 >= 0.995, q
    assert q.mean_q >= 0.9, q
    assert (q.non_manifold_edges, q.non_manifold_vertices, q.self_intersections) == (0, 0, 0), q


@pytest.mark.parametrize("name", ["rotated_box", "box_minus_sphere"])
def test_eno_edge_f1_within_0_05_of_input(eno_results, name):
    mesh, result, _ = eno_results(name)
    before = edge_f1(mesh, name)
    assert before > 0.75  # blurred by the ENO normals, but the sharp edges are there to keep
    assert edge_f1(result.mesh, name) >= before - 0.05


# The ENO input itself: at the rims the nearer end's normal and the linear crossing put
# vertices 0.38 (box), 0.22 (cylinder) and 0.37 voxel (box minus sphere) off the true shape;
# with the crossing and plane of the end whose tangent line holds there (the kink test) 0.18,
# 0.07 and 0.34 (0.62 on the box minus sphere without the fallback to the linear data at a
# corner; the exact-normal input: 0.34).
@pytest.mark.parametrize("name, bound", [("rotated_box", 0.2), ("cylinder", 0.1), ("box_minus_sphere", 0.35)])
def test_eno_input_vertices_near_the_true_shape(eno_results, name, bound):
    mesh, _, _ = eno_results(name)
    assert np.abs(shapes.dc_shape(name).sdf(mesh.vertices)).max() <= bound
