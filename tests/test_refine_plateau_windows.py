"""The plateau windows' compiled pass (levels.plateau_sums, window_labels, inside_inner; issue 29) against the numpy
code it replaced, bit for bit: each window summed over its ions in the band's order, as ``np.bincount`` sums it; each
object's own outer edge (issue 25), and the open objects' edges (levels.open_window_edges) on counts whose shells'
midpoints are known exactly."""

import numpy as np
import pytest

from apt_filters.refine.band import Band
from apt_filters.refine.composition import IonAtoms
from apt_filters.refine.levels import open_window_edges, plateau_sums, window_labels

WINDOW = (0.75, 3.0)


def _labels(distance, comp, n, window):
    """The numpy oracle: labels from each object's deepest ion (``np.maximum.at``), the outside window set last."""
    inner, outer = window
    outer = np.broadcast_to(np.asarray(outer, dtype=np.float64), (n,))[np.maximum(comp, 0)]
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


@pytest.mark.parametrize("k, weighted, own", [(3, False, False), (3, True, False), (1, True, False),
                                               (0, False, False), (3, True, True)])
def test_plateau_sums_are_the_numpy_sums_bit_for_bit(k, weighted, own):
    rng = np.random.default_rng(29 + k + weighted)
    components, band = _band(rng)
    n = int(components.max()) + 1
    # each object's own outer edge: object 0 (the ions on the edges) keeps 3 nm, the others 2-4 nm
    window = (WINDOW[0], np.concatenate([[WINDOW[1]], rng.uniform(2.0, 4.0, n - 1)])) if own else WINDOW
    atoms = (rng.integers(0, 3, (3 * len(band.index), k)) * rng.random((1, k)) * 1.7).astype(np.float32)
    weight = rng.random(len(band.index)) if weighted else None
    comp = components[band.vertex]
    got = plateau_sums(band, IonAtoms([f"E{e}" for e in range(k)], atoms), components, n, window, weight)
    want = _sums(band.distance, comp, n, window, atoms, band.index, weight)
    assert got.shape == want.shape == (n, 2, k)
    assert np.array_equal(got.view(np.uint64), want.view(np.uint64))
    labels = window_labels(band, comp, n, window)
    assert labels.dtype == np.int64 and np.array_equal(labels, _labels(band.distance, comp, n, window))
    # the edges: both windows' bounds are in them, the thin object's inside window starts at 0.3 nm
    assert labels[:6].tolist() == [0, 1, 0, 1, -1, -1] and labels[6:8].tolist() == [-1, -1]
    assert (labels[comp == 1] == 0).sum() == ((band.distance[comp == 1] <= -0.3)).sum()
    assert np.all(labels[comp < 0] == -1) and np.all(labels[comp >= 0] >= -1)


def _shells(fractions, atoms_per_ion=2):
    """A band of one ion per (object, side, shell) cell holding ``atoms_per_ion`` atoms of two elements, the first
    (the species) at ``fractions[c][side][j]`` of them (exact: multiples of 1/atoms_per_ion), at the middle of
    window (1-3 nm, j = 0) or shell j (3-5, 5-7, 7-9 nm); a cell of fraction None holds no ion."""
    index, vertex, distance, atoms = [], [], [], []
    for c, sides in enumerate(fractions):
        for side, row in enumerate(sides):
            for j, f in enumerate(row):
                if f is None:
                    continue
                depth = 2.0 + 2.0 * j
                index.append(len(atoms))
                vertex.append(c)
                distance.append(depth if side else -depth)
                atoms.append([f * atoms_per_ion, (1 - f) * atoms_per_ion])
    return Band(np.array(index), np.array(vertex), np.array(distance)), IonAtoms(["A", "B"],
                                                                                np.array(atoms, np.float32))


def test_open_window_edges_widen_while_the_midpoint_is_flat():
    cells = [
        [[0.5, 0.5, 0.5, 0.9], [0.1, 0.1, 0.1, 0.1]],         # 0: open, a neighbour phase inside beyond 7 nm
        [[0.45, 0.5, 0.5, 0.5], [0.15, 0.1, 0.1, 0.1]],       # 1: open, wide tails: both windows pulled, midpoint flat
        [[0.5, 0.5, None, None], [0.1, 0.1, 0.1, 0.1]],       # 2: open, its inside ends at 5 nm (specimen edge)
        [[0.5, 0.5, 0.5, 0.5], [0.1, 0.1, 0.1, 0.1]],         # 3: closed, flat: keeps its 3 nm
        [[0.5, 0.7, 0.5, 0.5], [0.1, 0.1, 0.1, 0.1]],         # 4: open, a gradient at its first shell
        [[0.5, 0.55, 0.55, 0.55], [0.1, 0.15, 0.15, 0.15]],   # 5: open, a midpoint shift of 0.05 beyond 3 nm
        [[0.5, None, None, None], [0.1, None, None, None]],   # 6: open, no ion beyond its window
    ]
    components = np.arange(len(cells))
    opened = np.array([True, True, True, False, True, True, True])
    # 1000 atoms per cell: object 5's first shell against its window is 3.7 standard errors off (refused), object
    # 4's 7.8, object 0's last 19
    edges = open_window_edges(*_shells(cells, 1000), components, opened, 0, window=(1.0, 3.0), reach=9.0)
    assert edges.tolist() == [7.0, 9.0, 9.0, 3.0, 3.0, 3.0, 3.0]
    # 100 atoms: object 5's shift is 1.2 standard errors, within the counting error (widened); object 4's 2.5
    edges = open_window_edges(*_shells(cells, 100), components, opened, 0, window=(1.0, 3.0), reach=9.0)
    assert edges.tolist() == [7.0, 9.0, 9.0, 3.0, 3.0, 9.0, 3.0]
    # no shell fits below the reach: every object keeps its window
    edges = open_window_edges(*_shells(cells, 1000), components, opened, 0, window=(1.0, 3.0), reach=4.9)
    assert edges.tolist() == [3.0] * 7
