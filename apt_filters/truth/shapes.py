"""Analytic test shapes with exact answers: signed distance, gradient, surface samples.

Shapes live in the box [-1, 1]³ (nm) and are placed off the grid planes and off-centre
so that no face coincides with a sample plane and x, y, z are not interchangeable.
The field handed to contouring is ``-sdf`` (inside above iso = 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

CENTRE = np.array([0.021, -0.034, 0.013])


def rotation(axis, degrees: float) -> np.ndarray:
    """(3, 3) rotation matrix about ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    a = np.radians(degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


@dataclass
class Shape:
    """Base class; subclasses define ``sdf`` and ``_sample`` (uniform points with normals)."""

    name: str
    exact_sdf: ClassVar[bool] = True  # |sdf| is the true distance everywhere

    def sdf(self, p: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def field_gradient(self, p: np.ndarray) -> np.ndarray:
        """(n, 3) gradient of the field ``-sdf`` (central differences with a 1e-6 nm step)."""
        p = np.asarray(p, dtype=np.float64)
        g = np.empty_like(p)
        for a in range(3):
            d = np.zeros(3)
            d[a] = 1e-6
            g[:, a] = -(self.sdf(p + d) - self.sdf(p - d)) / 2e-6
        return g

    def grid(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Field ``-sdf`` on an n³ grid spanning [-1, 1]³: (values, spacing, origin)."""
        axis = np.linspace(-1.0, 1.0, n)
        values = np.empty((n, n, n))
        for i, x in enumerate(axis):  # one x slab at a time keeps memory at O(n²)
            pts = np.stack(np.meshgrid([x], axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
            values[i] = -self.sdf(pts).reshape(n, n)
        h = 2.0 / (n - 1)
        return values, np.full(3, h), np.full(3, -1.0)

    def sample(self, density: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Uniform random surface points (``density`` per nm²) and their outward unit normals."""
        return self._sample(density, rng)

    def _sample(self, density, rng):  # pragma: no cover - abstract
        raise NotImplementedError


def _count(area: float, density: float, rng: np.random.Generator) -> int:
    return int(rng.poisson(area * density))


@dataclass
class Sphere(Shape):
    radius: float = 0.62
    centre: np.ndarray = field(default_factory=lambda: CENTRE.copy())

    def sdf(self, p):
        return np.linalg.norm(p - self.centre, axis=1) - self.radius

    def _sample(self, density, rng):
        n = rng.normal(size=(_count(4 * np.pi * self.radius**2, density, rng), 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return self.centre + self.radius * n, n


@dataclass
class Box(Shape):
    half: np.ndarray = field(default_factory=lambda: np.array([0.55, 0.45, 0.5]))
    rot: np.ndarray = field(default_factory=lambda: np.eye(3))
    centre: np.ndarray = field(default_factory=lambda: CENTRE.copy())

    def sdf(self, p):
        d = np.abs((p - self.centre) @ self.rot) - self.half
        return np.linalg.norm(np.maximum(d, 0), axis=1) + np.minimum(d.max(axis=1), 0)

    def _sample(self, density, rng):
        pts, nrm = [], []
        for a in range(3):
            u, v = (a + 1) % 3, (a + 2) % 3
            for s in (-1.0, 1.0):
                m = _count(4 * self.half[u] * self.half[v], density, rng)
                q = np.zeros((m, 3))
                q[:, a] = s * self.half[a]
                q[:, u] = rng.uniform(-self.half[u], self.half[u], m)
                q[:, v] = rng.uniform(-self.half[v], self.half[v], m)
                n = np.zeros((m, 3))
                n[:, a] = s
                pts.append(q)
                nrm.append(n)
        return np.concatenate(pts) @ self.rot.T + self.centre, np.concatenate(nrm) @ self.rot.T


@dataclass
class Cylinder(Shape):
    """Capped cylinder along z."""

    radius: float = 0.45
    half_height: float = 0.6
    centre: np.ndarray = field(default_factory=lambda: CENTRE.copy())

    def sdf(self, p):
        q = p - self.centre
        d = np.stack([np.hypot(q[:, 0], q[:, 1]) - self.radius, np.abs(q[:, 2]) - self.half_height], 1)
        return np.linalg.norm(np.maximum(d, 0), axis=1) + np.minimum(d.max(axis=1), 0)

    def _sample(self, density, rng):
        r, hh = self.radius, self.half_height
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
        return np.concatenate(pts) + self.centre, np.concatenate(nrm)


@dataclass
class BoxMinusSphere(Shape):
    """Box with a spherical bite out of one corner: concave edges where the sphere meets the faces."""

    exact_sdf: ClassVar[bool] = False  # max() of two SDFs underestimates near the concave rim

    box: Box = field(default_factory=lambda: Box("box", half=np.array([0.55, 0.5, 0.45])))
    sphere: Sphere = field(default_factory=lambda: Sphere("sphere", 0.5, CENTRE + np.array([0.55, 0.5, 0.45])))

    def sdf(self, p):
        return np.maximum(self.box.sdf(p), -self.sphere.sdf(p))

    def _sample(self, density, rng):
        bp, bn = self.box.sample(density, rng)
        keep = self.sphere.sdf(bp) > 0
        sp, sn = self.sphere.sample(density, rng)
        inside = self.box.sdf(sp) < 0
        return np.concatenate([bp[keep], sp[inside]]), np.concatenate([bn[keep], -sn[inside]])


def benchmark_shapes() -> list[Shape]:
    """The six benchmark shapes of issue 4."""
    return [
        Sphere("sphere"),
        Box("box"),
        Box("rotated_box", rot=rotation([1.0, 2.0, 3.0], 27.0)),
        Cylinder("cylinder"),
        BoxMinusSphere("box_minus_sphere"),
        Box("thin_plate", half=np.array([0.7, 0.6, 0.06]), rot=rotation([1.0, 0.3, 0.0], 9.0)),
    ]
