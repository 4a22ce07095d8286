"""Ground truth: what an exactly known specimen or shape says about a measured surface.

Used by tests and benchmarks, and by ``apt-filters run --truth`` on synthetic specimens; no
analysis step imports it.

- :mod:`.shapes`: analytic benchmark shapes (exact SDFs and surface samples) for contouring;
- :mod:`.metrics`: a mesh against an analytic shape (Hausdorff, Chamfer, normal and edge metrics,
  sanity counts), :func:`evaluate`;
- :mod:`.surface`: one object's surface against its truth (volume, area, distances),
  :func:`surface_error`, and the matching of measured objects to true ones, :func:`match_objects`;
- :mod:`.counting`: the counting floor no method can beat (:func:`counting_floor`; of an open surface's mean
  distance, :func:`distance_floor`) and what the ions themselves hold against the true surface
  (:func:`counted_truth`);
- :mod:`.specimen`: a run's objects and excess against a synthetic specimen's ``truth.json``.
"""

from apt_filters.truth.counting import (CountedTruth, CountingFloor, DistanceFloor, counted_truth, counting_floor,
                                       distance_floor)
from apt_filters.truth.surface import SurfaceError, match_objects, surface_error, surface_error_within

__all__ = ["CountedTruth", "CountingFloor", "DistanceFloor", "SurfaceError", "counted_truth", "counting_floor",
           "distance_floor", "match_objects", "surface_error", "surface_error_within"]
