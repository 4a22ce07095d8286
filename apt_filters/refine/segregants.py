"""Which species segregate to a surface: read off their peak at it, to leave them out of the basis.

A species held in a layer at an interface (a segregant) has, against the ions' signed distance to the
surface, a fraction of the atoms that rises above *both* of its plateaus; a species that partitions
between the phases steps monotonically from one plateau to the other under any blur. Left in the
concentration's denominator, a segregant dilutes every other species where it sits, which pulls the
iso-surface of the species drawn inward (gamma-prime-like specimens: object volumes -39 to -54 % with
the 8 % B shell counted, ~0 % without). So :func:`find_segregants` measures, over all the objects
pooled, each species' fraction in bins of the distance to a first surface and calls it a segregant
where a bin near that surface stands ``significance`` binomial standard errors above the higher of its
two plateaus. The surface only has to lie near the interface: the contour of the user's own basis
(shrunk by the dilution and the delocalization) has the shell within 1-2 nm of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.band import NearIons, vertex_normals
from apt_filters.voxel import ConcentrationBasis

SIGNIFICANCE = 5.0
"""Binomial standard errors by which a species' peak must stand above both of its plateaus."""

REACH = (2.0, 4.0)
"""nm: the peak is looked for within ``REACH[0]`` of the surface, the plateaus between the two, each side."""


@dataclass
class Segregants:
    """What :func:`find_segregants` found.

    Attributes
    ----------
    species : tuple of str
        The segregants, most significant first (to be left out of the basis).
    peaks : dict species -> dict
        Every species tested: ``peak_at_nm`` (bin centre, positive outside), ``peak`` (its fraction of the
        atoms there), ``plateau`` (the higher plateau), ``z`` (standard errors above it).
    kept : tuple of str
        Segregants kept in the basis because the caller named them (``include``).
    """

    species: tuple[str, ...] = ()
    peaks: dict[str, dict] = field(default_factory=dict)
    kept: tuple[str, ...] = ()

    def describe(self) -> str:
        """One line for the run's log."""
        if not self.species and not self.kept:
            return "no segregant"
        text = ", ".join(f"{s} ({self.peaks[s]['z']:.0f} se)" for s in self.species) or "none left out"
        return "segregants " + text + (f"; kept in the basis as asked: {', '.join(self.kept)}" if self.kept else "")


def find_segregants(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str, *,
                    basis: ConcentrationBasis = ConcentrationBasis(), include=(), bin_width: float = 0.25,
                    significance: float = SIGNIFICANCE) -> Segregants:
    """The species that peak at the surface ``mesh`` above both of their plateaus.

    Parameters
    ----------
    mesh : TriMesh
        A first iso-surface of ``species`` (normals out of the region above the iso-value).
    ions : IonTable
    ranges : RangeTable
    species : str
        The iso-surface's element: never a segregant of its own surface.
    basis : ConcentrationBasis
        The user's basis: species it leaves out already are not tested.
    include : iterable of str
        Species to keep in the basis even if they peak (reported in ``kept``).
    bin_width : float, nm
        Profile bins.
    significance : float
        Binomial standard errors (of the bin and the plateau together) a peak must clear.

    Returns
    -------
    Segregants
    """
    near_reach, far = REACH
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    near = NearIons.select(ions, ranges, ConcentrationBasis(), vertices, mesh.faces, far + 1.0)
    band = near.band(vertices, vertex_normals(vertices, mesh.faces), far + 1.0)
    atoms = near.atoms.atoms[band.index].astype(np.float64)
    total = atoms.sum(axis=1)
    d = band.distance
    edges = np.arange(-near_reach, near_reach + 1e-9, bin_width)
    b = np.digitize(d, edges) - 1
    in_bins = (b >= 0) & (b < len(edges) - 1)
    n_bin = np.bincount(b[in_bins], weights=total[in_bins], minlength=len(edges) - 1)
    sides = [(d <= -near_reach) & (d >= -far), (d >= near_reach) & (d <= far)]
    found, peaks, kept = [], {}, []
    for k, element in enumerate(near.atoms.elements):
        if element == species or element in basis.exclude:
            continue
        k_bin = np.bincount(b[in_bins], weights=atoms[in_bins, k], minlength=len(edges) - 1)
        plateaus = [(atoms[s, k].sum(), total[s].sum()) for s in sides]
        fractions = [kk / max(n, 1.0) for kk, n in plateaus]
        high = int(np.argmax(fractions))
        p, n_p = fractions[high], max(plateaus[high][1], 1.0)
        f = k_bin / np.maximum(n_bin, 1.0)
        se = np.sqrt(np.maximum(np.maximum(f * (1 - f), p * (1 - p)), 1e-12) * (1 / np.maximum(n_bin, 1.0) + 1 / n_p))
        z = np.where(n_bin > 0, (f - p) / se, -np.inf)
        j = int(np.argmax(z))
        peaks[element] = {"peak_at_nm": float(0.5 * (edges[j] + edges[j + 1])), "peak": float(f[j]),
                          "plateau": float(p), "z": float(z[j])}
        if z[j] > significance:
            (kept if element in include else found).append(element)
    found.sort(key=lambda e: -peaks[e]["z"])
    return Segregants(tuple(found), peaks, tuple(kept))
