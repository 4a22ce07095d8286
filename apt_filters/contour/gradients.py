"""Field gradients at edge crossings, estimated from the sampled field only.

Dual contouring places vertices on sharp features only as well as its Hermite normals
allow. Three estimators, all evaluated at the two grid points of a crossed edge and
combined at the crossing, in index space (voxel units):

``"central"``
    Plain central differences, linearly interpolated (the usual baseline; it averages the
    two sides of an edge and rounds sharp features).
``"fit"``
    Least-squares plane fitted to the 3×3×3 neighbourhood (a Sobel-like smoothed
    gradient): robust on noisy (counted) fields, but rounds edges like ``"central"``.
``"eno"`` (default)
    Essentially non-oscillatory one-sided differences: per axis, the one-sided difference
    whose stencil has the smaller second difference, i.e. the one that does not reach
    across a kink of the field. The two edge ends are then weighted by how smooth their
    stencils were (relative residual curvature), so a crossing next to a convex edge takes
    its normal from the flat inside end, next to a concave edge from the outside end. Ends
    whose normals differ by more than 20° lie on two faces and are not blended: along the
    edge each end's tangent line is extended to where the two meet (the kink), the crossing
    is taken on the line of the end on its side of the kink, at that line's zero, with that
    end's normal (:func:`hermite_crossings`); without a kink inside the edge, the end with
    the larger weight.
"""

from __future__ import annotations

import numpy as np

from apt_filters.contour.cells import strides

METHODS = ("eno", "central", "fit")


def _shifted(flat: np.ndarray, pts: np.ndarray, shape, axis: int, d: int) -> np.ndarray:
    """Values at point + d along axis, clamped at the box (so differences fall back one-sided)."""
    q = pts.copy()
    q[:, axis] = np.clip(q[:, axis] + d, 0, shape[axis] - 1)
    return flat[q @ strides(shape)].astype(np.float64)


def point_gradients(values: np.ndarray, pts: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (n, 3) and relative roughness (n,) at integer index points (n, 3)."""
    shape = values.shape
    flat = values.reshape(-1)
    g = np.zeros((len(pts), 3))
    rough = np.zeros(len(pts))
    if method == "fit":
        for axis in range(3):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            acc = np.zeros(len(pts))
            for du, dv in np.ndindex(3, 3):
                du, dv = du - 1, dv - 1
                q = pts.copy()
                q[:, u] = np.clip(q[:, u] + du, 0, shape[u] - 1)
                q[:, v] = np.clip(q[:, v] + dv, 0, shape[v] - 1)
                acc += _shifted(flat, q, shape, axis, 1) - _shifted(flat, q, shape, axis, -1)
            g[:, axis] = acc / 18.0
        return g, rough
    for axis in range(3):
        f0 = flat[pts @ strides(shape)].astype(np.float64)
        fm1, fp1 = _shifted(flat, pts, shape, axis, -1), _shifted(flat, pts, shape, axis, 1)
        if method == "central":
            g[:, axis] = (fp1 - fm1) / 2.0
            continue
        fm2, fp2 = _shifted(flat, pts, shape, axis, -2), _shifted(flat, pts, shape, axis, 2)
        left, right = f0 - fm1, fp1 - f0
        curv_left, curv_right = np.abs(f0 - 2 * fm1 + fm2), np.abs(fp2 - 2 * fp1 + f0)
        use_left = curv_left < curv_right
        g[:, axis] = np.where(use_left, left, right)
        rough += np.minimum(curv_left, curv_right)
    return g, rough / (np.linalg.norm(g, axis=1) + 1e-300)


def crossing_gradients(values: np.ndarray, start: np.ndarray, axis: np.ndarray, t: np.ndarray,
                       method: str = "eno") -> np.ndarray:
    """(V, 3) index-space gradients at crossings on grid edges (see :func:`hermite_crossings`)."""
    return hermite_crossings(values, start, axis, t, method)[1]


def hermite_crossings(values: np.ndarray, start: np.ndarray, axis: np.ndarray, t: np.ndarray,
                      method: str = "eno") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crossings on grid edges, re-placed along kinked edges, and their index-space gradients.

    Parameters
    ----------
    values : (nx, ny, nz) ndarray
    start : (V,) int64 flat index of each edge's first point; axis (V,) its direction
    t : (V,) fraction along the edge (linear interpolation)
    method : {"eno", "central", "fit"}

    Returns
    -------
    t : (V,) fraction along the edge; with ``"eno"``, where the two ends lie on different
        faces of a sharp edge, the zero of the end's tangent line that holds at the
        crossing (see :func:`_near_piece`), else the input ``t``
    gradients : (V, 3)
    linear : (V, 3)
        Gradients for the linear crossings (the input ``t``): where ``t`` was re-placed, the
        end with the larger weight, as chosen before the kink test; elsewhere ``gradients``.
    """
    if method not in METHODS:
        raise ValueError(f"unknown gradient method {method!r}; choose one of {METHODS}")
    p0 = np.stack(np.unravel_index(start, values.shape), axis=1)
    p1 = p0.copy()
    p1[np.arange(len(p1)), axis] += 1
    g0, r0 = point_gradients(values, p0, method)
    g1, r1 = point_gradients(values, p1, method)
    w0, w1 = 1.0 - t, t.copy()
    if method == "eno":
        # 0.05 voxel⁻¹ of residual curvature counts as smooth: below it ends mix linearly.
        w0 = w0 / (r0 + 0.05)
        w1 = w1 / (r1 + 0.05)
    n0 = g0 / (np.linalg.norm(g0, axis=1, keepdims=True) + 1e-300)
    n1 = g1 / (np.linalg.norm(g1, axis=1, keepdims=True) + 1e-300)
    blend = w0[:, None] * n0 + w1[:, None] * n1
    if method != "eno":
        return t, blend, blend
    # Ends on two different faces of a sharp edge: a blend is a plane that does not exist.
    # Take the end whose plane holds at the crossing and that plane's zero on the edge (the
    # linear t, up to 0.35 voxel off there, offsets the plane by that times the normal's
    # component along the edge); where no kink lies on the edge, the end with the larger weight.
    split = np.einsum("ij,ij->i", n0, n1) < np.cos(np.radians(20.0))
    piece, t_piece = _near_piece(values, start, axis, t, g0, g1)
    kinked = split & (piece >= 0)
    linear = np.where(split[:, None], np.where((w0 >= w1)[:, None], n0, n1), blend)
    return (np.where(kinked, t_piece, t), np.where(kinked[:, None], np.where((piece == 0)[:, None], n0, n1), linear),
            linear)


def _near_piece(values: np.ndarray, start: np.ndarray, axis: np.ndarray, t: np.ndarray, g0: np.ndarray,
                g1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which end's tangent line holds at the crossing along a kinked edge, and where it crosses.

    Along the edge the field is taken as two lines, each end's own (its value and its
    gradient's component along the edge), meeting at a kink where they cross. The field
    changes sign once, so the crossing lies between the kink and the end whose value has
    the other sign than the field at the kink; that end's plane is the one through the
    crossing. The nearer end (the larger t-weight) is often the wrong one: a crossing
    close to a convex rim's outer sample can still lie on the face of the inner sample.

    Returns (V,) piece: 0, 1, or -1 where no kink lies inside the edge; (V,) the zero of
    that end's line (meaningful where piece >= 0).
    """
    flat = values.reshape(-1)
    idx = np.arange(len(start))
    v0 = flat[start].astype(np.float64)
    v1 = flat[start + strides(values.shape)[axis]].astype(np.float64)
    s0, s1 = g0[idx, axis], g1[idx, axis]
    iso = v0 + t * (v1 - v0)  # t is the linear crossing, so this is the iso-value
    den = s0 - s1
    safe = np.abs(den) > 1e-9 * (np.abs(s0) + np.abs(s1) + 1e-300)
    kink = np.where(safe, (v1 - s1 - v0) / np.where(safe, den, 1.0), -1.0)
    at_kink = v0 + s0 * kink - iso
    piece = np.where(safe & (kink > 0) & (kink < 1) & (at_kink != 0),
                     np.where(at_kink * (v1 - iso) > 0, 0, 1), -1)
    # Between its end and the kink the chosen line changes sign, so its slope is not 0 there.
    slope = np.where(piece == 0, s0, s1)
    slope = np.where(slope != 0, slope, 1.0)
    zero = np.where(piece == 0, (iso - v0) / slope, 1.0 + (iso - v1) / slope)
    return piece, np.where(piece >= 0, zero, t)
