"""A surface against the truth: volume, area and distances to an exactly known surface.

Distances: ``mean`` is the mean of the two one-sided mean distances (mesh samples to the true
surface, ``|sdf|``, which is exact; true-surface samples to the mesh, exact point-to-triangle,
:mod:`apt_filters.core.distance`), ``hausdorff`` the larger of the two maxima. Samples: ``density``
uniform random points per nm².
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from apt_filters.contour.metrics import sample_mesh
from apt_filters.core.distance import mesh_distance
from apt_filters.core.mesh import TriMesh


@dataclass
class SurfaceError:
    """One object's surface against its truth (nm, nm², nm³; relative errors as fractions)."""

    volume: float
    true_volume: float
    area: float
    true_area: float
    mean_distance: float
    mesh_to_true_mean: float
    true_to_mesh_mean: float
    hausdorff: float

    @property
    def volume_error(self) -> float:
        return self.volume / self.true_volume - 1

    @property
    def area_error(self) -> float:
        return self.area / self.true_area - 1

    def as_dict(self) -> dict:
        return {**asdict(self), "volume_error": self.volume_error, "area_error": self.area_error}


def surface_error(part: TriMesh, sdf: Callable[[np.ndarray], np.ndarray], true_mesh: TriMesh,
                  true_volume: float, true_area: float, density: float = 20.0, seed: int = 0) -> SurfaceError:
    """Compare one closed object's surface ``part`` with the true surface (its SDF and a fine mesh of it)."""
    rng = np.random.default_rng(seed)
    pts, _ = sample_mesh(part, density, rng)
    to_true = np.abs(sdf(pts))
    true_pts, _ = sample_mesh(true_mesh, density, rng)
    to_mesh = mesh_distance(part, true_pts)
    return SurfaceError(part.signed_volume(), true_volume, part.area(), true_area,
                        0.5 * (to_true.mean() + to_mesh.mean()), float(to_true.mean()), float(to_mesh.mean()),
                        float(max(to_true.max(), to_mesh.max())))


def match_objects(parts: list[TriMesh], sdfs: list[Callable[[np.ndarray], np.ndarray]]) -> list[int | None]:
    """For each true object, the index of the part whose vertices lie closest to its surface (None if no part
    has its mean vertex inside the object's reach of 1.5 nm)."""
    out = []
    for sdf in sdfs:
        best, best_d = None, 1.5
        for i, p in enumerate(parts):
            used = np.unique(p.faces)
            d = float(np.abs(sdf(p.vertices[used])).mean())
            if d < best_d:
                best, best_d = i, d
        out.append(best)
    return out


def surface_error_within(part: TriMesh, sdf: Callable[[np.ndarray], np.ndarray], true_mesh: TriMesh,
                         region: Callable[[np.ndarray], np.ndarray], true_area: float, true_volume: float | None = None,
                         bounds: tuple[np.ndarray, np.ndarray] | None = None, density: float = 20.0,
                         volume_samples: int = 200_000, seed: int = 0) -> SurfaceError:
    """Compare the part of a surface inside ``region`` (``region(points) < 0``) with the truth there.

    For surfaces that end at the specimen edge (open and bicontinuous interfaces, objects cut by the
    edge), where the measured surface stops short of the edge and an object is not closed. Areas: the
    mesh's area times the fraction of its uniform samples inside the region (``true_area`` is the truth's
    area inside the region). Distances as :func:`surface_error`, over the samples inside the region.
    Volume (where ``true_volume`` is given): the fraction of ``volume_samples`` uniform points in
    ``bounds`` (lower, upper corners; the region's part that can hold the object) that lie inside the
    region and behind ``part`` (its signed distance negative), times the box's volume; NaN otherwise.
    """
    from apt_filters.core.distance import SurfaceDistance

    rng = np.random.default_rng(seed)
    pts, _ = sample_mesh(part, density, rng)
    inside = region(pts) < 0
    to_true = np.abs(sdf(pts[inside]))
    true_pts, _ = sample_mesh(true_mesh, density, rng)
    true_pts = true_pts[region(true_pts) < 0]
    to_mesh = mesh_distance(part, true_pts)
    area = part.area() * inside.mean() if len(pts) else 0.0
    volume = np.nan
    if true_volume is not None:
        lo, hi = bounds
        probe = lo + (hi - lo) * rng.random((volume_samples, 3))
        behind = SurfaceDistance(part).query(probe).distance < 0
        volume = float(np.prod(hi - lo) * np.mean(behind & (region(probe) < 0)))
    return SurfaceError(volume, np.nan if true_volume is None else true_volume, area, true_area,
                        0.5 * (to_true.mean() + to_mesh.mean()), float(to_true.mean()), float(to_mesh.mean()),
                        float(max(to_true.max(), to_mesh.max())))
