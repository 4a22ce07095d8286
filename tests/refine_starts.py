"""The refinement's start as `apt-filters run` makes it, for the refinement's tests.

The specimen voxelized with the defaults, its concentration of ``species`` in ``basis`` contoured by
marching cubes at ``iso`` inside the specimen, and the components the speck rule calls noise removed.
"""

from apt_filters.core.mesh import TriMesh
from apt_filters.pipeline.surface import contour_surface
from apt_filters.refine import remove_specks
from apt_filters.synth import Specimen
from apt_filters.voxel import ConcentrationBasis, Fields, inside_mask, voxelize

NO_B = ConcentrationBasis(exclude=("B",))
"""The gamma-prime specimens' basis with their segregant left out."""


def speckless_start(specimen: Specimen, *, basis: ConcentrationBasis = NO_B, species: str = "Al",
                    iso: float = 0.15, fields: Fields | None = None) -> TriMesh:
    """The start surface of ``specimen`` (``fields``: its voxelization, made here when None)."""
    fields = fields if fields is not None else voxelize(specimen.ions, specimen.ranges)
    mask = inside_mask(fields).dense()
    mesh = contour_surface(fields, mask, species, iso, basis=basis)
    return remove_specks(mesh, fields=fields, mask=mask, ions=specimen.ions, ranges=specimen.ranges,
                         species=species, iso=iso, basis=basis)[0]
