"""Real Si data: the pipeline's interface position and C excess against an independent 1D analysis.

The 1D analysis uses numpy and the file readers only (no analysis code of the pipeline): a cylinder of
ions along the normal of the Cr/Si interface through the specimen's centre, a composition profile along
its axis, the interface where Cr is 50 % of the way between its plateaus, and the C excess by the
cumulative-count method (Krakauer & Seidman, Phys. Rev. B 48 (1993) 6724,
doi:10.1103/PhysRevB.48.6724) with its counting error.

The interface (cap of Cr/O/"Cr2O" on Si, 10-90 % about 4-5 nm) lies near z = -16 nm; the Si plateau is
read 25-35 nm deep, the cap's 5-10 nm from the top of the data, where the profile along z is flat
(looked at once, 1 nm bins through a 5 nm cylinder).
"""

import numpy as np

from apt_filters.io import read_ions, read_ranges
from apt_filters.meshlab.exports import read_ply

RADIUS = 8.0
"""Cylinder radius, nm: inside the specimen (about 20 nm across at the interface) along the whole profile."""

BIN = 0.1
"""Profile bins along the axis, nm."""

LOW, HIGH = (-18.0, -8.0), (8.0, 14.0)
"""Plateaus along the axis (nm from the interface plane): Si side and cap side, beyond the 5 nm interface."""


def _cumulative_excess(x, n, total, low, high):
    """Krakauer-Seidman: cumulative solute against cumulative atoms, lines fitted over the plateaus and
    extrapolated to the interface (x = 0); the excess count is their offset there. The counting error is
    the solute between the plateaus (Poisson) and the two lines' extrapolation errors."""
    cum_n, cum_t = np.cumsum(n), np.cumsum(total)
    at = np.interp(0.0, x, cum_t)
    offset, var = 0.0, 0.0
    for (a, b), sign in ((low, -1.0), (high, 1.0)):
        w = (x >= a) & (x <= b)
        c = n[w].sum() / total[w].sum()
        slope, intercept = np.polyfit(cum_t[w], cum_n[w], 1)
        offset += sign * (intercept + slope * at)
        var += (at - cum_t[w].mean()) ** 2 * c * (1 - c) / total[w].sum()
    between = (x > low[1]) & (x < high[0])
    return offset, np.sqrt(var + n[between].sum())


def one_dimensional(folder):
    ions, ranges = read_ions(str(folder / "Si.pos")), read_ranges(str(folder / "Si.RRNG"))
    index = ranges.ion_index(ions.mz)
    ranged = index >= 0
    atoms = ranges.element_matrix()[index[ranged]].astype(np.float64)
    p = ions.positions[ranged].astype(np.float64)
    cr, c = ranges.elements.index("Cr"), ranges.elements.index("C")
    total = atoms.sum(axis=1)

    # the interface plane: the Cr midpoint crossing along z in 4 x 4 nm columns, a plane fitted through them
    centre = p[:, :2].mean(axis=0)
    edges = np.arange(-40.0, 0.0 + 0.25, 0.25)
    z = 0.5 * (edges[1:] + edges[:-1])
    points = []
    for dx in np.arange(-12.0, 12.1, 4.0):
        for dy in np.arange(-12.0, 12.1, 4.0):
            col = (np.abs(p[:, 0] - centre[0] - dx) < 2) & (np.abs(p[:, 1] - centre[1] - dy) < 2)
            ncr = np.convolve(np.histogram(p[col, 2], edges, weights=atoms[col, cr])[0], np.ones(4), "same")
            nt = np.convolve(np.histogram(p[col, 2], edges, weights=total[col])[0], np.ones(4), "same")
            lo, hi = (z > -35) & (z < -25), (z > -10) & (z < -5)
            if nt[lo].sum() < 100 or nt[hi].sum() < 100:
                continue  # a column leaving the specimen
            f = ncr / np.maximum(nt, 1) - 0.5 * (ncr[lo].sum() / nt[lo].sum() + ncr[hi].sum() / nt[hi].sum())
            k = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0) & (z[:-1] > -25) & (z[1:] < -10))
            if len(k) == 1:
                k = k[0]
                points.append((centre[0] + dx, centre[1] + dy, z[k] - f[k] * (z[k + 1] - z[k]) / (f[k + 1] - f[k])))
    points = np.array(points)
    design = np.c_[np.ones(len(points)), points[:, :2]]
    coef = np.linalg.lstsq(design, points[:, 2], rcond=None)[0]
    normal = np.array([-coef[1], -coef[2], 1.0]) / np.hypot(1.0, np.hypot(coef[1], coef[2]))
    origin = np.array([centre[0], centre[1], coef @ [1.0, centre[0], centre[1]]])

    # the cylinder and its profile along the normal (towards the Cr-rich cap)
    d = p - origin
    s = d @ normal
    inside = np.linalg.norm(d - s[:, None] * normal, axis=1) < RADIUS
    edges = np.arange(LOW[0], HIGH[1] + BIN / 2, BIN)
    x = 0.5 * (edges[1:] + edges[:-1])
    n_cr, n_c, n_t = (np.histogram(s[inside], edges, weights=w[inside])[0]
                      for w in (atoms[:, cr], atoms[:, c], total))
    lo, hi = (x >= LOW[0]) & (x <= LOW[1]), (x >= HIGH[0]) & (x <= HIGH[1])
    # 50 % of the way: the cumulative Cr count against the atoms reaches the midpoint level's line there
    c_lo, c_hi = n_cr[lo].sum() / n_t[lo].sum(), n_cr[hi].sum() / n_t[hi].sum()
    run = np.convolve(n_cr, np.ones(10), "same") / np.maximum(np.convolve(n_t, np.ones(10), "same"), 1)
    f = run - 0.5 * (c_lo + c_hi)
    k = np.flatnonzero((f[:-1] < 0) & (f[1:] >= 0) & (x[:-1] > LOW[1]) & (x[1:] < HIGH[0]))
    assert len(k) == 1, "one crossing of the Cr midpoint"
    k = k[0]
    position = x[k] - f[k] * (x[k + 1] - x[k]) / (f[k + 1] - f[k])
    # its counting error: the midpoint level's binomial error over 1 nm of profile, through the local slope
    window = np.abs(x - position) < 0.5
    c_mid = 0.5 * (c_lo + c_hi)
    slope = np.polyfit(x[window], n_cr[window] / np.maximum(n_t[window], 1), 1)[0]
    position_error = np.sqrt(c_mid * (1 - c_mid) / n_t[window].sum()) / abs(slope)
    count, count_error = _cumulative_excess(x - position, n_c, n_t, LOW, HIGH)
    area = np.pi * RADIUS ** 2
    return {"normal": normal, "origin": origin, "position": position, "position_error": position_error,
            "excess": count / area, "excess_error": count_error / area}


def test_interface_position_and_c_excess_agree_with_a_1d_cylinder(real_si, si_run):
    out, report = si_run
    ref = one_dimensional(real_si)
    assert ref["normal"][2] > 0.99, "the interface is nearly normal to z"
    surface = report["surfaces"][0]
    interface = max(surface["objects"], key=lambda o: o["area"])
    step = surface["interface"]["step"]
    assert step["species"] == "Cr" and 3.0 < step["width"] < 6.0, "a wide interface, fitted"
    assert surface["interface"]["inner_nm"] >= step["width"], "plateau windows beyond the interface"

    # position: the surface within the cylinder, moved by the fitted 50 % point, against the 1D crossing
    mesh = read_ply(out / "meshes" / f"{surface['label']}.ply")
    d = mesh.vertices - ref["origin"]
    axial = d @ ref["normal"]
    near = np.linalg.norm(d - axial[:, None] * ref["normal"], axis=1) < RADIUS
    position = axial[near].mean() + step["centre"]
    sigma = np.hypot(ref["position_error"], step["centre_error"])
    assert abs(position - ref["position"]) <= 2 * sigma, (position, ref["position"], sigma)

    # C excess in detected atoms per nm², both with their counting errors
    [c] = [e for e in surface["excess"] if e["solute"] == "C" and e["object_id"] == interface["object_id"]]
    gamma, gamma_error = c["cumulative"]["gamma_detected"], c["cumulative"]["gamma_detected_error"]
    sigma = np.hypot(ref["excess_error"], gamma_error)
    assert abs(gamma - ref["excess"]) <= 2 * sigma, (gamma, gamma_error, ref["excess"], ref["excess_error"])
    assert ref["excess"] > 5 * ref["excess_error"], "the 1D analysis resolves the C excess"
