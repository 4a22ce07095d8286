"""An open, low-contrast curved interface with the defaults of ``apt-filters run``, against its exact truth.

The interface crosses the whole box (its rim is where it leaves the specimen); Mg 9 -> 17 at.% at detection
efficiency 0.4 gives few ions per nm² of contrast, so each vertex's placement is noisy and the surface's
smoothness must come from the data (``refine.crossval.cross_validated_lengths``), with its rim held.
"""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
from apt_filters.pipeline.surface import finished_surface
from apt_filters.synth import Box, generate
from apt_filters.synth.implicit import SphereInterface
from apt_filters.synth.specimen import Feature, SpecimenSpec
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

MATRIX = {"Al": 0.78, "Mg": 0.09, "Cu": 0.13}
INSIDE = {"Al": 0.80, "Mg": 0.17, "Cu": 0.03}


@pytest.fixture(scope="module")
def curved():
    box = Box((16.0, 16.0, 18.0))
    shape = SphereInterface(box, (2.0, -1.5, -49.0), 40.0, convex=True)
    spec = SpecimenSpec(box, MATRIX, (Feature(shape, INSIDE, 0.3, (), "curved interface"),), efficiency=0.4,
                        blur=(0.25, 0.12), name="curved")
    sp = generate(spec, 4)
    config = PipelineConfig()
    v = config.voxel
    basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
    fields = voxelize(sp.ions, sp.ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size,
                      basis=basis, efficiency=config.analysis.efficiency)
    iso = 0.5 * (MATRIX["Mg"] + INSIDE["Mg"])
    mesh, record = finished_surface(fields, inside_mask(fields).dense(), sp.ions, sp.ranges, SurfaceConfig("Mg", iso),
                                    config=config, basis=basis)
    return sp, shape, box, mesh, record


def test_a_low_contrast_curved_interface_is_placed_within_a_tenth_of_a_nanometre(curved):
    sp, shape, box, mesh, record = curved
    # compared 2 nm inside the box, as the zoo benchmark compares (the measured surface stops at the voxel mask)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    inner = box.sdf(centroids) + 2.0 < 0
    areas = mesh.face_areas()[inner]
    d = shape.sdf(centroids[inner])
    mean = float(np.sum(areas * np.abs(d)) / areas.sum())
    assert mean <= 0.1, mean  # measured 0.070 (0.144 without the smoothing of open surfaces)
    assert abs(float(np.sum(areas * d) / areas.sum())) < 0.05  # measured -0.004
    assert np.abs(d).max() < 1.0  # measured 0.45
