"""Issue 7 on real data: the proxigram across the Si data's cap/Si iso-surface (open at the
specimen edge) agrees with a 1D profile along z in a central cylinder."""

import numpy as np

from apt_filters.analysis.proxigram import compute_proxigram
from apt_filters.io import read_ions, read_ranges
from apt_filters.meshlab.chains import apply_chain
from apt_filters.pipeline.surface import contour_surface
from apt_filters.voxel import inside_mask, voxelize

RADIUS = 5.0  # nm: the interface is flat to within a voxel over the central cylinder


def test_proxigram_matches_central_cylinder_profile(real_si):
    ions, ranges = read_ions(real_si / "Si.pos"), read_ranges(real_si / "Si.RRNG")
    fields = voxelize(ions, ranges, efficiency=0.5)
    mesh, _ = apply_chain(contour_surface(fields, inside_mask(fields).dense(), "Cr", 0.3, "dc"), "clean")
    assert len(mesh.boundary_edges()) > 0, "the interface meets the specimen edge: open"
    prox = compute_proxigram(ions, ranges, mesh)
    c, err = prox.pooled().concentration()
    k = prox.elements.index("Cr")

    centre = np.median(ions.positions[:, :2], axis=0)
    in_cyl = np.linalg.norm(ions.positions[:, :2] - centre, axis=1) < RADIUS
    z0 = mesh.vertices[np.linalg.norm(mesh.vertices[:, :2] - centre, axis=1) < RADIUS, 2].mean()
    index = ranges.ion_index(ions.mz[in_cyl])
    atoms = np.where(index[:, None] >= 0, ranges.element_matrix()[index], 0)
    s = ions.positions[in_cyl, 2] - z0  # the cap (Cr-rich, "inside") lies above the interface
    n_cr = np.histogram(s, prox.edges, weights=atoms[:, k])[0]
    n_all = np.histogram(s, prox.edges, weights=atoms.sum(axis=1))[0]
    c_cyl = n_cr / n_all
    sigma = np.hypot(err[0, :, k], np.sqrt(c_cyl * (1 - c_cyl) / n_all))
    z = (c[0, :, k] - c_cyl) / sigma
    assert np.mean(np.abs(z) < 3) > 0.95, f"bins off by > 3 sigma: {np.sum(np.abs(z) >= 3)} of {len(z)}"
    assert abs(np.mean(z)) < 0.5, "no systematic shift between the two profiles"
    far = np.abs(prox.centers) > 2
    assert np.all(c[0, far & (prox.centers > 0), k] > 0.4) and np.all(c[0, far & (prox.centers < 0), k] < 0.2)
