"""Putting the surface where the interface is: refinement of iso-surfaces against the ions.

After contouring (``apt_filters.contour``) on a delocalized concentration field, the surface of a
small precipitate sits inside the true interface (delocalization and segregant dilution shrink
it by 30-45% in volume). This step

- removes specks: components whose ions do not differ across them beyond what noise draws at the
  iso-value (:func:`remove_specks`),
- measures each object's own inside/outside plateaus and midpoint iso-value
  (:func:`~apt_filters.refine.levels.object_levels`),
- moves every vertex along its normal to where the ions' local composition profile crosses the
  midpoint of its object's plateaus (cross-fitted on two halves of the ions), regularised and fold-free,
  low-passes each closed object to the harmonics held-out ions choose, undoes the blur's curvature
  bias, places each object by the peak of a segregant left out of the basis as well (:mod:`.marker`)
  and rebuilds faceted edges on planes fitted to the ions (:func:`refine_surface`, settings in
  :class:`RefineParams`, what each stage did in :attr:`RefineResult.stages`),
- gives the interfacial excess per object over its own area (:func:`object_excess`).

The counting floor no method can beat, on synthetic specimens, is :func:`apt_filters.truth.counting_floor`.

Typical use (the defaults are the ones benchmarks/bench_refine.py measured)::

    basis = ConcentrationBasis(exclude=("B",))            # segregants out of the denominator
    c = fields.concentration("Al", basis).dense()
    mask = inside_mask(fields).dense()
    mesh = marching_cubes(c, 0.15, spacing=grid.voxel, origin=grid.origin, mask=mask)
    mesh, specks = remove_specks(mesh, fields=fields, mask=mask, ions=ions, ranges=ranges, species="Al", iso=0.15,
                                 basis=basis)            # family-wise p <= 0.001 against noise
    result = refine_surface(mesh, ions, ranges, "Al", basis, RefineParams())
    excess = object_excess(result.mesh, ions, ranges, "B")  # per object, over its refined area

The parts (plateaus :mod:`.levels`, scores :mod:`.composition`, the stages' modules) are importable from their
modules; the package exports only these five names.
"""

from apt_filters.refine.excess import object_excess
from apt_filters.refine.specks import remove_specks
from apt_filters.refine.surface import RefineParams, RefineResult, refine_surface

__all__ = ["RefineParams", "RefineResult", "object_excess", "refine_surface", "remove_specks"]
