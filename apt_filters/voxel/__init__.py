"""Voxelization: ions -> block-sparse count, concentration and density fields.

``voxelize(ions_or_chunks, ranges, ...)`` returns :class:`Fields`; transfer functions
square / sawtooth / gaussian (AP Suite two-pass scheme); :func:`inside_mask` marks voxels
outside the specimen; :func:`gradient` / :func:`gradient_at` give sub-voxel gradients.
"""

from apt_filters.voxel.fields import UNRANGED_FIELD, ConcentrationBasis, Fields, voxelize
from apt_filters.voxel.gradient import field_gradient, gradient, gradient_at, sample
from apt_filters.voxel.grid import BLOCK, Grid, check_budget, default_budget
from apt_filters.voxel.mask import inside_mask
from apt_filters.voxel.sparse import SparseField
from apt_filters.voxel.transfer import KERNELS, kernel_reach, second_pass_sigma

__all__ = [
    "BLOCK",
    "ConcentrationBasis",
    "Fields",
    "Grid",
    "KERNELS",
    "SparseField",
    "UNRANGED_FIELD",
    "check_budget",
    "default_budget",
    "field_gradient",
    "gradient",
    "gradient_at",
    "inside_mask",
    "kernel_reach",
    "sample",
    "second_pass_sigma",
    "voxelize",
]
