"""Edge F1 against a shape's true sharp edges (:func:`apt_filters.truth.metrics.truth_edge_f1`): the rule the
remesher's tests and benchmark judge feature edges by, on shapes whose edges are known exactly."""

import numpy as np

from apt_filters.core.mesh import TriMesh
from apt_filters.synth.shapes import Capsule, Cuboid, Sphere
from apt_filters.truth.metrics import is_sharp, truth_edge_f1
from apt_filters.truth.shapes import rotation
from tests import remesh_shapes as shapes

VOXEL = 0.5  # nm
BOX = Cuboid([0.3, -0.2, 0.1], [6.0, 5.0, 4.0], rotation([1, 2, 3], 27.0))


def smoothed(mesh: TriMesh, rounds: int) -> TriMesh:
    """``mesh`` after ``rounds`` of Laplacian smoothing (each vertex halfway to its neighbours' mean)."""
    v = mesh.vertices.copy()
    edges = np.unique(np.sort(mesh.edges(), axis=1), axis=0)
    degree = np.bincount(edges.ravel(), minlength=len(v))[:, None]
    for _ in range(rounds):
        total = np.zeros_like(v)
        np.add.at(total, edges[:, 0], v[edges[:, 1]])
        np.add.at(total, edges[:, 1], v[edges[:, 0]])
        v = 0.5 * v + 0.5 * total / degree
    return TriMesh(v, mesh.faces)


def test_box_mesh_scores_one_and_a_smoothed_box_less():
    mesh = BOX.mesh(0.25)
    f1, scored = truth_edge_f1(mesh, [BOX], VOXEL)
    assert scored == [0] and f1 >= 0.99  # samples, not curves: 0.999
    assert truth_edge_f1(smoothed(mesh, 1), [BOX], VOXEL)[0] < 0.5  # one round rounds the edges away: 0.10


def test_rounded_objects_are_left_out_not_given_edges():
    """A sphere has no sharp edge: alone it gives no F1; beside the box it is left out (its component with it),
    and the box scores as it does alone."""
    ball = Sphere([9.0, 0.0, 0.0], 2.0)
    box, sphere = BOX.mesh(0.25), ball.mesh(0.25)
    both = TriMesh(np.vstack([box.vertices, sphere.vertices]), np.vstack([box.faces, sphere.faces + len(box.vertices)]))
    f1, scored = truth_edge_f1(sphere, [ball], VOXEL)
    assert np.isnan(f1) and scored == []
    assert truth_edge_f1(both, [BOX, ball], VOXEL) == truth_edge_f1(box, [BOX], VOXEL)
    assert truth_edge_f1(both, [ball, BOX], VOXEL)[1] == [1]


def test_box_sphere_plate_mesh_on_its_analytic_shape():
    """The benchmark's box minus sphere with a plate lies on the union it is built from, edges and all
    (the bench scores it at voxel = 2 x its edge 0.04)."""
    mesh = shapes.box_minus_sphere_plate(0.5)
    shape = shapes.box_minus_sphere_plate_shape()
    assert np.abs(shape.sdf(mesh.vertices)).max() < 0.005  # the marching-cubes ball: 0.0024
    assert truth_edge_f1(mesh, [shape], 0.08)[0] >= 0.99  # 0.998


def test_capsule_samples_lie_on_it_and_have_no_sharp_edge():
    """A rod's samples (the demo's and the zoo's rods are capsules): on its surface, outward, as many as its
    area holds; rounded everywhere, so it is left out of the edge F1."""
    rod = Capsule([1.0, 8.0, -49.0], 1.5, 8.0, rotation=(1.0, 0.3, 0.2))
    points, normals = rod.sample(50.0, np.random.default_rng(0))
    assert np.abs(rod.sdf(points)).max() < 1e-9
    assert np.abs(rod.sdf(points + 1e-3 * normals) - 1e-3).max() < 1e-9
    assert abs(len(points) / (50.0 * rod.area()) - 1) < 0.03  # Poisson: 1 sd = 0.7 %
    assert not is_sharp(rod, 0.5)


def test_iso_shapes_are_the_objects_the_iso_surface_bounds():
    """The demo specimen at Al 15 at.%: its cubes, spheres and rod (Al 20 inside, 10 or 4 outside), not the
    Cr-rich plate (Al 4 inside, 10 outside) nor the layer (a half-space)."""
    from apt_filters.synth import preset
    from apt_filters.synth.generate import build_truth
    from apt_filters.truth.specimen import iso_shapes

    kinds = [s.kind for s in iso_shapes(build_truth(preset("default"), 0)[0], "Al", 0.15)]
    assert kinds == ["cuboid", "sphere", "cuboid", "sphere", "capsule", "sphere"]
