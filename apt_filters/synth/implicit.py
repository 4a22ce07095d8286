"""Shapes whose surface is the zero set of an implicit function, with their exact signed distance.

Superellipsoids of general exponents and bicontinuous (spinodal-like) level sets have no closed-form
distance. :class:`ZeroSet` samples the surface ``{F = 0}`` densely (marching cubes of ``F`` on a fine
grid, every vertex then moved onto the surface by Newton steps along ``grad F``, so the samples lie on
it to ~1e-12 nm) and answers a distance query by a foot-point iteration from the nearest sample: the query is
dropped onto the tangent plane there and the result moved onto the surface again, which leaves a
second-order error (within 5e-3 nm of brute force within ``NEAR`` nm of surfaces curved up to 6 nm^-1, tested;
farther out, where it starts from a coarser subset, within ~0.01 nm).
The sign is the sign of ``F`` itself, so the zero set, and with it the true surface, is exact.

Level-set areas come from Steiner's formula with the principal curvatures at each sample (from the
Hessian of ``F``): ``A(d) = sum_v a_v (1 + k1 d)(1 + k2 d)``, each factor clipped at 0 (exact for
parallel surfaces up to the first focal point).

Also here: :class:`SphereInterface`, a curved open interface spanning a box (a large sphere's cap:
exact distance, area, volume and level-set areas by Gauss-Legendre quadrature over the box section),
and :class:`CutSphere`, a sphere cut by a plane face of the specimen, whose measures are those of its
part inside.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.synth.shapes import Shape, Sphere, _Solid, _positive

Field = Callable[[np.ndarray], np.ndarray]


class ZeroSet:
    """Dense samples of the surface ``{F = 0}`` inside the box ``lower``-``upper`` and exact distances to it.

    Parameters
    ----------
    fn, grad : callable
        ``F(points (N, 3)) -> (N,)`` (negative inside) and its gradient ``(N, 3)``.
    lower, upper : (3,) float
        Box sampled (nm); the surface must not reach its faces, or it is open there.
    spacing : float
        Grid step of the marching cubes (nm); samples are about this far apart.
    """

    NEWTON = 6
    HESSIAN_STEP = 1e-4
    COARSE = 0.4
    NEAR = 3.0
    FOOT_STEPS = 6
    KNOTS = 257

    def __init__(self, fn: Field, grad: Field, lower, upper, spacing: float):
        from scipy.spatial import cKDTree

        from apt_filters.contour.marching_cubes import marching_cubes

        self.fn, self.grad = fn, grad
        lower, upper = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
        axes = [np.arange(lo, hi + spacing, spacing) for lo, hi in zip(lower, upper)]
        values = np.empty([len(a) for a in axes])
        yz = np.stack(np.meshgrid(axes[1], axes[2], indexing="ij"), axis=-1).reshape(-1, 2)
        for i, x in enumerate(axes[0]):  # slab by slab: a 20 nm box at 0.1 nm holds 8M points
            values[i] = fn(np.column_stack([np.full(len(yz), x), yz])).reshape(values.shape[1:])
        # the region below F = 0 is inside: contour -F above 0, normals outward
        mesh = marching_cubes(-values, 0.0, spacing=spacing, origin=lower)
        if mesh.n_faces == 0:
            raise AptFiltersError("the implicit surface does not cross its sampling box")
        self.mesh = TriMesh(self.project(mesh.vertices), mesh.faces)
        g = grad(self.mesh.vertices)
        self.normals = g / np.linalg.norm(g, axis=1, keepdims=True)
        self.k1, self.k2 = self._curvatures(self.mesh.vertices, g)
        corner = np.zeros(self.mesh.n_vertices)
        np.add.at(corner, self.mesh.faces.ravel(), np.repeat(self.mesh.face_areas() / 3, 3))
        self.vertex_area = corner
        # one sample per COARSE cell starts each distance query (a dense tree is slow for far points)
        cells = np.floor(self.mesh.vertices / self.COARSE).astype(np.int64)
        _, self._coarse_index = np.unique(cells, axis=0, return_index=True)
        self._coarse = cKDTree(self.mesh.vertices[self._coarse_index])
        self._tree = cKDTree(self.mesh.vertices)

    def project(self, points: np.ndarray, steps: int | None = None) -> np.ndarray:
        """Points moved onto ``{F = 0}`` by Newton steps along the gradient."""
        p = np.array(points, dtype=np.float64)
        for _ in range(self.NEWTON if steps is None else steps):
            g = self.grad(p)
            p -= (self.fn(p) / np.maximum(np.einsum("ij,ij->i", g, g), 1e-300))[:, None] * g
        return p

    def _curvatures(self, p: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Principal curvatures (nm^-1, positive where the surface bulges outward) from the Hessian of F."""
        h = self.HESSIAN_STEP
        hess = np.stack([(self.grad(p + h * e) - self.grad(p - h * e)) / (2 * h) for e in np.eye(3)], axis=2)
        hess = 0.5 * (hess + hess.transpose(0, 2, 1))
        norm = np.linalg.norm(g, axis=1)
        n = g / norm[:, None]
        proj = np.eye(3) - n[:, :, None] * n[:, None, :]
        shape_op = proj @ hess @ proj / norm[:, None, None]
        trace = np.trace(shape_op, axis1=1, axis2=2)
        gauss = 0.5 * (trace ** 2 - np.einsum("nij,nji->n", shape_op, shape_op))
        mean = 0.5 * trace
        root = np.sqrt(np.maximum(mean ** 2 - gauss, 0.0))
        return mean + root, mean - root

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance (nm) to the surface, negative where ``F < 0``.

        The nearest sample (of a coarse subset beyond ``NEAR`` nm) starts a foot-point iteration: the
        query's offset along the tangent plane there, divided by ``1 + H d`` (H the sample's mean curvature,
        d the distance: the step that lands on a sphere's foot point), moved onto the surface,
        ``FOOT_STEPS`` times. Where the
        iteration ends off the surface or farther than that sample (it stalled near a corner or on a far
        part of a non-convex surface), the sample's distance is kept (an upper bound within ``COARSE`` nm
        far out, within the sample spacing near the surface).
        """
        p = np.asarray(points, dtype=np.float64)
        out = np.empty(len(p))
        for start in range(0, len(p), 1 << 18):  # bounded memory for millions of ions
            q = p[start:start + (1 << 18)]
            start_d, idx = self._coarse.query(q)
            idx = self._coarse_index[idx]
            near = start_d < self.NEAR  # near the surface the dense samples are quick to search, and start closer
            if near.any():
                start_d[near], idx[near] = self._tree.query(q[near])
            foot = self.mesh.vertices[idx]
            # a tangent step from the foot is short by 1 + k d on a surface of curvature k (a sphere: exactly)
            bend = np.clip(1 + 0.5 * (self.k1[idx] + self.k2[idx]) * np.where(self.fn(q) < 0, -start_d, start_d),
                           0.2, 5.0)
            for _ in range(self.FOOT_STEPS):
                g = self.grad(foot)
                n = g / np.linalg.norm(g, axis=1, keepdims=True)
                rel = q - foot
                normal = np.einsum("ij,ij->i", rel, n)[:, None] * n
                foot = self.project(foot + (rel - normal) / bend[:, None], steps=1)
            foot = self.project(foot, steps=2)
            g = self.grad(foot)
            on = np.abs(self.fn(foot)) < 1e-6 * np.linalg.norm(g, axis=1)  # the iteration ended on the surface
            dist = np.where(on, np.minimum(np.linalg.norm(q - foot, axis=1), start_d), start_d)
            out[start:start + len(q)] = np.where(self.fn(q) < 0, -1.0, 1.0) * dist
        return out

    def level_area(self, d: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
        """Steiner areas (nm²) of the level sets at d (k,) nm, over the samples ``keep`` (default all); more than
        ``KNOTS`` levels are interpolated from that many."""
        d = np.atleast_1d(np.asarray(d, dtype=np.float64))
        a, k1, k2 = ((self.vertex_area, self.k1, self.k2) if keep is None
                     else (self.vertex_area[keep], self.k1[keep], self.k2[keep]))
        knots = d if len(d) <= self.KNOTS else np.linspace(d.min(), d.max(), self.KNOTS)  # smooth in d
        areas = np.array([np.maximum(1 + k1 * di, 0.0) @ (np.maximum(1 + k2 * di, 0.0) * a) for di in knots])
        return areas if knots is d else np.interp(d, knots, areas)


class Superellipsoid(_Solid):
    """``|x/a|^p + |y/b|^q + |z/c|^r <= 1`` in its local frame: semi-axes ``axes`` (3,) nm, exponents (3,) >= 1.

    Exponents of 2 give an ellipsoid; larger ones square it off towards a box, smaller ones (down to 1)
    sharpen it towards an octahedron. Volume exact (Dirichlet's integral,
    ``8abc G(1+1/p) G(1+1/q) G(1+1/r) / G(1+1/p+1/q+1/r)``); distance, area and level-set areas by
    :class:`ZeroSet` on a grid of ``GRID`` nm.
    """

    kind = "superellipsoid"
    GRID = 0.1

    def __init__(self, center, axes, exponents, rotation=None):
        super().__init__(center, rotation)
        self.axes = np.asarray(axes, dtype=np.float64).reshape(3)
        self.exponents = np.asarray(exponents, dtype=np.float64).reshape(3)
        if not (np.isfinite(self.axes).all() and (self.axes > 0).all()):
            raise AptFiltersError("superellipsoid semi-axes must be positive numbers of nm")
        if not (np.isfinite(self.exponents).all() and (self.exponents >= 1).all()):
            raise AptFiltersError("superellipsoid exponents must be >= 1 (convex)")
        self._zero: ZeroSet | None = None

    def _f(self, p):
        # the sum to the power 1 / (largest exponent) grows about linearly far out, where Newton steps
        # on the sum itself would crawl
        return np.sum(np.abs(p / self.axes) ** self.exponents, axis=1) ** (1 / self.exponents.max()) - 1.0

    def _grad(self, p):
        u = p / self.axes
        total = np.sum(np.abs(u) ** self.exponents, axis=1)
        scale = total ** (1 / self.exponents.max() - 1) / self.exponents.max()
        return scale[:, None] * self.exponents * np.sign(u) * np.abs(u) ** (self.exponents - 1) / self.axes

    def zero_set(self) -> ZeroSet:
        """The sampled surface in the local frame (built on first use)."""
        if self._zero is None:
            reach = self.axes + 3 * self.GRID
            self._zero = ZeroSet(self._f, self._grad, -reach, reach, self.GRID)
        return self._zero

    def _half_extent(self):
        return self.axes.copy()

    def _local_sdf(self, p):
        return self.zero_set().sdf(p)

    def volume(self, within=None):
        from scipy.special import gamma

        inv = 1.0 / self.exponents
        return float(8 * np.prod(self.axes) * np.prod(gamma(1 + inv)) / gamma(1 + inv.sum()))

    def level_area(self, d, within=None):
        return self.zero_set().level_area(d)

    def depth(self):
        return float(self.axes.min())

    def _local_mesh(self, spacing):
        mesh = self.zero_set().mesh
        return mesh.vertices, mesh.faces

    def params(self):
        return {"kind": self.kind, "axes": self.axes.tolist(), "exponents": self.exponents.tolist(),
                **self._placement()}


class LevelSetInterface(Shape):
    """A bicontinuous interface spanning a box: the zero set of a periodic-like field, inside where ``F < 0``.

    ``field`` is ``"waves"`` (a spinodal-like structure: ``F = sqrt(2/n) sum_i cos(k_i . x + phi_i) - level``,
    ``n`` plane waves of one wavelength in random directions, Cahn's model of early spinodal decomposition)
    or ``"gyroid"`` (``sin X cos Y + sin Y cos Z + sin Z cos X - level`` with ``X = 2 pi x' / wavelength``
    in a rotated frame). Its measures are those of its part inside the box ``box`` (the specimen's, a
    :class:`~.geometry.Box`); the surface is sampled 3 nm beyond it so distances near the faces are exact.
    """

    kind = "levelset"
    GRID = 0.2
    PAD = 2.5

    def __init__(self, box, field: str, wavelength: float, level: float, seed: int, waves: int = 16):
        if field not in ("waves", "gyroid"):
            raise AptFiltersError(f"unknown level-set field {field!r}; choose waves or gyroid")
        self.box, self.field, self.level, self.seed, self.waves = box, field, float(level), int(seed), int(waves)
        self.wavelength = _positive(wavelength, "level-set wavelength")
        rng = np.random.default_rng(self.seed)
        k = 2 * math.pi / self.wavelength
        if field == "waves":
            u = rng.normal(size=(self.waves, 3))
            self._k = k * u / np.linalg.norm(u, axis=1, keepdims=True)
            self._phase = rng.uniform(0, 2 * math.pi, self.waves)
            self._amp = math.sqrt(2.0 / self.waves)
        else:
            from apt_filters.synth.shapes import rotation_matrix

            self._rot = k * rotation_matrix(int(rng.integers(1 << 30))).T  # x' = R^T x, scaled
            self._shift = rng.uniform(0, 2 * math.pi, 3)
        lo, hi = box.bounds()
        self._lower, self._upper = lo, hi
        self._zero: ZeroSet | None = None

    def _f(self, p):
        if self.field == "waves":
            return self._amp * np.cos(p @ self._k.T + self._phase).sum(axis=1) - self.level
        x = p @ self._rot.T + self._shift
        s, c = np.sin(x), np.cos(x)
        return s[:, 0] * c[:, 1] + s[:, 1] * c[:, 2] + s[:, 2] * c[:, 0] - self.level

    def _grad(self, p):
        if self.field == "waves":
            return -self._amp * np.sin(p @ self._k.T + self._phase) @ self._k
        x = p @ self._rot.T + self._shift
        s, c = np.sin(x), np.cos(x)
        gx = np.stack([c[:, 0] * c[:, 1] - s[:, 2] * s[:, 0], -s[:, 0] * s[:, 1] + c[:, 1] * c[:, 2],
                       -s[:, 1] * s[:, 2] + c[:, 2] * c[:, 0]], axis=1)
        return gx @ self._rot

    def zero_set(self) -> ZeroSet:
        if self._zero is None:
            self._zero = ZeroSet(self._f, self._grad, self._lower - self.PAD, self._upper + self.PAD, self.GRID)
        return self._zero

    def _in_box(self) -> np.ndarray:
        v = self.zero_set().mesh.vertices
        return np.all((v >= self._lower) & (v <= self._upper), axis=1)

    def sdf(self, points):
        return self.zero_set().sdf(points)

    def bounds(self):
        return None

    def depth(self):
        return math.inf

    def level_area(self, d, within=None):
        """Steiner areas of the level sets over the samples inside the box."""
        return self.zero_set().level_area(d, self._in_box())

    def volume(self, within=None):
        """Volume (nm³) of the inside phase within the box: the fraction of a 0.2 nm cell-centred grid with F < 0."""
        step = 0.2
        axes = [np.arange(lo + step / 2, hi, step) for lo, hi in zip(self._lower, self._upper)]
        yz = np.stack(np.meshgrid(axes[1], axes[2], indexing="ij"), axis=-1).reshape(-1, 2)
        inside = sum(int((self._f(np.column_stack([np.full(len(yz), x), yz])) < 0).sum()) for x in axes[0])
        return inside * step ** 3

    def mesh(self, spacing=0.1, within=None):
        """The sampled surface, faces whose three vertices lie inside the box (open at its faces)."""
        mesh = self.zero_set().mesh
        keep = self._in_box()[mesh.faces].all(axis=1)
        used, faces = np.unique(mesh.faces[keep], return_inverse=True)
        return TriMesh(mesh.vertices[used], faces.reshape(-1, 3))

    def params(self):
        return {"kind": self.kind, "field": self.field, "wavelength": self.wavelength, "level": self.level,
                "seed": self.seed, "waves": self.waves, "box": self.box.params()}


def _gauss_rectangle(half: np.ndarray, n: int = 96) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes (x, y) and weights over the rectangle ``[-half_x, half_x] x [-half_y, half_y]``."""
    t, w = np.polynomial.legendre.leggauss(n)
    x, y = np.meshgrid(half[0] * t, half[1] * t, indexing="ij")
    return x.ravel(), y.ravel(), np.outer(half[0] * w, half[1] * w).ravel()


class SphereInterface(Shape):
    """A curved open interface across a box: a cap of the sphere of ``radius`` nm about ``center``.

    ``convex`` True: the inside is the ball (the interface bulges towards +z when the centre lies below
    it); False: the inside is everything outside the ball. The cap must be a graph ``z(x, y)`` over the
    whole box section (its centre farther than the box half-diagonal from every lateral point), so its
    area, the inside volume and every level set's area (concentric spheres) are integrals over the
    section, done by Gauss-Legendre quadrature (exact to ~1e-12 for these smooth integrands); level sets
    are taken to stay inside the box's z range (true within the interface's reach for the zoo's draws).
    """

    kind = "sphere_interface"

    def __init__(self, box, center, radius: float, convex: bool):
        self.box, self.center = box, np.asarray(center, dtype=np.float64).reshape(3)
        self.radius, self.convex = _positive(radius, "interface radius"), bool(convex)
        lo, hi = box.bounds()
        self._half = (hi - lo)[:2] / 2
        self._bottom = lo[2]
        corner = np.abs(self.center[:2]) + self._half
        if np.hypot(*corner) >= 0.98 * self.radius:
            raise AptFiltersError("sphere interface: the cap must be a graph over the whole box section")
        self._up = self.center[2] < 0.5 * (lo[2] + hi[2])  # the centre below: the cap is the ball's top

    def sdf(self, points):
        r = np.linalg.norm(np.asarray(points, dtype=np.float64) - self.center, axis=1) - self.radius
        return r if self.convex else -r

    def _graph(self, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x, y, w = _gauss_rectangle(self._half)
        rho2 = (x - self.center[0]) ** 2 + (y - self.center[1]) ** 2
        root = np.sqrt(radius * radius - rho2)
        return x, y, w, self.center[2] + (root if self._up else -root)

    def _level_radius(self, d: float) -> float:
        return self.radius + (d if self.convex else -d)

    def level_area(self, d, within=None):
        out = []
        for di in np.atleast_1d(np.asarray(d, dtype=np.float64)):
            rad = self._level_radius(float(di))
            x, y, w, z = self._graph(rad)
            out.append(float(np.sum(w * rad / np.abs(z - self.center[2]))))
        return np.array(out)

    def volume(self, within=None):
        """Inside volume within the box: below the cap (ball's top, convex) or below it (concave), to the bottom."""
        x, y, w, z = self._graph(self.radius)
        below = float(np.sum(w * (z - self._bottom)))
        if self.convex == self._up:
            return below
        return float(np.prod(2 * self._half) * (-self._bottom)) - below  # the region above the cap

    def bounds(self):
        return None

    def depth(self):
        return math.inf

    def mesh(self, spacing=0.1, within=None):
        """The cap over a square grid of the box section (vertices exactly on the sphere), normals outward."""
        n = [max(2, math.ceil(2 * h / spacing)) + 1 for h in self._half]
        x, y = np.meshgrid(np.linspace(-self._half[0], self._half[0], n[0]),
                           np.linspace(-self._half[1], self._half[1], n[1]), indexing="ij")
        rho2 = (x - self.center[0]) ** 2 + (y - self.center[1]) ** 2
        z = self.center[2] + (1 if self._up else -1) * np.sqrt(self.radius ** 2 - rho2)
        verts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
        idx = np.arange(x.size).reshape(x.shape)
        a, b, c, e = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        faces = np.vstack([np.stack([a, b, c], 1), np.stack([a, c, e], 1)])
        mesh = TriMesh(verts, faces)
        centroids = verts[faces].mean(axis=1)
        outward = (centroids - self.center) * (1 if self.convex else -1)
        if np.einsum("ij,ij->", mesh.face_normals(), outward) < 0:
            mesh = TriMesh(verts, faces[:, ::-1])
        return mesh

    def params(self):
        return {"kind": self.kind, "center": self.center.tolist(), "radius": self.radius, "convex": self.convex,
                "box": self.box.params()}


class CutSphere(Sphere):
    """A sphere cut by the specimen face ``{p . normal <= offset}`` (unit ``normal`` pointing out of the
    specimen): its volume, area and level-set areas are those of its part inside (a sphere minus a cap:
    exact), its mesh that part's surface, open at the face. The distance is the whole sphere's."""

    kind = "cut_sphere"
    cut = True

    def __init__(self, center, radius: float, normal, offset: float):
        super().__init__(center, radius)
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        self.normal, self.offset = n / np.linalg.norm(n), float(offset)
        self.inset = self.offset - float(self.center @ self.normal)  # centre to face, positive inside
        if not -self.radius < self.inset < self.radius:
            raise AptFiltersError("cut sphere: the face must cut the sphere")

    def volume(self, within=None):
        t = self.radius - self.inset  # height of the cap beyond the face
        return 4.0 / 3.0 * math.pi * self.radius ** 3 - math.pi * t * t * (3 * self.radius - t) / 3

    def level_area(self, d, within=None):
        r = np.maximum(self.radius + np.asarray(d, dtype=np.float64), 0.0)
        return np.clip(2 * math.pi * r * (r + self.inset), 0.0, 4 * math.pi * r * r)

    def moved_in(self, margin: float) -> "CutSphere":
        """The same sphere cut by the face moved ``margin`` nm into the specimen."""
        return CutSphere(self.center, self.radius, self.normal, self.offset - margin)

    def mesh(self, spacing=0.1, within=None):
        whole = super().mesh(spacing)
        keep = (whole.vertices[whole.faces] @ self.normal <= self.offset).all(axis=1)
        used, faces = np.unique(whole.faces[keep], return_inverse=True)
        return TriMesh(whole.vertices[used], faces.reshape(-1, 3))

    def params(self):
        return {**super().params(), "kind": self.kind, "normal": self.normal.tolist(), "offset": self.offset}
