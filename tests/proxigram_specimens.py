"""Ground truth for the proxigram tests: exact meshes and ions with known compositions and excess.

Meshes follow the project convention: normals point out of the region above the iso-value
(the precipitate), so signed distances are positive inside it.
"""

from __future__ import annotations

import numpy as np

from apt_filters.core.deps import open3d
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable

RANGES = RangeTable([
    Range(55.0, 57.0, (("Fe", 1),), "FF0000"),
    Range(26.5, 27.5, (("Al", 1),), "00AA00"),
    Range(10.5, 11.5, (("B", 1),), "0000FF"),
    Range(83.0, 85.0, (("Cr", 1), ("O", 2)), "AA00AA"),
])
MZ = {"Fe": 56.0, "Al": 27.0, "B": 11.0, "CrO2": 84.0, None: 40.0}  # None: unranged (background)

MATRIX = {"Fe": 0.80, "Al": 0.10, "B": 0.01, "CrO2": 0.07, None: 0.02}
PRECIPITATE = {"Fe": 0.55, "Al": 0.35, "B": 0.01, "CrO2": 0.07, None: 0.02}


def element_fractions(ion_fractions: dict) -> dict[str, float]:
    """Atomic fractions of the elements for given ion fractions (unranged ions left out)."""
    atoms: dict[str, float] = {}
    for ion, frac in ion_fractions.items():
        if ion is None:
            continue
        for el, n in RANGES.ion_compositions()[ion]:
            atoms[el] = atoms.get(el, 0.0) + n * frac
    total = sum(atoms.values())
    return {el: v / total for el, v in atoms.items()}


def _mesh(legacy) -> TriMesh:
    return TriMesh(np.asarray(legacy.vertices), np.asarray(legacy.triangles))


def icosphere(radius: float, subdivisions: int = 4, center=(0.0, 0.0, 0.0)) -> TriMesh:
    """Icosphere with vertices on the sphere, outward normals."""
    o3d = open3d()
    m = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(subdivisions)
    v = np.asarray(m.vertices)
    v = radius * v / np.linalg.norm(v, axis=1, keepdims=True) + np.asarray(center)
    return TriMesh(v, np.asarray(m.triangles))


def cube(half: tuple[float, float, float], subdivisions: int = 3, center=(0.0, 0.0, 0.0)) -> TriMesh:
    """Exact box [center - half, center + half] (planar faces split into small triangles), outward normals."""
    o3d = open3d()
    half = np.asarray(half, dtype=np.float64)
    m = o3d.geometry.TriangleMesh.create_box(*(2 * half)).subdivide_midpoint(subdivisions)
    return TriMesh(np.asarray(m.vertices) - half + np.asarray(center), np.asarray(m.triangles))


def plane(half: float, n: int = 40) -> TriMesh:
    """Open square z = 0, |x|, |y| <= half, normal +z (the precipitate is the half-space z < 0)."""
    g = np.linspace(-half, half, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + (n + 1), i.ravel() + (n + 2), i.ravel() + 1
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return TriMesh(v, faces)


def box_distance(points: np.ndarray, half, center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Exact signed distance to a box, positive inside."""
    q = np.abs(points - np.asarray(center)) - np.asarray(half)
    return -(np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0))


def sphere_distance(points: np.ndarray, radius: float, center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Exact signed distance to a sphere, positive inside."""
    return radius - np.linalg.norm(points - np.asarray(center), axis=1)


def label_ions(rng: np.random.Generator, inside: np.ndarray) -> np.ndarray:
    """m/z (N,) float32 drawn from PRECIPITATE where ``inside`` and MATRIX elsewhere."""
    mz = np.empty(len(inside), dtype=np.float32)
    for mask, comp in ((inside, PRECIPITATE), (~inside, MATRIX)):
        names = list(comp)
        pick = rng.choice(len(names), size=int(mask.sum()), p=list(comp.values()))
        mz[mask] = np.array([MZ[n] for n in names], dtype=np.float32)[pick]
    return mz


def specimen(rng: np.random.Generator, lo, hi, density: float, signed_distance) -> tuple[IonTable, np.ndarray]:
    """Uniform random ions (``density`` per nm³) in the box [lo, hi], labelled by the sign of the
    exact ``signed_distance``; returns the ions and their true signed distances."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    n = rng.poisson(density * np.prod(hi - lo))
    pos = (lo + (hi - lo) * rng.random((n, 3))).astype(np.float32)
    truth = signed_distance(pos.astype(np.float64))
    return IonTable(pos, label_ions(rng, truth > 0)), truth


def with_sphere_shell(rng: np.random.Generator, ions: IonTable, radius: float, gamma: float,
                      width: float = 0.4) -> tuple[IonTable, int]:
    """Add ``gamma`` B ions per nm² of a sphere, uniform in a shell of ``width`` around it.

    The ions are added, not substituted, so the Gibbsian excess relative to a B background c is
    ``(1 - c)`` times the number added (1 % low here): within the tests' tolerance.
    """
    n = rng.poisson(gamma * 4 * np.pi * radius ** 2)
    r_lo, r_hi = radius - width / 2, radius + width / 2
    r = (r_lo ** 3 + rng.random(n) * (r_hi ** 3 - r_lo ** 3)) ** (1 / 3)
    d = rng.normal(size=(n, 3))
    pos = (d / np.linalg.norm(d, axis=1, keepdims=True) * r[:, None]).astype(np.float32)
    return IonTable(np.concatenate([ions.positions, pos]),
                    np.concatenate([ions.mz, np.full(n, MZ["B"], np.float32)])), n
