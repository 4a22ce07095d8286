"""One Al-rich sphere in a Ni-Al-Cr matrix, voxelized and contoured: the specimen of the speck rule's tests.

Truth: the sphere is the specimen's only object; every other component of its iso-surface is noise by construction.
"""

from dataclasses import dataclass

import numpy as np

from apt_filters.contour import marching_cubes
from apt_filters.core.mesh import TriMesh
from apt_filters.synth import Specimen, Sphere, generate
from apt_filters.synth.geometry import Box
from apt_filters.synth.specimen import Feature, SpecimenSpec
from apt_filters.voxel import Fields, inside_mask, voxelize

MATRIX = {"Ni": 0.75, "Al": 0.10, "Cr": 0.15}


@dataclass
class Contoured:
    """A specimen, its voxelization, the mask inside it, its Al field and that field's iso-surface."""

    specimen: Specimen
    fields: Fields
    mask: np.ndarray
    values: np.ndarray
    mesh: TriMesh


def contoured_sphere(*, centre, radius: float, contrast: float, width: float, box: float, efficiency: float,
                     iso: float, seed: int, close: bool = False) -> Contoured:
    """A sphere of ``radius`` nm ``contrast`` richer in Al than :data:`MATRIX` (at Cr's expense), interface
    ``width`` nm, in a cube of side ``box`` nm, contoured at ``iso``."""
    inside = {"Ni": 0.75, "Al": 0.10 + contrast, "Cr": 0.15 - contrast}
    spec = SpecimenSpec(Box((box, box, box)), MATRIX, (Feature(Sphere(centre, radius), inside, width, (), "s"),),
                        efficiency=efficiency, name="speck test")
    sp = generate(spec, seed=seed)
    fields = voxelize(sp.ions, sp.ranges)
    mask = inside_mask(fields).dense()
    values = fields.concentration("Al").dense()
    mesh = marching_cubes(values, iso, spacing=fields.grid.voxel, origin=fields.grid.origin, mask=mask, close=close)
    return Contoured(sp, fields, mask, values, mesh)
