"""Test and benchmark inputs for the remesher: analytic shapes as sliver-rich triangle meshes.

Smooth shapes come from marching cubes (scikit-image, used here only, never in
``apt_filters``) on analytic signed-distance fields sampled at voxel size 1, so lengths are in
voxels. Shapes with sharp features are built exactly (jittered triangulations of planes and
a mesh boolean), because marching cubes would chamfer their edges; they stand in for the
dual-contouring meshes of the pipeline.
"""

from __future__ import annotations

import numpy as np

from apt_filters.core.mesh import TriMesh


def rotation(seed: int = 3) -> np.ndarray:
    """A fixed, generic 3x3 rotation matrix."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def marching_cubes(field, half: float, inside=None) -> TriMesh:
    """Iso-surface 0 of ``field(x, y, z)`` (positive inside) on a voxel-1 grid over [-half, half]^3.

    Arrays are x, y, z ordered; normals point out of the region where the field is positive.
    The surface is open where it meets the grid's faces or leaves the region where
    ``inside(x, y, z)`` holds (the specimen's edge), as the pipeline's surfaces are.
    """
    from skimage.measure import marching_cubes as mc

    axis = np.arange(-half, half + 1.0)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    values = field(x, y, z)
    verts, faces, _, _ = mc(values, 0.0, mask=None if inside is None else inside(x, y, z))
    mesh = TriMesh(verts + axis[0], faces)
    centre = np.round(verts[faces].mean(axis=1)).astype(int)  # orient by the field's gradient, open or closed
    grad = np.stack(np.gradient(values), -1)[tuple(np.clip(centre, 0, len(axis) - 1).T)]
    if np.einsum("ij,ij->", mesh.face_normals(), grad) > 0:
        mesh.faces = mesh.faces[:, ::-1].copy()
    return mesh


def sphere(radius: float = 10.0) -> TriMesh:
    return marching_cubes(lambda x, y, z: radius - np.sqrt(x**2 + y**2 + z**2), radius + 3)


def torus(major: float = 10.0, minor: float = 4.0) -> TriMesh:
    return marching_cubes(lambda x, y, z: minor - np.hypot(np.hypot(x, y) - major, z), major + minor + 3)


def capped_cylinder(radius: float = 8.0, half_height: float = 8.0) -> TriMesh:
    """Marching-cubes cylinder (its rims come out chamfered, as marching cubes does)."""
    r = rotation(5)

    def field(x, y, z):
        p = np.stack([x, y, z], -1) @ r
        return np.minimum(radius - np.hypot(p[..., 0], p[..., 1]), half_height - np.abs(p[..., 2]))

    return marching_cubes(field, max(radius, half_height) * 1.8 + 2)


def open_sphere(radius: float = 10.0, cut: float = 4.0) -> TriMesh:
    """The marching-cubes sphere without its faces above z = ``cut``: one jagged boundary loop."""
    mesh = sphere(radius)
    keep = mesh.vertices[mesh.faces].mean(axis=1)[:, 2] < cut
    used, faces = np.unique(mesh.faces[keep], return_inverse=True)
    return TriMesh(mesh.vertices[used], faces.reshape(-1, 3))


def gyroid(period: float = 12.0, half: float = 14.0, level: float = 0.3) -> TriMesh:
    """Bicontinuous (spinodal-like) surface: the gyroid level set sin x cos y + ... = ``level``
    (period in voxels) in a cube, open on the cube's faces, genus in the dozens."""
    k = 2 * np.pi / period

    def field(x, y, z):
        x, y, z = k * x + 0.3, k * y - 0.2, k * z + 0.1
        return np.sin(x) * np.cos(y) + np.sin(y) * np.cos(z) + np.sin(z) * np.cos(x) - level

    return marching_cubes(field, half)


def tilted_sheet(radius: float = 14.0, tilt: float = 25.0, curvature: float = 0.02) -> TriMesh:
    """An open interface across a specimen tip: a curved sheet (paraboloid of curvature
    ``curvature`` 1/voxel) tilted by ``tilt`` degrees, clipped to a cone of half-angle 15° (the
    tip) of base radius ``radius``; one boundary loop on the cone."""
    t = np.radians(tilt)
    half = radius + 4

    def field(x, y, z):
        u, w = np.cos(t) * x + np.sin(t) * z, -np.sin(t) * x + np.cos(t) * z
        return w - curvature * (u**2 + y**2) - 1.3

    def inside(x, y, z):
        return np.hypot(x, y) < radius - (half - z) * np.tan(np.radians(15.0)) * 0.5

    return marching_cubes(field, half, inside)


def thin_plate(thickness: float = 1.6, half: float = 10.0) -> TriMesh:
    """A closed plate ``thickness`` voxels thick (a few voxels: both faces within one edge length
    of each other), rounded rim, generically rotated."""
    r = rotation(7)

    def field(x, y, z):
        p = np.stack([x, y, z], -1) @ r
        return np.minimum(thickness / 2 - np.abs(p[..., 2]), half - np.hypot(p[..., 0], p[..., 1]))

    return marching_cubes(field, half + 3)


def small_spheres(radius: float = 2.0, count: int = 8, spacing: float = 6.3) -> TriMesh:
    """``count`` spheres of ``radius`` voxels in a row (one component each), off the grid planes."""
    centres = np.c_[spacing * np.arange(count) - spacing * (count - 1) / 2, np.full(count, 0.37), np.full(count, -0.21)]

    def field(x, y, z):
        d = np.full(x.shape, np.inf)
        for c in centres:
            d = np.minimum(d, np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2))
        return radius - d

    return marching_cubes(field, spacing * count / 2 + 2)


def _jittered_box(half: np.ndarray, spacing: float, seed: int) -> TriMesh:
    """Axis-aligned closed box, each face a jittered grid triangulation (many poor triangles)."""
    import pymeshlab

    rng = np.random.default_rng(seed)
    verts, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            nu, nv = (np.ceil(2 * half[[u, v]] / spacing)).astype(int)
            gu, gv = np.meshgrid(np.linspace(-half[u], half[u], nu + 1), np.linspace(-half[v], half[v], nv + 1),
                                 indexing="ij")
            inner = np.zeros_like(gu, bool)
            inner[1:-1, 1:-1] = True
            du, dv = 2 * half[u] / nu, 2 * half[v] / nv
            gu = gu + inner * rng.uniform(-0.25, 0.25, gu.shape) * du
            gv = gv + inner * rng.uniform(-0.25, 0.25, gv.shape) * dv
            p = np.zeros((gu.size, 3))
            p[:, axis], p[:, u], p[:, v] = sign * half[axis], gu.ravel(), gv.ravel()
            i = np.arange(gu.size).reshape(gu.shape)
            a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
            quads = np.stack([np.stack([a, b, c], 1), np.stack([a, c, d], 1)], 1).reshape(-1, 3)
            faces.append(quads + sum(len(x) for x in verts))
            verts.append(p)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.vstack(verts), np.vstack(faces)))
    ms.meshing_merge_close_vertices(threshold=pymeshlab.PureValue(spacing * 1e-3))
    ms.meshing_re_orient_faces_coherently()
    m = ms.current_mesh()
    mesh = TriMesh(m.vertex_matrix(), m.face_matrix())
    if mesh.signed_volume() < 0:
        mesh.faces = mesh.faces[:, ::-1].copy()
    return mesh


def rotated_box(half=(9.0, 7.0, 5.0), spacing: float = 0.7, seed: int = 0) -> TriMesh:
    """A generically rotated box with exact sharp edges and a jittered triangulation."""
    mesh = _jittered_box(np.asarray(half, float), spacing, seed)
    return TriMesh(mesh.vertices @ rotation().T, mesh.faces)


# The box minus sphere (with a plate) in the box's own frame, before the rotation: cube half edge, ball radius
# and centre (over the half edge); the plate's half sizes and centre.
BOX_HALF, BALL_RADIUS, BALL_CENTRE = 8.0, 7.0, np.array([1.0, 1.0, 0.2])
PLATE_HALF, PLATE_CENTRE = np.array([5.0, 0.3, 4.0]), np.array([-4.0, -4.0, 10.0])


def box_minus_sphere(half: float = BOX_HALF, radius: float = BALL_RADIUS, spacing: float = 0.7) -> TriMesh:
    """Rotated cube with a sphere centred on one corner carved out (boolean: sharp curves, slivers)."""
    import pymeshlab

    box = _jittered_box(np.full(3, half), spacing, 1)
    ball = sphere(radius)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(box.vertices, box.faces))
    ms.add_mesh(pymeshlab.Mesh(ball.vertices + half * BALL_CENTRE, ball.faces))
    ms.generate_boolean_difference(first_mesh=0, second_mesh=1)
    m = ms.current_mesh()
    return TriMesh(m.vertex_matrix() @ rotation().T, m.face_matrix())


def box_minus_sphere_plate(spacing: float = 0.25, scale: float = 1 / 16) -> TriMesh:
    """The issue's side-by-side test mesh: the box minus sphere with a thin plate (0.6 thick)
    standing out of one face, scaled to a unit box (about 50k triangles at the default spacing;
    the issue remeshed it at edge 0.04)."""
    import pymeshlab

    body = box_minus_sphere(spacing=spacing)
    plate = _jittered_box(PLATE_HALF, spacing, 2)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(body.vertices, body.faces))
    ms.add_mesh(pymeshlab.Mesh(plate.vertices @ rotation().T + rotation() @ PLATE_CENTRE, plate.faces))
    ms.generate_boolean_union(first_mesh=0, second_mesh=1)
    m = ms.current_mesh()
    return TriMesh(m.vertex_matrix() * scale, m.face_matrix())


def box_minus_sphere_plate_shape(scale: float = 1 / 16):
    """The analytic solid :func:`box_minus_sphere_plate` triangulates (its sharp edges: the cube's, the rim where
    the ball cuts it, the plate's and where the plate meets the cube; the ball there is a marching-cubes sphere,
    within a few hundredths of a voxel of this one)."""
    from apt_filters.synth.shapes import Cuboid, Sphere
    from apt_filters.truth.shapes import Difference, Union

    r = rotation()
    return Union(Difference(Cuboid(np.zeros(3), 2 * BOX_HALF * scale, r),
                            Sphere(r @ (BOX_HALF * BALL_CENTRE) * scale, BALL_RADIUS * scale)),
                 Cuboid(r @ PLATE_CENTRE * scale, 2 * PLATE_HALF * scale, r))


def pipeline_surface(preset: str = "small", seed: int = 3, folder=None, ions: int | None = None) -> TriMesh:
    """The pipeline's own cleaned surface (``apt-filters run --remesh none``: marching cubes,
    refinement against the ions, clean chain) of the Al 15 at.% iso-surface of a synthetic
    specimen (``small``: a 6 nm gamma-prime-like cube and a 3 nm sphere; ``ions``: the preset
    lengthened to about that many ions); cached in ``folder``."""
    from apt_filters.meshlab.bridge import read_mesh
    from apt_filters.pipeline import config as cfg
    from apt_filters.pipeline.run import run_pipeline
    from apt_filters.synth import preset as make_preset, write_specimen

    folder = _pipeline_folder(preset, seed, folder, ions)
    ply = folder / "out" / "meshes" / "Al15.ply"
    if not ply.exists():
        write_specimen(folder, make_preset(preset, ions), seed=seed, overwrite=True, keep_ions=False)
        config = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.15)])
        config.input.ions, config.input.ranges = str(folder / "specimen.pos"), str(folder / "specimen.rrng")
        config.voxel.exclude = ["B"]
        config.remesh.method = "none"
        run_pipeline(config, folder / "out", quiet=True, force=True)
    mesh = read_mesh(ply)
    return TriMesh(mesh.vertices, mesh.faces)


def _pipeline_folder(preset: str, seed: int, folder, ions: int | None):
    import tempfile
    from pathlib import Path

    return Path(folder or tempfile.gettempdir()) / (f"remesh_bench_{preset}_{seed}" + ("" if ions is None else f"_{ions}"))


def pipeline_truth(preset: str = "small", seed: int = 3, folder=None, ions: int | None = None) -> list:
    """The true objects whose surfaces :func:`pipeline_surface` (same arguments; made first if not cached)
    contours: :func:`apt_filters.truth.specimen.iso_shapes` of its specimen's ``truth.json`` at Al 15 at.%."""
    import json

    from apt_filters.truth.specimen import iso_shapes

    pipeline_surface(preset, seed, folder, ions)
    truth = json.loads((_pipeline_folder(preset, seed, folder, ions) / "truth.json").read_text())
    return iso_shapes(truth, "Al", 0.15)


def bumpy(mesh: TriMesh, amplitude: float, seed: int = 0) -> TriMesh:
    """``mesh`` with every vertex moved along its normal by Gaussian noise of sd ``amplitude``
    (nm), then every face split in four: a stand-in for a small object after the pipeline's
    refinement against the ions (bumps of a few tenths of a nm) and clean chain (edges halved)."""
    from apt_filters.remesh.sampling import split

    rng = np.random.default_rng(seed)
    normals = mesh.vertex_normals()
    moved = mesh.vertices + amplitude * rng.standard_normal((len(normals), 1)) * normals
    return split(TriMesh(moved, mesh.faces), 2).mesh()


# The issue's own inputs: the analytic shapes contoured by our dual contouring at 1 nm voxels
# (sharp rims and corners kept, slivers and clamped vertices as the pipeline produces them).

DC_CENTRE = np.array([0.31, -0.27, 0.37])  # off the grid planes (voxels)


def dc_shape(name: str):
    """The analytic shape (:mod:`apt_filters.synth.shapes`) of ``name`` at voxel scale (nm = voxel),
    centred off the grid planes; sizes as the marching-cubes stand-ins above."""
    from apt_filters.synth.shapes import Cuboid, CustomShape, Cylinder, Sphere
    from apt_filters.truth.shapes import Difference, rotation

    turn = rotation([1.0, 2.0, 3.0], 27.0)
    if name == "sphere":
        return Sphere(DC_CENTRE, 10.0)
    if name == "rotated_box":
        return Cuboid(DC_CENTRE, [18.0, 14.0, 10.0], turn)
    if name == "cylinder":  # along z, as in the contouring benchmark: flat caps, sharp rims
        return Cylinder(DC_CENTRE, 8.0, 16.0)
    if name == "box_minus_sphere":
        return Difference(Cuboid(DC_CENTRE, [16.0, 16.0, 16.0], turn),
                          Sphere(DC_CENTRE + turn @ np.array([8.0, 8.0, 1.6]), 7.0))
    if name == "torus":
        def torus(p, major=10.0, minor=4.0):
            q = p - DC_CENTRE
            return np.hypot(np.hypot(q[:, 0], q[:, 1]) - major, q[:, 2]) - minor

        return CustomShape(torus, DC_CENTRE - [14.0, 14.0, 4.0], DC_CENTRE + [14.0, 14.0, 4.0], name="torus")
    raise ValueError(f"unknown shape {name!r}")


DC_SHAPES = ["sphere", "rotated_box", "cylinder", "box_minus_sphere", "torus"]


def dual_contoured(name: str, exact_normals: bool = True) -> TriMesh:
    """Dual-contouring mesh (voxel 1 nm) of the analytic shape ``name`` (one of ``DC_SHAPES``).

    Hermite normals from the analytic field's gradient (``exact_normals``) or the default ENO
    estimate from the samples, as ``benchmarks.bench_contour`` does.
    """
    from apt_filters.contour import dual_contouring
    from apt_filters.truth.shapes import field_gradient

    shape = dc_shape(name)
    half = 17.0
    axis = np.arange(-half, half + 1.0)
    p = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    values = -shape.sdf(p).reshape((len(axis),) * 3)
    gradient = field_gradient(shape) if exact_normals else None
    return dual_contouring(values, 0.0, (1.0, 1.0, 1.0), (axis[0],) * 3, gradient=gradient)

