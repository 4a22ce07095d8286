"""Synthetic specimens refined by the pipeline's defaults; spheres near the specimen's side (``tests/test_clipped.py``,
``tests/test_inside_out.py``, ``tests/test_open_surface.py``)."""

from __future__ import annotations

from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
from apt_filters.pipeline.surface import finished_surface
from apt_filters.synth import Box, generate
from apt_filters.synth.specimen import Feature, SpecimenSpec
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

MATRIX = {"Ni": 0.80, "Al": 0.09, "Cr": 0.11}
INSIDE = {"Ni": 0.67, "Al": 0.30, "Cr": 0.03}


def refined(shapes, seed: int, name: str):
    """(mesh, record) of :func:`finished_surface` on ``shapes`` (each a feature of ``INSIDE`` in ``MATRIX``, interface
    width 0.2 nm) in a 15.6 x 16 x 18 nm box (the face x = 7.8 between the grid's points 7, inside the mask, and
    8), efficiency 0.5, blur (0.3, 0.1) nm, ions drawn with ``seed``, at the midpoint iso-value of Al."""
    features = tuple(Feature(shape, INSIDE, 0.2, (), f"sphere {i}") for i, shape in enumerate(shapes))
    spec = SpecimenSpec(Box((15.6, 16.0, 18.0)), MATRIX, features, efficiency=0.5, blur=(0.3, 0.1), name=name)
    return defaults(spec, seed, "Al", 0.5 * (MATRIX["Al"] + INSIDE["Al"]))


def defaults(spec: SpecimenSpec, seed: int, species: str, iso: float):
    """(mesh, record) of ``finished_surface`` on ``spec``'s ions drawn from ``seed``, every option at its default."""
    sp = generate(spec, seed)
    config = PipelineConfig()
    v = config.voxel
    basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
    fields = voxelize(sp.ions, sp.ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size,
                      basis=basis, efficiency=config.analysis.efficiency)
    return finished_surface(fields, inside_mask(fields).dense(), sp.ions, sp.ranges, SurfaceConfig(species, iso),
                            config=config, basis=basis)
