"""The counting error of an object's own plateau levels, carried into its reported offset error (issue 25).

Truth: two objects of one phase under an error-function interface of known width and levels (rod 10039's: Ti 0.308
inside, 0.1015 outside, width 0.77 nm), each with an inside window of ~1000 atoms and an outside one of tens of
thousands, drawn binomially. Each object's levels are its windows shrunk toward the pool (``levels_from_sums``), the
placement stops where the true profile crosses their midpoint; the spread of that crossing over the draws is what
the levels' counting alone does to the surface, which the step's error (levels held fixed) leaves out.
"""

import numpy as np
from scipy.special import ndtri

from apt_filters.refine.composition import object_scores
from apt_filters.refine.levels import PLATEAU_PRIOR, agreeing_pools, levels_from_sums
from apt_filters.refine.surface import _level_offset_errors

C_IN, C_OUT, WIDTH = 0.308, 0.1015, 0.77
ATOMS = np.array([[1000, 40000], [980, 50000]])  # (object, inside / outside window)


def _draw(rng):
    """(levels, crossing nm of object 0): the levels from binomial windows, and where the true profile
    ``C_OUT + (C_IN - C_OUT) Phi(-x / WIDTH)`` crosses object 0's midpoint."""
    part = rng.binomial(ATOMS, np.array([C_IN, C_OUT]))
    sums = np.stack([part, ATOMS - part], axis=2).astype(np.float64)  # (object, side, [Ti, rest])
    levels = levels_from_sums(sums, ["Ti", "X"], "Ti", PLATEAU_PRIOR, agreeing_pools(sums, 0, PLATEAU_PRIOR))
    return levels, -WIDTH * ndtri((levels[0].iso - C_OUT) / (C_IN - C_OUT))


def test_the_levels_counting_error_moves_the_surface_as_reported():
    rng = np.random.default_rng(7)
    drawn = [_draw(rng) for _ in range(3000)]
    spread = float(np.std([x for _, x in drawn]))
    reported = [_level_offset_errors(lv, object_scores(lv, ["Ti", "X"], "Ti", "species", PLATEAU_PRIOR),
                                     np.full(2, WIDTH))[0] for lv, _ in drawn]
    # the spread is ~0.04 nm (4-5 % of a 1.85 nm rod's volume); its own sampling error over 3000 draws is 1.3 %
    assert 0.03 < spread < 0.06
    assert abs(np.mean(reported) / spread - 1) < 0.06, (np.mean(reported), spread)


def test_a_level_worth_more_atoms_moves_the_surface_less():
    levels, _ = _draw(np.random.default_rng(1))
    scores = object_scores(levels, ["Ti", "X"], "Ti", "species", PLATEAU_PRIOR)
    wide = _level_offset_errors(levels, scores, np.full(2, WIDTH))
    for lv in levels:
        lv.worth_inside *= 4
        lv.worth_outside *= 4
    assert np.allclose(_level_offset_errors(levels, scores, np.full(2, WIDTH)), wide / 2)
