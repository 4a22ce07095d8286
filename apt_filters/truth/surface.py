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


MATCH_REACH = 1.5
"""nm: a part is a candidate for a true object when its vertices' mean distance to the object's surface is below
this."""
SHARED_SAMPLES = 20_000
"""Uniform points in a candidate part's bounding box that measure the volume it shares with a true object."""


def match_objects(parts: list[TriMesh], sdfs: list[Callable[[np.ndarray], np.ndarray]]) -> list[int | None]:
    """For each true object (its SDF, negative inside), the index of the part that shares the most volume with it
    (None if no part's vertices lie within a mean :data:`MATCH_REACH` nm of its surface).

    The candidates are the parts within reach; of these, the one holding the most of the object's inside wins,
    measured as the share of :data:`SHARED_SAMPLES` uniform points in the part's bounding box that lie behind
    the part (:class:`~apt_filters.core.distance.SurfaceDistance`, negative) and inside the object, times the
    box's volume (nm³; fixed seed, so one mesh always gets one answer). Nearness alone would pair a thin disc
    with a speck lying on its face, whose few vertices sit closer to the true surface on average than the
    disc's own. Where no candidate shares volume (open sheets of an interface), the nearest one (smallest mean
    ``|sdf|`` of its vertices) wins, as it does between candidates that share exactly as much.
    """
    from apt_filters.core.distance import SurfaceDistance

    used = [p.vertices[np.unique(p.faces)] for p in parts]
    near = [[float(np.abs(sdf(u)).mean()) for sdf in sdfs] for u in used]
    shared: dict[tuple[int, int], float] = {}
    for i, p in enumerate(parts):
        reached = [k for k in range(len(sdfs)) if near[i][k] < MATCH_REACH]
        if not reached:
            continue
        lo, hi = used[i].min(axis=0), used[i].max(axis=0)
        probe = lo + (hi - lo) * np.random.default_rng(0).random((SHARED_SAMPLES, 3))
        behind = SurfaceDistance(p).query(probe).distance < 0
        for k in reached:
            shared[i, k] = float(np.prod(hi - lo) * np.mean(behind & (sdfs[k](probe) < 0)))
    out = []
    for k in range(len(sdfs)):
        candidates = [i for i in range(len(parts)) if (i, k) in shared]
        out.append(max(candidates, key=lambda i: (shared[i, k], -near[i][k]), default=None))
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
    # a part may have nothing inside the region (a cut object's surface found only within the margin): its side
    # of the distances is undefined, NaN, not an error; the truth's side still says how far the part stands off
    mesh_side = float(to_true.mean()) if len(to_true) else np.nan
    true_side = float(to_mesh.mean()) if len(to_mesh) else np.nan
    far = max([float(d.max()) for d in (to_true, to_mesh) if len(d)], default=np.nan)
    return SurfaceError(volume, np.nan if true_volume is None else true_volume, area, true_area,
                        0.5 * (mesh_side + true_side), mesh_side, true_side, far)
