"""One streamed selection of the ions near a finished surface or inside its objects serves every analysis.

:func:`~apt_filters.pipeline.surface.analysis_ions` on a synthetic specimen: the object table, the
proxigram and the excess maps computed from the selected ions equal those from the whole table.
"""

import numpy as np
import pytest

from apt_filters.analysis.maps import excess_maps
from apt_filters.analysis.objects import ions_in_objects, object_table
from apt_filters.analysis.proxigram import compute_proxigram
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.hull import SpecimenHull
from apt_filters.core.nearby import select_near
from apt_filters.pipeline.surface import analysis_ions, contour_surface
from apt_filters.synth import generate, preset
from apt_filters.voxel import inside_mask, voxelize


@pytest.fixture(scope="module")
def specimen():
    """The small preset's Al 15 at.% surface, open at the specimen edge (the cube and the sphere closed)."""
    sp = generate(preset("small"), seed=3)
    fields = voxelize(sp.ions, sp.ranges)
    mesh = contour_surface(fields, inside_mask(fields).dense(), "Al", 0.15)
    mesh.face_scalars["object_id"] = mesh.face_components()
    return sp, mesh


def test_the_selected_ions_give_the_whole_tables_figures(specimen):
    sp, mesh = specimen
    near, measured = analysis_ions(sp.ions, mesh, reach=3.0)
    assert 0.05 * len(sp.ions) < len(near) < 0.8 * len(sp.ions)
    hull = SpecimenHull.from_points(sp.ions.positions)
    whole, part = object_table(mesh, sp.ions, sp.ranges), object_table(mesh, near, sp.ranges, specimen=hull)
    assert whole.rows() == part.rows() and sum(o.n_ions > 0 for o in whole.objects) >= 2
    p_whole, p_part = (compute_proxigram(ions, sp.ranges, mesh, max_distance=3.0) for ions in (sp.ions, near))
    assert np.array_equal(p_whole.counts, p_part.counts) and np.array_equal(p_whole.unranged, p_part.unranged)
    # the selection's own distances: the same counts, no search (and none over a wider range than measured)
    p_reused = compute_proxigram(near, sp.ranges, mesh, max_distance=3.0, measured=measured)
    assert np.array_equal(p_whole.counts, p_reused.counts) and np.array_equal(p_whole.unranged, p_reused.unranged)
    assert p_reused.n_rim == p_whole.n_rim
    with pytest.raises(AptFiltersError, match="measured distances cover"):
        compute_proxigram(near, sp.ranges, mesh, max_distance=3.5, measured=measured)
    m_whole, m_part = (excess_maps(mesh=mesh, ions=ions, ranges=sp.ranges, solutes=["B"], max_distance=3.0)
                       for ions in (sp.ions, near))
    for key, values in m_whole.vertex_scalars().items():
        np.testing.assert_allclose(m_part.vertex_scalars()[key], values, rtol=1e-12, atol=0, equal_nan=True)


def test_ions_in_objects_covers_every_ion_the_table_counts(specimen):
    sp, mesh = specimen
    test = ions_in_objects(mesh)
    kept = test(sp.ions.positions)
    table = object_table(mesh, sp.ions, sp.ranges)
    only = object_table(mesh, sp.ions.subset(kept), sp.ranges, specimen=SpecimenHull.from_points(sp.ions.positions))
    assert [o.n_ions for o in only.objects] == [o.n_ions for o in table.objects]
    assert kept.mean() < 0.5  # the objects' voxels, not the specimen


def test_the_lean_selection_keeps_the_full_selections_ions_and_distances(specimen, tmp_path):
    """analysis_ions keeps no rows nor float64 positions: the table and the distances the analyses read are the
    full selection's, bit for bit, also read chunk by chunk from a memory map."""
    sp, mesh = specimen
    near, measured = analysis_ions(sp.ions, mesh, reach=3.0)
    full = select_near(sp.ions.positions, mesh, 3.0, also=ions_in_objects(mesh), carry=(sp.ions.mz,))
    assert near.positions.dtype == np.float32 and np.array_equal(near.positions, sp.ions.positions[full.rows])
    assert np.array_equal(near.mz, full.carried[0])
    mapped = np.memmap(tmp_path / "xyz", np.float32, "w+", shape=sp.ions.positions.shape)
    mapped[:] = sp.ions.positions
    chunked = select_near(mapped, mesh, 3.0, chunk=4096, also=ions_in_objects(mesh), carry=(mapped,), lean=True)
    for lean in (measured, chunked):
        assert lean.rows is None and lean.positions is None and lean.face.dtype == np.int32
        for name in ("distance", "face", "on_boundary"):
            assert np.array_equal(getattr(lean, name), getattr(full, name), equal_nan=True)
    assert np.array_equal(chunked.carried[0], near.positions)
    with pytest.raises(ValueError, match="lean"):
        measured.within(mesh, 2.0)
