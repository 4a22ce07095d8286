"""Moving an iso-surface onto the interface the ions show: normal displacement to the profile's midpoint.

Method
------
Each outer iteration:

1. Every ion within reach is assigned to its nearest vertex and gets its signed distance ``d``
   to the faces around that vertex, i.e. to the mesh itself (:mod:`apt_filters.refine.band`;
   not the offset along the vertex normal: on a convex surface the faces lie below the vertex's
   tangent plane, so that offset sees the interface inside the mesh and the vertices walk
   inward, -0.02 nm along cube edges, -0.03 nm at corners, and the faces' chord deficit stays).
   The ions within reach are
   selected once for the whole refinement, chunk by chunk (:class:`~apt_filters.refine.band.NearIons`;
   the cross-fit's halves, the held-out ions and the segregant's peak are subsets of them; faces that move
   beyond the selection's margin get their ions added, :meth:`~apt_filters.refine.band.NearIons.cover`),
   and their nearest vertices followed as the mesh moves by walking its edges (:mod:`apt_filters.refine.nearest`).
2. Each object's plateaus (inside and outside, ``plateau_window`` nm from its surface, see
   :data:`REFINE_WINDOW`; an open object's reach farther, as far as its ions' midpoint stays flat,
   :func:`_window_edges`) give the score weights
   (:func:`~apt_filters.refine.composition.contrast_weights`: only elements whose plateaus
   differ significantly) and the score's two levels ``s_in`` and ``s_out``. With
   ``cross_fit=True`` (default) they are measured once, before the iterations, on ions that did not place
   the surface they are measured against: the even and the odd ions each place a surface of their own
   (the same iterations), and each half's windows are counted against the other half's surface (a closed
   object a half turned inside out against its start, :func:`_right_side_out`);
   with ``cross_fit=False`` they are measured again in every iteration against the current surface,
   which reads the inside plateau high (the surface's own noise selects the ions).
3. Per vertex, the profile of the score fraction in bins of ``d`` over ``[-half_width, half_width]``
   is pooled with the vertices within ``pool_radius`` (Gaussian weights). Its crossing of the
   midpoint is estimated by the equal-area (Gibbs) rule: with ``u = (f - s_out) / (s_in - s_out)``,
   the offset is ``t = sum(u) * bin_width - half_width``. The rule uses every ion of the profile,
   is unbiased for any symmetric blur, and is exact for a step; bins without ions take the step's
   value on their side.
4. The offsets are clamped to ``max_step``, smoothed ``smoothing`` times by the umbrella
   Laplacian (bilateral, with normals averaged over ``normal_smoothing`` passes; the regularisation: noise cannot roughen the surface faster than neighbours
   agree; fewer passes at creases, so that cube edges and corners come out), and each vertex moves along its normal
   (full steps for ``full_steps`` iterations, then damped); a tangential relaxation then evens out the
   triangles without changing the shape.

After the iterations (each step can be switched off):

5. Each closed object's smoothness (``select_modes``, :mod:`apt_filters.refine.crossval`): the two half
   surfaces of the cross-fit, low-passed in their manifold harmonics (:mod:`apt_filters.refine.spectral`)
   to 4-36 modes and finished as below, are scored on the other half's ions; the object keeps the
   fewest modes within one standard error of the best. A 3 nm sphere keeps 4-9 (its noise and the
   start's grid pattern at degrees 2-8 go), a cube 4-36 (the facets then rebuild its edges). Each open
   object (an interface leaving the specimen, a bicontinuous structure, an object cut by the edge) is
   low-passed with its rim held at the length the held-out ions choose
   (:func:`~apt_filters.refine.crossval.cross_validated_lengths`), its start smoothed first below the
   length the iterations smooth their moves over (:func:`~apt_filters.refine.crossval.open_start`).
6. The blur's curvature bias (:mod:`apt_filters.refine.blur`, ``blur``): a blurred interface's midpoint
   lies ``(1/2) tr(Sigma S)`` inside a convex surface, ~0.02 nm on a 3 nm sphere; each vertex moves
   out by that much. By default the lateral blur is read off the ions (the profile width's orientation
   dependence): the peak of the species left out of the basis where they peak at the surface (segregants:
   a quarter of the scatter), else the score's step. With it, on the final surface, blur or none, the flat
   faces' sag: the vertices lie on the interface and the faces between them ``(1/2) tr(C S)`` inside, ``C`` the
   faces' second moment (:func:`~apt_filters.refine.blur.face_covariance`; 4-6 % of a thin rod's volume at its
   ~0.6 nm edges).
7. The segregant's mark (:mod:`apt_filters.refine.marker`, ``marker``): where the species the basis leaves
   out peak at the surface, each object's peak centre is a second reading of where its interface lies,
   from ions the step never counted; combined with the step's by their errors (the layer's common offset
   from the midpoint fitted, not assumed), each object moves out by the difference, along with its facets'
   planes.
8. Sharp edges and corners (:mod:`apt_filters.refine.facets`, ``facets``): where planar facets of an
   object are found (on the surface as the iterations left it), and refitted to its ions where they close
   it (a blurred convex polyhedron, opposite faces parallel), the rounded rims between them move onto
   the envelope of the facets' planes, one vertex onto each corner and a row of vertices along each edge.

Every move is guarded: a face whose normal would turn by more than 90° in one move, or an
edge whose two faces would fold (normals more than 120° apart, :func:`folded_pairs`), halves the
move of its vertices, up to ``GUARD_HALVINGS`` times, and then cancels it. The guard keeps folds
it is given, so the input's folds are removed first (:func:`~apt_filters.refine.untangle.unfold`);
crossings of faces farther apart, and any fold left, are smoothed away at the end
(:func:`~apt_filters.refine.untangle.untangle`). ``RefineResult.folded_pairs`` and
``self_intersections`` measure the output (0 on every benchmark specimen).

Peak memory: one chunk of the ion table at a time (it may be memory-mapped), then the ions within
``max(plateau_window[1], half_width) + 1 + RESELECT`` nm of the surface (``OPEN_REACH + 1 + RESELECT``, 11.5 nm,
where it has an open object): rows (int64), positions (float64),
nearest vertex (int64) and atoms per element and per basis element (float32), 40 + 4 (k + K) bytes per ion,
their halves and held-out subsets (as much again at most); the triangle grid
of the distance engine (:mod:`apt_filters.core.distance`, ~170 bytes per triangle) and a few (vertices × bins)
float64 arrays.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import csr_matrix, diags
from scipy.spatial import cKDTree

from apt_filters.core.checks import folded_pairs, self_intersecting_faces
from apt_filters.core.mesh import TriMesh, face_normals, topology, vertex_normals
from apt_filters.core.threads import on_threads, per_item, serial_blas
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.band import (EXACT, Band, NearIons, Pairs, adjacency, binned, normal_weight, pooled,
                                    profile_reach)
from apt_filters.refine.blur import BlurEstimate, blur_shift, lateral_blur, peak_blur, smoothed_normals
from apt_filters.refine.composition import ObjectScores, object_scores
from apt_filters.refine.crossval import (CANDIDATES, ONE_SE, SCORED, ModeSelection, apply_modes, basis_size,
                                        cross_validated_lengths, cross_validated_modes, object_harmonics,
                                        open_low_pass, open_start)
from apt_filters.refine.facets import (Facet, closes, edge_and_corner_steps, facet_frames, facet_steps, find_facets,
                                      fit_to_ions, judged, missed, slab_fit, slab_pair, slab_side)
from apt_filters.refine.marker import MarkerOffsets, marker_offsets
from apt_filters.refine.subdivide import subdivide
from apt_filters.refine.untangle import unfold, untangle
from apt_filters.refine.levels import (OPEN_REACH, PLATEAU_PRIOR, BallFit, ObjectLevels, agreeing_pools, ball_profile,
                                      chosen_pools, crossing_share, fit_ball, fit_balls, held_out_gain,
                                      levels_from_sums, lobe_weights, object_shapes, object_volumes, open_window_edges,
                                      plateau_sums, plateaus, pooled_profiles, profile_better, profile_levels,
                                      short_of_plateau, split_worth, unmixed_sums, unmixing_shift, window_bias,
                                      window_labels, within_rim)
from apt_filters.voxel import ConcentrationBasis

GUARD_HALVINGS = 6
RESELECT = 1.5
"""nm a vertex may move before the ions near the surface are selected again."""
FOLD_ANGLE = 120.0
BALL_SE = 2.0
"""Standard errors by which the held-out gain of an object's ball profile over its flat windows must exceed zero
for ``curved_levels`` to unmix it: a one-sided two-sigma test (the windows, the simpler model, wrongly replaced
~2 % of the time). An unmixed object's levels move by several points of volume, so a chance gain must not choose
it: at one standard error (the mode selection's rule, :data:`~apt_filters.refine.crossval.ONE_SE`) objects whose
windows were right were unmixed at gains of 1.4-1.9 standard errors and came out beyond their counting error
(held-out ``thin`` 10005, ``rod`` 10025). Windows that the fitted ball says fall short of their plateau by more than
their own counting error (:func:`~apt_filters.refine.levels.short_of_plateau`) are not right: for them one standard
error suffices (``curved_levels``)."""
REFINE_WINDOW = (1.0, 3.0)
"""nm from the surface between which the refinement measures each object's plateaus (``plateau_window``);
the reported plateaus (:data:`apt_filters.refine.levels.PLATEAU_WINDOW`, 0.75-3 nm) keep the wider window."""


@dataclass(frozen=True)
class RefineParams:
    """Every setting of :func:`refine_surface`, checked once (``ValueError`` in one line for a value outside its
    range or an invalid combination). The defaults are the ones the benchmarks measured (docs/refine.md).

    Profile (each vertex's composition profile across the interface)

    half_width : float, nm, [0.5, 5]
        Profile range each side of the current surface. It should hold ~5 profile widths: a curved interface's
        blurred profile has a longer tail inside, and cut short it loses part of the curvature shift the blur
        correction then adds back (a dense 3 nm sphere under an isotropic 0.45 nm blur: shift -4.2 % of the
        volume at 1.5 nm, -7.1 % at 2.5 nm, theory -6.75 %; under the gamma-prime blur 1.5 nm keeps it).
    bin_width : float, nm, [0.05, half_width / 2]
        Profile bins.
    pool_radius : float, nm, [0, 10]
        Vertices within this distance pool their profiles (Gaussian weights, sigma = radius / 2).
    normal_power : float, [0, 64]
        Bilateral factor of pooling and smoothing, ``max(0, n_i . n_j) ** normal_power``
        (:func:`~apt_filters.refine.band.normal_weight`); 0 pools across edges, which rounds them.
    plateau_window : (inner, outer) nm, 0 <= inner < outer <= 20
        Distances from the surface between which each object's plateaus are measured. The inner edge lies
        beyond the matched filter's reach (two profile widths, ~0.7 nm), so the ions that place the surface
        barely take part in measuring its plateaus: at 0.75 nm the windows follow the surface's own noise
        (gamma-prime, 12 precipitates: inside plateau +0.98 at.%, surfaces ~0.04 nm inside); at 1.0 nm
        +0.24 at.%, and the cross-fit removes the rest. An open object's outer edge is widened from ``outer``
        in shells as wide as the window, up to :data:`~apt_filters.refine.levels.OPEN_REACH`, as far as its
        ions' midpoint stays flat (:func:`_window_edges`).
    plateau_prior : float, atoms, [0, 1e9]
        Weight of the pooled plateaus of all objects in each object's own (see
        :func:`~apt_filters.refine.levels.object_levels`): a 3 nm sphere holds only ~300 atoms in its window. The
        final levels pool only objects whose windows agree (:func:`~apt_filters.refine.levels.agreeing_pools`).
    score : {"contrast", "species"}
        Profile of every element weighted by its contrast (:func:`~apt_filters.refine.composition.contrast_weights`),
        or of the iso-surface species alone.
    distance : {"mesh", "tangent"}
        Each ion's profile coordinate: its signed distance to the faces around its nearest vertex, or its offset
        along that vertex's normal (biased inward on convex surfaces: -0.02 nm at cube edges; for comparison).

    Iterations

    iterations : int, [0, 1000]
        At most this many; they stop when no vertex moves more than ``tolerance``.
    far_iterations : int, [0, iterations]
        Iterations that use the equal-area rule (robust far from the interface); later ones use the matched
        filter with each object's measured profile width.
    full_steps : int, [1, 1000]
        Iterations whose moves are the full (smoothed) offsets; iteration ``k`` after them moves
        ``full_steps / k`` of it (Robbins-Monro): it keeps a small sphere from following its noise. 4: gamma-prime
        seeds 1-5 all better by 0.2-0.6 points of volume and area than 3; full steps throughout do better on cubes
        but roughen 3 nm spheres.
    max_step : float, nm, (0, 5]
        Largest move per iteration.
    tolerance : float, nm, [0, 1]
        Convergence: largest move of an iteration (times its gain).

    Regularisation

    smoothing : int, [0, 100]
        Umbrella-Laplacian passes (bilateral) over each iteration's offsets: noise cannot roughen the surface
        faster than neighbours agree.
    crease_angle : float, degrees, [0, 180]
    crease_smoothing : int, [0, smoothing]
        Vertices whose smoothed normal differs by more than ``crease_angle`` from a neighbour's (cube edges and
        corners as they form; not a 3 nm sphere, ~10° between neighbours) get ``crease_smoothing`` passes
        instead: gamma-prime seeds 1-3, corners -0.130 -> -0.105 nm, volume 5.7 -> 5.6 % mean abs.
    normal_smoothing : int, [0, 100]
        Umbrella passes over the vertex normals used for the bilateral weights and the moves (the raw normals
        of a marching-cubes mesh keep its roughness).
    tangential : float, [0, 1]
        Weight of the tangential relaxation per iteration (evens out triangles without changing the shape).
    subdivisions : int, [0, 3]
        Midpoint subdivisions of the input first: each halves the edge length, so that edges and corners can form.
    relax_start : int, [0, 1000]
        Rounds of guarded tangential relaxation of the subdivided input (fewer sliver triangles, whose flips
        the fold guard would otherwise cancel vertex by vertex).

    Stages after the iterations

    cross_fit : bool
        Measure the plateaus on ions that did not place the surface they are measured against (each half of the
        ions, even and odd rows, places a surface of its own; each half's windows are counted against the other
        half's surface). Against the same ions' surface the inside plateau reads high (gamma-prime seeds 1-5,
        20 objects: +0.35 +- 0.12 at.% Al, cross-fitted +0.03 +- 0.14). Costs two placements of half the ions.
    curved_levels : bool
        With ``cross_fit``: take out of each closed object's cross-fitted windows the share of its interface they
        hold (:func:`_curved_levels`): the interface of a ball of the object's volume, area and curvature
        (:func:`~apt_filters.refine.levels.object_shapes`), blurred (:func:`~apt_filters.refine.levels.ball_profile`),
        its offset and own width fitted to the object's profile. Where an object's half-thickness is not several
        interface widths its windows never reach its phases (the inside one reads low, the outside one high),
        and its midpoint level, and its surface, move out. Each object's unmixed windows are used only where the
        ball's profile fitted on one half of the cross-fit predicts the other half's window ions better than
        that half's flat windows (:func:`~apt_filters.refine.levels.held_out_gain`, both folds), and moved toward
        them by the share of the shift that is estimated bias (:func:`~apt_filters.refine.levels.unmixing_weight`:
        0 where the unmixed level is not expected the nearer the truth; a weight, not a hard choice, whose own
        variance the levels' worth carries); the objects so unmixed are shrunk
        toward every object's levels as chosen, the others toward every object's windows (``plateau_prior``; each
        only toward the objects that agree with it, :func:`~apt_filters.refine.levels.agreeing_pools`). The model's
        ions are measured a second time, with exact distances.
    select_modes : bool
        Low-pass each closed object to the number of manifold harmonics that best predicts held-out ions
        (two-fold cross-validation on the cross-fit's halves, :mod:`apt_filters.refine.crossval`); needs
        ``cross_fit``.
    blur : (lateral, depth) nm >= 0, "auto" or None
        Reconstruction blur whose curvature bias ``(1/2) tr(Sigma S)`` is undone (:mod:`apt_filters.refine.blur`).
        ``"auto"``: the lateral sigma read off the ions (the profile width's orientation dependence, of a
        segregant's peak where one peaks at the surface, else of the score's step; depth 0; no correction where
        the orientations allow no estimate). None or zeros: no correction.
    facets : bool
        Rebuild sharp edges and corners where planar facets of an object meet, on planes fitted to its ions where
        they close it (:mod:`apt_filters.refine.facets`).
    marker : bool
        Where the ranged species the basis leaves out (segregants) peak at an object's surface, combine that
        peak's reading of its offset with the step's (:mod:`apt_filters.refine.marker`; needs two objects).
        Gamma-prime seeds 1-8: 31 of 32 volumes within 5 % (25 without).
    """

    half_width: float = 1.5
    bin_width: float = 0.25
    pool_radius: float = 2.0
    normal_power: float = 8.0
    plateau_window: tuple[float, float] = REFINE_WINDOW
    plateau_prior: float = PLATEAU_PRIOR
    score: str = "contrast"
    distance: str = "mesh"
    iterations: int = 12
    far_iterations: int = 2
    full_steps: int = 4
    max_step: float = 0.5
    tolerance: float = 0.02
    smoothing: int = 10
    crease_angle: float = 20.0
    crease_smoothing: int = 6
    normal_smoothing: int = 2
    tangential: float = 0.3
    subdivisions: int = 1
    relax_start: int = 10
    cross_fit: bool = True
    curved_levels: bool = True
    select_modes: bool = True
    blur: tuple[float, float] | str | None = "auto"
    facets: bool = True
    marker: bool = True

    def __post_init__(self):
        if not isinstance(self.plateau_window, tuple):
            object.__setattr__(self, "plateau_window", tuple(self.plateau_window))
        if isinstance(self.blur, list):
            object.__setattr__(self, "blur", tuple(self.blur))
        problem = _problem(self)
        if problem:
            raise ValueError(f"RefineParams: {problem}")


_RANGES = {"half_width": (0.5, 5.0), "bin_width": (0.05, 2.5), "pool_radius": (0.0, 10.0), "normal_power": (0.0, 64.0),
           "plateau_prior": (0.0, 1e9), "iterations": (0, 1000), "far_iterations": (0, 1000), "full_steps": (1, 1000),
           "max_step": (1e-6, 5.0), "tolerance": (0.0, 1.0), "smoothing": (0, 100), "crease_angle": (0.0, 180.0),
           "crease_smoothing": (0, 100), "normal_smoothing": (0, 100), "tangential": (0.0, 1.0),
           "subdivisions": (0, 3), "relax_start": (0, 1000)}
_INTEGERS = {"iterations", "far_iterations", "full_steps", "smoothing", "crease_smoothing", "normal_smoothing",
             "subdivisions", "relax_start"}


def _problem(p: RefineParams) -> str:
    """What is wrong with ``p`` in words ('' if nothing)."""
    for name, (lo, hi) in _RANGES.items():
        value = getattr(p, name)
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            return f"{name} must be a number, got {value!r}"
        if name in _INTEGERS and int(value) != value:
            return f"{name} must be a whole number, got {value!r}"
        if not lo <= value <= hi:
            return f"{name} must lie in [{lo:g}, {hi:g}], got {value!r}"
    for name in ("cross_fit", "curved_levels", "select_modes", "facets", "marker"):
        if not isinstance(getattr(p, name), bool):
            return f"{name} must be True or False, got {getattr(p, name)!r}"
    window = p.plateau_window
    if len(window) != 2 or not all(np.isfinite(window)) or not 0.0 <= window[0] < window[1] <= 20.0:
        return f"plateau_window must be (inner, outer) nm with 0 <= inner < outer <= 20, got {window!r}"
    if p.bin_width > p.half_width / 2:
        return f"bin_width {p.bin_width:g} nm leaves fewer than 4 bins over +-half_width {p.half_width:g} nm"
    if p.far_iterations > p.iterations:
        return f"far_iterations ({p.far_iterations}) exceeds iterations ({p.iterations})"
    if p.crease_smoothing > p.smoothing:
        return f"crease_smoothing ({p.crease_smoothing}) exceeds smoothing ({p.smoothing})"
    if p.score not in ("contrast", "species"):
        return f"score must be 'contrast' or 'species', got {p.score!r}"
    if p.distance not in ("mesh", "tangent"):
        return f"distance must be 'mesh' or 'tangent', got {p.distance!r}"
    if p.select_modes and not p.cross_fit:
        return "select_modes needs cross_fit (its held-out ions are the cross-fit's halves)"
    blur = p.blur
    if not (blur is None or blur == "auto" or (isinstance(blur, tuple) and len(blur) == 2
                                               and all(np.isfinite(blur)) and min(blur) >= 0)):
        return f"blur must be (lateral, depth) sigmas >= 0 nm, 'auto' or None, got {blur!r}"
    return ""


@dataclass
class StageReport:
    """What one stage of :func:`refine_surface` did.

    Attributes
    ----------
    name : str
        ``prepare`` (subdivision, unfolding, relaxation), ``cross_fit`` (two half placements and the plateaus
        from them), ``place`` (the iterations), ``modes``, ``lengths`` (open objects), ``blur_and_marker``,
        ``facets``, ``untangle``.
    moved : int
        Vertices the stage moved by more than 1e-6 nm.
    mean_move, max_move : float, nm
        Mean and largest distance a vertex moved in the stage.
    iterations : int
        Iterations (place, cross_fit: the most of either half) or rounds (untangle); 0 where there are none.
    seconds : float
        Wall time.
    note : str
        What it decided, in words (modes kept, blur used, facets found).
    """

    name: str
    moved: int = 0
    mean_move: float = 0.0
    max_move: float = 0.0
    iterations: int = 0
    seconds: float = 0.0
    note: str = ""

    @classmethod
    def between(cls, name: str, before: np.ndarray, after: np.ndarray, since: float, iterations: int = 0,
                note: str = "") -> "StageReport":
        """The report of a stage that took the vertices from ``before`` to ``after`` (same count), started at
        ``since`` (``time.perf_counter()``)."""
        move = np.sqrt(np.sum((after - before) ** 2, axis=1)) if len(before) == len(after) else np.zeros(0)
        return cls(name, int(np.count_nonzero(move > 1e-6)), float(move.mean()) if len(move) else 0.0,
                   float(move.max()) if len(move) else 0.0, int(iterations), time.perf_counter() - since, note)


@dataclass
class RefineResult:
    """The refined surface and what the refinement did.

    Attributes
    ----------
    mesh : TriMesh
        Same faces as the input, vertices moved; ``vertex_scalars["displacement"]`` is each
        vertex's total signed move along its normals (nm, positive outward).
    levels : list of ObjectLevels
        Each object's plateaus and midpoint iso-value (``plateau_window``, ``plateau_prior``): the
        cross-fitted ones the surface was placed with (``cross_fit``; a thin object's inside level at the share
        of its profile's that its placement crosses at, :func:`_curved_levels`), or else measured against
        the refined surface with the same ions (biased: see ``cross_fit``).
    displacement : dict
        ``mean``, ``rms``, ``max_abs`` of the total signed normal displacement (nm), and
        ``last_step_max`` (nm), the largest move of the final iteration (convergence).
    iterations : int
    folded_pairs : int
        Edge-adjacent face pairs folded (normals > 120° apart) in the output: 0 by construction.
    self_intersections : int
        Faces crossing another face in the output (0 unless :func:`untangle` gave up).
    guarded : int
        Vertex moves the fold guard had to shorten or cancel, summed over iterations.
    untangle_rounds : int
        Rounds :func:`~apt_filters.refine.untangle.untangle` needed (0: no intersection).
    score : str
    basis : str
        ``ConcentrationBasis.describe()`` of the fractions.
    history : list of float
        Largest move (nm) of each iteration.
    blur : (lateral, depth) float, nm
        Blur whose curvature bias was undone ((0, 0): none).
    facets : int
        Planar facets found (:func:`~apt_filters.refine.facets.find_facets`), all objects together.
    sharpened : int
        Vertices moved onto the envelope of their facets' planes (edges and corners).
    blur_estimate : BlurEstimate or None
        The lateral blur read off the ions (``blur="auto"``), None if not estimated.
    modes : ModeSelection or None
        Manifold harmonics kept per closed object and the held-out losses behind the choice
        (``select_modes``), None if not selected.
    widths : (c,) float64, nm
        Each object's profile width (error-function sigma) in the last iteration.
    offset_errors : (c,) float64, nm
        Counting-statistics standard error of each object's mean offset along its normals, from the
        Fisher information of its score profile (NaN for objects without both plateaus), combined with its
        segregant's peak where ``marker`` moved it, and its own plateau levels' counting error
        (:func:`_level_offset_errors`); times the object's area it is that of its volume. From
        the score alone, on the gamma-prime specimen 0.035-0.041 nm for a 3 nm sphere (3.5-4.1 % of its
        volume), against the Cramér-Rao floor of all the element profiles with the truth known, 0.036 nm
        (:func:`~apt_filters.truth.counting_floor`).
    marker : MarkerOffsets or None
        Each object's segregant peak, the layer's common offset and the moves (``marker``), None where no
        species left out of the basis is ranged or ``marker=False``.
    params : RefineParams
        The settings it ran with.
    stages : list of StageReport
        What each stage did (vertices moved, iterations, time, a note).
    shape_errors : (c, 2) float64, nm³ and nm²
        Of each faceted object (facets kept on either half's surface): the standard errors of its volume and
        area from the two cross-fit halves, each finished as the whole is (its modes, its facets), ``|X_0 -
        X_1| / 2`` (each half holds half the ions: twice the variance of the whole). Which facets a surface
        finds, and so how many of its edges are rebuilt, is a discrete decision whose spread an offset's
        counting error does not hold (:func:`~apt_filters.analysis.objects.counting_errors` takes the larger
        of the two). NaN for other objects, and without ``cross_fit`` and ``select_modes``.
    """

    mesh: TriMesh
    levels: list[ObjectLevels]
    displacement: dict
    iterations: int
    folded_pairs: int
    self_intersections: int
    guarded: int
    untangle_rounds: int
    score: str
    basis: str
    history: list[float] = field(default_factory=list)
    blur: tuple[float, float] = (0.0, 0.0)
    facets: int = 0
    sharpened: int = 0
    blur_estimate: BlurEstimate | None = None
    modes: ModeSelection | None = None
    widths: np.ndarray = field(default_factory=lambda: np.zeros(0))
    offset_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    marker: MarkerOffsets | None = None
    params: RefineParams = field(default_factory=RefineParams)
    stages: list[StageReport] = field(default_factory=list)
    shape_errors: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


def umbrella(adj: csr_matrix, normals: np.ndarray | None = None, normal_power: float = 0.0) -> csr_matrix:
    """Row-normalised adjacency: ``umbrella(adj) @ x`` is the (normal-weighted) mean of each vertex's neighbours.

    With ``normals``, neighbour ``j`` of ``i`` weighs :func:`normal_weight` (bilateral: smoothing
    does not carry across sharp edges).
    """
    if normals is not None and normal_power > 0:
        coo = adj.tocoo()
        adj = csr_matrix((coo.data * normal_weight(normals, coo.row, coo.col, normal_power), (coo.row, coo.col)),
                         shape=adj.shape)
    deg = np.asarray(adj.sum(axis=1)).ravel()
    return diags(np.divide(1.0, deg, out=np.zeros_like(deg), where=deg > 0)) @ adj


def creases(adj: csr_matrix, normals: np.ndarray, angle: float) -> np.ndarray:
    """(n,) bool: vertices whose unit normal is more than ``angle`` degrees from some neighbour's."""
    coo = adj.tocoo()
    lowest = np.ones(adj.shape[0])
    np.minimum.at(lowest, coo.row, np.einsum("ij,ij->i", normals[coo.row], normals[coo.col]))
    return lowest < np.cos(np.radians(angle))


def guarded_move(vertices: np.ndarray, faces: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, int]:
    """``vertices + step`` where that folds nothing; offending vertices' steps halved, then cancelled.

    A face is offending when its normal would turn by more than 90° or it would form a folded
    pair (:data:`FOLD_ANGLE`) that the input did not have. After :data:`GUARD_HALVINGS` halvings
    the vertices of offending faces stop (step 0) until none is left: faces whose vertices all
    stand still are unchanged, so the loop ends with no new fold. Returns the new vertices and
    how many vertices had their step shortened. The faces' edge-adjacent pairs and the faces around each vertex
    come from the :func:`~apt_filters.core.mesh.topology` cache of ``faces``.
    """
    topo = topology(faces, len(vertices))
    pairs = topo.face_pairs
    limit = np.cos(np.radians(FOLD_ANGLE))

    def folded(normals: np.ndarray, some: slice | np.ndarray = slice(None)) -> np.ndarray:
        return np.einsum("ij,ij->i", normals[pairs[some, 0]], normals[pairs[some, 1]]) < limit

    before = face_normals(vertices, faces)
    existing = folded(before)
    moved = vertices + step
    after = face_normals(moved, faces)
    # which faces turn over and which pairs fold, kept up to date where a shortened step changes them: each row's
    # dot product is the one a pass over every face or pair gives it (einsum's rows do not depend on one another)
    turned = np.einsum("ij,ij->i", before, after) < 0.0
    folds = folded(after)
    scale = np.ones(len(vertices))
    touched = np.zeros(len(vertices), dtype=bool)
    # the faces that may turn over and the pairs that may newly fold: every one at first; after a halving only the
    # faces it changed and the pairs holding one of them. Any other turned face or new fold was there before the
    # halving with the same normals: its faces offended, so a vertex of each was shortened (and then it changed)
    # or all of them stand still (and they offend no more)
    some, held = np.arange(len(faces)), np.arange(len(pairs))
    attempt = 0
    while True:
        new_folds = held[folds[held] & ~existing[held]]
        bad = np.union1d(some[turned[some]], pairs[new_folds].ravel())
        bad = bad[(scale[faces[bad]] > 0).any(axis=1)]
        if not len(bad):
            return moved, int(touched.sum())
        verts = np.unique(faces[bad])
        touched[verts] = True
        scale[verts] = scale[verts] * 0.5 if attempt < GUARD_HALVINGS else 0.0
        moved[verts] = vertices[verts] + scale[verts, None] * step[verts]
        # only the faces around the shortened steps change, and the pairs holding one of them
        some = topo.faces_around(verts)
        after[some] = face_normals(moved, faces[some])
        turned[some] = np.einsum("ij,ij->i", before[some], after[some]) < 0.0
        held = topo.pairs_of(some)
        folds[held] = folded(after, held)
        attempt += 1


def _centres(n_bins: int, half_width: float, bin_width: float) -> np.ndarray:
    return -half_width + bin_width * (np.arange(n_bins) + 0.5)


def normalised_profile(score: np.ndarray, total: np.ndarray, s_in: np.ndarray, s_out: np.ndarray,
                       half_width: float, bin_width: float) -> np.ndarray:
    """(n, bins) ``u = (f - s_out) / (s_in - s_out)`` of pooled sums (1 inside, 0 outside).

    Bins without ions take the step's value on their side of the current surface.
    """
    step = np.broadcast_to((_centres(score.shape[1], half_width, bin_width) < 0).astype(np.float64), score.shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = (score / total - s_out[:, None]) / (s_in - s_out)[:, None]
    return np.where((total > 0) & np.isfinite(u), u, step)


def profile_width(u: np.ndarray, bin_width: float) -> float:
    """Gaussian width s (nm) of a normalised step profile: ``sqrt(pi) * integral u (1 - u)`` (exact for an
    error-function step; ``u`` clipped to [0, 1]), at least ``bin_width / sqrt(12)``.

    The floor is the binning's own sigma (a box of one bin): a perfectly sharp step reads 0-0.44 bin by the
    integral, depending on where it falls in its bin, ``sqrt(pi) / 6`` bin (= 1.02 ``bin_width / sqrt(12)``) on
    average, so a width below it is not measured (an error-function step averaged over its bins reads +4 % at
    one bin, +11 % at 0.6, +25 % at 0.4, and below 0.3 bin no longer follows its width). A profile clipped by levels
    inside its own range (a thin plate at low contrast, whose normalised ``u`` jumps from above 1 to below 0:
    held-out plate 10010, 0.0004-0.024 nm) would otherwise give the models that divide by the width (the held-out
    losses, the offset errors, the facets' fit) a width of ~0: undefined or overconfident. The matched filter keeps
    its own floor of one bin (:func:`matched_offset` samples its model at the bins' centres).
    """
    u = np.clip(u, 0.0, 1.0)
    return max(float(np.sqrt(np.pi) * np.sum(u * (1 - u)) * bin_width), bin_width / np.sqrt(12))


def equal_area_offset(u: np.ndarray, half_width: float, bin_width: float) -> np.ndarray:
    """(n,) offset (nm, along the normal) of the Gibbs equal-area position of normalised profiles ``u``:
    ``sum(u) * bin_width - half_width``. Unbiased for any symmetric blur; used while far off."""
    return u.sum(axis=1) * bin_width - half_width


def matched_offset(u: np.ndarray, total: np.ndarray, width: np.ndarray, half_width: float,
                   bin_width: float) -> np.ndarray:
    """(n,) Gauss-Newton step of the offset of an error-function step of ``width`` (n,) nm fitted to ``u``.

    Each bin weighs its ions times the model's slope there (the matched filter), the efficient
    estimate near the interface: bins on the plateaus, which only add noise to the equal-area
    rule, get no weight.
    """
    from scipy.special import erfc

    d = _centres(u.shape[1], half_width, bin_width)[None, :]
    s = width[:, None]
    model = 0.5 * erfc(d / (np.sqrt(2) * s))
    slope = np.exp(-0.5 * (d / s) ** 2) / (np.sqrt(2 * np.pi) * s)  # d model / d offset
    den = np.sum(total * slope ** 2, axis=1)
    return np.divide(np.sum(total * slope * (u - model), axis=1), den, out=np.zeros(len(u)), where=den > 0)


@dataclass
class _Placed:
    """Where the iterations left one surface (same faces as the prepared start)."""

    vertices: np.ndarray
    levels: list[ObjectLevels]
    widths: np.ndarray
    normals: np.ndarray
    near: NearIons
    guarded: int
    history: list[float]
    iterations: int


def _prepare(mesh: TriMesh, subdivisions: int, relax_start: int) -> tuple[TriMesh, np.ndarray, csr_matrix]:
    """Subdivided input, its unfolded and relaxed vertices (the iterations' start, and what :func:`untangle`
    falls back on), the umbrella operator."""
    for _ in range(subdivisions):
        mesh = subdivide(mesh)
    vertices, faces = mesh.vertices.astype(np.float64).copy(), mesh.faces
    plain = umbrella(adjacency(faces, len(vertices)))
    # the fold guard keeps the folds it is given: none may be left in the start
    vertices, _ = unfold(vertices, faces, plain)
    for _ in range(relax_start):
        nn = vertex_normals(vertices, faces)
        lap = plain @ vertices - vertices
        lap -= np.einsum("ij,ij->i", lap, nn)[:, None] * nn
        vertices, _ = guarded_move(vertices, faces, 0.5 * lap)
    return mesh, vertices, plain


def _place(vertices: np.ndarray, faces: np.ndarray, near: NearIons, species: str,
           fixed: list[ObjectLevels] | None, p: RefineParams, pairs_near: Pairs, edges: np.ndarray) -> _Placed:
    """The iterations of :func:`refine_surface` (module docstring, steps 1-4 and the guards) from ``vertices``.

    ``near``: the ions within ``reach + RESELECT`` of the start, completed from the ion table where the surface
    moves farther than :data:`RESELECT` (:meth:`~apt_filters.refine.band.NearIons.cover`); ``pairs_near``: the
    profiles' pooling pairs of ``vertices`` (:meth:`~apt_filters.refine.band.Pairs.find` with ``p.pool_radius``;
    one search serves every run from the same start); ``edges``: (c,) nm, the outer edge of each object's plateau
    windows (:func:`_window_edges`; read only where ``fixed`` is None)."""
    vertices = vertices.copy()
    n = len(vertices)
    components = topology(faces, n).vertex_components
    n_comp = int(components.max()) + 1 if n else 0
    adj = adjacency(faces, n)
    plain = umbrella(adj)
    # with the levels fixed no window is counted: the ions within the refinement's own windows' reach serve
    reach = _reach(p, edges if fixed is None else None)
    window = (p.plateau_window[0], edges)
    # the ions beyond the profiles only count in a plateau window (none without measuring plateaus)
    shell = _shell(p, p.half_width, edges.max(initial=p.plateau_window[1]) if fixed is None else np.inf)
    guarded, history, levels = 0, [], []
    widths = np.ones(n_comp)
    beyond = _beyond_rim(vertices, faces, near, reach, p.distance, shell)
    # with the levels fixed only the profiles' ions count (binned within half_width): the band leaves out the ions
    # that cannot be among them (profile_reach), which most of it are; the profiles are the same bit for bit. Not
    # past an open object's rim (the ions beyond it take offsets of their own, _tangent_beyond)
    narrow = fixed is not None and p.distance == "mesh" and p.half_width <= EXACT and not beyond.any()
    it = 0
    for it in range(1, p.iterations + 1):
        normals = vertex_normals(vertices, faces)
        for _ in range(p.normal_smoothing):
            normals = plain @ normals
            normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        within = profile_reach(vertices, faces, p.half_width) if narrow else reach
        # the rim's paraboloids fitted within the profiles' and closed windows' reach, however far an open object's
        # windows reach: the ions beyond a rim lie within a few nm of it laterally
        band = _tangent_beyond(near.cover(vertices, reach).band(vertices, normals, min(within, reach), p.distance,
                                                                shell), beyond, near, vertices, normals, components,
                               _reach(p))
        # measured again every iteration: plateaus measured against a surface still off the interface
        # take interface ions into a window. Pooled with every object's: tested at every iteration of both halves,
        # such windows split where a surface off the interface reads them apart (held-out spinodal 10001: its pieces
        # split in all 26 readings; so placed, its H 0.54 -> 0.56 nm, excess -1.0 -> -1.1 sigma), and the
        # cross-fit's levels, which fix the final placement, pool only the objects that agree
        levels = fixed if fixed is not None else plateaus(band, near.atoms, components, n_comp, species, window,
                                                          p.plateau_prior, agreeing=False)
        scores = object_scores(levels, near.atoms.elements, species, p.score, p.plateau_prior)
        usable = np.append(scores.usable, False)  # last entry: unused vertices (-1)
        s_in, s_out = scores.inside, scores.outside
        ion_score, ion_total = scores.fraction(near.atoms.atoms[band.index], components[band.vertex])
        pairs_near = pairs_near.update(vertices, components)
        mean_of_neighbours = umbrella(adj, normals, p.normal_power)
        raw_s, raw_t = binned(band.vertex, band.distance, (ion_score, ion_total), n, p.half_width, p.bin_width)
        s_sum, t_sum = np.hsplit(pooled(np.hstack([raw_s, raw_t]), vertices, normals, pairs_near, p.normal_power), 2)
        ok = usable[components] & (np.abs(s_in - s_out)[components] > 0)
        u = normalised_profile(s_sum, t_sum, s_in[components], s_out[components], p.half_width, p.bin_width)
        used = components >= 0
        obj_s, obj_t = (np.zeros((n_comp, raw_s.shape[1])) for _ in range(2))
        np.add.at(obj_s, components[used], raw_s[used])
        np.add.at(obj_t, components[used], raw_t[used])
        widths = np.array([profile_width(normalised_profile(obj_s[c:c + 1], obj_t[c:c + 1], s_in[c:c + 1],
                                                            s_out[c:c + 1], p.half_width, p.bin_width), p.bin_width)
                           if usable[c] else 1.0 for c in range(n_comp)])
        offset = np.zeros(n)
        if it <= p.far_iterations:
            offset[ok] = equal_area_offset(u[ok], p.half_width, p.bin_width)
        else:
            offset[ok] = matched_offset(u[ok], t_sum[ok], np.maximum(widths[components[ok]], p.bin_width),
                                        p.half_width, p.bin_width)
        offset = np.clip(offset, -p.max_step, p.max_step)
        crease = creases(adj, normals, p.crease_angle)
        at_crease = offset
        for k in range(p.smoothing):
            offset = np.where(ok, mean_of_neighbours @ offset, 0.0)
            if k + 1 == min(p.crease_smoothing, p.smoothing):
                at_crease = offset
        # fewer passes where the surface bends sharply: a cube's corner needs a larger step than its faces
        offset = np.where(crease, at_crease, offset)
        # full steps first, then Robbins-Monro averaging of the noisy estimates
        gain = min(1.0, p.full_steps / it)
        new, g = guarded_move(vertices, faces, gain * offset[:, None] * normals)
        step = np.einsum("ij,ij->i", new - vertices, normals)
        guarded += g
        vertices = new
        if p.tangential > 0:
            normals = vertex_normals(vertices, faces)
            lap = plain @ vertices - vertices
            lap -= np.einsum("ij,ij->i", lap, normals)[:, None] * normals
            vertices, g = guarded_move(vertices, faces, p.tangential * np.where(ok[:, None], lap, 0.0))
            guarded += g
        history.append(float(np.abs(step).max()) if n else 0.0)
        if history[-1] < p.tolerance * gain:
            break
    near.cover(vertices, reach)
    normals = smoothed_normals(vertices, faces, p.normal_smoothing)
    if fixed is None:
        levels = plateaus(near.band(vertices, normals, reach, p.distance, shell), near.atoms, components, n_comp,
                          species, window, p.plateau_prior, agreeing=False)
    return _Placed(vertices, levels, widths, normals, near, guarded, history, it)


def _shell(p: RefineParams, profile: float, outer: float) -> tuple[float, float] | None:
    """``NearIons.band``'s ``shell`` for a caller that bins distances within ``profile`` nm and counts plateau
    windows (``p.plateau_window``, up to ``outer``): beyond both the profile and the window's inner edge only
    the side and the place relative to ``outer`` matter."""
    lo = max(profile, p.plateau_window[0])
    return (lo, outer) if lo < outer else None


def _reach(p: RefineParams, edges: np.ndarray | None = None) -> float:
    """nm from the surface within which the iterations use ions (profiles and plateau windows; ``edges``: (c,) nm,
    each object's windows' outer edge, :func:`_window_edges`, ``p.plateau_window[1]`` for all where None)."""
    outer = p.plateau_window[1] if edges is None else edges.max(initial=p.plateau_window[1])
    return max(outer, p.half_width) + 1.0


def _window_edges(near: NearIons, start: np.ndarray, faces: np.ndarray, components: np.ndarray, rimmed: np.ndarray,
                  species: str, p: RefineParams) -> np.ndarray:
    """(c,) nm: the outer edge of each object's plateau windows: ``p.plateau_window[1]`` for a closed object, as far
    as its ions are flat for an open one (:func:`~apt_filters.refine.levels.open_window_edges`, on all the ions
    against the start: a surface within a nm of the interface places the shells beyond its window as well as the
    refined one would). ``near``: the ions within :data:`~apt_filters.refine.levels.OPEN_REACH` + 1 nm of
    ``start`` where ``rimmed`` (the open objects) is not empty.

    A closed object keeps its windows: beyond them lie its neighbours, and its levels' choice (``curved_levels``)
    was set on them."""
    n_comp = int(components.max()) + 1 if len(components) else 0
    if not len(rimmed):
        return np.full(n_comp, p.plateau_window[1])
    opened = np.zeros(n_comp, dtype=bool)
    opened[rimmed] = True
    reach = OPEN_REACH + 1.0
    band = within_rim(near.band(start, smoothed_normals(start, faces, p.normal_smoothing), reach, p.distance),
                      near, TriMesh(start, faces), reach)
    return open_window_edges(band, near.atoms, components, opened, near.atoms.elements.index(species),
                             p.plateau_window, OPEN_REACH)


def _beyond_rim(vertices: np.ndarray, faces: np.ndarray, near: NearIons, reach: float, distance: str,
                shell) -> np.ndarray:
    """(len(near.rows),) bool: the ions beyond the rim of an open object of the surface ``vertices``
    (:func:`~apt_filters.refine.levels.within_rim`), found once against the placement's start (the rim moves
    little; found at every iteration the query cost an open interface's refinement 3.5 times its CPU), among the
    ions whose nearest vertex is on the rim (an ion beyond it is nearest an end of the boundary edge it is beyond)."""
    mesh = TriMesh(vertices, faces)
    rim = mesh.boundary_edges()
    if not len(rim):
        return np.zeros(0, dtype=bool)
    on_rim = np.zeros(len(vertices), dtype=bool)
    on_rim[rim.ravel()] = True
    band = near.cover(vertices, reach).band(vertices, vertex_normals(vertices, faces), reach, distance, shell)
    band = Band(*(a[on_rim[band.vertex]] for a in (band.index, band.vertex, band.distance)))
    beyond = np.zeros(len(near.rows), dtype=bool)
    beyond[band.index] = True
    beyond[within_rim(band, near, mesh, reach).index] = False
    return beyond


def _tangent_beyond(band: Band, beyond: np.ndarray, near: NearIons, vertices: np.ndarray, normals: np.ndarray,
                    components: np.ndarray, reach: float) -> Band:
    """``band`` with the ions ``beyond`` the rim (:func:`_beyond_rim`) at their offset from the surface continued
    past the rim: the paraboloid fitted to the positions of their vertex's object within ``reach`` (nm, how far
    from it its ions lie) of it (:func:`_rim_paraboloids`).

    Their distance to the mesh is mostly lateral, to the rim edge (an ion 1 nm beyond the rim and on the interface
    counts 1 nm deep), its side that of the rim's tangent plane: on a cap cut by the specimen edge the matrix
    between that plane and the sphere beyond the rim entered the inside of the rim vertices' profiles. The offset
    from the paraboloid is exact on a flat interface, whose rim keeps its ions (left out, they roughened open
    interfaces' rims), and on a sphere up to the paraboloid's misfit. The vertex's own normal and the normal
    curvatures along its edges would not do: at a rim they are read from faces on one side of the vertex, the normal
    tilted toward the cap and the curvature about half of ``1/R`` (the ions 0.3-1.3 nm past a 4.5 nm sphere's rim
    read 0.058 nm inward on exact truth; from the fit 0.024 outward). The fit reaches as far as the ions it
    continues the surface to: a nearer one reads the placement's noise (a 2-ring fit, exact on exact truth, put the
    cut sphere's ions beyond its rim 0.3-0.5 nm off on average; the faces within 0.5 nm of its rim, draws 5-12:
    -0.10 and -0.07 nm within 1 and 2 nm, -0.03 within 4 nm, -0.085 from the vertex's normal and curvature)."""
    if not beyond.any():
        return band
    out = np.zeros(len(band.index), dtype=bool)
    held = band.index < len(beyond)  # the ions added since (cover) lie near faces that moved, not beyond
    out[held] = beyond[band.index[held]]
    at, which = np.unique(band.vertex[out], return_inverse=True)
    frames, coef = _rim_paraboloids(vertices, normals, components, at, reach)
    local = np.einsum("mij,mj->mi", frames[which], near.positions[band.index[out]] - vertices[at][which])
    height = np.einsum("mi,mi->m", _quadric_terms(local[:, 0], local[:, 1]), coef[which])
    d = band.distance.copy()
    d[out] = (local[:, 2] - height) / np.sqrt(1 + coef[which, 0] ** 2 + coef[which, 1] ** 2)
    return Band(band.index, band.vertex, d)


def _quadric_terms(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(m, 5) the terms ``x, y, x^2 / 2, x y, y^2 / 2`` of a height field through the origin."""
    return np.column_stack([x, y, 0.5 * x * x, x * y, 0.5 * y * y])


def _rim_paraboloids(vertices: np.ndarray, normals: np.ndarray, components: np.ndarray, at: np.ndarray,
                     radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The paraboloid through each vertex ``at`` fitted by least squares to the positions of the vertices of its
    object (``components``) within ``radius`` nm: (len(at), 3, 3) frames (rows: two tangents and ``normals[at]``)
    and (len(at), 5) coefficients of the height along the normal, ``a x + b y + (A x^2 + 2 B x y + C y^2) / 2``
    (:func:`_quadric_terms`, x and y along the tangents).

    The fit reads the slope and the curvature from the positions around the vertex, not from normals averaged
    over its faces, which at a rim lie on one side of it. A degenerate neighbourhood (collinear, or none) gets the
    least-norm solution: no tilt or bend it does not show."""
    n = normals[at]
    # a tangent: the normal crossed with the axis it is least aligned with
    t1 = np.cross(n, np.eye(3)[np.argmin(np.abs(n), axis=1)])
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    frames = np.stack([t1, np.cross(n, t1), n], axis=1)
    pairs = cKDTree(vertices[at]).sparse_distance_matrix(cKDTree(vertices), radius, output_type="coo_matrix")
    row, col = pairs.row.astype(np.int64), pairs.col.astype(np.int64)
    keep = (components[col] == components[at[row]]) & (col != at[row])
    row, col = row[keep], col[keep]
    local = np.einsum("mij,mj->mi", frames[row], vertices[col] - vertices[at[row]])
    terms = _quadric_terms(local[:, 0], local[:, 1])
    normal = np.empty((len(at), 5, 5))
    for i in range(5):
        for j in range(i, 5):
            normal[:, i, j] = normal[:, j, i] = np.bincount(row, terms[:, i] * terms[:, j], len(at))
    rhs = np.column_stack([np.bincount(row, terms[:, i] * local[:, 2], len(at)) for i in range(5)])
    return frames, np.einsum("mij,mj->mi", np.linalg.pinv(normal, hermitian=True), rhs)


def _against(near: NearIons, vertices: np.ndarray, radius: float) -> NearIons:
    """The ions of ``near`` (completed from the table where needed) whose nearest vertex of ``vertices`` (the same
    mesh, moved) lies within ``radius``, assigned to it."""
    return near.cover(vertices, radius).subset(np.arange(len(near.rows)), vertices, radius)


def _right_side_out(fit: _Placed, start: np.ndarray, faces: np.ndarray, components: np.ndarray, closed: np.ndarray,
                    p: RefineParams) -> _Placed:
    """``fit`` with each closed object that its half placement turned inside out (signed volume of the other sign
    than the start's) put back at the start.

    A small start (a sphere's first contour at a third of its volume) holds a handful of ions in its inside window,
    and a half placement's levels read on them can invert its step (inside 0.000 of 3 atoms): the object collapses
    through itself. The cross-fit would then read the matrix around it as its inside window (twin sphere 1 nm from
    the side, ions seed 4: Al 0.101 inside, 0.094 outside; truth 0.30, 0.09) and the placement with those levels
    swell the object to the specimen's side (V +126.8 %). The start's inside is the object's, whatever its size."""
    n_comp = len(closed)
    flipped = closed & (object_volumes(fit.vertices, faces, components, n_comp)
                        * object_volumes(start, faces, components, n_comp) < 0)
    if not flipped.any():
        return fit
    back = (components >= 0) & flipped[np.maximum(components, 0)]
    vertices = np.where(back[:, None], start, fit.vertices)
    return replace(fit, vertices=vertices, normals=smoothed_normals(vertices, faces, p.normal_smoothing))


def _cross_fitted_levels(fits: list[_Placed], faces: np.ndarray, held: list[NearIons], species: str,
                         p: RefineParams, closed: np.ndarray, edges: np.ndarray) -> list[ObjectLevels]:
    """Each object's plateaus from the even ions against the odd ions' surface plus the odd ions against the
    even ions' (see ``cross_fit`` of :class:`RefineParams`); ``held[k]``: the ions of half ``k`` assigned to the
    other half's surface; ``closed``: the objects without a rim (``curved_levels`` unmixes theirs); ``edges``: (c,)
    nm, the outer edge of each object's windows (:func:`_window_edges`)."""
    components = topology(faces, len(fits[0].vertices)).vertex_components
    n_comp = int(components.max()) + 1 if len(components) else 0
    outer = edges.max(initial=p.plateau_window[1])
    reach = outer + 1.0
    window = (p.plateau_window[0], edges)
    # the model's bands with exact distances for every ion (the interface's share of each window ion is modelled);
    # the windows' sums stay those of the bounded distances, so that an object that keeps them keeps its levels.
    # Both from one pass over each half's ions
    curved = p.curved_levels and closed.any()
    sums, bands, windows_of = 0.0, [], []
    for k in (0, 1):
        other = fits[1 - k]
        args = (other.vertices, other.normals, reach, p.distance, _shell(p, 0.0, outer))
        band, exact = held[k].bands(*args) if curved else (held[k].band(*args), None)
        # the ions beyond an open object's rim are on neither side of it (within_rim): an object cut by the specimen
        # edge took the matrix beyond its rim into its inside window (edge draw 31: 811 of 3,736 atoms truly
        # outside, its level 0.47 for 0.55, its surface inflated by 0.09 nm)
        band = within_rim(band, held[k], TriMesh(other.vertices, faces), reach)
        sums = sums + plateau_sums(band, held[k].atoms, components, n_comp, window)
        bands.append(exact)
        windows_of.append(band)
    sums = np.asarray(sums).reshape(n_comp, 2, -1)
    k = held[0].atoms.elements.index(species)
    sums = _lobe_weighted(sums, windows_of, held, components, k, window, p.plateau_window[1])
    windows = agreeing_pools(sums, k, p.plateau_prior)
    if not curved:
        return levels_from_sums(sums, held[0].atoms.elements, species, p.plateau_prior, windows)
    unmixed, chosen, balls, share, shared, bias = _curved_levels(fits, faces, held, bands, sums, windows, species, p,
                                                                 closed)
    best = np.where(chosen[:, None, None], unmixed, sums)
    pooled = chosen_pools(windows, best, chosen, balls, shared, k, p.plateau_prior)
    levels = levels_from_sums(best, held[0].atoms.elements, species, p.plateau_prior, pooled)
    _count_bias(levels, bias, k)
    # a thin object is placed where its step, taken at this share of its inside level, stops at its interface
    for c in np.flatnonzero(share != 1.0):
        lv = levels[c]
        lv.inside = lv.outside + share[c] * (lv.inside - lv.outside)
        lv.iso = float(0.5 * (lv.inside + lv.outside)[held[0].atoms.elements.index(species)])
    return levels


def _count_bias(levels: list[ObjectLevels], bias: np.ndarray, k: int) -> None:
    """Each object's inside level's worth (:attr:`~apt_filters.refine.levels.ObjectLevels.worth_inside`) lowered, in
    place, to count ``bias`` (n_components,) fraction², its estimated squared bias (:func:`_curved_levels`): the
    level is as certain as ``f (1 - f) / (var + bias)`` atoms, its mean squared error (``f`` its fraction of basis
    element ``k``, ``var`` its counting variance), so that the reported errors (:func:`_level_offset_errors`) cover
    a shortfall the level keeps."""
    for c in np.flatnonzero(bias > 0):
        lv = levels[c]
        f = float(lv.inside[k])
        lv.worth_inside = f * (1 - f) / (f * (1 - f) / lv.worth_inside + bias[c])


def _lobe_weighted(sums: np.ndarray, bands: list[Band], held: list[NearIons], components: np.ndarray, k: int,
                   window: tuple, cell: float) -> np.ndarray:
    """``sums`` (:func:`plateau_sums` of both halves' ``bands``) with each inside window ion counted at its
    posterior of lying inside its object rather than in a lobe of matrix the surface holds (:func:`lobe_weights`,
    the two halves' ions pooled into its cubes of ``cell`` nm); ``sums`` itself where no object's window is shown to
    hold one. ``window``: as :func:`~apt_filters.refine.levels.window_labels`'."""
    n_comp = len(sums)
    inside = [(window_labels(band, components[band.vertex], n_comp, window) == 0) & (components[band.vertex] >= 0)
              for band in bands]
    total = sums[:, 1].sum(axis=1)
    outside = np.divide(sums[:, 1, k], total, out=np.zeros(n_comp), where=total > 0)
    weight = lobe_weights(positions=np.concatenate([h.positions[b.index[i]] for h, b, i in zip(held, bands, inside)]),
                          atoms=np.concatenate([h.atoms.atoms[b.index[i]] for h, b, i in zip(held, bands, inside)]),
                          objects=np.concatenate([components[b.vertex[i]] for b, i in zip(bands, inside)]),
                          outside=outside, k=k, cell=cell)
    if np.all(weight == 1.0):
        return sums
    cut = np.cumsum([0] + [int(i.sum()) for i in inside])
    weighted = 0.0
    for h, (band, i) in enumerate(zip(bands, inside)):
        per_ion = np.ones(len(band.index))
        per_ion[i] = weight[cut[h]:cut[h + 1]]
        weighted = weighted + plateau_sums(band, held[h].atoms, components, n_comp, window, per_ion)
    return np.asarray(weighted).reshape(sums.shape)


def _curved_levels(fits: list[_Placed], faces: np.ndarray, held: list[NearIons], bands: list[Band], sums: np.ndarray,
                   pools: np.ndarray, species: str, p: RefineParams,
                   closed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cross-fitted window sums of each closed object with its interface's share taken out
    (:func:`~apt_filters.refine.levels.unmixed_sums`), and which objects the held-out ions choose them for
    (``pools``: what each object's windows are shrunk toward, :func:`~apt_filters.refine.levels.agreeing_pools`).

    Per object: its ball (radius and dimension from the two half surfaces' volume, area and total mean curvature,
    :func:`~apt_filters.refine.levels.object_shapes`), the interface's offset and own width fitted to the iso
    species' profile of the held ions (:func:`~apt_filters.refine.levels.fit_ball`) under the reconstruction blur
    (``blur`` given, or read off the first half's surface as the blur stage reads it, isotropic sigma
    ``sqrt(tr(Sigma) / 3)``), and each window's mean share of the inside phase under that model. The midpoint of
    the unmixed plateaus is the fitted interface's; the placement then puts the surface at the ions' crossing of
    it, and the blur stage moves it out by the blur's curvature bias as before (the model's blur only reads the
    plateaus). An object is unmixed only where the ball's profile fitted on one half predicts the other half's
    window ions better than that half's flat windows do, summed over both folds, by more than :data:`BALL_SE`
    standard errors of that gain (:func:`~apt_filters.refine.levels.held_out_gain`), or by more than one where its
    inside window falls short of its plateau under that ball by more than its own counting error
    (:func:`~apt_filters.refine.levels.short_of_plateau`): the same two-fold
    cross-validation as the mode selection, the windows the simpler model; its windows are then moved toward the
    unmixed levels by the share of their shift that is estimated bias, with the fit's covariance and the
    amplified counts (:func:`~apt_filters.refine.levels.unmixing_shift`,
    :func:`~apt_filters.refine.levels.unmixing_weight`): a fit that does not fix the interface (a thin object at
    low contrast) unmixes by shares it does not know (weight 0), and taken whole the unmixed levels would follow
    the draws whose shift is noise. An object of weight 0 takes its inside level from its whole fitted profile
    (:func:`~apt_filters.refine.levels.profile_levels`) where that is expected nearer the truth than its shrunk
    window's (:func:`~apt_filters.refine.levels.profile_better`; the profile level's worth no greater than the
    spread of the same level read on each half's ions allows, :func:`~apt_filters.refine.levels.split_worth`): a
    thin object, whose
    inside window holds a few atoms of its axis and whose level is then the pool's. Where two or more objects are
    closed they are also fitted together (shared levels, :func:`~apt_filters.refine.levels.fit_balls`): an object
    whose own ball is refused is put to the same tests with the joint ball, and one whose own profile level is
    refused is offered the joint profile level where the joint ball's held-out gain exceeds one standard error and
    its inside window falls short of its plateau by more than its counting error
    (:func:`~apt_filters.refine.levels.short_of_plateau`). Such an object's surface is
    placed where its step, taken at the share of that level its blurred profile calls for, stops at its fitted
    interface (:func:`~apt_filters.refine.levels.crossing_share`).

    Returns
    -------
    unmixed : (n_components, 2, k) float64
        Window sums, moved toward the unmixed levels where chosen (:func:`~apt_filters.refine.levels.unmixed_sums`).
    chosen : (n_components,) bool
    balls : (n_components,) bool
        The objects unmixed (chosen for their ball; the others chosen take their profile's level).
    share : (n_components,) float64
        The share of its inside level at which each object's placement takes its crossing
        (:func:`~apt_filters.refine.levels.crossing_share`; 1 but for the objects whose level is their profile's).
    shared : (k,) float64
        Every closed object's profile level (:func:`~apt_filters.refine.levels.profile_levels`) pooled, times the
        pool's worth in atoms (:func:`~apt_filters.refine.levels.pooled_profiles`): what an unmixed object's inside
        level is shrunk toward.
    bias : (n_components,) float64
        Fraction²: the squared bias of each kept object's shrunk window level as its profile reads it, the positive
        part of ``b^2 - var b`` (:func:`~apt_filters.refine.levels.window_bias`; the joint profile's where the joint
        ball's held-out gain offers it, else its own); 0 for the objects chosen for their ball or profile level,
        whose worth carries their own errors. Only the reported errors take it (:func:`_count_bias`).
    """
    components = topology(faces, len(fits[0].vertices)).vertex_components
    n_comp = len(sums)
    shapes = [object_shapes(f.vertices, faces, components, n_comp) for f in fits]
    radius, dims = 0.5 * (shapes[0][0] + shapes[1][0]), 0.5 * (shapes[0][1] + shapes[1][1])
    blur = p.blur
    if isinstance(blur, str):
        levels = levels_from_sums(sums, held[0].atoms.elements, species, p.plateau_prior)
        scores = object_scores(levels, held[0].atoms.elements, species, p.score, p.plateau_prior)
        # on a copy of the first half's ions: a band reassigns the ions it is drawn from, and the later stages
        # must find the halves' ions as the windows' model found them
        near = fits[0].near.subset(np.arange(len(fits[0].near.rows)), fits[0].vertices)
        estimate = _estimate_blur(near, near.band(fits[0].vertices, fits[0].normals, p.half_width, p.distance),
                                  fits[0].normals, components, scores, p.half_width)
        blur = (estimate.lateral, 0.0) if estimate is not None else None
    sigma = float(np.sqrt((2 * blur[0] ** 2 + blur[1] ** 2) / 3)) if blur else 0.0
    k = held[0].atoms.elements.index(species)
    comp, distance, part, total, window, half, atoms = [], [], [], [], [], [], []
    for fold, (h, band) in enumerate(zip(held, bands)):
        a = h.atoms.atoms[band.index].astype(np.float64)
        c = components[band.vertex]
        comp.append(c)
        atoms.append(a)
        distance.append(band.distance)
        part.append(a[:, k])
        total.append(a.sum(axis=1))
        window.append(window_labels(band, c, n_comp, p.plateau_window))
        half.append(np.full(len(c), fold))
    comp, distance, part, total, window, half = map(np.concatenate, (comp, distance, part, total, window, half))
    atoms = np.concatenate(atoms)
    mixed, weight, worth = np.tile([1.0, 0.0], (n_comp, 1)), np.zeros(n_comp), np.zeros((n_comp, 2))
    chosen = np.zeros(n_comp, dtype=bool)
    balls = np.zeros(n_comp, dtype=bool)
    bias = np.zeros(n_comp)
    share = np.ones(n_comp)
    profiled = {}
    order = np.argsort(comp, kind="stable")
    starts = np.searchsorted(comp[order], np.arange(n_comp + 1))

    def level_of(c: int) -> tuple | None:
        """Object ``c``'s unmixing where the ball is chosen for it (:class:`~apt_filters.refine.levels.Unmixing`,
        None, 1), its profile's inside atoms and crossing share where that level is chosen (None, atoms, share), else
        (None, None, 1); last, its profile's level (:func:`profile_levels`; None where it has none). None where it
        has no fit."""
        mine = order[starts[c]:starts[c + 1]]
        if radius[c] <= 0 or not len(mine):
            return None
        ball = dict(radius=radius[c], dims=dims[c], blur=sigma, half_width=p.plateau_window[1])
        # each half's own ball, fitted once: the held-out gain's two folds and the profile level's halves
        # (halves_of) read the same fits of the same ions
        own = [fit_ball(distance[sel], part[sel], total[sel], **ball)
               for sel in (mine[half[mine] == h] for h in (0, 1))]
        gain = held_out_gain(distance[mine], part[mine], total[mine], window[mine], half[mine], fits=own, **ball)
        fit = fit_ball(distance[mine], part[mine], total[mine], **ball)
        if fit is None:
            return None
        level = profile_levels(distance[mine], atoms[mine], k, fit, **ball)
        # the object's own ball, else the ball fitted with the other objects of its phase (shared levels: a small
        # object's own levels trade off against its interface), each judged on the held-out ions
        candidates = [(gain, fit)]
        if c in joint[2]:
            candidates.append((held_out_gain(distance[mine], part[mine], total[mine], window[mine], half[mine],
                                             fits=(joint[0][c], joint[1][c]), **ball), joint[2][c]))
        # the joint level is offered below only where the held-out ions prefer the joint ball to the windows by the
        # one-standard-error rule (the mode selection's): windows that reach their plateau keep their own level
        # rather than borrow the other objects' atoms (a 4 nm sphere under a sharp interface beside a small one)
        offered = len(candidates) > 1 and candidates[1][0] is not None and \
            candidates[1][0][0] > ONE_SE * candidates[1][0][1]
        for gain, model in candidates:
            if gain is None or gain[0] <= ONE_SE * gain[1]:  # the windows, the simpler model, unless worse
                continue
            unmixing = unmixing_shift(distance[mine], part[mine], total[mine], window[mine], model,
                                      radius=radius[c], dims=dims[c], blur=sigma)
            # windows the ball says fall short of their plateau by more than their own counting error are biased by
            # more than their noise: the ball need then only beat them by the one-standard-error rule, as the joint
            # level is offered below (a lath 3 nm thick under a 0.9 nm interface: windows 89 % inside, gain 1.9 SE,
            # kept whole its level 3.4 points low and its volume +31 %); elsewhere clearly, by BALL_SE
            if gain[0] <= BALL_SE * gain[1] and not short_of_plateau(sums[c, 0], model, unmixing.mixed[0], k):
                continue
            # the windows moved toward the ball's levels where those are expected nearer the truth, by the share of
            # the shift that is bias (a fit that does not fix the interface unmixes by shares it does not know:
            # weight 0); windows that cannot tell the phases apart are left as they are (unmixed_sums keeps them)
            if unmixing.weight > 0 and unmixing.mixed[0] - unmixing.mixed[1] > 0.1:
                return unmixing, None, 1.0, level, 0.0
        # an object not unmixed: its inside level from its whole profile where that is expected nearer the truth
        deep = mine[window[mine] == 0]

        def inside_share(model: BallFit) -> float:  # the inside window's mean share of the inside phase
            return (np.average(ball_profile(distance[deep] - model.offset, radius=max(radius[c] + model.offset, 0.0),
                                            dims=dims[c], width=max(model.width, 0.02), blur=sigma),
                               weights=total[deep]) if total[deep].sum() > 0 else 1.0)

        def halves_of(route: int) -> list:
            """The route's profile level (its own ball's, 0, or the joint balls', 1) on each cross-fit half's ions
            alone, each under that half's own fit (None where a half has none): what :func:`split_worth` checks the
            level's worth against."""
            out = []
            for h in (0, 1):
                if route == 0:
                    sel = mine[half[mine] == h]
                    out.append(None if own[h] is None else profile_levels(distance[sel], atoms[sel], k, own[h], **ball))
                else:
                    sel = np.flatnonzero(some & (half == h))
                    out.append(profile_levels(distance[sel], atoms[sel], k, joint[h], radius=radius, dims=dims,
                                              blur=sigma, half_width=p.plateau_window[1], group=comp[sel])
                               if c in joint[h] else None)
            return out

        # its own profile's level, else the level of every closed object's profile fitted together (shared levels),
        # offered only where its window falls short of its plateau by more than its own counting error: a window
        # at its plateau keeps its level (a level change within its error still moves the surface and what is read
        # off it, its facets and the shared segregant marker, for a gain in precision the windows' shrinkage
        # already takes: dev rod 3's fourth rod, docs/refine.md)
        routes = [(level, fit)]
        if offered and short_of_plateau(sums[c, 0], joint[2][c], inside_share(joint[2][c]), k) and \
                together() is not None:
            routes.append((together(), joint[2][c]))
        for route, (taken, model) in enumerate(routes):
            g_in = inside_share(model)
            if taken is not None and profile_better(split_worth(taken, halves_of(route), k), model, sums[c, 0],
                                                    pools[c, 0], g_in, k, p.plateau_prior):
                return None, taken[0] * taken[1], crossing_share(
                    distance[mine], total[mine], model, radius=radius[c], dims=dims[c], blur=sigma,
                    lift=0.5 * sigma ** 2 * (dims[c] - 1) / max(radius[c] + model.offset, 1e-3),
                    half_width=p.half_width, bin_width=p.bin_width), level, 0.0
        # kept on its windows: its level's error counts the bias its profile reads in them, by the joint profile where
        # the joint ball describes its ions (the objects of one phase share their windows' shortfall, which their
        # pool keeps: window_bias), else by its own
        model, taken = (joint[2][c], together()) if offered and together() is not None else (fit, level)
        read = None if taken is None else window_bias(taken, model, sums[c, 0], pools[c, 0], inside_share(model), k,
                                                      p.plateau_prior)
        return None, None, 1.0, level, 0.0 if read is None else max(read[0] ** 2 - read[1], 0.0)

    objects = np.flatnonzero(closed).tolist()
    # the closed objects fitted together (shared levels) on each half and on all ions (fit_balls); {} for fewer than two
    some = np.isin(comp, objects) & (np.abs(distance) <= p.plateau_window[1])
    joint = [fit_balls(distance[some & sel], part[some & sel], total[some & sel], comp[some & sel], radius=radius,
                       dims=dims, blur=sigma, half_width=p.plateau_window[1])
             for sel in (half == 0, half == 1, np.ones(len(comp), dtype=bool))]
    whole, cov = joint[2]
    joint = [fits for fits, _ in joint]
    kept, lock = [], threading.Lock()

    def together() -> tuple | None:
        """The joint profile level (every closed object's ions, each under its joint ball; :func:`profile_levels`),
        computed the first time an object is offered it: most surfaces offer it to none, and it costs two solves
        over all their ions per object."""
        with lock:
            if not kept:
                kept.append(profile_levels(distance, atoms, k, whole, radius=radius, dims=dims, blur=sigma,
                                           half_width=p.plateau_window[1], group=comp, cov=cov) if whole else None)
            return kept[0]

    # the objects are independent (their profiles' special functions release the GIL): every core busy
    profiles = []
    for c, result in zip(objects, per_item(level_of, objects)):
        if result is None:
            continue
        unmixing, inside, share[c], level, bias[c] = result
        if level is not None and level[1] > 0:
            profiles.append(level)
        if unmixing is not None:
            chosen[c], balls[c] = True, True
            mixed[c], weight[c], worth[c] = unmixing.mixed, unmixing.weight, unmixing.worth
        elif inside is not None:
            chosen[c], profiled[c] = True, inside
    out = unmixed_sums(sums, mixed, weight, worth)
    for c, inside in profiled.items():
        out[c, 0] = inside
    # the pool of the model's levels: every closed object's profile level, their scatter beyond their stated errors
    # counted (a level's worth moves with its own error)
    shared = pooled_profiles(levels=profiles, species=k) if profiles else np.zeros(len(held[0].atoms.elements))
    return out, chosen, balls, share, shared, bias


def _normalised(near: NearIons, band: Band, components: np.ndarray,
                scores: ObjectScores) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ions of ``band`` (of ``near``, within the profiles' ``half_width`` of a surface) with a usable object:
    (which of the band, their normalised scores ``u`` (0 outside, 1 inside) and atoms)."""
    comp = components[band.vertex]
    use = scores.usable[comp] & (np.abs(scores.inside - scores.outside)[comp] > 0)
    score, total = scores.fraction(near.atoms.atoms[band.index[use]], comp[use])
    keep = np.flatnonzero(use)[total > 0]
    comp, score, total = comp[keep], score[total > 0], total[total > 0]
    u = (score / total - scores.outside[comp]) / (scores.inside - scores.outside)[comp]
    return keep, u, total


def _estimate_blur(near: NearIons, band: Band, normals: np.ndarray, components: np.ndarray, scores: ObjectScores,
                   half_width: float) -> BlurEstimate | None:
    """:func:`~apt_filters.refine.blur.lateral_blur` from the ions ``near`` a surface (``band``: those within
    ``half_width`` of it, ``normals`` its vertices')."""
    keep, u, total = _normalised(near, band, components, scores)
    nz = normals[band.vertex[keep], 2]
    return lateral_blur(band.distance[keep], u, total, nz ** 2, half_width=half_width)


def _segregant(near: NearIons, band: Band, basis: ConcentrationBasis, normals: np.ndarray, components: np.ndarray,
               scores: ObjectScores, step_errors: np.ndarray, half_width: float, blur: bool,
               marker: bool) -> tuple[BlurEstimate | None, MarkerOffsets | None]:
    """The ranged species left out of ``basis`` (segregants, by the basis's own account) around the objects with
    both plateaus: the blur from their pooled peak's width (:func:`~apt_filters.refine.blur.peak_blur`, if
    ``blur``; None without a peak) and each object's peak centre combined with its step (:func:`marker_offsets`,
    if ``marker``); (None, None) without such species. ``near``: the ions near the surface, with all their
    species; ``band``: those of them within ``half_width`` of it."""
    left_out = [e for e in basis.exclude if e in near.everything.elements]
    if not left_out or not (blur or marker):
        return None, None
    use = scores.usable[components[band.vertex]]
    atoms = near.everything.atoms[band.index[use]].astype(np.float64)
    mark = atoms[:, [near.everything.elements.index(e) for e in left_out]].sum(axis=1)
    total, name = atoms.sum(axis=1), "+".join(left_out)
    return ((peak_blur(band.distance[use], mark, total, normals[band.vertex[use], 2] ** 2, name,
                       half_width=half_width) if blur else None),
            (marker_offsets(band.distance[use], mark, total, components[band.vertex[use]], step_errors, name,
                            half_width) if marker else None))


def _fitted_facets(found: list, placed: _Placed, components: np.ndarray, scores: ObjectScores, half_width: float,
                   distance: str, chosen: dict, cap: float = 45.0, spare: dict | None = None) -> list:
    """The facets ``found`` on ``placed`` of the objects ``chosen`` does not map to False, those of each object they
    close refitted to its ions (:func:`~apt_filters.refine.facets.fit_to_ions`): the ions whose nearest vertex's
    normal lies within ``cap`` degrees of one of the object's facets (an edge's ions, ~45° from both faces, count;
    a corner's few do not). Where that fit fails (its planes no longer close the object, or one turned away), the
    object's ``spare`` facets (component -> the faces its halves found that ``found`` lacks,
    :func:`~apt_filters.refine.facets.missed`) are added and the fit tried again, kept where it holds."""
    band = placed.near.band(placed.vertices, placed.normals, half_width, distance)
    keep, u, total = _normalised(placed.near, band, components, scores)
    vertex = band.vertex[keep]
    comp = components[vertex]

    def fit(facets: list) -> list:
        normals = np.array([f.normal for f in facets])
        # the object's ions first: the normals' test on them alone, not on every ion of the band
        sel = np.flatnonzero(comp == facets[0].component)
        sel = sel[(placed.normals[vertex[sel]] @ normals.T).max(axis=1) > np.cos(np.radians(cap))]
        return fit_to_ions(facets, placed.near.positions[band.index[keep[sel]]], u[sel], total[sel],
                           float(placed.widths[facets[0].component]))

    def slabbed(pair: tuple, own: np.ndarray) -> list | None:
        """A slab's two facets with its side and rims placed by its ions (:func:`~apt_filters.refine.facets.slab_fit`;
        its other facets lie on that side, which takes their place); None where its side does not go round it
        (``own``: its vertices)."""
        side = slab_side(pair, placed.vertices[own], placed.normals[own])
        if side is None:
            return None
        sel = np.flatnonzero(comp == pair[0].component)
        side, rounding = slab_fit(pair, side, placed.near.positions[band.index[keep[sel]]], u[sel], total[sel],
                                  float(placed.widths[pair[0].component]))
        return [replace(f, side=side, rounding=rounding, fitted=True) for f in pair]

    def fitted(c: int) -> list:
        mine = [f for f in found if f.component == c]
        own = components == c
        pair = slab_pair(mine, placed.vertices[own], placed.normals[own])
        slab = slabbed(pair, own) if pair is not None else None
        if slab is not None:
            return slab
        if not closes(mine):
            return mine
        out = fit(mine)
        if (spare or {}).get(c) and all(a is b for a, b in zip(out, mine)):  # the fit failed: the planes as given
            more = mine + spare[c]
            again = fit(more)
            if not all(a is b for a, b in zip(again, more)):
                return again
        return out

    # the objects' fits are independent: every core busy, each object's planes what its fit alone gives (those
    # of the objects left out are never fitted: the fits are most of the refinement's time at 10^7 ions)
    objects = sorted({f.component for f in found if chosen.get(f.component, True)})
    return [f for part in per_item(fitted, objects) for f in part]


def _offset_errors(near: NearIons, band: Band, components: np.ndarray, levels: list[ObjectLevels],
                   scores: ObjectScores, widths: np.ndarray) -> np.ndarray:
    """(c,) nm: counting-statistics standard error of each object's mean offset (``RefineResult.offset_errors``)
    from the ions of ``band`` (of ``near``, within the profiles' ``half_width`` of the surface).

    The score profile of an object is ``m(d) = s_out + (s_in - s_out) Phi(-d / w)`` (its plateaus and
    width); an atom at ``d`` carries ``m'(d)^2 / var(d)`` of information on a shift of the whole surface,
    ``var(d) = sum_k w_k^2 f_k(d) - m(d)^2`` the variance of one atom's score (``f_k`` the element
    fractions' own steps). One over the square root of the sum over the object's atoms within
    ``half_width`` is the error of its mean offset; times its area, that of its volume.
    """
    from scipy.special import erfc

    n_comp = len(levels)
    comp = components[band.vertex]
    total = near.atoms.atoms[band.index].sum(axis=1).astype(np.float64)
    out = np.full(n_comp, np.nan)
    for c in np.flatnonzero(scores.usable & (np.abs(scores.inside - scores.outside) > 0)):
        mine = comp == c
        d, atoms = band.distance[mine], total[mine]
        w = widths[c]
        step = 0.5 * erfc(d / (np.sqrt(2) * w))
        fractions = levels[c].outside + (levels[c].inside - levels[c].outside) * step[:, None]
        weights = scores.weights[c]
        mean = fractions @ weights
        var = np.maximum(fractions @ weights ** 2 - mean ** 2, 1e-12)
        slope = (scores.inside[c] - scores.outside[c]) * np.exp(-0.5 * (d / w) ** 2) / (np.sqrt(2 * np.pi) * w)
        info = float(np.sum(atoms * slope ** 2 / var))
        out[c] = 1.0 / np.sqrt(info) if info > 0 else np.nan
    return out


def _level_offset_errors(levels: list[ObjectLevels], scores: ObjectScores, widths: np.ndarray) -> np.ndarray:
    """(c,) nm: standard error of each object's offset from the counting error of its own two plateau levels.

    The placement stops where the object's score crosses the midpoint of its levels, ``(s_in + s_out) / 2``
    (:func:`matched_offset` on the normalised profile); an error ``e`` of that midpoint moves the crossing by ``e``
    over the profile's slope there, ``(s_in - s_out) / (sqrt(2 pi) w)`` for an error-function step of width ``w``.
    Each level is as certain as ``worth`` atoms (:attr:`~apt_filters.refine.levels.ObjectLevels.worth_inside`; the
    window's and the prior's), an atom's score varying by ``sum_k f_k w_k^2 - (sum_k f_k w_k)^2`` at the plateau's
    fractions ``f`` (score weights ``w``). :func:`_offset_errors` holds the levels fixed; this is the rest, and where
    the inside window holds ~1000 atoms on a low-contrast wide interface it is the larger part (rod 10039: contrast
    0.21, width 0.93 nm, an inside level uncertain by 0.014, its midpoint by 0.007, the surface by ~0.07 nm, 8 % of
    a 1.85 nm rod's volume). NaN for objects without both plateaus (``scores.usable``); infinite where a level is
    worth no atoms or its worth is not known (NaN: an ``ObjectLevels`` made other than by ``levels_from_sums``).
    """
    out = np.full(len(levels), np.nan)
    for c in np.flatnonzero(scores.usable & (np.abs(scores.inside - scores.outside) > 0)):
        lv, weights = levels[c], scores.weights[c]
        var = 0.0
        for fractions, worth in ((lv.inside, lv.worth_inside), (lv.outside, lv.worth_outside)):
            per_atom = max(float(fractions @ weights ** 2 - (fractions @ weights) ** 2), 0.0)
            var += per_atom / worth if worth > 0 else np.inf
        slope = abs(scores.inside[c] - scores.outside[c]) / (np.sqrt(2 * np.pi) * widths[c])
        out[c] = 0.5 * np.sqrt(var) / slope
    return out


def _finisher(found: list[Facet], faces: np.ndarray, blur: tuple[float, float] | None,
              lift: np.ndarray | None = None, components: np.ndarray | None = None, sag: bool = False):
    """What follows the iterations (and the low-pass): blur correction, then the facets ``found``, as a function
    of the vertices returning (vertices, facets, vertices sharpened, moves the fold guard shortened, the vertices
    after the blur correction and before the facets, the ``time.perf_counter()`` there).

    ``lift`` (c,) nm moves each object (``components``: of each vertex) out on top of the blur's shift, and its
    facets' planes with it (the segregant's mark, :mod:`apt_filters.refine.marker`). ``sag``: the flat faces' sag
    is undone as well, blur or none (:func:`~apt_filters.refine.blur.blur_shift`); the final surface only: the
    cross-validation's candidates and the shape the blur is read on are compared with ions at the vertices'
    crossing, as before, and it would cost one more shape operator per candidate.

    The facets are found (:func:`_placed_facets`) on the surface as the iterations left it, not on its low-passed copy:
    its faces are flat where the copy's are curved, and planes fitted to curved faces tilted by up to 12°
    (cubes of gamma-prime seeds 6 and 8, which then stood out by ~1 nm at a corner).
    """

    if lift is not None:
        found = [replace(f, offset=f.offset + lift[f.component],
                         side=f.side.moved(lift[f.component]) if f.side is not None else None) for f in found]
        lift = np.where(components >= 0, lift[np.maximum(components, 0)], 0.0)
    frames = facet_frames(found)  # what the planes alone fix of the edges and corners: once for every surface

    def finish(vertices: np.ndarray) -> tuple[np.ndarray, int, int, int, np.ndarray, float]:
        guarded = 0
        if (blur is not None and any(blur)) or lift is not None or sag:
            shift, along = blur_shift(TriMesh(vertices, faces), blur or (0.0, 0.0), sag=sag)
            if lift is not None:
                shift = shift + lift
            vertices, g = guarded_move(vertices, faces, shift[:, None] * along)
            guarded += g
        sharpened, corrected, between = 0, vertices, time.perf_counter()
        if found:
            step, along = facet_steps(vertices, faces, found)
            vertices, g = guarded_move(vertices, faces, step[:, None] * along)
            corners = edge_and_corner_steps(vertices, faces, found, frames=frames)
            vertices, g2 = guarded_move(vertices, faces, corners)
            guarded += g + g2
            sharpened = int(np.count_nonzero(step) + np.count_nonzero(corners.any(axis=1)))
        return vertices, len(found), sharpened, guarded, corrected, between

    return finish


def _found_facets(vertices: np.ndarray, faces: np.ndarray, facets: bool, halves: list | None = None,
                  unjudged: bool = False) -> list:
    """The facets of the surface ``vertices`` (none if ``facets`` is off), as the halves' facets (``halves``, where
    given) judged them; ``unjudged`` as :func:`_placed_facets`'."""
    found = find_facets(vertices, faces, **({"peak": np.inf} if unjudged else {})) if facets else []
    return judged(found, halves) if halves is not None else found


def _placed_facets(placed: _Placed, faces: np.ndarray, components: np.ndarray, scores: ObjectScores, facets: bool,
                   half_width: float, distance: str, chosen: dict | None = None, halves: list | None = None,
                   unjudged: bool = False, found: list | None = None) -> list:
    """The facets of a surface as the iterations left it (none if switched off), as the halves' facets
    (``halves``, where given) judged them (:func:`~apt_filters.refine.facets.judged`), fitted to its ions where
    they close an object (:func:`_fitted_facets`); only those of the objects ``chosen`` (component -> bool,
    default True: the held-out ions' choice, ``ModeSelection.facets``) does not map to False.

    ``unjudged``: no held-out ions will judge these facets (``select_modes`` off), so none from the search for
    crowded normals (``find_facets(peak=inf)``): on a refined surface a small sphere's lumps crowd as much as a
    lath's narrow faces (eight 3 nm spheres, ``cross_fit=False``: crowd ratios 1.2-3.3 against the laths'
    1.9-3.5), and every one of them was closed by 6-7 such facets; only the held-out test tells them apart.

    ``found``: the facets of ``placed`` already found (:func:`_found_facets`), not searched for again."""
    if found is None:
        found = _found_facets(placed.vertices, faces, facets, halves, unjudged)
    spare = missed(found, halves) if halves is not None else None
    return (_fitted_facets(found, placed, components, scores, half_width, distance, chosen or {}, spare=spare)
            if found else [])


def _low_passed(vertices: np.ndarray, target: np.ndarray, faces: np.ndarray,
                plain: csr_matrix) -> tuple[np.ndarray, int]:
    """The low-passed shape ``target`` (n, 3) of the placed ``vertices`` (n, 3), and how many vertices the fold
    guard had to hold back (0 unless it still folds once unfolded).

    The low-passed shape is smooth and is taken whole: the fold guard would cancel the moves of the noisy
    placement's tilted slivers (whose normals turn past 90° on the way) and crumple the mesh. Where the smooth
    shape itself has folded pairs (slivers of the crumpled placement turned over on it), only they are undone
    (:func:`~apt_filters.refine.untangle.unfold`: the folded vertices and one ring moved to their neighbours'
    mean, then, where folds are left, back toward the placement, which has none), not the whole move of every
    vertex of a face the move would turn: that held them where the placement had them, rough and inflated
    (held-out ``plate`` 10010's second plate, 4.2 points of contrast: 23 folded pairs on its 9-mode shape, 540
    of its 2,046 vertices held back, its area 234 -> 383 nm² against a true 261; unfolded: 189 vertices moved,
    262 nm²). Only folds that this leaves go to the guard. ``plain``: the umbrella operator.
    """
    if not len(folded_pairs(target, faces, FOLD_ANGLE)):
        return target, 0
    target, _ = unfold(target, faces, plain, original=vertices)
    if not len(folded_pairs(target, faces, FOLD_ANGLE)):
        return target, 0
    return guarded_move(vertices, faces, target - vertices)


def _slabs_unflattened(vertices: np.ndarray, placed: np.ndarray, faces: np.ndarray, components: np.ndarray,
                       found: list[Facet]) -> np.ndarray:
    """The low-passed ``vertices`` (n, 3), each slab of ``found`` (facets with a side) whose low-pass holds under half
    of its placed volume (``placed`` (n, 3)) back where the placement left it (``components`` (n,): each vertex's
    object).

    A slab's finish moves every vertex onto its prism along the vertex's normal, from where the low-pass left it.
    The few modes chosen with a slab can press a thin plate through itself: seen 10080's 2.25 nm plate at 4 modes
    kept 9 % of its volume, no ray met its prism from the right side, the fold guard held 660 moves back and the
    plate came out V -24 %, A +26 %; finished from its placement, V +4 %, A +3 %."""
    slabs = sorted({f.component for f in found if f.side is not None})
    face_object = components[faces[:, 0]]
    out = vertices.copy()
    for c in slabs:
        mine = faces[face_object == c]
        if TriMesh(vertices, mine).signed_volume() < 0.5 * TriMesh(placed, mine).signed_volume():
            out[components == c] = placed[components == c]
    return out


def _unclosed(found: list[Facet], vertices: np.ndarray, normals: np.ndarray, components: np.ndarray,
              fitted: list[Facet] = ()) -> dict[int, int]:
    """The objects with facets ``found`` that they do not close (:func:`closes`), that make a slab of them
    (:func:`~apt_filters.refine.facets.slab_pair` of the surface ``vertices`` (n, 3), unit ``normals`` (n, 3), each
    vertex's object ``components`` (n,)), or whose polyhedron the ions refused: ``fitted``, the same facets as
    :func:`_placed_facets` fitted them, kept the vertices' planes of the object (``Facet.fitted`` False:
    :func:`~apt_filters.refine.facets.fit_to_ions` found something else). Each with its number of facets: no
    polyhedron is refitted to their ions."""
    per, ions = {}, {}
    for f in found:
        per.setdefault(f.component, []).append(f)
    for f in fitted:
        ions[f.component] = ions.get(f.component, False) or f.fitted
    return {c: len(mine) for c, mine in per.items()
            if not closes(mine) or slab_pair(mine, vertices[components == c], normals[components == c]) is not None
            or not ions.get(c, True)}


def _half_spreads(fits: list[_Placed], half_facets: list[list[Facet]], keep: dict, faces: np.ndarray,
                  components: np.ndarray, low_pass) -> np.ndarray:
    """(c, 2) standard errors of the faceted objects' volumes and areas from the two halves' surfaces, each
    low-passed (``low_pass(vertices)``) and finished with its own facets as the whole is
    (``RefineResult.shape_errors``); NaN elsewhere."""
    out = np.full((int(components.max()) + 1, 2), np.nan)
    objects = sorted({f.component for found in half_facets for f in found if keep.get(f.component, True)})
    if not objects:
        return out
    face_object = components[faces[:, 0]]
    sizes = np.zeros((2, len(objects), 2))
    for k, fit in enumerate(fits):
        found = [f for f in half_facets[k] if keep.get(f.component, True)]
        vertices = _finisher(found, faces, None)(low_pass(fit.vertices))[0]
        for i, c in enumerate(objects):
            part = TriMesh(vertices, faces[face_object == c])
            sizes[k, i] = part.signed_volume(), part.area()
    out[objects] = 0.5 * np.abs(sizes[0] - sizes[1])
    return out


@serial_blas  # its parallel work runs in numba; OpenBLAS threads would spin around its small solves
def refine_surface(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str,
                   basis: ConcentrationBasis = ConcentrationBasis(), params: RefineParams = RefineParams()
                   ) -> RefineResult:
    """Move each vertex of an iso-surface along its normal to where the ions' composition crosses midway.

    See the module docstring for the method and :class:`RefineParams` for every setting.

    Parameters
    ----------
    mesh : TriMesh
        Iso-surface, e.g. from :func:`apt_filters.contour.marching_cubes` (normals out of the
        region above iso). Remove specks first (:func:`remove_specks`).
    ions : IonTable
        May be memory-mapped: the ions within reach of the surface are selected in one streamed pass (again
        only where the surface moves farther than :data:`RESELECT`).
    ranges : RangeTable
    species : str
        The iso-surface element (its plateaus give each object's midpoint iso-value).
    basis : ConcentrationBasis
        Which elements count in the fractions; leave segregants out (``exclude=("B",)``) so that
        their shell does not dilute the profile at the interface.
    params : RefineParams

    Returns
    -------
    RefineResult
        With one :class:`StageReport` per stage (``stages``).
    """
    p = params
    if mesh.n_faces == 0:  # nothing to move (every component was a speck): the empty surface passes through
        return RefineResult(mesh, [], {"mean": 0.0, "rms": 0.0, "max_abs": 0.0, "last_step_max": 0.0}, 0, 0, 0, 0,
                            0, p.score, basis.describe(), params=p)
    clock = time.perf_counter()
    mesh, start, plain = _prepare(mesh, p.subdivisions, p.relax_start)
    faces = mesh.faces
    n = len(start)
    stages = [StageReport.between("prepare", mesh.vertices.astype(np.float64), start, clock, p.relax_start,
                                  f"{p.subdivisions} subdivision(s), {n:,} vertices")]
    components = topology(faces, n).vertex_components
    rimmed = np.unique(components[TriMesh(start, faces).boundary_edges().ravel()])
    if p.select_modes:  # open surfaces: no noise of the start shared by the halves' surfaces (open_start)
        start = open_start(start, faces, components, rimmed, p.smoothing)
    # an open object's windows reach as far as its ions are flat: they are selected that far
    radius = max(_reach(p), OPEN_REACH + 1.0 if len(rimmed) else 0.0) + RESELECT
    near = NearIons.select(ions, ranges, basis, start, faces, radius)  # one streamed pass over the ion table
    edges = _window_edges(near, start, faces, components, rimmed, species, p)
    fits, held, fixed = [], [], None
    pairs_start = Pairs.find(start, components, p.pool_radius)
    if p.cross_fit:
        clock = time.perf_counter()
        # the halves are independent: one thread each (their compiled loops and numpy release the GIL)
        fits = on_threads(lambda k: _place(start, faces, near.half(k, start), species, None, p, pairs_start, edges),
                          [(0,), (1,)])
        # the ions of each half against the other half's surface: its plateaus, and the held-out ions of the
        # smoothness selection
        reach = max(_reach(p, edges), SCORED + 1.0)
        closed = np.ones(int(components.max()) + 1 if n else 0, dtype=bool)
        closed[rimmed] = False
        fits = [_right_side_out(fit, start, faces, components, closed, p) for fit in fits]
        held = [_against(fits[k].near, fits[1 - k].vertices, reach) for k in (0, 1)]
        fixed = _cross_fitted_levels(fits, faces, held, species, p, closed, edges)
        stages.append(StageReport.between("cross_fit", start, fits[0].vertices, clock,
                                          max(f.iterations for f in fits),
                                          "plateaus of each half's ions against the other half's surface"))
    clock = time.perf_counter()
    placed = _place(start, faces, near, species, fixed, p, pairs_start, edges)
    stages.append(StageReport.between("place", start, placed.vertices, clock, placed.iterations,
                                      f"largest move of the last iteration {placed.history[-1] if placed.history else 0:.3f} nm"))
    scores = object_scores(placed.levels, placed.near.atoms.elements, species, p.score, p.plateau_prior)
    closed = np.ones(len(scores.usable), dtype=bool)
    closed[rimmed] = False
    objects = [c for c in range(len(closed)) if closed[c] and scores.usable[c]]
    auto = isinstance(p.blur, str)
    blur = p.blur
    selection, half_facets, whole_facets, whole_fitted = None, None, None, None
    vertices, guarded = placed.vertices, placed.guarded
    shape_errors = np.full((len(closed), 2), np.nan)
    clock = time.perf_counter()
    if p.select_modes and objects:
        # candidates are finished with the blur given, or without one while it is still to be estimated
        half_facets = on_threads(lambda fit: _placed_facets(fit, faces, components, scores, p.facets, p.half_width,
                                                            p.distance), [(fit,) for fit in fits])
        # the whole's facets as the halves judge them, found and fitted to the ions here since those that close no
        # object, or whose planes the ions refuse, must win
        whole_facets = _found_facets(placed.vertices, faces, p.facets, half_facets)
        whole_fitted = _placed_facets(placed, faces, components, scores, p.facets, p.half_width, p.distance,
                                      None, half_facets, found=whole_facets)
        selection = cross_validated_modes([f.vertices for f in fits], faces, components, objects, held, scores,
                                          placed.widths,
                                          lambda k, kept: _finisher(half_facets[k] if kept else [], faces,
                                                                    None if auto else blur),
                                          faceted_objects={f.component for found in half_facets for f in found},
                                          unclosed=_unclosed(whole_facets, placed.vertices, placed.normals,
                                                            components, whole_fitted))
        kept = {c: k for c, k in selection.modes.items() if k}
        bases = (object_harmonics(vertices, faces, components, list(kept), basis_size(max(kept.values())))
                 if kept else None)
        shape_errors = _half_spreads(fits, half_facets, selection.facets, faces, components,
                                     lambda v: apply_modes(v, bases, kept) if kept else v)
        if kept:
            vertices, g = _low_passed(vertices, apply_modes(vertices, bases, kept), faces, plain)
            guarded += g
        stages.append(StageReport.between("modes", placed.vertices, vertices, clock, 0,
                                          f"{len(kept)} of {len(objects)} closed objects low-passed"))
    opened = [c for c in range(len(closed)) if not closed[c] and scores.usable[c]]
    if p.select_modes and opened:  # open surfaces: a smoothing length by held-out ions, the rim held
        clock, before = time.perf_counter(), vertices
        lengths = cross_validated_lengths([f.vertices for f in fits], faces, components, opened, held, scores,
                                          placed.widths)
        vertices, g = _low_passed(vertices, open_low_pass(vertices, faces, components, lengths), faces, plain)
        guarded += g
        selection = selection or ModeSelection({}, CANDIDATES, np.full((len(closed), len(CANDIDATES) + 1), np.nan))
        selection.lengths = lengths
        stages.append(StageReport.between("lengths", before, vertices, clock, 0, "open objects low-passed at "
                                          + ", ".join(f"{v:g}" for v in lengths.values()) + " nm"))
    clock = time.perf_counter()
    # facets only as the held-out ions judged them: those the halves found, where the ions preferred them
    if whole_fitted is not None:  # fitted already, for the held-out test: those of the objects that keep them
        found = [f for f in whole_fitted if selection.facets.get(f.component, True)]
    else:
        found = _placed_facets(placed, faces, components, scores, p.facets, p.half_width, p.distance,
                               selection.facets if selection is not None else None, half_facets,
                               unjudged=selection is None, found=whole_facets)
    vertices = _slabs_unflattened(vertices, placed.vertices, faces, components, found)
    # read on the finished shape (rounded cube edges would widen the edge-on profiles) before the blur correction,
    # whose curvature bias shifts the step's midpoint and a segregant's peak alike
    finished = _finisher(found, faces, None)(vertices)[0]
    along = smoothed_normals(finished, faces, p.normal_smoothing)
    ions_near = placed.near.cover(finished, p.half_width + 1.0)
    # one band of the finished shape for its offset errors, the segregant's peak and the step's blur
    profiles = ions_near.band(finished, along, p.half_width, p.distance)
    errors = _offset_errors(ions_near, profiles, components, placed.levels, scores, placed.widths)
    estimate, marks = _segregant(ions_near, profiles, basis, along, components, scores, errors, p.half_width, auto,
                                 p.marker)
    if auto:
        estimate = estimate or _estimate_blur(ions_near, profiles, along, components, scores, p.half_width)
        # weighed against the prior by its error: a wide interface's step on a few small objects reads the slope to
        # no better than its own size (blur.SLOPE_PRIOR). The cross-fit's ball model keeps the fit's own reading: its
        # held-out choice (BALL_SE) was set on it, and a ball blur lifted off 0 there flips level choices (dev lath
        # 32048 V +5.6 -> +7.5 %, seen rod 10137 rod 0 -22.4 -> -29.2 %)
        blur = (estimate.shrunk_lateral, 0.0) if estimate is not None else None
    lift = marks.shift if marks is not None and marks.marked else None
    before = vertices
    vertices, n_facets, sharpened, g, corrected, between = _finisher(found, faces, blur, lift, components,
                                                                     sag=True)(vertices)
    guarded += g
    # the facets' time from where the blur's correction ended; the blur's from the facets' finding on
    stages.append(replace(StageReport.between(
        "blur_and_marker", before, corrected, clock, 0,
        f"blur {'none' if not blur or not any(blur) else f'{blur[0]:.3f}/{blur[1]:.3f} nm'}"
        f"{'' if lift is None else f', segregant mark moved {np.count_nonzero(lift)} objects'}"),
        seconds=between - clock))
    stages.append(StageReport.between("facets", corrected, vertices, between, 0,
                                      f"{n_facets} facets, {sharpened} vertices on edges and corners"))
    # the levels' own counting error, which the step's error holds fixed, in the reported errors only: the marker
    # weighed the step by its error without it (so the surface is as before), and the combination takes the level's
    # shift at the step's weight, (combined / step)^2
    step_weight = np.ones(len(errors))
    if marks is not None:
        step_weight = np.divide(marks.errors, errors, out=np.ones(len(errors)), where=errors > 0) ** 2
        errors = marks.errors
    errors = np.sqrt(errors ** 2 + (step_weight * _level_offset_errors(placed.levels, scores, placed.widths)) ** 2)
    clock = time.perf_counter()
    before = vertices
    vertices, untangled = untangle(vertices, faces, start, plain)
    stages.append(StageReport.between("untangle", before, vertices, clock, untangled))
    original = mesh.vertices.astype(np.float64)
    moved_total = np.einsum("ij,ij->i", vertices - original, vertex_normals(original, faces))
    out = TriMesh(vertices, faces.copy(), {**mesh.vertex_scalars, "displacement": moved_total},
                  dict(mesh.face_scalars))
    stats = {"mean": float(moved_total.mean()) if n else 0.0,
             "rms": float(np.sqrt(np.mean(moved_total ** 2))) if n else 0.0,
             "max_abs": float(np.abs(moved_total).max()) if n else 0.0,
             "last_step_max": placed.history[-1] if placed.history else 0.0}
    crossing = int(self_intersecting_faces(vertices, faces).sum())
    return RefineResult(out, placed.levels, stats, placed.iterations, len(folded_pairs(vertices, faces, FOLD_ANGLE)),
                        crossing, guarded, untangled, p.score, basis.describe(), placed.history,
                        tuple(blur) if blur is not None else (0.0, 0.0), n_facets, sharpened, estimate, selection,
                        placed.widths, errors, marks, p, stages, shape_errors)
