"""An object cut by the specimen edge, with the defaults of ``apt-filters run``, against its exact truth.

The measured surface of a sphere cut by a side face of the specimen stops at the voxel mask, short of the face: it
is open there, and the ions between its rim and the face are beyond the rim, on neither side of it. Counted in the
refinement's plateau windows they put the matrix into the object's inside level, whose midpoint then moves the
surface outward. Exact truth: the generated specimen's own compositions and sphere.
"""

from __future__ import annotations

import numpy as np
import pytest

from apt_filters.core.mesh import topology
from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig
from apt_filters.pipeline.surface import finished_surface
from apt_filters.synth import Box, generate
from apt_filters.synth.implicit import CutSphere
from apt_filters.synth.specimen import Feature, SpecimenSpec
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize

MATRIX = {"Ni": 0.80, "Al": 0.09, "Cr": 0.11}
INSIDE = {"Ni": 0.42, "Al": 0.55, "Cr": 0.03}


@pytest.fixture(scope="module")
def cut():
    box = Box((16.0, 16.0, 18.0))
    # the centre 0.8 nm beyond the face x = 8: a cap 3.7 nm deep into the specimen
    shape = CutSphere((8.8, -1.0, -9.0), 4.5, (1.0, 0.0, 0.0), 8.0)
    spec = SpecimenSpec(box, MATRIX, (Feature(shape, INSIDE, 0.3, (), "edge 0"),), efficiency=0.5,
                        blur=(0.4, 0.07), name="cut sphere")
    sp = generate(spec, 5)
    config = PipelineConfig()
    v = config.voxel
    basis = ConcentrationBasis(tuple(v.exclude), v.include_unranged)
    fields = voxelize(sp.ions, sp.ranges, kernel=v.kernel, delocalization=v.delocalization, voxel=v.size,
                      basis=basis, efficiency=config.analysis.efficiency)
    iso = 0.5 * (MATRIX["Al"] + INSIDE["Al"])
    mesh, record = finished_surface(fields, inside_mask(fields).dense(), sp.ions, sp.ranges, SurfaceConfig("Al", iso),
                                    config=config, basis=basis)
    return shape, box, mesh, record


def test_the_inside_level_of_an_object_cut_by_the_edge_holds_no_matrix(cut):
    shape, box, mesh, record = cut
    refined = record.refined
    assert len(refined.mesh.boundary_edges()), "the measured surface is open at the specimen edge"
    components = topology(refined.mesh.faces, refined.mesh.n_vertices).vertex_components
    sizes = np.bincount(components[components >= 0])
    level = refined.levels[int(np.argmax(sizes))]
    k = level.elements.index("Al")
    sigma = np.sqrt(INSIDE["Al"] * (1 - INSIDE["Al"]) / level.n_inside)
    # main measured 0.489 (-6.9 sigma of the window's count) with the ions beyond the rim in the windows; 0.547 now
    assert abs(level.inside[k] - INSIDE["Al"]) < 2 * sigma, (level.inside[k], sigma)


def test_an_object_cut_by_the_edge_is_not_inflated(cut):
    shape, box, mesh, record = cut
    # compared 2 nm inside the box, as the zoo benchmark compares (the measured surface stops at the voxel mask)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    inner = box.sdf(centroids) + 2.0 < 0
    areas = mesh.face_areas()[inner]
    d = shape.sdf(centroids[inner])
    # main: +0.062 nm out (the matrix in its inside window lowered its midpoint); now -0.060: an inward offset of
    # the same size is left (no blur estimated for it, so no curvature correction), not asserted here
    assert float(np.sum(areas * d) / areas.sum()) < 0.03
