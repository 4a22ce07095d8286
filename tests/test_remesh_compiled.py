"""Compiled kernels of the remesher against the numpy forms they replaced: the same bits."""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.remesh import cvt, features as feat
from apt_filters.remesh.remesh import SAMPLES_PER_EDGE
from apt_filters.remesh.sampling import chunk_length, refine
from tests import remesh_shapes as shapes


def _numpy_voxel_means(samples, faces, origin, size, step):
    """The numpy form: the samples a chunk of ``step`` input faces at a time, each chunk's cubes and sums by
    ``np.unique`` and ``np.bincount``, then the chunks' sums per cube, in chunk order."""
    cells, sums, counts = [], [], []
    for first in range(0, len(faces), step):
        points = samples.points(samples.of_faces(faces[first:first + step]))
        cell, inverse, count = np.unique(np.floor((points - origin) / size).astype(np.int64), axis=0,
                                         return_inverse=True, return_counts=True)
        cells.append(cell)
        counts.append(count)
        sums.append(np.stack([np.bincount(inverse.ravel(), points[:, k]) for k in range(3)], 1))
    inverse = np.unique(np.vstack(cells), axis=0, return_inverse=True)[1].ravel()
    total = np.stack([np.bincount(inverse, np.concatenate([s[:, k] for s in sums])) for k in range(3)], 1)
    return total / np.bincount(inverse, np.concatenate(counts))[:, None]


@pytest.mark.parametrize("shape", ["thin plate", "bumpy sheet"])
def test_voxel_means_are_the_numpy_forms_bits(shape):
    mesh = shapes.thin_plate() if shape == "thin plate" else shapes.bumpy(shapes.tilted_sheet(), 0.25)
    edge = 0.5
    features = feat.detect(mesh, 40.0, min_area=edge**2)
    samples = refine(mesh, edge / SAMPLES_PER_EDGE)
    lattice = samples.lattice
    sizes = np.bincount(features.patch)
    checked = 0
    for p in np.argsort(sizes)[::-1][:4]:  # the largest patches: many parts and cubes
        faces = np.flatnonzero(features.patch == p)
        args = (lattice.vertices, lattice.faces, lattice.centroid, faces)
        origin = cvt._samples_min(*args)
        assert np.array_equal(origin, samples.points(samples.of_faces(faces)).min(axis=0))
        # cubes of a sample spacing (thousands of cubes: the table grows many times) to a few edges; parts of one
        # input face, of the remesher's own length and of all faces
        for size in (0.05, 0.3, 1.7):
            for step in (1, max(samples.chunk // samples.per_face, 1), len(faces)):
                got = cvt._voxel_means(args, origin, size, step)
                want = _numpy_voxel_means(samples, faces, origin, size, step)
                assert got.shape == want.shape and got.tobytes() == want.tobytes()
                checked += 1
    assert checked == 36


def test_chunk_length_bounds():
    assert [chunk_length(n) for n in (0, 1023, 1028, 4 * 16384, 10**9)] == [256, 256, 257, 16384, 16384]
    assert isinstance(chunk_length(np.int64(5000)), int)
