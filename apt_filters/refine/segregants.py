"""Which species segregate to a surface: read off their peak at it, to leave them out of the basis.

A species held in a layer at an interface (a segregant) has, against the ions' signed distance to the
surface, a fraction of the atoms that rises above *both* of its plateaus; a species that partitions
between the phases steps monotonically from one plateau to the other under any blur. Left in the
concentration's denominator, a segregant dilutes every other species where it sits, which pulls the
iso-surface of the species drawn inward (gamma-prime-like specimens: object volumes -39 to -54 % with
the 8 % B shell counted, ~0 % without). So :func:`find_segregants` measures, over all the objects
pooled, each species' fraction in bins of the exact signed distance to a first surface (one streamed
pass, :func:`~apt_filters.core.nearby.select_near`) and calls it a segregant
where a bin near that surface stands ``significance`` binomial standard errors above the higher of its
two references, all the atoms more than ``GAP`` nm beyond the bin on each side (out to 4 nm; the ions beyond
an open surface's rim, on neither side of it, left out): under a
monotone step no bin exceeds the mean of what lies beyond it on its higher side, however wide the
interface or thin the object (a 3 nm sphere has few atoms 2-4 nm inside its first contour). The surface
only has to lie near the interface: the contour of the user's own basis
(shrunk by the dilution and the delocalization) has the shell within 1-2 nm of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from apt_filters.core.mesh import TriMesh
from apt_filters.core.nearby import NearSurface, select_near
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import RangeTable
from apt_filters.refine.composition import ion_atoms
from apt_filters.voxel import ConcentrationBasis

SIGNIFICANCE = 5.0
"""Binomial standard errors by which a species' peak must stand above its references on both sides."""

REACH = (2.0, 4.0)
"""nm: the peak is looked for within ``REACH[0]`` of the surface, its references out to ``REACH[1]``."""

GAP = 1.0
"""nm between a candidate bin and its references on either side (a shell's sigma with the blur is 0.3-0.5 nm)."""


@dataclass
class Segregants:
    """What :func:`find_segregants` found.

    Attributes
    ----------
    species : tuple of str
        The segregants, most significant first (to be left out of the basis).
    peaks : dict species -> dict
        Every species tested, at its most significant bin: ``peak_at_nm`` (bin centre, positive outside),
        ``peak`` (its fraction of the atoms there), ``plateau`` (the higher reference), ``z`` (standard errors
        above it).
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


def _rise(f: np.ndarray, n: np.ndarray, p: np.ndarray, n_p: np.ndarray) -> np.ndarray:
    """Binomial z of fractions ``f`` of ``n`` atoms above references ``p`` of ``n_p`` atoms, under the null that
    the bin holds the reference's fraction (-inf where either is empty); a pseudo-count keeps a reference with
    none of the species from making a few atoms significant."""
    q = (p * n_p + 0.5) / (n_p + 1.0)
    se = np.sqrt(q * (1 - q) * (1 / np.maximum(n, 1.0) + 1 / np.maximum(n_p, 1.0)))
    return np.where((n > 0) & (n_p > 0), (f - p) / np.maximum(se, 1e-12), -np.inf)


def segregant_ions(mesh: TriMesh, ions: IonTable) -> NearSurface:
    """The ions :func:`find_segregants` reads, in one streamed pass: those within ``REACH[1]`` nm of ``mesh``,
    with exact signed distances and faces within ``REACH[0] + GAP`` nm and, beyond, on a closed mesh only their
    side (distance +-inf); m/z carried. The speck test of the same mesh reads the ions within 3 nm from it too."""
    near_reach, far = REACH
    return select_near(ions.positions, mesh, far, carry=(ions.mz,), distances=near_reach + GAP)


def find_segregants(mesh: TriMesh, ions: IonTable, ranges: RangeTable, species: str, *,
                    basis: ConcentrationBasis = ConcentrationBasis(), include=(), bin_width: float = 0.25,
                    significance: float = SIGNIFICANCE, near: NearSurface | None = None) -> Segregants:
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
        Binomial standard errors (of the bin and its reference together) a peak must clear.
    near : NearSurface, optional
        :func:`segregant_ions` of ``mesh`` and ``ions``, where the caller reuses it (default: selected here).

    Returns
    -------
    Segregants
    """
    near_reach, far = REACH
    # One streamed pass over the ions within reach of the references. Beyond near_reach + GAP an ion only
    # counts in the reference on its side, so there its side is enough (on a closed mesh the reach grid
    # proves most of them without a search); it goes to the outermost bin on that side.
    near = segregant_ions(mesh, ions) if near is None else near
    everything = ion_atoms(IonTable(near.positions, near.carried[0]), ranges, ConcentrationBasis())
    atoms = everything.atoms.astype(np.float64)
    # fine bins over [-far, far]: each candidate bin's references are sums of whole fine bins
    fine = bin_width / 5
    edges = np.arange(-far, far + fine / 2, fine)
    distance = np.where(np.isinf(near.distance), np.sign(near.distance) * (far - fine / 2), near.distance)
    b = np.digitize(distance, edges) - 1
    # an ion whose closest point is an open surface's rim lies beyond the rim, not across the surface: its side
    # is no phase's (on a bicontinuous or open surface cut by the specimen, the inside phase's ions beyond the
    # rim read as "outside" and would pull that side's reference toward the inside's composition)
    ok = (b >= 0) & (b < len(edges) - 1) & ~near.on_boundary
    n_fine = len(edges) - 1
    counts = np.stack([np.bincount(b[ok], weights=atoms[ok, k], minlength=n_fine) for k in range(atoms.shape[1])])
    cum = np.concatenate([np.zeros((len(counts), 1)), np.cumsum(counts, axis=1)], axis=1)
    cum_total = cum.sum(axis=0)
    lo = np.arange(round((far - near_reach) / fine), round((far + near_reach - bin_width) / fine) + 1)  # bin starts
    hi = lo + 5
    gap = round(GAP / fine)
    inner_end, outer_start = np.maximum(lo - gap, 0), np.minimum(hi + gap, n_fine)

    def share(k, a, z):  # element k's fraction and the atoms between fine-bin edges a and z
        n = cum_total[z] - cum_total[a]
        return (cum[k, z] - cum[k, a]) / np.maximum(n, 1.0), n

    found, peaks, kept = [], {}, []
    for k, element in enumerate(everything.elements):
        if element == species or element in basis.exclude:
            continue
        f, n = share(k, lo, hi)
        p_in, n_in = share(k, np.zeros_like(lo), inner_end)
        p_out, n_out = share(k, outer_start, np.full_like(lo, n_fine))
        # under a monotone step no bin rises above everything beyond it on its higher side; it must stand above
        # each side by that side's own error: a side with few atoms (inside a sliver of an object thinner than
        # the delocalization) cannot show that the species drops there, and an object's own enrichment beyond
        # the sliver is no peak
        z_in, z_out = _rise(f, n, p_in, n_in), _rise(f, n, p_out, n_out)
        z = np.minimum(z_in, z_out)
        higher = p_in > p_out
        p = np.where(higher, p_in, p_out)
        j = int(np.argmax(z))
        peaks[element] = {"peak_at_nm": round(float(edges[lo[j]] + bin_width / 2), 3), "peak": float(f[j]),
                          "plateau": float(p[j]), "z": float(z[j])}
        if z[j] > significance:
            (kept if element in include else found).append(element)
    found.sort(key=lambda e: -peaks[e]["z"])
    return Segregants(tuple(found), peaks, tuple(kept))
