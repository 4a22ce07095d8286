"""Putting the surface where the interface is: refinement of iso-surfaces against the ions.

After contouring (``apt_filters.contour``) on a delocalized concentration field, the surface of a
small precipitate sits inside the true interface (delocalization and segregant dilution shrink
it by 30-45% in volume). This step

- removes specks: components whose ions do not differ across them beyond what noise draws at the
  iso-value (:func:`remove_specks`),
- measures each object's own inside/outside plateaus and midpoint iso-value (:func:`object_levels`,
  :func:`per_object_iso`),
- moves every vertex along its normal to where the ions' local composition profile crosses the
  midpoint of its object's plateaus (cross-fitted on two halves of the ions), regularised and fold-free,
  low-passes each closed object to the harmonics held-out ions choose, undoes the blur's curvature
  bias, places each object by the peak of a segregant left out of the basis as well (:mod:`.marker`)
  and rebuilds faceted edges on planes fitted to the ions (:func:`refine_surface`),
- gives the interfacial excess per object over its own area (:func:`object_excess`),
The counting floor no method can beat, on synthetic specimens, is :func:`apt_filters.truth.counting_floor`.

Typical use (the defaults are the ones benchmarks/bench_refine.py measured)::

    basis = ConcentrationBasis(exclude=("B",))            # segregants out of the denominator
    c = fields.concentration("Al", basis).dense()
    mask = inside_mask(fields).dense()
    mesh = marching_cubes(c, 0.15, spacing=grid.voxel, origin=grid.origin, mask=mask)
    mesh, specks = remove_specks(mesh, fields=fields, mask=mask, ions=ions, ranges=ranges, species="Al", iso=0.15,
                                 basis=basis)            # family-wise p <= 0.001 against noise
    result = refine_surface(mesh, ions, ranges, "Al", basis)
    excess = object_excess(result.mesh, ions, ranges, "B")  # per object, over its refined area

On the gamma-prime specimen (8 seeds, 32 precipitates) this takes volumes from -32% (AP Suite-style,
mean abs) to 1.8% (signed +0.3%, 31 of 32 within 5%, at the counting floor: 2.4% for a 3 nm sphere, rms
error 1.01 floors), mean distance to the true surface from 0.42 to 0.09 nm, Hausdorff from 1.5 to 0.43 nm
(every object within 0.8 nm), area errors from 23% to 1.3% (every object within 5%), with no folds,
self-intersections or proxigram sign errors (benchmarks/results_refine.md, docs/refine.md).
"""

from apt_filters.refine.composition import IonAtoms, contrast_weights, ion_atoms
from apt_filters.refine.excess import ObjectExcess, object_excess
from apt_filters.refine.levels import ObjectLevels, object_levels, per_object_iso
from apt_filters.refine.marker import MarkerOffsets, marker_offsets
from apt_filters.refine.recontour import merge, recontour
from apt_filters.refine.specks import Specks, remove_specks
from apt_filters.refine.subdivide import subdivide
from apt_filters.refine.surface import RefineResult, guarded_move, refine_surface
from apt_filters.refine.untangle import unfold, untangle

__all__ = [
    "IonAtoms", "MarkerOffsets", "ObjectExcess", "ObjectLevels", "RefineResult", "Specks", "contrast_weights",
    "marker_offsets", "guarded_move", "ion_atoms", "merge", "recontour", "object_excess", "object_levels",
    "per_object_iso", "refine_surface", "remove_specks", "subdivide", "unfold", "untangle",
]
