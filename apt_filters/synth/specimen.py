"""What a synthetic specimen is made of: outline, matrix, features with interfaces, segregation.

Composition field
-----------------
The local composition starts as the matrix composition and is blended feature by feature, in
order: with d the feature's signed distance and w its interface width,

    c <- c + 0.5 * (1 - tanh(d / w)) * (c_feature - c)

and then, for each segregating species s of that feature (a Gaussian shell of peak p and width
sigma, centred at d = offset),

    g = p * exp(-(d - offset)^2 / (2 sigma^2));   c <- (1 - g) * c + g * e_s

so the segregant dilutes all other species in proportion. Later features are painted over
earlier ones, so a precipitate inside a layer (a half-space) gets the layer as its outside.
Features must not overlap: :func:`check_layout` demands that interfaces are far enough apart
that each one's composition change has decayed below 1e-4 at the other.

Interfacial excess
------------------
The Gibbsian excess of species k at a feature's interface is defined relative to the Gibbs
dividing surface at d = 0 with the two plateau compositions (c_in for d < 0, c_out for d > 0):

    Gamma_k = rho / A(0) * integral (c_k(d) - c_k^step(d)) A(d) dd      [atoms / nm^2]

where A(d) is the area of the level set {sdf = d} (exact for every built-in shape, as the SDFs
are exact distances) and rho the atomic density. Detected ions per nm^2 are Gamma_k times the
detection efficiency. The integral includes the (small) contribution of the tanh profile on a
curved interface, where A(d) grows outward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import simpson

from apt_filters.core.errors import AptFiltersError
from apt_filters.synth.geometry import Box, Tip
from apt_filters.synth.shapes import Shape
from apt_filters.synth.spectrum import SpectrumModel

CULL_TOLERANCE = 1e-12
"""Composition change below which a feature is not evaluated at all (bounding-box culling)."""

LAYOUT_TOLERANCE = 1e-4
"""Composition change one feature may still cause at another's interface or at the tip surface."""


@dataclass(frozen=True)
class Segregation:
    """A species enriched in a Gaussian shell at an interface.

    Attributes
    ----------
    species : str
        Element symbol.
    peak : float
        Fraction of the segregant added at the centre of the shell, in (0, 1].
    sigma : float
        Gaussian width of the shell in nm.
    offset : float
        Position of the shell centre in signed distance (nm; positive: outside the feature).
    modulation : callable, optional
        ``modulation(points (N, 3), shape) -> (N,)`` factors >= 0 on the peak at each atom's true
        position (:mod:`.modulation`): segregation that varies along the interface.
    """

    species: str
    peak: float
    sigma: float
    offset: float = 0.0
    modulation: object = None

    def __post_init__(self) -> None:
        if not (0 < self.peak <= 1 and self.sigma > 0 and math.isfinite(self.offset)):
            raise AptFiltersError(f"segregation of {self.species}: peak must be in (0, 1] and sigma > 0 nm")


@dataclass(frozen=True)
class Feature:
    """A region of its own composition: a precipitate or (with a half-space) a layer.

    Attributes
    ----------
    shape : Shape
        Signed-distance shape (:mod:`.shapes`).
    composition : dict element -> fraction
        Composition deep inside (fractions summing to 1).
    width : float
        tanh interface width w in nm (10-90% width is 2.2 w).
    segregation : tuple of Segregation
        Shells of enriched species at this interface.
    name : str
        Label in truth.json and summaries.
    """

    shape: Shape
    composition: dict[str, float]
    width: float = 0.2
    segregation: tuple[Segregation, ...] = ()
    name: str = ""

    def __post_init__(self) -> None:
        if not self.width > 0:
            raise AptFiltersError(f"feature {self.name}: interface width must be > 0 nm")

    def reach(self, tolerance: float) -> float:
        """Distance (nm) from the interface beyond which this feature changes compositions by < tolerance."""
        r = 0.5 * self.width * math.log(1 / tolerance)
        for s in self.segregation:
            r = max(r, abs(s.offset) + s.sigma * math.sqrt(2 * math.log(s.peak / tolerance)))
        return r


@dataclass(frozen=True)
class SpecimenSpec:
    """Every parameter of a synthetic specimen (see the module docstring for the model).

    Attributes
    ----------
    geometry : Tip or Box
        Outline (top at z = 0, extending to z = -length).
    matrix : dict element -> fraction
        Composition where no feature is.
    features : tuple of Feature
        Painted in order over the matrix.
    density : float
        Atomic density in atoms/nm³.
    efficiency : float
        Detection efficiency (see :data:`.instruments.DETECTION_EFFICIENCY`).
    blur : (lateral, depth) float
        Gaussian reconstruction blur sigmas in nm (x and y share the lateral one; depth is z).
    spectrum : SpectrumModel
        Charge states, peak widths, background noise.
    mesh_spacing : float
        Edge length (nm) of the true surface meshes.
    artefacts : tuple
        Density artefacts (:mod:`.artefacts`): each ``keep(points) -> (N,)`` probability that a detected
        atom at its true position is kept.
    """

    geometry: Tip | Box
    matrix: dict[str, float]
    features: tuple[Feature, ...] = ()
    density: float = 85.0
    efficiency: float = 0.5
    blur: tuple[float, float] = (0.3, 0.1)
    spectrum: SpectrumModel = field(default_factory=SpectrumModel)
    name: str = "custom"
    mesh_spacing: float = 0.1
    artefacts: tuple = ()

    def __post_init__(self) -> None:
        if not (self.density > 0 and 0 < self.efficiency <= 1):
            raise AptFiltersError("density must be > 0 atoms/nm³ and efficiency in (0, 1]")
        if len(self.blur) != 2 or min(self.blur) < 0:
            raise AptFiltersError("blur must be two sigmas >= 0 nm (lateral, depth)")

    @property
    def species(self) -> list[str]:
        """Element symbols in a fixed order: the matrix's, then new ones from features and segregation."""
        names = list(self.matrix)
        for f in self.features:
            names += list(f.composition) + [s.species for s in f.segregation]
        return list(dict.fromkeys(names))

    def vector(self, composition: dict[str, float]) -> np.ndarray:
        """(S,) fractions in :attr:`species` order."""
        return np.array([composition.get(sp, 0.0) for sp in self.species], dtype=np.float64)

    def expected_ions(self) -> float:
        """Expected number of ions, detected atoms plus noise (before any density artefact)."""
        return self.density * self.efficiency * self.geometry.volume() / (1 - self.spectrum.noise_fraction)


def blend(c: np.ndarray, d: np.ndarray, feature: Feature, target: np.ndarray, species: list[str],
          points: np.ndarray | None = None) -> None:
    """Apply ``feature`` in place to compositions c (N, S) at signed distances d (N,).

    ``points`` (N, 3): where a modulated segregation's factor is evaluated (without them, at 1).
    """
    c += (0.5 * (1 - np.tanh(d / feature.width)))[:, None] * (target - c)
    for s in feature.segregation:
        g = s.peak * np.exp(-0.5 * ((d - s.offset) / s.sigma) ** 2)
        if s.modulation is not None and points is not None:
            g = np.minimum(g * s.modulation(points, feature.shape), 1.0)
        c *= (1 - g)[:, None]
        c[:, species.index(s.species)] += g


def composition_at(spec: SpecimenSpec, points: np.ndarray, upto: int | None = None) -> np.ndarray:
    """(N, S) local composition at points (N, 3) nm, from the first ``upto`` features (all if None).

    Features are evaluated only for points in their bounding box grown by their reach, and blended
    only within their reach of the interface (changes below ``CULL_TOLERANCE`` are skipped), so
    the cost is about N * S plus the ions near each feature. Peak memory ~ N * (S + 4) * 8 bytes.
    """
    species = spec.species
    c = np.tile(spec.vector(spec.matrix), (len(points), 1))
    for feature in spec.features[:upto]:
        reach = feature.reach(CULL_TOLERANCE)
        box = feature.shape.bounds()
        if box is None:
            idx = np.arange(len(points))
        else:
            lo, hi = box[0] - reach, box[1] + reach
            idx = np.flatnonzero((points[:, 2] >= lo[2]) & (points[:, 2] <= hi[2]))  # most features are thin in z
            idx = idx[np.all((points[idx, :2] >= lo[:2]) & (points[idx, :2] <= hi[:2]), axis=1)]
        d = feature.shape.sdf(points[idx])
        target = spec.vector(feature.composition)
        c[idx[d <= -reach]] = target  # deep inside, where blending changes nothing above 1e-12
        near = np.abs(d) < reach
        sub = c[idx[near]]
        blend(sub, d[near], feature, target, species, points[idx[near]])
        c[idx[near]] = sub
    return c


def _check_composition(comp: dict[str, float], what: str) -> None:
    values = np.array(list(comp.values()), dtype=np.float64)
    if not len(values) or (values < 0).any() or not np.isfinite(values).all() or abs(values.sum() - 1) > 1e-9:
        raise AptFiltersError(f"{what}: composition must be non-negative fractions summing to 1, got {comp}")


def check_layout(spec: SpecimenSpec) -> list[np.ndarray]:
    """Check compositions and that features neither overlap nor touch the specimen surface.

    Returns the coarse (0.5 nm) surface points of each feature used for the checks.

    Raises
    ------
    AptFiltersError
        Naming the feature(s) at fault.
    """
    _check_composition(spec.matrix, "matrix")
    for i, f in enumerate(spec.features):
        _check_composition(f.composition, f"feature {i} ({f.name})")
    points = []
    for i, f in enumerate(spec.features):
        try:
            points.append(f.shape.mesh(0.5, spec.geometry).vertices)
        except AptFiltersError as exc:
            raise AptFiltersError(f"feature {i} ({f.name}): {exc}") from exc
    for i, f in enumerate(spec.features):
        reach = f.reach(LAYOUT_TOLERANCE)
        if f.shape.bounds() is not None and not f.shape.cut and spec.geometry.sdf(points[i]).max() > -reach:
            raise AptFiltersError(f"feature {i} ({f.name}) is not inside the specimen with {reach:.2f} nm to spare")
        for j in range(i + 1, len(spec.features)):
            g = spec.features[j]
            gap = reach + g.reach(LAYOUT_TOLERANCE)
            if np.abs(f.shape.sdf(points[j])).min() < gap or g.shape.sdf(points[i]).min() < gap:
                raise AptFiltersError(
                    f"features {i} ({f.name}) and {j} ({g.name}) overlap or are closer than {gap:.2f} nm "
                    "(or the later one would cover the earlier)")
    return points


def outside_composition(spec: SpecimenSpec, index: int, surface_points: np.ndarray) -> np.ndarray:
    """(S,) composition around feature ``index``: what the earlier features left at its surface."""
    c = composition_at(spec, surface_points, upto=index)
    return c.mean(axis=0)


def interface_excess(spec: SpecimenSpec, index: int, c_out: np.ndarray) -> np.ndarray:
    """(S,) Gibbsian excess in atoms/nm² of each species at feature ``index`` (module docstring).

    Integrated with Simpson's rule on a grid of w/50 or finer on each side of d = 0; the
    half-space's section areas (numerical) are interpolated from 129 knots.
    """
    f = spec.features[index]
    shape = f.shape
    reach = f.reach(CULL_TOLERANCE)
    d_in = -min(reach, shape.depth())
    finest = min([f.width] + [s.sigma for s in f.segregation]) / 50
    sides = [np.linspace(d_in, 0.0, max(2001, math.ceil(-d_in / finest) | 1)),
             np.linspace(0.0, reach, max(2001, math.ceil(reach / finest) | 1))]
    if shape.bounds() is None:
        knots = np.linspace(d_in, reach, 129)
        knot_area = shape.level_area(knots, spec.geometry)
        area_of = lambda d: np.interp(d, knots, knot_area)  # noqa: E731
    else:
        area_of = lambda d: shape.level_area(d, spec.geometry)  # noqa: E731
    c_in = spec.vector(f.composition)
    total = np.zeros(len(c_in))
    for d, step in zip(sides, (c_in, c_out)):
        c = np.tile(c_out, (len(d), 1))
        blend(c, d, f, c_in, spec.species)
        total += simpson((c - step) * area_of(d)[:, None], x=d, axis=0)
    return spec.density * total / float(area_of(np.zeros(1))[0])
