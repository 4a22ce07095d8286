"""The blurred ball profile (:func:`apt_filters.refine.levels.ball_profile`) as a Poisson mixture of central gamma
distribution functions, against its definition: the average over the width's nodes of scipy's noncentral chi-square
distribution function, node by node (kept here as the oracle)."""

import numpy as np
import pytest
import scipy.special

from apt_filters.refine.levels import _WIDTH_NODES, _on_grid, ball_profile

BOUND = 1e-12
"""Largest difference allowed from the oracle (ball_profile's docstring): nine orders below the counting error of
the fractions it is fitted to."""


def oracle(d, *, radius, dims, width, blur):
    """The definition: each distance's noncentral chi-square distribution function (scipy's ``chndtr``) at every
    node of the width, averaged; far from the centre (beyond 30 blurs) the curvature-shifted planar step, as
    ball_profile takes it; on the same 0.01 nm grid for many distances."""
    d = np.asarray(d, dtype=np.float64)
    if d.size <= 256:
        r = np.maximum(radius + d, 0.0)
    else:
        r = np.arange(max(radius + d.min(), 0.0), max(radius + d.max(), 0.0) + 0.02, 0.01)
    h = np.exp(-0.5 * _WIDTH_NODES ** 2)
    h /= h.sum()
    edge = np.maximum(radius + width * _WIDTH_NODES, 0.0)
    s = max(blur, 0.1 * max(width, 1e-3), 1e-3)
    g = np.empty(len(r))
    for k, rk in enumerate(r):
        if (rk / s) ** 2 > 900.0:
            step = scipy.special.ndtr((edge - rk - (dims - 1) * s ** 2 / (2 * rk)) / s)
        else:
            step = np.where(edge > 0, scipy.special.chndtr((edge / s) ** 2, dims, (rk / s) ** 2), 0.0)
        g[k] = step @ h
    g = np.clip(g, 0.0, 1.0)
    return g if d.size <= 256 else np.interp(np.maximum(radius + d, 0.0), r, g)


@pytest.mark.parametrize("seed", range(4))
def test_the_poisson_mixture_is_the_node_by_node_noncentral_average(seed):
    # radii from far below the blur to 12 nm (far rows and near ones in one call), every dims in [1, 3], widths up to
    # 3 nm (nodes whose ball shrinks to nothing), blurs down to 0 (floored at a tenth of the width), a few distances
    # (evaluated at each) and many (on the grid)
    rng = np.random.default_rng(seed)
    worst = 0.0
    for n in (1, 60, 256, 3000):
        for _ in range(6):
            radius, dims = rng.uniform(0.05, 12.0), rng.uniform(1.0, 3.0)
            width, blur = rng.uniform(0.02, 3.0), rng.choice([0.0, rng.uniform(0.05, 0.6)])
            d = rng.uniform(-3.5, 3.5, n) + rng.uniform(-1.0, 1.0)
            ours = ball_profile(d, radius=radius, dims=dims, width=width, blur=blur)
            worst = max(worst, float(np.abs(ours - oracle(d, radius=radius, dims=dims, width=width, blur=blur)).max()))
    assert worst <= BOUND, worst


def test_the_width_nodes_average_within_5e4_of_a_fine_quadrature_where_the_fits_call_it(monkeypatch):
    # the reference: the same average on 1921 nodes (12 times finer). Where the fits call it the blur is at least a
    # fifth of the width (the quick preset's calls: 0.28-, median 0.72) and the radius at least the width; the
    # worst there is a slab (dims 1) of radius about its width, whose nodes' shrunk radius reaches 0 in the
    # Gaussian's bulk (a kink) under a sharp blur: 3.6e-4 (241 nodes 2.0e-4, 121 nodes 8.0e-4: fails), an order
    # below the counting error of such a thin object's windows (~1e-2 at 10^3 atoms)
    import itertools

    import apt_filters.refine.levels as levels

    d = np.linspace(-3.5, 3.5, 141)
    calls = [dict(radius=k * w, dims=dims, width=w, blur=f * w)
             for k, dims, w, f in itertools.product((1.0, 1.2, 2.0), (1.0, 2.0, 3.0), (0.3, 1.0), (0.2, 0.5))]
    ours = [ball_profile(d, **kw) for kw in calls]
    monkeypatch.setattr(levels, "_WIDTH_NODES", np.linspace(-6.0, 6.0, 1921))
    worst = max(float(np.abs(a - ball_profile(d, **kw)).max()) for a, kw in zip(ours, calls))
    assert worst <= 5e-4, worst


def test_the_profile_takes_no_noncentral_distribution_function_per_node(monkeypatch):
    # main evaluated scipy's chndtr (~1 us) at every distance and node: 241 per distance, the ball fit's whole cost
    def refused(*args):
        raise AssertionError("chndtr called")

    monkeypatch.setattr(scipy.special, "chndtr", refused)
    g = ball_profile(np.linspace(-3.0, 3.0, 61), radius=1.5, dims=2.4, width=0.4, blur=0.25)
    assert np.all(np.diff(g) <= 0) and g[0] > 0.9 and g[-1] < 1e-3


@pytest.mark.parametrize("seed", range(4))
def test_the_grid_reading_is_numpys_interpolation_bit_for_bit(seed):
    # the oracle is np.interp itself: every case it has (left of the grid, right of it, at its end, at a node,
    # between nodes, NaN) on the grids ball_profile builds (0.01 nm from a radius that is no multiple of it)
    rng = np.random.default_rng(seed)
    start = rng.uniform(0.0, 4.0)
    xp = np.arange(start, start + rng.uniform(0.05, 7.0), 0.01)
    fp = np.clip(np.cumsum(rng.normal(0.0, 0.05, len(xp))), 0.0, 1.0)
    fp[rng.integers(0, len(xp), 5)] = fp[0]  # flat stretches
    x = np.concatenate([rng.uniform(xp[0] - 0.5, xp[-1] + 0.5, 20_000), xp, xp[rng.integers(0, len(xp), 50)],
                        np.nextafter(xp, np.inf), np.nextafter(xp, -np.inf), [np.nan, xp[0], xp[-1]]])
    rng.shuffle(x)
    assert _on_grid(x, xp, fp).tobytes() == np.interp(x, xp, fp).tobytes()
