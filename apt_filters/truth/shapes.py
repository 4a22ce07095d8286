"""Analytic benchmark shapes for contouring, with exact answers: signed distance, gradient, surface samples.

The shapes are :mod:`apt_filters.synth.shapes` solids (the one shape library), placed in the box
[-1, 1]³ (nm) off the grid planes and off-centre so that no face coincides with a sample plane and
x, y, z are not interchangeable, plus two composites, :class:`Difference` and :class:`Union`. The field handed to
contouring is ``-sdf`` (inside above iso = 0).
"""

from __future__ import annotations

import numpy as np

from apt_filters.synth.shapes import Cuboid, Cylinder, Shape, Sphere

CENTRE = np.array([0.021, -0.034, 0.013])


def rotation(axis, degrees: float) -> np.ndarray:
    """(3, 3) rotation matrix about ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    a = np.radians(degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx


class Difference(Shape):
    """``a`` with ``b`` cut out: concave edges where ``b``'s surface meets ``a``'s.

    ``max(sdf_a, -sdf_b)`` underestimates the distance near the concave rim, so ``exact_sdf`` is False.
    """

    kind = "difference"
    exact_sdf = False

    def __init__(self, a: Shape, b: Shape):
        self.a, self.b = a, b

    def sdf(self, points):
        return np.maximum(self.a.sdf(points), -self.b.sdf(points))

    def sample(self, density, rng):
        ap, an = self.a.sample(density, rng)
        keep = self.b.sdf(ap) > 0
        bp, bn = self.b.sample(density, rng)
        inside = self.a.sdf(bp) < 0
        return np.concatenate([ap[keep], bp[inside]]), np.concatenate([an[keep], -bn[inside]])


class Union(Shape):
    """The union of ``parts``: each part's surface outside every other part (concave edges where two meet).

    ``min`` of the parts' SDFs is exact outside the union but not inside where parts overlap, so ``exact_sdf``
    is False.
    """

    kind = "union"
    exact_sdf = False

    def __init__(self, *parts: Shape):
        self.parts = parts

    def sdf(self, points):
        return np.min([p.sdf(points) for p in self.parts], axis=0)

    def sample(self, density, rng):
        points, normals = [], []
        for i, part in enumerate(self.parts):
            p, n = part.sample(density, rng)
            keep = np.ones(len(p), bool)
            for other in self.parts[:i] + self.parts[i + 1:]:
                keep &= other.sdf(p) > 0
            points.append(p[keep])
            normals.append(n[keep])
        return np.concatenate(points), np.concatenate(normals)


def field_gradient(shape: Shape):
    """The gradient of the field ``-sdf`` as a function of points (n, 3) -> (n, 3) (central differences,
    1e-6 nm step), as dual contouring takes it (``gradient=``)."""

    def gradient(p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        g = np.empty_like(p)
        for a in range(3):
            d = np.zeros(3)
            d[a] = 1e-6
            g[:, a] = -(shape.sdf(p + d) - shape.sdf(p - d)) / 2e-6
        return g

    return gradient


def grid(shape: Shape, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The field ``-sdf`` on an n³ grid spanning [-1, 1]³: (values, spacing, origin)."""
    axis = np.linspace(-1.0, 1.0, n)
    values = np.empty((n, n, n))
    for i, x in enumerate(axis):  # one x slab at a time keeps memory at O(n²)
        pts = np.stack(np.meshgrid([x], axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
        values[i] = -shape.sdf(pts).reshape(n, n)
    h = 2.0 / (n - 1)
    return values, np.full(3, h), np.full(3, -1.0)


def benchmark_shapes() -> dict[str, Shape]:
    """The six benchmark shapes, by name: sphere, box, rotated box, cylinder, box minus sphere, thin plate."""
    return {
        "sphere": Sphere(CENTRE, 0.62),
        "box": Cuboid(CENTRE, [1.1, 0.9, 1.0]),
        "rotated_box": Cuboid(CENTRE, [1.1, 0.9, 1.0], rotation(np.array([1.0, 2.0, 3.0]), 27.0)),
        "cylinder": Cylinder(CENTRE, 0.45, 1.2),
        "box_minus_sphere": Difference(Cuboid(CENTRE, [1.1, 1.0, 0.9]), Sphere(CENTRE + np.array([0.55, 0.5, 0.45]), 0.5)),
        "thin_plate": Cuboid(CENTRE, [1.4, 1.2, 0.12], rotation(np.array([1.0, 0.3, 0.0]), 9.0)),
    }
