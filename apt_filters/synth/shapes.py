"""Precipitate shapes as exact signed-distance functions (negative inside).

Every shape knows, exactly where geometry allows, its volume, its surface area, the area of each
of its level sets ``{sdf = d}`` (needed to integrate interfacial excess over curved interfaces),
its depth (largest distance from an interior point to the surface) and a fine triangulation of
its surface with outward normals.

Solids (:class:`Sphere`, :class:`Cuboid`, :class:`Capsule`, :class:`Cylinder`) are defined in a
local frame and placed by a centre and a rotation (``world = R @ local + centre``).
:class:`HalfSpace` (a flat interface) is unbounded: its area, volume and mesh are those of its
section with the specimen, so these methods take the specimen geometry as ``within``.
:class:`CustomShape` wraps any user SDF; its measures come from marching cubes on a fine grid.

The SDFs are exact Euclidean distances (|grad| = 1), so the volume between level sets d and
d + dd is ``level_area(d) * dd`` (coarea formula); this is what makes the excess integrals exact.
"""

from __future__ import annotations

import math
from typing import Callable, Protocol

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh


class Within(Protocol):
    """What a half-space needs from the specimen geometry (see :mod:`.geometry`)."""

    def sdf(self, points: np.ndarray) -> np.ndarray: ...

    def cross_section_area(self, z: np.ndarray) -> np.ndarray: ...

    def bounds(self) -> tuple[np.ndarray, np.ndarray]: ...


def rotation_matrix(rotation: None | int | np.ndarray | list) -> np.ndarray:
    """A proper rotation matrix (3, 3) from a specification.

    ``None`` gives the identity; an ``int`` a uniformly distributed random rotation drawn from
    that seed (a normalised Gaussian quaternion); a 3-vector the rotation that maps local +z
    onto that axis (shortest arc); a (3, 3) array is checked to be orthonormal with det +1.
    """
    if rotation is None:
        return np.eye(3)
    if isinstance(rotation, (int, np.integer)):
        q = np.random.default_rng(int(rotation)).normal(size=4)
        w, x, y, z = q / np.linalg.norm(q)
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ])
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape == (3,):
        return _rotation_z_to(r)
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
        raise AptFiltersError("rotation must be an int seed, an axis 3-vector or an orthonormal 3x3 matrix with det +1")
    return r


def _rotation_z_to(axis: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(axis)
    if not np.isfinite(norm) or norm == 0:
        raise AptFiltersError("rotation axis must be a finite non-zero 3-vector")
    a = axis / norm
    c = a[2]  # cos of the angle between +z and a
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    v = np.array([-a[1], a[0], 0.0])  # z x a
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


class Shape:
    """Interface of every shape; see the module docstring."""

    kind = "shape"
    exact_sdf = True
    """``|sdf|`` is the true distance to the surface everywhere."""
    cut = False
    """The specimen's edge cuts the shape: its measures and mesh are those of its part inside."""

    def sdf(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance in nm of points (N, 3); negative inside."""
        raise NotImplementedError

    def volume(self, within: Within | None = None) -> float:
        """Enclosed volume in nm³."""
        raise NotImplementedError

    def area(self, within: Within | None = None) -> float:
        """Surface area in nm² (the level set d = 0)."""
        return float(self.level_area(np.zeros(1), within)[0])

    def level_area(self, d: np.ndarray, within: Within | None = None) -> np.ndarray:
        """Area in nm² of each level set ``{sdf = d}``, for d (k,) in nm."""
        raise NotImplementedError

    def depth(self) -> float:
        """Largest distance in nm from an interior point to the surface (inf if unbounded)."""
        raise NotImplementedError

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lower, upper) corners of a box holding the shape, or None if unbounded."""
        raise NotImplementedError

    def mesh(self, spacing: float = 0.1, within: Within | None = None) -> TriMesh:
        """Closed (or, for a half-space, clipped) triangulation with outward normals, edges <= ~spacing nm."""
        raise NotImplementedError

    def params(self) -> dict:
        """JSON-ready description of the shape."""
        raise NotImplementedError

    def sample(self, density: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Uniform random surface points (``density`` per nm², Poisson count) and their outward unit normals."""
        raise NotImplementedError


def _count(area: float, density: float, rng: np.random.Generator) -> int:
    return int(rng.poisson(area * density))


class _Solid(Shape):
    """A bounded shape placed by a centre and a rotation; subclasses work in the local frame."""

    def __init__(self, center, rotation=None):
        self.center = np.asarray(center, dtype=np.float64).reshape(3)
        self.rotation = rotation_matrix(rotation)

    def _half_extent(self) -> np.ndarray:
        raise NotImplementedError

    def _local_sdf(self, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _local_mesh(self, spacing: float) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def sdf(self, points: np.ndarray) -> np.ndarray:
        local = (np.asarray(points, dtype=np.float64) - self.center) @ self.rotation
        return self._local_sdf(local)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        ext = np.abs(self.rotation) @ self._half_extent()
        return self.center - ext, self.center + ext

    def mesh(self, spacing: float = 0.1, within: Within | None = None) -> TriMesh:
        v, f = self._local_mesh(spacing)
        return TriMesh(v @ self.rotation.T + self.center, f)

    def sample(self, density: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        p, n = self._local_sample(density, rng)
        return p @ self.rotation.T + self.center, n @ self.rotation.T

    def _local_sample(self, density: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def _placement(self) -> dict:
        return {"center": self.center.tolist(), "rotation": self.rotation.tolist()}


class Sphere(_Solid):
    """Sphere of ``radius`` nm."""

    kind = "sphere"

    def __init__(self, center, radius: float):
        super().__init__(center)
        self.radius = _positive(radius, "sphere radius")

    def _half_extent(self):
        return np.full(3, self.radius)

    def _local_sdf(self, p):
        return np.linalg.norm(p, axis=1) - self.radius

    def volume(self, within=None):
        return 4.0 / 3.0 * math.pi * self.radius**3

    def level_area(self, d, within=None):
        r = np.maximum(self.radius + np.asarray(d, dtype=np.float64), 0.0)
        return 4.0 * math.pi * r**2

    def depth(self):
        return self.radius

    def _local_mesh(self, spacing):
        return _revolve(*_arc(0.0, self.radius, math.pi, 0.0, spacing), spacing)

    def _local_sample(self, density, rng):
        n = rng.normal(size=(_count(4 * np.pi * self.radius**2, density, rng), 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return self.radius * n, n

    def params(self):
        return {"kind": self.kind, "radius": self.radius, **self._placement()}


class Cuboid(_Solid):
    """Box with edges ``size`` (3,) nm along its local axes: sharp edges and corners (a cube if equal)."""

    kind = "cuboid"

    def __init__(self, center, size, rotation=None):
        super().__init__(center, rotation)
        self.size = np.asarray(size, dtype=np.float64).reshape(-1) * np.ones(3)
        _positive(self.size.min(), "cuboid edge")

    def _half_extent(self):
        return self.size / 2

    def _local_sdf(self, p):
        q = np.abs(p) - self.size / 2
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        return outside + np.minimum(q.max(axis=1), 0.0)

    def volume(self, within=None):
        return float(np.prod(self.size))

    def level_area(self, d, within=None):
        d = np.asarray(d, dtype=np.float64)
        a, b, c = self.size
        # inside, the level set is the box shrunk by |d|; outside, the Steiner parallel surface:
        # faces + quarter cylinders along the 12 edges + eighth spheres at the 8 corners
        e = np.maximum(self.size[:, None] + 2 * np.minimum(d, 0.0)[None, :], 0.0)
        inner = 2 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])
        dp = np.maximum(d, 0.0)
        outer = 2 * (a * b + b * c + c * a) + 2 * math.pi * (a + b + c) * dp + 4 * math.pi * dp**2
        return np.where(d < 0, inner, outer)

    def depth(self):
        return float(self.size.min() / 2)

    def _local_mesh(self, spacing):
        return _box_surface(self.size / 2, spacing)

    def _local_sample(self, density, rng):
        half = self.size / 2
        pts, nrm = [], []
        for a in range(3):
            u, v = (a + 1) % 3, (a + 2) % 3
            for s in (-1.0, 1.0):
                m = _count(4 * half[u] * half[v], density, rng)
                q = np.zeros((m, 3))
                q[:, a] = s * half[a]
                q[:, u] = rng.uniform(-half[u], half[u], m)
                q[:, v] = rng.uniform(-half[v], half[v], m)
                n = np.zeros((m, 3))
                n[:, a] = s
                pts.append(q)
                nrm.append(n)
        return np.concatenate(pts), np.concatenate(nrm)

    def params(self):
        return {"kind": self.kind, "size": self.size.tolist(), **self._placement()}


class _Axial(_Solid):
    """A solid of revolution about local z with a ``radius`` and a ``length`` (nm)."""

    def __init__(self, center, radius: float, length: float, rotation=None):
        super().__init__(center, rotation)
        self.radius = _positive(radius, f"{self.kind} radius")
        self.length = _positive(length, f"{self.kind} length")

    def params(self):
        return {"kind": self.kind, "radius": self.radius, "length": self.length, **self._placement()}


class Capsule(_Axial):
    """Rod: a cylinder of ``radius`` and axis ``length`` (nm) with hemispherical caps, along local z."""

    kind = "capsule"

    def _half_extent(self):
        return np.array([self.radius, self.radius, self.radius + self.length / 2])

    def _local_sdf(self, p):
        axis = np.zeros_like(p)
        axis[:, 2] = np.clip(p[:, 2], -self.length / 2, self.length / 2)
        return np.linalg.norm(p - axis, axis=1) - self.radius

    def volume(self, within=None):
        r, h = self.radius, self.length
        return math.pi * r * r * h + 4.0 / 3.0 * math.pi * r**3

    def level_area(self, d, within=None):
        r = np.maximum(self.radius + np.asarray(d, dtype=np.float64), 0.0)
        return 2 * math.pi * r * self.length + 4 * math.pi * r**2

    def depth(self):
        return self.radius

    def _local_mesh(self, spacing):
        r, h = self.radius, self.length / 2
        rho, z = _join(_arc(-h, r, math.pi, math.pi / 2, spacing),
                       _segment((r, -h), (r, h), spacing),
                       _arc(h, r, math.pi / 2, 0.0, spacing))
        return _revolve(rho, z, spacing)

    def _local_sample(self, density, rng):
        r, hh = self.radius, self.length / 2
        m = _count(2 * np.pi * r * 2 * hh, density, rng)
        phi = rng.uniform(0, 2 * np.pi, m)
        side_n = np.stack([np.cos(phi), np.sin(phi), np.zeros(m)], 1)
        side = r * side_n + np.outer(rng.uniform(-hh, hh, m), [0.0, 0.0, 1.0])
        # the caps are a sphere's two halves, each moved to its end of the axis
        cap_n = rng.normal(size=(_count(4 * np.pi * r**2, density, rng), 3))
        cap_n /= np.linalg.norm(cap_n, axis=1, keepdims=True)
        caps = r * cap_n + np.outer(np.where(cap_n[:, 2] < 0, -hh, hh), [0.0, 0.0, 1.0])
        return np.concatenate([side, caps]), np.concatenate([side_n, cap_n])


class Cylinder(_Axial):
    """Cylinder with flat caps along local z: a rod if long, a plate (disc) if ``length`` < ``radius``."""

    kind = "cylinder"

    def _half_extent(self):
        return np.array([self.radius, self.radius, self.length / 2])

    def _local_sdf(self, p):
        dr = np.hypot(p[:, 0], p[:, 1]) - self.radius
        dz = np.abs(p[:, 2]) - self.length / 2
        return np.minimum(np.maximum(dr, dz), 0.0) + np.hypot(np.maximum(dr, 0.0), np.maximum(dz, 0.0))

    def volume(self, within=None):
        return math.pi * self.radius**2 * self.length

    def level_area(self, d, within=None):
        d = np.asarray(d, dtype=np.float64)
        r, h = self.radius, self.length
        ri = np.maximum(r + np.minimum(d, 0.0), 0.0)
        hi = np.maximum(h + 2 * np.minimum(d, 0.0), 0.0)
        inner = np.where((ri > 0) & (hi > 0), 2 * math.pi * ri * ri + 2 * math.pi * ri * hi, 0.0)
        dp = np.maximum(d, 0.0)
        # Steiner: caps + lateral, plus the two quarter-tori around the circular edges
        outer = 2 * math.pi * r * r + 2 * math.pi * r * h + 2 * (math.pi * h + math.pi**2 * r) * dp + 4 * math.pi * dp**2
        return np.where(d < 0, inner, outer)

    def depth(self):
        return min(self.radius, self.length / 2)

    def _local_mesh(self, spacing):
        r, h = self.radius, self.length / 2
        rho, z = _join(_segment((0.0, -h), (r, -h), spacing),
                       _segment((r, -h), (r, h), spacing),
                       _segment((r, h), (0.0, h), spacing))
        return _revolve(rho, z, spacing)

    def _local_sample(self, density, rng):
        r, hh = self.radius, self.length / 2
        m = _count(2 * np.pi * r * 2 * hh, density, rng)
        phi = rng.uniform(0, 2 * np.pi, m)
        side = np.stack([r * np.cos(phi), r * np.sin(phi), rng.uniform(-hh, hh, m)], 1)
        side_n = np.stack([np.cos(phi), np.sin(phi), np.zeros(m)], 1)
        pts, nrm = [side], [side_n]
        for s in (-1.0, 1.0):
            m = _count(np.pi * r**2, density, rng)
            rad, phi = r * np.sqrt(rng.uniform(0, 1, m)), rng.uniform(0, 2 * np.pi, m)
            pts.append(np.stack([rad * np.cos(phi), rad * np.sin(phi), np.full(m, s * hh)], 1))
            nrm.append(np.tile([0.0, 0.0, s], (m, 1)))
        return np.concatenate(pts), np.concatenate(nrm)


class HalfSpace(Shape):
    """Flat interface through ``point`` with unit ``normal``; the inside (sdf < 0) is behind the normal.

    E.g. ``HalfSpace((0, 0, -50), (0, 0, 1))`` is the layer below z = -50 nm. Area, volume and
    mesh are those of its section with the (convex) specimen ``within``.
    """

    kind = "halfspace"
    _ANGLES = 256

    def __init__(self, point, normal):
        self.point = np.asarray(point, dtype=np.float64).reshape(3)
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        if not np.isfinite(n).all() or np.linalg.norm(n) == 0:
            raise AptFiltersError("half-space normal must be a finite non-zero 3-vector")
        self.normal = n / np.linalg.norm(n)
        self.rotation = _rotation_z_to(self.normal)  # columns 0, 1 span the plane

    def sdf(self, points):
        return (np.asarray(points, dtype=np.float64) - self.point) @ self.normal

    def bounds(self):
        return None

    def depth(self):
        return math.inf

    def _section(self, d: float, within: Within, n_angles: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre (3,), in-plane directions (n, 3) and boundary radii (n,) of the section at offset d.

        The specimen is convex, so along each ray from an interior point its SDF has one root,
        found by bisection. A section that misses the specimen has zero radii.
        """
        if within is None:
            raise AptFiltersError("a half-space needs the specimen geometry for its area, volume and mesh")
        lo, hi = within.bounds()
        middle = (lo + hi) / 2
        plane_point = self.point + d * self.normal
        centre = middle - ((middle - plane_point) @ self.normal) * self.normal
        # the deepest point of a grid over the plane is inside the section if anything is
        size = float(np.linalg.norm(hi - lo))
        u, v = np.meshgrid(np.linspace(-size, size, 65), np.linspace(-size, size, 65), indexing="ij")
        grid = centre + u.reshape(-1, 1) * self.rotation[:, 0] + v.reshape(-1, 1) * self.rotation[:, 1]
        depth = within.sdf(grid)
        origin = grid[np.argmin(depth)]
        phi = 2 * math.pi * np.arange(n_angles) / n_angles
        dirs = np.cos(phi)[:, None] * self.rotation[:, 0] + np.sin(phi)[:, None] * self.rotation[:, 1]
        if depth.min() >= 0:
            return origin, dirs, np.zeros(n_angles)
        t_lo, t_hi = np.zeros(n_angles), np.full(n_angles, 2 * size)
        for _ in range(48):
            t = (t_lo + t_hi) / 2
            inside = within.sdf(origin + t[:, None] * dirs) < 0
            t_lo, t_hi = np.where(inside, t, t_lo), np.where(inside, t_hi, t)
        return origin, dirs, (t_lo + t_hi) / 2

    def level_area(self, d, within=None):
        """Section areas; exact (the outline's own cross-section) for planes normal to z, else polygons."""
        d = np.atleast_1d(np.asarray(d, dtype=np.float64))
        if within is not None and abs(self.normal[2]) == 1.0:
            return within.cross_section_area(self.point[2] + d * self.normal[2])
        out = np.empty(len(d))
        for i, di in enumerate(d):
            r = self._section(float(di), within, self._ANGLES)[2]
            out[i] = 0.5 * math.sin(2 * math.pi / self._ANGLES) * float(np.sum(r * np.roll(r, -1)))
        return out

    def volume(self, within=None):
        """Volume in nm³ of the specimen on the inside of the plane (Simpson over level sets)."""
        from scipy.integrate import simpson

        lo, hi = within.bounds() if within is not None else (None, None)
        if lo is None:
            raise AptFiltersError("a half-space needs the specimen geometry for its volume")
        corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(3, -1).T
        d_min = float(self.sdf(corners).min())
        if d_min >= 0:
            return 0.0
        d = np.linspace(d_min, 0.0, 257)
        return float(simpson(self.level_area(d, within), x=d))

    def mesh(self, spacing=0.1, within=None):
        """Polar triangulation of the section: rim segments <= spacing, rings 1 nm apart (the plane is exact)."""
        origin, dirs, radii = self._section(0.0, within, 64)
        if radii.max() == 0:
            raise AptFiltersError("the flat interface does not cut the specimen")
        n_angles = max(self._ANGLES, math.ceil(2 * math.pi * radii.max() / spacing))
        origin, dirs, radii = self._section(0.0, within, n_angles)
        n_rings = max(2, math.ceil(radii.max() / 1.0))
        frac = np.arange(1, n_rings + 1) / n_rings
        rings = origin + (frac[:, None, None] * radii[None, :, None]) * dirs[None]  # (rings, angles, 3)
        verts = np.vstack([origin[None], rings.reshape(-1, 3)])
        j = np.arange(n_angles)
        jn = (j + 1) % n_angles
        faces = [np.stack([np.zeros(n_angles, np.int64), 1 + j, 1 + jn], axis=1)]
        for k in range(n_rings - 1):
            a, b = 1 + k * n_angles + j, 1 + k * n_angles + jn
            c, e = a + n_angles, b + n_angles
            faces += [np.stack([a, c, e], axis=1), np.stack([a, e, b], axis=1)]
        f = np.vstack(faces)
        mesh = TriMesh(verts, f)
        if (mesh.face_normals() @ self.normal).mean() < 0:
            mesh = TriMesh(verts, f[:, ::-1])
        return mesh

    def params(self):
        return {"kind": self.kind, "point": self.point.tolist(), "normal": self.normal.tolist()}


class CustomShape(Shape):
    """Any user SDF ``fn(points (N, 3)) -> (N,)`` (negative inside) within the box ``lower``-``upper``.

    Volume, area, level-set areas and mesh come from marching cubes on a grid of ``grid`` nm spanning
    the box grown by ``pad`` nm (error O(grid²); level sets farther out than ``pad`` are not seen);
    the SDF should be a true distance near its surface for the excess to be exact.
    """

    kind = "custom"

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], lower, upper, name: str = "custom", grid: float = 0.1,
                 pad: float = 3.0):
        self.fn = fn
        self.lower = np.asarray(lower, dtype=np.float64).reshape(3)
        self.upper = np.asarray(upper, dtype=np.float64).reshape(3)
        if not (self.upper > self.lower).all():
            raise AptFiltersError("custom shape bounds: upper must exceed lower on every axis")
        self.name, self.grid, self.pad = name, float(grid), float(pad)
        self._field: np.ndarray | None = None

    def sdf(self, points):
        return np.asarray(self.fn(np.asarray(points, dtype=np.float64)), dtype=np.float64)

    def bounds(self):
        return self.lower.copy(), self.upper.copy()

    def _values(self) -> np.ndarray:
        if self._field is None:
            axes = [np.arange(lo - self.pad, hi + self.pad + self.grid, self.grid) for lo, hi in zip(self.lower, self.upper)]
            pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
            self._field = self.sdf(pts.reshape(-1, 3)).reshape(pts.shape[:3])
            self._origin = np.array([a[0] for a in axes])
        return self._field

    def _level_mesh(self, level: float) -> TriMesh:
        from apt_filters.contour.marching_cubes import marching_cubes

        field = self._values()
        if not field.min() < level < field.max():
            return TriMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
        # the region below the level is inside: contour -sdf above -level, normals outward
        mesh = marching_cubes(-field, -level, spacing=self.grid, origin=self._origin)
        return TriMesh(mesh.vertices, mesh.faces)

    def level_area(self, d, within=None):
        d = np.atleast_1d(np.asarray(d, dtype=np.float64))
        knots = np.linspace(d.min(), d.max(), 33) if d.max() > d.min() else d[:1]
        areas = np.array([self._level_mesh(float(k)).area() for k in knots])
        return np.interp(d, knots, areas)

    def volume(self, within=None):
        return self._level_mesh(0.0).signed_volume()

    def depth(self):
        return float(-self._values().min())

    def mesh(self, spacing=0.1, within=None):
        return self._level_mesh(0.0)

    def params(self):
        return {"kind": self.kind, "name": self.name, "lower": self.lower.tolist(), "upper": self.upper.tolist(),
                "grid": self.grid, "pad": self.pad}


def _positive(value: float, what: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise AptFiltersError(f"{what} must be a positive number of nm, got {value}")
    return value


# ---- profile curves (rho, z) for surfaces of revolution, from the bottom pole to the top pole ----

def _arc(z_center: float, radius: float, theta0: float, theta1: float, spacing: float):
    n = max(2, math.ceil(radius * abs(theta1 - theta0) / spacing))
    theta = np.linspace(theta0, theta1, n + 1)
    rho = radius * np.sin(theta)
    rho[np.isclose(theta, 0.0) | np.isclose(theta, math.pi)] = 0.0
    return rho, z_center + radius * np.cos(theta)


def _segment(p0: tuple[float, float], p1: tuple[float, float], spacing: float):
    n = max(1, math.ceil(math.hypot(p1[0] - p0[0], p1[1] - p0[1]) / spacing))
    t = np.linspace(0.0, 1.0, n + 1)
    return p0[0] + t * (p1[0] - p0[0]), p0[1] + t * (p1[1] - p0[1])


def _join(*parts):
    rho = np.concatenate([parts[0][0]] + [p[0][1:] for p in parts[1:]])
    z = np.concatenate([parts[0][1]] + [p[1][1:] for p in parts[1:]])
    return rho, z


def _revolve(rho: np.ndarray, z: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed surface of revolution about z of a profile from a bottom pole (rho=0) to a top pole.

    Rings go counter-clockwise about +z and upward, so quads (ring k, j) -> (k, j+1) -> (k+1, j+1)
    face outward.
    """
    n = max(12, math.ceil(2 * math.pi * rho.max() / spacing))
    phi = 2 * math.pi * np.arange(n) / n
    ring_rho, ring_z = rho[1:-1], z[1:-1]
    rings = np.stack([ring_rho[:, None] * np.cos(phi), ring_rho[:, None] * np.sin(phi),
                      np.broadcast_to(ring_z[:, None], (len(ring_z), n))], axis=-1).reshape(-1, 3)
    top = 1 + len(rings)
    verts = np.vstack([[0.0, 0.0, z[0]], rings, [0.0, 0.0, z[-1]]])
    j = np.arange(n)
    jn = (j + 1) % n
    last = 1 + (len(ring_z) - 1) * n
    faces = [np.stack([np.zeros(n, np.int64), 1 + jn, 1 + j], axis=1),
             np.stack([np.full(n, top), last + j, last + jn], axis=1)]
    for k in range(len(ring_z) - 1):
        a, b = 1 + k * n + j, 1 + k * n + jn
        faces += [np.stack([a, b, b + n], axis=1), np.stack([a, b + n, a + n], axis=1)]
    return verts, np.vstack(faces)


def _box_surface(half: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed box surface, each face a grid of squares <= spacing, shared edge vertices merged."""
    verts, faces, offset = [], [], 0
    for k in range(3):
        u, v = (k + 1) % 3, (k + 2) % 3  # (u, v, k) is right-handed: e_u x e_v = e_k
        gu = np.linspace(-half[u], half[u], max(1, math.ceil(2 * half[u] / spacing)) + 1)
        gv = np.linspace(-half[v], half[v], max(1, math.ceil(2 * half[v] / spacing)) + 1)
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        idx = np.arange(uu.size).reshape(uu.shape)
        a, b, c, e = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tri = np.vstack([np.stack([a, b, c], axis=1), np.stack([a, c, e], axis=1)])
        for sign in (-1.0, 1.0):
            p = np.empty((uu.size, 3))
            p[:, k], p[:, u], p[:, v] = sign * half[k], uu.ravel(), vv.ravel()
            verts.append(p)
            faces.append((tri if sign > 0 else tri[:, ::-1]) + offset)
            offset += len(p)
    allv = np.vstack(verts)
    uniq, inverse = np.unique(np.round(allv, 9), axis=0, return_inverse=True)
    return uniq, inverse.reshape(-1)[np.vstack(faces)]


def shape_from_params(params: dict) -> Shape:
    """The shape that :meth:`Shape.params` describes (a truth.json feature's ``shape``).

    Custom shapes (a callable SDF) cannot be rebuilt from their parameters and raise AptFiltersError.
    """
    kind = params.get("kind")
    if kind == "sphere":
        return Sphere(params["center"], params["radius"])
    if kind == "cuboid":
        return Cuboid(params["center"], params["size"], params["rotation"])
    if kind in ("capsule", "cylinder"):
        axial = Capsule if kind == "capsule" else Cylinder
        return axial(params["center"], params["radius"], params["length"], params["rotation"])
    if kind == "halfspace":
        return HalfSpace(params["point"], params["normal"])
    raise AptFiltersError(f"a {kind!r} shape cannot be rebuilt from its parameters")
