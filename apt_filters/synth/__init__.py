"""Synthetic APT specimens with exactly known ground truth.

Build a :class:`SpecimenSpec` (outline, matrix, features with tanh interfaces and segregation,
density, efficiency, blur, spectrum) or take a preset, then :func:`generate` it in memory or
:func:`write_specimen` it to a folder (POS, RRNG, truth.json, true surfaces as PLY)::

    from apt_filters.synth import preset, write_specimen
    specimen = write_specimen("out", preset("small"), seed=1)
    specimen.truth["features"][1]["excess"]["B"]["ions_per_nm2"]
"""

from apt_filters.synth.generate import Specimen, build_truth, generate, iter_ions, summary, write_specimen
from apt_filters.synth.geometry import Box, Tip
from apt_filters.synth.instruments import DETECTION_EFFICIENCY
from apt_filters.synth.modulation import (MAP_SPECIMENS, FacetModulation, LinearModulation, map_specimen, map_surface,
                                          true_excess_map)
from apt_filters.synth.presets import PRESETS, preset, with_ions
from apt_filters.synth.shapes import (Capsule, Cuboid, CustomShape, Cylinder, HalfSpace, Shape, Sphere, rotation_matrix,
                                      shape_from_params)
from apt_filters.synth.specimen import Feature, Segregation, SpecimenSpec, composition_at
from apt_filters.synth.spectrum import SpectrumModel

__all__ = [
    "Box", "Capsule", "Cuboid", "CustomShape", "Cylinder", "DETECTION_EFFICIENCY", "FacetModulation", "Feature",
    "HalfSpace", "LinearModulation", "MAP_SPECIMENS", "map_specimen", "map_surface",
    "PRESETS", "Segregation", "Shape", "Specimen", "SpecimenSpec", "SpectrumModel", "Sphere", "Tip",
    "build_truth", "composition_at", "generate", "iter_ions", "preset", "rotation_matrix", "shape_from_params",
    "summary", "true_excess_map", "with_ions", "write_specimen",
]
