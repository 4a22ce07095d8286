"""A zoo of randomised specimens with exact truth, split into development and held-out draws.

The presets are fixed specimens of one family (gamma-prime-like cubes and spheres); a method tuned on
them is not known to work elsewhere. :func:`zoo_specimen` draws a small specimen (a box of at most
~1.5M ions) of one *family* from a seed:

==============  ====================================================================================
family          objects (1-4 per specimen, randomly rotated and placed)
==============  ====================================================================================
sphere          radius 1.5-6 nm
cuboid          edges 4-10 nm (aspect up to 1.5)
plate           discs 2-3 nm thick, radius 4-7 nm
rod             capsules of radius 1.5-2 nm, 5-12 nm long
ellipsoid       semi-axes 1.8-5 nm (exact distance, :class:`Ellipsoid`)
lath            cuboids 2.5-4 x 5-8 x 9-14 nm
rounded         cuboids of edges 5-9 nm with edges rounded by 0.5-2 nm (:class:`RoundedCuboid`)
superellipsoid  semi-axes 2-5 nm, exponents 1.5-5 each (:class:`~.implicit.Superellipsoid`)
thin            discs 1.5-2 nm thick (radius 4-7 nm) or rods of radius 1-1.5 nm (6-12 nm long)
edge            1-2 spheres of radius 3-6 nm cut by a side face of the box (:class:`~.implicit.CutSphere`;
                truth: their part inside)
artefact        spheres, cuboids or rounded cuboids with density artefacts (:mod:`.artefacts`): 1-3
                detector-efficiency patches (dips of 20-50 %, sigma 3-8 nm) and a local magnification
                (density inside the objects 0.6-1.6 times the matrix's)
open            one flat interface tilted 0-40 degrees from the analysis direction, across the box
curved          one curved interface across the box: a sphere cap of radius 30-80 nm tilted 0-25
                degrees, bulging up or down, tanh ``w`` 0.15-2.3 nm (10-90 % up to 5 nm, like the real
                Si one) (:class:`~.implicit.SphereInterface`)
spinodal        a bicontinuous structure filling a 20 x 20 x 24 nm box: the zero set of 16 plane waves of
                wavelength 7-12 nm in random directions, level -0.4..0.4 (volume fraction ~0.35-0.65)
gyroid          the same box filled by a gyroid of period 8-14 nm, level -0.3..0.3
==============  ====================================================================================

Every draw randomises the chemistry (one of three alloy systems; the iso species' outside fraction
1-15 at.% and its contrast 4-80 at.% points), the interface width (tanh ``w`` 0.15-1.1 nm: 10-90 %
widths 0.33-2.4 nm, at most half the object's depth, at most a tenth of a bicontinuous structure's
wavelength; ``curved`` draws its own), a segregant shell (half the draws: peak 3-15 %,
sigma 0.2-0.4 nm, offset -0.2..0.2 nm), the detection efficiency (0.37-0.8) and the reconstruction
blur (lateral 0.2-0.4 nm, depth 0.05-0.15 nm).

Splits (:data:`SPLITS`): ``dev`` draws the families a method may be developed on, seeds 0-999;
``heldout`` draws other families (superellipsoid, spinodal, curved, edge, artefact, thin, ellipsoid,
lath, rounded) *and* other seeds (from 10000), so a figure reported on ``heldout`` was not tuned on it
either way. :func:`draws` lists (family, seed) pairs.

Truth of the open and bicontinuous families is that of their part inside the box (area, and the
inside phase's volume); ``edge`` objects are ``cut`` shapes whose volume and area are their part
inside the specimen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.synth.geometry import Box
from apt_filters.synth.shapes import Capsule, Cuboid, Cylinder, HalfSpace, Sphere, _Solid
from apt_filters.synth.artefacts import EfficiencyPatches, LocalMagnification
from apt_filters.synth.implicit import CutSphere, LevelSetInterface, SphereInterface, Superellipsoid
from apt_filters.synth.specimen import Feature, Segregation, SpecimenSpec, check_layout

SYSTEMS = (
    # (host, iso species, third element, segregant)
    ("Ni", "Al", "Cr", "B"),
    ("Al", "Mg", "Cu", "Si"),
    ("Co", "Ti", "Mo", "Si"),
)
"""Alloy systems: the host, the species whose iso-surface is drawn, a third element that partitions the
other way, and the species that segregates to the interfaces (in half the draws)."""


@dataclass(frozen=True)
class Split:
    """Families and seed range of one split."""

    families: tuple[str, ...]
    first_seed: int


SPLITS = {
    "dev": Split(("sphere", "cuboid", "plate", "rod", "open", "gyroid"), 0),
    "heldout": Split(("superellipsoid", "spinodal", "curved", "edge", "artefact", "thin", "ellipsoid", "lath",
                      "rounded", "sphere", "plate", "rod", "cuboid", "open"), 10000),
}
"""``heldout`` repeats the dev families with seeds the development never saw, and adds nine families it
never saw at all (the new ones first, so a short run covers them)."""

FAMILIES = ("sphere", "cuboid", "plate", "rod", "ellipsoid", "lath", "rounded", "superellipsoid", "thin", "edge",
            "artefact", "open", "curved", "spinodal", "gyroid")



def draws(split: str, count: int) -> list[tuple[str, int]]:
    """The first ``count`` (family, seed) pairs of ``split``, families in turn."""
    if split not in SPLITS:
        raise AptFiltersError(f"unknown zoo split {split!r}; choose one of {', '.join(SPLITS)}")
    s = SPLITS[split]
    return [(s.families[k % len(s.families)], s.first_seed + k) for k in range(count)]


class Ellipsoid(_Solid):
    """Ellipsoid of semi-axes ``axes`` (3,) nm along its local axes, with its exact Euclidean distance.

    The closest surface point of ``p`` is ``x_i = a_i^2 p_i / (t + a_i^2)`` where ``t`` is the root of
    ``sum (a_i p_i / (t + a_i^2))^2 = 1`` in ``(-a_min^2, a_max |p|)`` (monotone there; bisection). The
    component along the shortest axis is then taken from the surface equation itself, which also gives
    the right point where the root sits at the pole ``-a_min^2`` (points on the medial disc).
    Area and level-set areas: marching cubes of the exact SDF on a 0.1 nm grid.
    """

    kind = "ellipsoid"
    GRID = 0.1

    def __init__(self, center, axes, rotation=None):
        super().__init__(center, rotation)
        self.axes = np.asarray(axes, dtype=np.float64).reshape(3)
        if not (np.isfinite(self.axes).all() and (self.axes > 0).all()):
            raise AptFiltersError("ellipsoid semi-axes must be positive numbers of nm")
        self._values: np.ndarray | None = None
        self._areas: np.ndarray | None = None

    def _half_extent(self):
        return self.axes.copy()

    def _local_sdf(self, p):
        a2 = self.axes ** 2
        k = int(np.argmin(self.axes))
        lo = np.full(len(p), -a2[k])
        hi = np.maximum(self.axes.max() * np.linalg.norm(p, axis=1), 0.0)
        ap = self.axes * p
        for _ in range(50):  # the bracket shrinks to 2^-50 of its width
            t = 0.5 * (lo + hi)
            f = np.sum((ap / (t[:, None] + a2)) ** 2, axis=1) - 1
            lo, hi = np.where(f > 0, t, lo), np.where(f > 0, hi, t)
        t = 0.5 * (lo + hi)
        x = a2 * p / (t[:, None] + a2)
        rest = [j for j in range(3) if j != k]
        x[:, k] = np.sign(p[:, k]) * self.axes[k] * np.sqrt(np.clip(1 - np.sum((x[:, rest] / self.axes[rest]) ** 2,
                                                                              axis=1), 0.0, None))
        inside = np.sum((p / self.axes) ** 2, axis=1) < 1
        return np.where(inside, -1.0, 1.0) * np.linalg.norm(p - x, axis=1)

    def volume(self, within=None):
        return 4.0 / 3.0 * math.pi * float(np.prod(self.axes))

    def _grid(self) -> tuple[np.ndarray, np.ndarray]:
        """The local SDF on a grid of ``GRID`` nm reaching 3.3 nm beyond the axes (computed once), and its origin."""
        if self._values is None:
            axes = [np.arange(-r, r + self.GRID, self.GRID) for r in self.axes + 3.3]
            pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
            self._values = self._local_sdf(pts.reshape(-1, 3)).reshape(pts.shape[:3])
            self._origin = np.array([a[0] for a in axes])
        return self._values, self._origin

    def _level_mesh(self, level: float) -> TriMesh:
        from skimage.measure import marching_cubes

        values, origin = self._grid()
        v, f, _, _ = marching_cubes(values, level=level, spacing=(self.GRID,) * 3)
        mesh = TriMesh(v + origin, f)
        return mesh if mesh.signed_volume() >= 0 else TriMesh(mesh.vertices, f[:, ::-1])

    def level_area(self, d, within=None):
        """Areas (nm²) at 17 knots from the centre to 3 nm out, interpolated."""
        d = np.atleast_1d(np.asarray(d, dtype=np.float64))
        knots = np.union1d(np.linspace(-self.depth(), 3.0, 17), [0.0])
        if self._areas is None:
            self._areas = np.array([self._level_mesh(float(k)).area() if k > -self.depth() else 0.0 for k in knots])
        return np.interp(d, knots, self._areas)

    def depth(self):
        return float(self.axes.min())

    def _local_mesh(self, spacing):
        mesh = self._level_mesh(0.0)
        return mesh.vertices, mesh.faces

    def params(self):
        return {"kind": self.kind, "axes": self.axes.tolist(), **self._placement()}


class RoundedCuboid(_Solid):
    """A box of edges ``size`` (3,) nm whose edges and corners are rounded by ``rounding`` nm: the box of
    edges ``size - 2 rounding`` grown by a ball, so its SDF is that box's minus ``rounding`` (exact), and
    its level-set areas are the inner box's (Steiner's formula outside it)."""

    kind = "rounded_cuboid"

    def __init__(self, center, size, rounding: float, rotation=None):
        super().__init__(center, rotation)
        self.size = np.asarray(size, dtype=np.float64).reshape(-1) * np.ones(3)
        self.rounding = float(rounding)
        if not (0 <= self.rounding < self.size.min() / 2):
            raise AptFiltersError("rounded cuboid: rounding must be in [0, half the shortest edge)")
        self._core = Cuboid((0, 0, 0), self.size - 2 * self.rounding)

    def _half_extent(self):
        return self.size / 2

    def _local_sdf(self, p):
        return self._core._local_sdf(p) - self.rounding

    def volume(self, within=None):
        a, b, c = self._core.size
        r = self.rounding
        return float(a * b * c + 2 * (a * b + b * c + c * a) * r + math.pi * (a + b + c) * r * r
                     + 4.0 / 3.0 * math.pi * r ** 3)

    def level_area(self, d, within=None):
        return self._core.level_area(np.asarray(d, dtype=np.float64) + self.rounding)

    def depth(self):
        return float(self.size.min() / 2)

    def _local_mesh(self, spacing):
        from skimage.measure import marching_cubes

        step = min(spacing, 0.1)
        axes = [np.arange(-h - 2 * step, h + 3 * step, step) for h in self.size / 2]
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        values = self._local_sdf(pts.reshape(-1, 3)).reshape(pts.shape[:3])
        v, f, _, _ = marching_cubes(values, level=0.0, spacing=(step,) * 3)
        v = v + np.array([a[0] for a in axes])
        mesh = TriMesh(v, f)
        return (v, f) if mesh.signed_volume() >= 0 else (v, f[:, ::-1])

    def params(self):
        return {"kind": self.kind, "size": self.size.tolist(), "rounding": self.rounding, **self._placement()}


def _object(family: str, rng: np.random.Generator, center) -> _Solid:
    """One random object of ``family`` at ``center``."""
    rot = int(rng.integers(1 << 30))
    u = rng.uniform
    if family == "sphere":
        return Sphere(center, u(1.5, 6.0))
    if family == "cuboid":
        edge = u(4.0, 10.0)
        return Cuboid(center, edge * np.array([1.0, u(1.0, 1.5), u(0.8, 1.0)]), rotation=rot)
    if family == "plate":
        return Cylinder(center, u(4.0, 7.0), u(2.0, 3.0), rotation=rot)
    if family == "rod":
        return Capsule(center, u(1.5, 2.0), u(5.0, 12.0), rotation=rot)
    if family == "ellipsoid":
        return Ellipsoid(center, np.sort(u(1.8, 5.0, 3)), rotation=rot)
    if family == "lath":
        return Cuboid(center, [u(2.5, 4.0), u(5.0, 8.0), u(9.0, 14.0)], rotation=rot)
    if family == "rounded":
        edge = u(5.0, 9.0)
        return RoundedCuboid(center, edge * np.array([1.0, u(1.0, 1.3), u(0.8, 1.0)]), u(0.5, min(2.0, 0.3 * edge)),
                             rotation=rot)
    if family == "superellipsoid":
        return Superellipsoid(center, np.sort(u(2.0, 5.0, 3)), u(1.5, 5.0, 3), rotation=rot)
    if family == "thin":
        if rng.random() < 0.5:
            return Cylinder(center, u(4.0, 7.0), u(1.5, 2.0), rotation=rot)
        return Capsule(center, u(1.0, 1.5), u(6.0, 12.0), rotation=rot)
    if family == "artefact":
        return _object(("sphere", "cuboid", "rounded")[int(rng.integers(3))], rng, center)
    raise AptFiltersError(f"unknown zoo family {family!r}; choose one of {', '.join(FAMILIES)}")


def _compositions(rng: np.random.Generator, system) -> tuple[dict, dict]:
    """Matrix and object compositions: the iso species at 1-15 at.% outside, 4-80 points more inside."""
    host, iso, third, _ = system
    c_out = rng.uniform(0.01, 0.15)
    c_in = min(c_out + rng.uniform(0.04, 0.80), 0.95)
    t_out = rng.uniform(0.05, 0.25)
    t_in = t_out * rng.uniform(0.1, 0.6)  # the third element partitions to the matrix
    matrix = {host: 1 - c_out - t_out, iso: c_out, third: t_out}
    inside = {host: max(1 - c_in - t_in, 0.0), iso: c_in, third: min(t_in, 1 - c_in)}
    return matrix, inside


def zoo_specimen(family: str, seed: int) -> SpecimenSpec:
    """A random specimen of ``family`` (module table) drawn from ``seed``; the same pair gives the same spec.

    Raises
    ------
    AptFiltersError
        For an unknown family.
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    system = SYSTEMS[int(rng.integers(len(SYSTEMS)))]
    matrix, inside = _compositions(rng, system)
    segregated = rng.random() < 0.5
    shell = ((Segregation(system[3], peak=rng.uniform(0.03, 0.15), sigma=rng.uniform(0.2, 0.4),
                          offset=rng.uniform(-0.2, 0.2)),) if segregated else ())
    width = rng.uniform(0.15, 1.1)
    efficiency = rng.uniform(0.37, 0.8)
    blur = (rng.uniform(0.2, 0.4), rng.uniform(0.05, 0.15))
    size = np.array([24.0, 24.0, 40.0])
    if family in ("spinodal", "gyroid"):
        return _bicontinuous(family, rng, inside, matrix, width, shell, efficiency, blur)
    if family == "curved":
        return _curved(rng, size, inside, matrix, shell, efficiency, blur)
    if family == "edge":
        return _edge(rng, size, inside, matrix, width, shell, efficiency, blur, seed)
    if family == "open":
        tilt = math.radians(rng.uniform(0.0, 40.0))
        phi = rng.uniform(0, 2 * math.pi)
        normal = (math.sin(tilt) * math.cos(phi), math.sin(tilt) * math.sin(phi), math.cos(tilt))
        features = (Feature(HalfSpace((0, 0, -size[2] / 2), normal), inside, width, shell, "open interface"),)
        spec = SpecimenSpec(Box(size), matrix, features, efficiency=efficiency, blur=blur, name=f"zoo-{family}")
        check_layout(spec)
        return spec
    # objects at least their reach apart and from the box sides, up to 4 of them, placed in turn
    objects: list[tuple[_Solid, np.ndarray]] = []
    for _ in range(200):
        if len(objects) == 4:
            break
        probe = _object(family, rng, (0.0, 0.0, 0.0))
        w = min(width, 0.5 * probe.depth())
        half = probe.bounds()[1] + Feature(probe, inside, w, shell).reach(1e-4) + 0.2  # rotated box, grown
        if (half >= size / 2).any():
            continue
        centre = rng.uniform(half - size / 2, size / 2 - half) + np.array([0.0, 0.0, -size[2] / 2])
        if all((np.abs(centre - o.center) > half + h).any() for o, h in objects):
            probe.center = centre  # its size and rotation were drawn at the origin
            objects.append((probe, half))
    if not objects:
        raise AptFiltersError(f"zoo: could not place a {family} object for seed {seed}")
    features = tuple(Feature(o, inside, min(width, 0.5 * o.depth()), shell, f"{family} {k}")
                     for k, (o, _) in enumerate(objects))
    artefacts = ()
    if family == "artefact":
        k = int(rng.integers(1, 4))
        ratio = rng.uniform(0.6, 1.6)
        artefacts = (EfficiencyPatches(rng.uniform(-size[:2] / 2, size[:2] / 2, (k, 2)), rng.uniform(3.0, 8.0, k),
                                       rng.uniform(0.2, 0.5, k)),
                     *(LocalMagnification(f.shape, ratio, f.width) for f in features))
    spec = SpecimenSpec(Box(size), matrix, features, efficiency=efficiency, blur=blur, name=f"zoo-{family}",
                        artefacts=artefacts)
    check_layout(spec)
    return spec


def _bicontinuous(family, rng, inside, matrix, width, shell, efficiency, blur) -> SpecimenSpec:
    """A spinodal-like (plane waves) or gyroid structure filling a 20 x 20 x 24 nm box."""
    box = Box((20.0, 20.0, 24.0))
    if family == "spinodal":
        shape = LevelSetInterface(box, "waves", rng.uniform(7.0, 12.0), rng.uniform(-0.4, 0.4),
                                  int(rng.integers(1 << 30)))
    else:
        shape = LevelSetInterface(box, "gyroid", rng.uniform(8.0, 14.0), rng.uniform(-0.3, 0.3),
                                  int(rng.integers(1 << 30)))
    feature = Feature(shape, inside, min(width, 0.1 * shape.wavelength), shell, family)
    spec = SpecimenSpec(box, matrix, (feature,), efficiency=efficiency, blur=blur, name=f"zoo-{family}")
    check_layout(spec)
    return spec


def _curved(rng, size, inside, matrix, shell, efficiency, blur) -> SpecimenSpec:
    """A sphere cap across the box, inside below it, through z -24..-16 nm on the axis."""
    box = Box(size)
    width = rng.uniform(0.15, 2.3)
    half = np.hypot(*(size[:2] / 2))
    for _ in range(100):
        radius, tilt, phi = rng.uniform(30.0, 80.0), math.radians(rng.uniform(0.0, 25.0)), rng.uniform(0, 2 * math.pi)
        off = radius * math.sin(tilt) * np.array([math.cos(phi), math.sin(phi)])
        if np.linalg.norm(off) + half < 0.95 * radius:
            break
    up = bool(rng.random() < 0.5)
    z0 = rng.uniform(-24.0, -16.0)
    rise = math.sqrt(radius ** 2 - off @ off)
    centre = np.array([off[0], off[1], z0 - rise if up else z0 + rise])
    shape = SphereInterface(box, centre, radius, convex=up)
    feature = Feature(shape, inside, width, shell, "curved interface")
    spec = SpecimenSpec(box, matrix, (feature,), efficiency=efficiency, blur=blur, name="zoo-curved")
    check_layout(spec)
    return spec


def _edge(rng, size, inside, matrix, width, shell, efficiency, blur, seed) -> SpecimenSpec:
    """1-2 spheres cut by distinct side faces of the box."""
    half = size / 2
    for _ in range(100):
        faces = rng.permutation(4)[:int(rng.integers(1, 3))]
        features = []
        for k, face in enumerate(faces):
            axis, sign = int(face // 2), 1.0 - 2.0 * (face % 2)
            r = rng.uniform(3.0, 6.0)
            w = min(width, 0.5 * r)
            reach = Feature(Sphere((0, 0, 0), r), inside, w, shell).reach(1e-4) + 0.2
            centre = np.empty(3)
            other = 1 - axis
            centre[other] = rng.uniform(-half[other] + r + reach, half[other] - r - reach)
            centre[2] = rng.uniform(-size[2] + r + reach, -r - reach)
            inset = rng.uniform(-0.4, 0.5) * r  # centre to face, positive inside
            centre[axis] = sign * (half[axis] - inset)
            normal = np.zeros(3)
            normal[axis] = sign
            features.append(Feature(CutSphere(centre, r, normal, half[axis]), inside, w, shell, f"edge {k}"))
        spec = SpecimenSpec(Box(size), matrix, tuple(features), efficiency=efficiency, blur=blur, name="zoo-edge")
        try:
            check_layout(spec)
        except AptFiltersError:
            continue
        return spec
    raise AptFiltersError(f"zoo: could not place the edge spheres for seed {seed}")

