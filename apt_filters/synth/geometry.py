"""Specimen outlines: a conical tip with a spherical apex, or a box.

Both have their top at z = 0 and extend down to z = -length, as reconstructions are usually
written (z is the analysis direction; deeper material has more negative z), centred on the z
axis. Both are convex, which the flat-interface sections rely on.
"""

from __future__ import annotations

import math

import numpy as np

from apt_filters.core.errors import AptFiltersError


class Tip:
    """Conical tip: a cone of ``half_angle_deg`` around -z, capped by a tangent sphere of ``apex_radius``.

    The tip is the Minkowski sum of a sharp cone (apex at the sphere centre, z = -apex_radius)
    and a ball of ``apex_radius``, cut flat at z = -``length``; so its SDF is the sharp cone's
    exact distance minus the apex radius (exact inside and on the shank).
    """

    kind = "tip"

    def __init__(self, apex_radius: float = 14.0, half_angle_deg: float = 8.0, length: float = 80.0):
        self.apex_radius = float(apex_radius)
        self.half_angle_deg = float(half_angle_deg)
        self.length = float(length)
        if not (self.apex_radius > 0 and 0 <= self.half_angle_deg < 60):
            raise AptFiltersError("tip: apex radius must be > 0 nm and half angle in [0, 60) degrees")
        if not self.length > self._cap_height():
            raise AptFiltersError(f"tip: length must exceed the apex cap height {self._cap_height():.3g} nm")

    @property
    def _alpha(self) -> float:
        return math.radians(self.half_angle_deg)

    def _cap_height(self) -> float:
        return self.apex_radius * (1 - math.sin(self._alpha))

    def radius_at(self, z: np.ndarray) -> np.ndarray:
        """Radius (nm) of the tip's cross-section at height z (0 above the apex or below the base)."""
        z = np.asarray(z, dtype=np.float64)
        r0, a = self.apex_radius, self._alpha
        zc = -r0  # sphere centre
        z_tangent = zc + r0 * math.sin(a)
        cap = np.sqrt(np.clip(r0 * r0 - (z - zc) ** 2, 0.0, None))
        shank = r0 * math.cos(a) + (z_tangent - z) * math.tan(a)
        r = np.where(z > z_tangent, cap, shank)
        return np.where((z > 0) | (z < -self.length), 0.0, r)

    def cross_section_area(self, z: np.ndarray) -> np.ndarray:
        """Area (nm²) of the section at height z."""
        return math.pi * self.radius_at(z) ** 2

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64)
        rho = np.hypot(p[:, 0], p[:, 1])
        h = -self.apex_radius - p[:, 2]  # depth below the sharp cone's apex
        ca, sa = math.cos(self._alpha), math.sin(self._alpha)
        behind_apex = rho * sa + h * ca < 0
        cone = np.where(behind_apex, np.hypot(rho, h), rho * ca - h * sa)
        return np.maximum(cone - self.apex_radius, -(p[:, 2] + self.length))

    def volume(self) -> float:
        r0, a = self.apex_radius, self._alpha
        hc = self._cap_height()
        cap = math.pi * hc * hc * (3 * r0 - hc) / 3
        height = self.length - hc
        r1 = r0 * math.cos(a)
        r2 = r1 + height * math.tan(a)
        return cap + math.pi * height * (r1 * r1 + r1 * r2 + r2 * r2) / 3

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 3) float64 points uniform in the tip, in random order.

        Shank (a frustum): dV is proportional to r^2 dr, so r = cbrt(r1^3 + u (r2^3 - r1^3)) exactly,
        then a point uniform in that disc. Apex cap: rejection from its bounding cylinder. Each
        point is in the cap with probability V_cap / V.
        """
        r0, a = self.apex_radius, self._alpha
        hc = self._cap_height()
        z_tangent = -hc
        r1 = r0 * math.cos(a)
        in_cap = rng.random(n) < math.pi * hc * hc * (3 * r0 - hc) / 3 / self.volume()
        out = np.empty((n, 3))
        m = int((~in_cap).sum())
        u = rng.random(m)
        if a > 0:
            r2 = r1 + (self.length - hc) * math.tan(a)
            radius = np.cbrt(r1**3 + u * (r2**3 - r1**3))
            z = z_tangent - (radius - r1) / math.tan(a)
        else:
            radius, z = np.full(m, r1), z_tangent - u * (self.length - hc)
        out[~in_cap] = _in_discs(radius, z, rng)
        cap, have, k = np.empty((int(in_cap.sum()), 3)), 0, int(in_cap.sum())
        while have < k:
            p = _in_discs(np.full(2 * (k - have) + 16, r1), z_tangent + hc * rng.random(2 * (k - have) + 16), rng)
            p = p[p[:, 0] ** 2 + p[:, 1] ** 2 + (p[:, 2] + r0) ** 2 < r0 * r0][: k - have]
            cap[have:have + len(p)] = p
            have += len(p)
        out[in_cap] = cap
        return out

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        r = float(self.radius_at(np.array([-self.length]))[0])
        return np.array([-r, -r, -self.length]), np.array([r, r, 0.0])

    @property
    def min_length(self) -> float:
        """Shortest valid length (nm): just the apex cap."""
        return self._cap_height() * (1 + 1e-9)

    def with_length(self, length: float) -> "Tip":
        return Tip(self.apex_radius, self.half_angle_deg, length)

    def params(self) -> dict:
        return {"kind": self.kind, "apex_radius": self.apex_radius, "half_angle_deg": self.half_angle_deg,
                "length": self.length, "top_z": 0.0, "base_radius": float(self.bounds()[1][0])}


class Box:
    """Box of ``size`` (x, y, z) nm: x and y centred on 0, z from -size[2] to 0."""

    kind = "box"

    def __init__(self, size=(40.0, 40.0, 80.0)):
        self.size = np.asarray(size, dtype=np.float64).reshape(3)
        if not (np.isfinite(self.size).all() and (self.size > 0).all()):
            raise AptFiltersError("box: every edge must be a positive number of nm")

    @property
    def length(self) -> float:
        return float(self.size[2])

    def sdf(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=np.float64).copy()
        p[:, 2] += self.size[2] / 2
        q = np.abs(p) - self.size / 2
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    def volume(self) -> float:
        return float(np.prod(self.size))

    def cross_section_area(self, z: np.ndarray) -> np.ndarray:
        """Area (nm²) of the section at height z."""
        z = np.asarray(z, dtype=np.float64)
        return np.where((z <= 0) & (z >= -self.size[2]), self.size[0] * self.size[1], 0.0)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """(n, 3) float64 points uniform in the box."""
        lo, hi = self.bounds()
        return lo + (hi - lo) * rng.random((n, 3))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        h = self.size / 2
        return np.array([-h[0], -h[1], -self.size[2]]), np.array([h[0], h[1], 0.0])

    min_length = 1e-6

    def with_length(self, length: float) -> "Box":
        return Box((self.size[0], self.size[1], length))

    def params(self) -> dict:
        return {"kind": self.kind, "size": self.size.tolist(), "top_z": 0.0}


def _in_discs(radius: np.ndarray, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points uniform in the discs of the given radii centred on the z axis at heights z."""
    rho = radius * np.sqrt(rng.random(len(radius)))
    phi = 2 * math.pi * rng.random(len(radius))
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
