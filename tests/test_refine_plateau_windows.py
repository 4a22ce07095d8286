"""The plateau windows' compiled pass (levels.plateau_sums, window_labels, inside_inner; issue 29) against the numpy
code it replaced, bit for bit: each window summed over its ions in the band's order, as ``np.bincount`` sums it."""

import numpy as np
import pytest

from apt_filters.refine.band import Band
from apt_filters.refine.composition import IonAtoms
from apt_filters.refine.levels import plateau_sums, window_labels

WINDOW = (0.75, 3.0)


def _labels(distance, comp, n, window):
    """The numpy oracle: labels from each object's deepest ion (``np.maximum.at``), the outside window set last."""
    inner, outer = window
    depth = np.zeros(n)
    inside = (distance < 0) & (comp >= 0)
    np.maximum.at(depth, comp[inside], -distance[inside])
    starts = np.where(depth > inner, inner, 0.5 * depth)
    out = np.full(len(comp), -1)
    out[(distance <= -starts[np.maximum(comp, 0)]) & (distance >= -outer)] = 0
    out[(distance >= inner) & (distance <= outer)] = 1
    return np.where(comp >= 0, out, -1)


def _sums(distance, comp, n, window, atoms, index, weight):
    """The numpy oracle: float64 atoms (times ``weight``) of the windows' ions, one ``np.bincount`` per element."""
    of = _labels(distance, comp, n, window)
    use = np.flatnonzero(of >= 0)
    a = atoms[index[use]].astype(np.float64)
    if weight is not None:
        a *= weight[use, None]
    key = 2 * comp[use] + of[use]
    per = [np.bincount(key, weights=a[:, e], minlength=2 * n) for e in range(a.shape[1])]
    return (np.stack(per, axis=1) if per else np.zeros((2 * n, 0))).reshape(n, 2, a.shape[1])


def _band(rng, b=60_000, n_vertices=400, n=5):
    """A band of ``b`` ions on ``n`` objects, one thin (no ion 0.75 nm deep: its window starts at half its depth),
    some vertices of no object, and ions placed on every window edge."""
    components = rng.integers(-1, n, n_vertices)
    components[:n] = np.arange(n)
    vertex = rng.integers(0, n_vertices, b)
    distance = rng.uniform(-4.0, 4.0, b)
    vertex[:8] = 0
    comp = components[vertex]
    thin = np.flatnonzero(comp == 1)
    distance[thin[distance[thin] < 0]] *= 0.15  # object 1 is 0.6 nm deep
    distance[thin[:2]] = [-0.6, -0.3]  # its deepest ion and one exactly on its window's start
    distance[:8] = [-3.0, 3.0, -0.75, 0.75, 0.0, -0.0, -3.0 - 1e-12, 3.0 + 1e-12]
    index = rng.permutation(3 * b)[:b]
    return components, Band(index, vertex, distance)


@pytest.mark.parametrize("k, weighted", [(3, False), (3, True), (1, True), (0, False)])
def test_plateau_sums_are_the_numpy_sums_bit_for_bit(k, weighted):
    rng = np.random.default_rng(29 + k + weighted)
    components, band = _band(rng)
    n = int(components.max()) + 1
    atoms = (rng.integers(0, 3, (3 * len(band.index), k)) * rng.random((1, k)) * 1.7).astype(np.float32)
    weight = rng.random(len(band.index)) if weighted else None
    comp = components[band.vertex]
    got = plateau_sums(band, IonAtoms([f"E{e}" for e in range(k)], atoms), components, n, WINDOW, weight)
    want = _sums(band.distance, comp, n, WINDOW, atoms, band.index, weight)
    assert got.shape == want.shape == (n, 2, k)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64))
    labels = window_labels(band, comp, n, WINDOW)
    assert labels.dtype == np.int64 and np.array_equal(labels, _labels(band.distance, comp, n, WINDOW))
    # the edges: both windows' bounds are in them, the thin object's inside window starts at 0.3 nm
    assert labels[:6].tolist() == [0, 1, 0, 1, -1, -1] and labels[6:8].tolist() == [-1, -1]
    assert (labels[comp == 1] == 0).sum() == ((band.distance[comp == 1] <= -0.3)).sum()
    assert np.all(labels[comp < 0] == -1) and np.all(labels[comp >= 0] >= -1)
