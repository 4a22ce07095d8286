"""The objects' pool of plateau windows (levels.agreeing_pools): objects of one phase pooled, of two phases not.

Exact truth: each window's atoms are drawn binomially from its object's true level (the last test: each ion's
element from its true region's level)."""

import math

import numpy as np

from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.refine.levels import agreeing_pools, levels_from_sums, object_levels
from apt_filters.refine.specks import ALPHA
from tests.proxigram_specimens import RANGES, icosphere, sphere_distance

PRIOR = 3000.0


def _windows(rng, inside, n_inside, outside=0.05, n_outside=5000):
    """(n_objects, 2, 2) window sums (measured species, the rest) drawn from the true levels."""
    sums = np.zeros((len(inside), 2, 2))
    for c, (f, n) in enumerate(zip(inside, n_inside)):
        a, b = rng.binomial(n, f), rng.binomial(n_outside, outside)
        sums[c] = [[a, n - a], [b, n_outside - b]]
    return sums


def _levels(sums):
    return np.array([lv.inside[0] for lv in levels_from_sums(sums, ["Al", "other"], "Al", PRIOR,
                                                             agreeing_pools(sums, 0, PRIOR))])


def test_objects_of_two_phases_keep_their_own_levels():
    """A small object of another phase beside a large one: pooling both (the shrinkage's pool of every window) pulls
    its level 7 points toward the large one's (RMS error 7.2 at.% against its own window's 1.5); the windows
    disagree by far more than their counting and the prior's spread allow, so each keeps its own (1.5)."""
    rng = np.random.default_rng(0)
    truth, atoms = np.array([0.15, 0.25]), [8000, 800]
    errors = np.array([_levels(_windows(rng, truth, atoms)) - truth for _ in range(400)])
    rms = np.sqrt((errors ** 2).mean(axis=0))
    own = np.sqrt(truth * (1 - truth) / atoms)
    assert (rms <= 1.2 * own).all(), (rms, own)


def test_objects_of_one_phase_stay_pooled():
    """Objects of one phase (their windows differ by counting alone): the pair test splits them in no more than the
    family-wise share its level allows (the speck test's), so their levels keep the pool's precision (a 60-atom
    window's level within the pool's error, not its own 5 points)."""
    rng = np.random.default_rng(1)
    truth, atoms = np.full(4, 0.20), [5000, 300, 300, 60]
    split, errors = 0, []
    for _ in range(600):
        sums = _windows(rng, truth, atoms)
        split += not np.array_equal(agreeing_pools(sums, 0, PRIOR), np.broadcast_to(sums.sum(axis=0), sums.shape))
        errors.append(_levels(sums) - truth)
    assert split / 600 <= ALPHA + 3 * math.sqrt(ALPHA * (1 - ALPHA) / 600), split
    rms = np.sqrt((np.array(errors) ** 2).mean(axis=0))
    assert rms[3] < 0.25 * math.sqrt(0.2 * 0.8 / 60), rms


def test_a_diluted_window_that_the_counts_cannot_refute_stays_pooled():
    """Held-out plate 10010's final windows (cross-fitted, both halves): 2004 atoms at 17.1 at.% (the plate with the
    noise lobes) and 797 at 20.2; both plates are 18.97 at.% in truth. They differ by 1.6 standard errors: the
    data do not refute one phase, and the pool (18.0) is nearer the truth than either window."""
    sums = np.array([[[0.171 * 2004, 0.829 * 2004], [0.1451 * 92765, 0.8549 * 92765]],
                     [[0.202 * 797, 0.798 * 797], [0.1475 * 71756, 0.8525 * 71756]]])
    assert np.array_equal(agreeing_pools(sums, 0, PRIOR), np.broadcast_to(sums.sum(axis=0), sums.shape))



def test_an_objects_plateaus_do_not_move_with_another_phase_beside_it():
    """Two spheres in one matrix (5 at.% Al): A (4 nm, 30 at.% Al) and B (3.5 nm) of A's phase or of another at 60
    at.%, on the same ions (only B's drawn again). With every object's windows pooled (as the placement's plateaus
    were), B's phase moved A's inside level by 0.060, seven of its standard errors; A pools only with windows that
    agree with its own, so B moves it by less than one, and it stays within two of the truth either way."""
    rng = np.random.default_rng(3)
    n = 75_000  # 20 per nm³ in the 26 x 12 x 12 nm box
    positions = rng.uniform([-13.0, -6.0, -6.0], [13.0, 6.0, 6.0], (n, 3))
    draw = rng.random(n)
    in_a = sphere_distance(positions, 4.0, (-7.0, 0.0, 0.0)) > 0
    in_b = sphere_distance(positions, 3.5, (7.0, 0.0, 0.0)) > 0
    a, b = icosphere(4.0, 4, (-7.0, 0.0, 0.0)), icosphere(3.5, 4, (7.0, 0.0, 0.0))
    mesh = TriMesh(np.vstack([a.vertices, b.vertices]), np.vstack([a.faces, b.faces + len(a.vertices)]))
    inside, sigma = {}, 0.0
    for phase in (0.30, 0.60):
        f = np.where(in_a, 0.30, np.where(in_b, phase, 0.05))
        ions = IonTable(positions.astype(np.float32), np.where(draw < f, 27.0, 56.0).astype(np.float32))
        level = object_levels(mesh, ions, RANGES, "Al")[0]
        inside[phase] = level.inside[level.elements.index("Al")]
        sigma = np.sqrt(0.3 * 0.7 / level.n_inside)
        assert abs(inside[phase] - 0.30) < 2 * sigma, (phase, inside[phase], sigma)
    assert abs(inside[0.60] - inside[0.30]) < sigma, (inside, sigma)
