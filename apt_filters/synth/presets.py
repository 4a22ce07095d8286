"""Built-in specimens: ``default`` (the demo), ``gamma-prime`` (Ni superalloy, the refinement's test
specimen) and ``small`` (tests).

All three model a Ni-based superalloy: gamma matrix (Al 10 at.%) with gamma-prime precipitates
(Al 20 at.%), and B segregated in a Gaussian shell at every interface. Their layout is fixed
(rotations come from fixed seeds), so the generation seed only changes the ions.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from apt_filters.core.errors import AptFiltersError
from apt_filters.synth.geometry import Box, Tip
from apt_filters.synth.shapes import Capsule, Cuboid, Cylinder, HalfSpace, Sphere
from apt_filters.synth.specimen import Feature, Segregation, SpecimenSpec, check_layout

GAMMA = {"Ni": 0.745, "Al": 0.10, "Cr": 0.15, "B": 0.005}
GAMMA_PRIME = {"Ni": 0.745, "Al": 0.20, "Cr": 0.05, "B": 0.005}
CR_RICH = {"Ni": 0.30, "Al": 0.04, "Cr": 0.65, "B": 0.01}
LAYER = {"Ni": 0.60, "Al": 0.04, "Cr": 0.35, "B": 0.01}
BORON_SHELL = (Segregation("B", peak=0.08, sigma=0.25),)
WIDTH = 0.2


def _precipitate(shape, composition=GAMMA_PRIME, name=""):
    return Feature(shape, composition, WIDTH, BORON_SHELL, name)


def default() -> SpecimenSpec:
    """~3.4M ions: tip 80 nm long (apex 14 nm, 8 deg); rotated cubes of 7 and 6 nm, spheres of 3 nm,
    a rod, a Cr-rich plate, a flat interface at z = -60 nm to a Cr-rich layer with a sphere in it."""
    features = (
        Feature(HalfSpace((0, 0, -60), (0, 0, 1)), LAYER, WIDTH, BORON_SHELL, "layer below z=-60"),
        _precipitate(Cuboid((3, -2, -15), 7.0, rotation=11), name="cube 7 nm"),
        _precipitate(Sphere((-6, 5, -25), 3.0), name="sphere 3 nm"),
        _precipitate(Cuboid((-3, -4, -35), 6.0, rotation=12), name="cube 6 nm"),
        _precipitate(Sphere((6, 5, -39), 3.0), name="sphere 3 nm"),
        _precipitate(Capsule((1, 8, -49), 1.5, 8.0, rotation=(1.0, 0.3, 0.2)), name="rod"),
        _precipitate(Cylinder((-6, -6, -48), 3.5, 1.2, rotation=13), CR_RICH, name="Cr-rich plate"),
        _precipitate(Sphere((2, -3, -70), 3.5), name="sphere 3.5 nm in the layer"),
    )
    return SpecimenSpec(Tip(14.0, 8.0, 80.0), GAMMA, features, name="default")


def gamma_prime() -> SpecimenSpec:
    """~1.2M ions: the refinement's test specimen. Tip 45 nm long (apex 12 nm, 10 deg), efficiency 0.5, blur
    0.3/0.1 nm; rotated gamma-prime cubes of 7 and 6 nm and two spheres of 3 nm (Al 0.20 inside,
    0.10 outside), B in a shell at every interface."""
    features = (
        _precipitate(Cuboid((2, 1, -12), 7.0, rotation=21), name="cube 7 nm"),
        _precipitate(Sphere((-4, -3, -22), 3.0), name="sphere 3 nm"),
        _precipitate(Cuboid((3, -2, -30.5), 6.0, rotation=22), name="cube 6 nm"),
        _precipitate(Sphere((-4, 3, -40), 3.0), name="sphere 3 nm"),
    )
    return SpecimenSpec(Tip(12.0, 10.0, 45.0), GAMMA, features, name="gamma-prime")


def small() -> SpecimenSpec:
    """~250k ions for fast tests: asymmetric box 16 x 14 x 28 nm; a rotated 6 nm cube, a 3 nm sphere,
    a flat interface at z = -23 nm to a Cr-rich layer; B at every interface."""
    features = (
        Feature(HalfSpace((0, 0, -23), (0, 0, 1)), LAYER, WIDTH, BORON_SHELL, "layer below z=-23"),
        _precipitate(Cuboid((0, 0, -6.5), 6.0, rotation=31), name="cube 6 nm"),
        _precipitate(Sphere((2, -2, -17), 3.0), name="sphere 3 nm"),
    )
    return SpecimenSpec(Box((16.0, 14.0, 28.0)), GAMMA, features, name="small")


def many() -> SpecimenSpec:
    """~8.4M ions with 47 precipitates (the end-to-end scale case; ``--ions`` lengthens the shank): tip
    130 nm long (apex 14 nm, 8 deg); layers every 8.5 nm, each of 3-5 precipitates (rotated 5 nm cubes and 2.5 nm spheres) around
    the axis, alternate layers turned so that no two sit on top of each other."""
    tip = Tip(14.0, 8.0, 130.0)
    features = []
    for layer, z in enumerate(np.arange(-12.0, -125.0, -8.5)):
        radius = float(tip.radius_at(np.array([z]))[0])
        count = 3 if radius < 24 else (4 if radius < 30 else 5)
        offset = 0.45 * radius
        for k in range(count):
            angle = 2 * np.pi * (k + 0.5 * (layer % 2)) / count
            centre = (offset * np.cos(angle), offset * np.sin(angle), float(z))
            shape = Cuboid(centre, 5.0, rotation=100 + len(features)) if (layer + k) % 2 else Sphere(centre, 2.5)
            features.append(_precipitate(shape, name=f"{'cube 5' if (layer + k) % 2 else 'sphere 2.5'} nm #{len(features)}"))
    return SpecimenSpec(tip, GAMMA, tuple(features), name="many")


PRESETS: dict[str, Callable[[], SpecimenSpec]] = {"default": default, "gamma-prime": gamma_prime, "small": small,
                                                  "many": many}


def preset(name: str, ions: int | None = None) -> SpecimenSpec:
    """The preset ``name``, optionally resized to about ``ions`` ions (see :func:`with_ions`)."""
    if name not in PRESETS:
        raise AptFiltersError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    spec = PRESETS[name]()
    return spec if ions is None else with_ions(spec, ions)


def with_ions(spec: SpecimenSpec, ions: int) -> SpecimenSpec:
    """``spec`` with the specimen length changed so that about ``ions`` ions are expected.

    The top (and every feature) stays in place; a longer specimen has more shank below.

    Raises
    ------
    AptFiltersError
        If the features no longer fit (too few ions for this layout).
    """
    if not ions > 0:
        raise AptFiltersError(f"number of ions must be positive, got {ions}")
    geometry = spec.geometry
    expected = lambda length: dataclasses.replace(spec, geometry=geometry.with_length(length)).expected_ions()  # noqa: E731
    lo, hi = geometry.min_length, geometry.length
    while expected(hi) < ions:
        hi *= 2
    for _ in range(100):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if expected(mid) < ions else (lo, mid)
    resized = dataclasses.replace(spec, geometry=geometry.with_length(hi))
    try:
        check_layout(resized)
    except AptFiltersError as exc:
        raise AptFiltersError(f"{ions:,} ions are too few for preset {spec.name!r}: "
                              f"a {hi:.1f} nm long specimen cannot hold its features ({exc})") from exc
    return resized
