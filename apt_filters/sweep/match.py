"""Objects matched across runs by the overlap of their bounding boxes, not by their index.

Runs of other analysis choices number their objects differently (an object may split, vanish or
appear), so a sweep matches each run's objects to tracks: the first run's objects start the
tracks, and each later run's objects are assigned to tracks by maximum total overlap
(Hungarian assignment of intersection over union, IoU, of axis-aligned bounding boxes), a pair
counting only from ``min_iou``; an object left over starts a new track.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

MIN_IOU = 0.25
"""Least bounding-box overlap of one object in two runs (a 3 nm sphere whose surface moves by 0.5
nm keeps an IoU of about 0.6; neighbours a diameter apart share none)."""


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) intersection over union of boxes ``[x0, y0, z0, x1, y1, z1]`` (nm)."""
    a, b = np.asarray(a, float).reshape(-1, 6), np.asarray(b, float).reshape(-1, 6)
    lo = np.maximum(a[:, None, :3], b[None, :, :3])
    hi = np.minimum(a[:, None, 3:], b[None, :, 3:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=2)
    vol_a = np.prod(a[:, 3:] - a[:, :3], axis=1)
    vol_b = np.prod(b[:, 3:] - b[:, :3], axis=1)
    union = vol_a[:, None] + vol_b[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def match_objects(runs: Sequence[Sequence[Sequence[float]]], *, min_iou: float = MIN_IOU) -> list[list[int]]:
    """Track index of each object of each run.

    Parameters
    ----------
    runs : sequence of (n_objects_i, 6) boxes
        Each run's objects' bounding boxes ``[x0, y0, z0, x1, y1, z1]``, in nm.
    min_iou : float
        Least overlap for a match.

    Returns
    -------
    list of list of int
        ``tracks[i][j]``: the track (0, 1, ...) of object ``j`` of run ``i``; tracks are numbered in
        order of first appearance, and no two objects of one run share a track.
    """
    reference: list[np.ndarray] = []  # each track's box where it was first seen
    out = []
    for boxes in runs:
        boxes = np.asarray(boxes, float).reshape(-1, 6)
        tracks = [-1] * len(boxes)
        if reference and len(boxes):
            iou = box_iou(boxes, np.array(reference))
            rows, cols = linear_sum_assignment(-iou)
            for r, c in zip(rows, cols):
                if iou[r, c] >= min_iou:
                    tracks[r] = int(c)
        for j in range(len(boxes)):
            if tracks[j] < 0:
                tracks[j] = len(reference)
                reference.append(boxes[j])
        out.append(tracks)
    return out
