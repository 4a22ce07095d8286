"""Real data (../shared apav-si): proxigram across a flat open surface at the Cr-oxide/Si interface.

Over a flat surface the signed distance of an ion above it is exactly its height, so the
proxigram must equal the 1D profile along z of the ions over the surface, bin by bin, and the
ions beyond the surface's rim must be left out. The comparison with a 1D profile in a central
cylinder across a true iso-surface needs the contouring step (not part of this package).
"""

import numpy as np

from apt_filters.analysis import compute_proxigram
from apt_filters.core.mesh import TriMesh
from apt_filters.io import read_ions, read_ranges
from tests.proxigram_specimens import plane

Z0, HALF = -17.0, 12.0  # the interface plane and the half width of the square surface, nm


def test_flat_interface_proxigram_equals_z_profile(real_si):
    ions, ranges = read_ions(real_si / "Si.pos"), read_ranges(real_si / "Si.RRNG")
    square = plane(HALF, n=24)
    v = square.vertices.copy()
    v[:, 2] = Z0
    # Cr oxide (above the iso-value) lies at z > Z0: normals point out of it, toward -z
    prox = compute_proxigram(ions, ranges, TriMesh(v, square.faces[:, ::-1]), bin_width=0.25)
    p = ions.positions.astype(np.float64)
    over = np.all(np.abs(p[:, :2]) <= HALF, axis=1)
    idx = ranges.ion_index(ions.mz)
    edges = Z0 + prox.edges
    expected = np.stack([np.histogram(p[over & (idx == k), 2], edges)[0] for k in range(len(ranges.ions))], axis=1)
    np.testing.assert_array_equal(prox.counts[0], expected)
    np.testing.assert_array_equal(prox.unranged[0], np.histogram(p[over & (idx < 0), 2], edges)[0])
    beyond = np.linalg.norm(np.maximum(np.abs(p[:, :2]) - HALF, 0), axis=1) ** 2 + (p[:, 2] - Z0) ** 2 < 9.0
    assert prox.n_rim == np.count_nonzero(~over & beyond) > 0
    # the oxide side is positive: Cr rises from < 5 at.% at -3 nm to > 50 at.% at +3 nm
    c, _ = prox.concentration("element")
    cr = prox.elements.index("Cr")
    assert c[0, 0, cr] < 0.05 and c[0, -1, cr] > 0.5
