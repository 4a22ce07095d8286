"""Per-triangle kernels: the closest point on a triangle (one numba kernel for every step that measures
point-to-mesh distances) and the faces' normals."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def closest_on_segment(px, py, pz, ax, ay, az, bx, by, bz):
    """Squared distance of p to segment ab and the parameter t in [0, 1] of its closest point a + t (b - a)."""
    ex, ey, ez = bx - ax, by - ay, bz - az
    ee = ex * ex + ey * ey + ez * ez
    t = 0.0
    if ee > 0.0:
        t = min(1.0, max(0.0, ((px - ax) * ex + (py - ay) * ey + (pz - az) * ez) / ee))
    dx, dy, dz = px - ax - t * ex, py - ay - t * ey, pz - az - t * ez
    return dx * dx + dy * dy + dz * dz, t


@njit(cache=True, nogil=True, error_model="numpy")
def _closest_on_degenerate(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point on a zero-area triangle: the nearest of its three edges."""
    best, t = closest_on_segment(px, py, pz, ax, ay, az, bx, by, bz)
    u, w = t, 0.0
    d, t = closest_on_segment(px, py, pz, ax, ay, az, cx, cy, cz)
    if d < best:
        best, u, w = d, 0.0, t
    d, t = closest_on_segment(px, py, pz, bx, by, bz, cx, cy, cz)
    if d < best:
        best, u, w = d, 1.0 - t, t
    return best, u, w


@njit(cache=True, nogil=True, error_model="numpy")
def closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point to p on triangle abc.

    Returns ``(d2, u, w, inner)``: the squared distance, the weights of b and c of the closest
    point ``a + u (b - a) + w (c - a)``, and whether it lies inside the face (not on an edge or a
    corner, where the sign of a distance needs the pseudo-normal of the neighbours).

    Ericson, Real-Time Collision Detection (2005), 5.1.5: Voronoi regions of the corners, then of
    the edges, then the face. Degenerate (zero-area) triangles fall back to their edges.
    """
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    u = 0.0
    w = 0.0
    inner = False
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz, 0.0, 0.0, False
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz, 1.0, 0.0, False
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 > d3:
        u = d1 / (d1 - d3)
    else:
        cpx, cpy, cpz = px - cx, py - cy, pz - cz
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        if d6 >= 0.0 and d5 <= d6:
            return cpx * cpx + cpy * cpy + cpz * cpz, 0.0, 1.0, False
        vb = d5 * d2 - d1 * d6
        if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 > d6:
            w = d2 / (d2 - d6)
        else:
            va = d3 * d6 - d5 * d4
            if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0 and d4 - d3 + d5 - d6 > 0.0:
                w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                u = 1.0 - w
            elif va + vb + vc > 0.0:
                u = vb / (va + vb + vc)
                w = vc / (va + vb + vc)
                inner = True
            else:
                d, u, w = _closest_on_degenerate(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
                return d, u, w, False
    qx = ax + u * abx + w * acx - px
    qy = ay + u * aby + w * acy - py
    qz = az + u * abz + w * acz - pz
    return qx * qx + qy * qy + qz * qz, u, w, inner


@njit(cache=True, nogil=True)
def face_normals_kernel(vertices, faces, normalize, out):
    """``out`` (m, 3): each face's ``cross(v1 - v0, v2 - v0)`` (twice its area, along its normal), or with
    ``normalize`` that over its length (zeros where the length is 0), for :func:`apt_filters.core.mesh.face_normals`.

    One pass without temporaries; the numbers of numpy's expression there, bit for bit: ``np.cross``'s products
    and differences (``a1 b2 - a2 b1``, ...), ``np.linalg.norm``'s squares summed as ``(x^2 + y^2) + z^2`` (the
    reduction's order over a row of three) and its square root, each component divided by the length."""
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        a0, a1, a2 = vertices[j, 0] - vertices[i, 0], vertices[j, 1] - vertices[i, 1], vertices[j, 2] - vertices[i, 2]
        b0, b1, b2 = vertices[k, 0] - vertices[i, 0], vertices[k, 1] - vertices[i, 1], vertices[k, 2] - vertices[i, 2]
        c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        if not normalize:
            out[f, 0], out[f, 1], out[f, 2] = c0, c1, c2
            continue
        # in the vertices' own precision (float32 stays float32, as in numpy)
        length = np.sqrt((c0 * c0 + c1 * c1) + c2 * c2)
        if length > 0:
            out[f, 0], out[f, 1], out[f, 2] = c0 / length, c1 / length, c2 / length
        else:
            out[f, 0] = out[f, 1] = out[f, 2] = 0.0
