"""Segregation that varies along an interface, and the excess map it makes (exact truth for maps).

A :class:`~.specimen.Segregation` with a ``modulation`` scales its shell's peak by a factor
``m(x) >= 0`` evaluated at each atom's true position x (``g <- min(1, m(x) g)``):

- :class:`LinearModulation`: ``m = 1 + gradient . (x - origin)`` (clipped at 0): an excess that
  varies linearly across the specimen, e.g. from 0 to twice its mean over a tip's diameter;
- :class:`FacetModulation`: one factor per facet of a faceted precipitate, the facet chosen by
  the direction of the shape's normal (gradient of its SDF) at x.

The segregant's excess is linear in the shell's peak (the shell adds ``g (1 - c_s)`` of the
segregant at each depth, c_s its fraction without the shell), so along the interface

    Gamma_s(x) = Gamma_s(no shell) + m(x) (Gamma_s(shell, m = 1) - Gamma_s(no shell))

exactly for a flat interface with the factor constant along the normal; on a curved one the
factor changes along the normal by ``grad m . n d`` which integrates to zero against a shell
centred at d = 0 (to first order). :func:`true_excess_map` evaluates this at surface points.
truth.json's ``excess`` is the feature's at ``m = 1`` everywhere.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from apt_filters.core.errors import AptFiltersError


class LinearModulation:
    """Factor ``max(0, 1 + gradient . (x - origin))``.

    Parameters
    ----------
    origin : (3,) float
        Point where the factor is 1, nm.
    gradient : (3,) float
        Change of the factor per nm. For 0 to 2x across a diameter D along x: ``(2 / D, 0, 0)``
        with the origin on the axis.
    """

    kind = "linear"

    def __init__(self, origin, gradient):
        self.origin = np.asarray(origin, dtype=np.float64).reshape(3)
        self.gradient = np.asarray(gradient, dtype=np.float64).reshape(3)
        if not (np.isfinite(self.origin).all() and np.isfinite(self.gradient).all()):
            raise AptFiltersError("linear modulation: origin and gradient must be finite 3-vectors")

    def __call__(self, points: np.ndarray, shape=None) -> np.ndarray:
        """(N,) factors at points (N, 3) nm (``shape`` unused)."""
        return np.maximum(1.0 + (np.asarray(points, dtype=np.float64) - self.origin) @ self.gradient, 0.0)

    def params(self) -> dict:
        return {"kind": self.kind, "origin": self.origin.tolist(), "gradient": self.gradient.tolist()}


class FacetModulation:
    """One factor per facet: the facet whose outward direction is nearest the shape's normal at x.

    Parameters
    ----------
    directions : (k, 3) float
        Outward facet directions (world frame), e.g. a cuboid's ``±rotation[:, i]``.
    factors : (k,) float
        Factor of each facet, >= 0.
    step : float
        Central-difference step (nm) of the SDF gradient that gives the normal.
    """

    kind = "facets"

    def __init__(self, directions, factors, step: float = 1e-3):
        d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        self.directions = d / np.linalg.norm(d, axis=1, keepdims=True)
        self.factors = np.asarray(factors, dtype=np.float64).reshape(-1)
        self.step = float(step)
        if len(self.factors) != len(self.directions) or (self.factors < 0).any():
            raise AptFiltersError("facet modulation: one factor >= 0 per direction")

    def __call__(self, points: np.ndarray, shape) -> np.ndarray:
        """(N,) factors at points (N, 3) nm on or near ``shape`` (its SDF gives the normal)."""
        p = np.asarray(points, dtype=np.float64)
        normal = np.stack([shape.sdf(p + self.step * e) - shape.sdf(p - self.step * e) for e in np.eye(3)], axis=1)
        return self.factors[np.argmax(normal @ self.directions.T, axis=1)]

    def params(self) -> dict:
        return {"kind": self.kind, "directions": self.directions.tolist(), "factors": self.factors.tolist()}


def true_excess_map(spec, index: int, species: str, points: np.ndarray) -> np.ndarray:
    """(N,) true excess of ``species`` (atoms/nm²) at points (N, 3) nm on feature ``index``'s surface.

    Exact for one modulated segregation of ``species`` at that feature (module docstring); the
    feature's other segregants are taken as unmodulated. Multiply by ``spec.efficiency`` for
    detected atoms per nm².
    """
    from apt_filters.synth import specimen as model

    feature = spec.features[index]
    mine = [s for s in feature.segregation if s.species == species and s.modulation is not None]
    if len(mine) > 1:
        raise AptFiltersError(f"feature {index}: more than one modulated segregation of {species}")
    surface = model.check_layout(spec)[index]
    c_out = model.outside_composition(spec, index, surface)
    k = spec.species.index(species)
    full = model.interface_excess(spec, index, c_out)[k]
    if not mine:
        return np.full(len(points), full)
    others = tuple(s for s in feature.segregation if s is not mine[0])
    bare = dataclasses.replace(spec, features=tuple(dataclasses.replace(f, segregation=others) if i == index else f
                                                    for i, f in enumerate(spec.features)))
    base = model.interface_excess(bare, index, c_out)[k]
    return base + mine[0].modulation(points, feature.shape) * (full - base)


MAP_SPECIMENS = ("flat", "cap", "cuboid")
"""Specimens of :func:`map_specimen`."""


def map_specimen(kind: str, modulated: bool = True, peak: float = 0.06):
    """A small specimen whose B segregation varies along one interface by design (maps' truth).

    Gamma / gamma-prime compositions of the presets (Al 10 / 20 at.%), B shell of ``peak`` and
    sigma 0.25 nm (about 1.6 detected B per nm² at efficiency 0.5), mesh spacing 0.5 nm:

    - ``flat``: a 30 x 30 x 16 nm box cut at z = -8 nm by a flat interface, excess varying
      linearly along x from 0 to twice its mean across the box;
    - ``cap``: a sphere of radius 10 nm in a 26 nm box, excess varying linearly along x from 0 to
      twice its mean across the sphere; its surface more than 2 nm above its centre is an open
      curved interface (:func:`map_surface`);
    - ``cuboid``: a 14 nm cube in a 26 nm box whose facets carry 0.5, 1.5, 1, 2, 0.25 and 1 times
      the excess (+x, +y, +z, -x, -y, -z).

    ``modulated=False`` gives the same specimen with uniform segregation.
    """
    from apt_filters.synth.geometry import Box
    from apt_filters.synth.shapes import Cuboid, HalfSpace, Sphere
    from apt_filters.synth.specimen import Feature, Segregation, SpecimenSpec

    if kind == "flat":
        geometry, shape = Box((30.0, 30.0, 16.0)), HalfSpace((0, 0, -8), (0, 0, 1))
        modulation = LinearModulation((0, 0, -8), (2 / 30, 0, 0))
    elif kind == "cap":
        geometry, shape = Box((26.0, 26.0, 26.0)), Sphere((0, 0, -13), 10.0)
        modulation = LinearModulation((0, 0, -13), (2 / 20, 0, 0))
    elif kind == "cuboid":
        geometry, shape = Box((26.0, 26.0, 26.0)), Cuboid((0, 0, -13), 14.0)
        modulation = FacetModulation(np.vstack([np.eye(3), -np.eye(3)]), [0.5, 1.5, 1.0, 2.0, 0.25, 1.0])
    else:
        raise AptFiltersError(f"map specimen must be one of {', '.join(MAP_SPECIMENS)}, not {kind!r}")
    shell = Segregation("B", peak, 0.25, 0.0, modulation if modulated else None)
    feature = Feature(shape, {"Ni": 0.745, "Al": 0.20, "Cr": 0.05, "B": 0.005}, 0.2, (shell,), kind)
    return SpecimenSpec(geometry, {"Ni": 0.745, "Al": 0.10, "Cr": 0.15, "B": 0.005}, (feature,),
                        name=f"map-{kind}", mesh_spacing=0.5)


def map_surface(specimen):
    """The interface a :func:`map_specimen` is mapped on: its true surface, of the cap only the part
    more than 2 nm above the sphere's centre (open). Normals point out of the feature, as the
    analysis expects (out of the region above the iso-value)."""
    from apt_filters.core.mesh import TriMesh

    mesh = specimen.meshes[0]
    if specimen.spec.features[0].name != "cap":
        return mesh
    keep = mesh.vertices[mesh.faces].mean(axis=1)[:, 2] > specimen.spec.features[0].shape.center[2] + 2.0
    used = np.unique(mesh.faces[keep])
    index = np.full(mesh.n_vertices, -1, np.int64)
    index[used] = np.arange(len(used))
    return TriMesh(mesh.vertices[used], index[mesh.faces[keep]])
