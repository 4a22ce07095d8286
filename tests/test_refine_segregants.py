"""Segregants found from their peak at a first contour, and left out of the basis (refine.segregants)."""

import dataclasses

import numpy as np
import pytest

from apt_filters.pipeline.surface import segregant_basis
from apt_filters.pipeline.surface import contour_surface
from apt_filters.refine.segregants import find_segregants
from apt_filters.synth import generate, preset
from apt_filters.voxel import ConcentrationBasis, inside_mask, voxelize


def _first_contour(spec, seed=2):
    sp = generate(spec, seed=seed)
    fields = voxelize(sp.ions, sp.ranges)
    return sp, contour_surface(fields, inside_mask(fields).dense(), "Al", 0.15, "mc")


@pytest.fixture(scope="module")
def shell():
    return _first_contour(preset("small"))


def test_the_boron_shell_is_found_and_nothing_else(shell):
    sp, mesh = shell
    found = find_segregants(mesh, sp.ions, sp.ranges, "Al")
    assert found.species == ("B",)
    assert found.peaks["B"]["z"] > 10
    assert abs(found.peaks["B"]["peak_at_nm"]) < 1.5, "the shell lies near the first contour"
    for element in ("Ni", "Cr"):  # they step between the phases: no peak
        assert found.peaks[element]["z"] < 5


def test_include_keeps_it_and_the_basis_follows(shell):
    sp, mesh = shell
    kept = find_segregants(mesh, sp.ions, sp.ranges, "Al", include=("B",))
    assert kept.species == () and kept.kept == ("B",)
    basis, found = segregant_basis(mesh, sp.ions, sp.ranges, "Al", ConcentrationBasis())
    assert basis.exclude == ("B",) and found.species == ("B",)
    user = ConcentrationBasis(exclude=("B",))
    assert segregant_basis(mesh, sp.ions, sp.ranges, "Al", user)[0] is user, "already left out: nothing to add"


def test_no_shell_no_segregant():
    spec = preset("small")
    plain = dataclasses.replace(spec, features=tuple(dataclasses.replace(f, segregation=()) for f in spec.features))
    sp, mesh = _first_contour(plain)
    assert find_segregants(mesh, sp.ions, sp.ranges, "Al").species == ()


def test_major_elements_of_a_gyroid_cut_by_the_specimen_are_no_segregants():
    """A gyroid (zoo dev draw 5's phases, wavelength and level, no shell) in a 16 nm box: its first contour is
    open where the box cuts it, and the inside phase's ions beyond the rim read as the far outside; counted
    there they dropped the outer phase's majors (Ni 74, Cr 21 at.%) 2-4 nm out, so their plateau read as a
    peak (z 7.5, 5.5) and both were left out of the basis."""
    from apt_filters.synth.geometry import Box
    from apt_filters.synth.implicit import LevelSetInterface
    from apt_filters.synth.zoo import zoo_specimen

    zoo = zoo_specimen("gyroid", 5)
    f, box = zoo.features[0], Box((16.0, 16.0, 16.0))
    shape = LevelSetInterface(box, "gyroid", f.shape.wavelength, f.shape.level, f.shape.seed)
    spec = dataclasses.replace(zoo, geometry=box,
                               features=(dataclasses.replace(f, shape=shape, segregation=()),))
    sp = generate(spec, seed=0)
    fields = voxelize(sp.ions, sp.ranges)
    iso = 0.5 * (f.composition["Al"] + spec.matrix["Al"])
    mesh = contour_surface(fields, inside_mask(fields).dense(), "Al", iso, "mc")
    assert len(mesh.boundary_edges()) > 0, "the surface is open: it has a rim"
    found = find_segregants(mesh, sp.ions, sp.ranges, "Al")
    assert found.species == ()
    for element in ("Ni", "Cr"):
        assert found.peaks[element]["z"] < 5


def _moved(mesh, per_component):
    """A stand-in for a RefineResult whose mesh is ``mesh`` with each component's vertices moved ``per_component``
    nm along their normals (the ``displacement`` the refinement records)."""
    from types import SimpleNamespace

    from apt_filters.core.mesh import TriMesh

    component = mesh.topology.vertex_components
    moved = np.asarray(per_component, dtype=float)[np.maximum(component, 0)]
    return SimpleNamespace(mesh=TriMesh(mesh.vertices, mesh.faces, {"displacement": moved}))


def test_searched_again_only_where_an_object_moved_beyond_the_first_search_reach(shell):
    """The finished surface is searched where some component moved more than GAP nm on average from its first
    contour (its first search then read the shell smeared), and nowhere else: no ion is read."""
    from apt_filters.pipeline.surface import refined_segregants
    from apt_filters.refine.segregants import GAP

    sp, mesh = shell
    n = mesh.topology.n_components
    assert n > 1
    assert refined_segregants(mesh, None, sp.ions, sp.ranges, "Al", ConcentrationBasis()) is None, "not refined"
    near = [0.0] * n
    assert refined_segregants(mesh, _moved(mesh, near), sp.ions, sp.ranges, "Al", ConcentrationBasis()) is None
    at_reach = [GAP] * n  # on average exactly GAP (its signs mixed): within reach
    assert refined_segregants(mesh, _moved(mesh, at_reach), sp.ions, sp.ranges, "Al", ConcentrationBasis()) is None
    one_far = near[:-1] + [-1.01 * GAP]  # one object moved inward beyond reach
    found = refined_segregants(mesh, _moved(mesh, one_far), sp.ions, sp.ranges, "Al", ConcentrationBasis())
    assert found == find_segregants(mesh, sp.ions, sp.ranges, "Al"), "the whole finished surface is searched"
    assert found.species == ("B",)
    user = ConcentrationBasis(exclude=("B",))  # the basis it was drawn in leaves B out already: not tested
    again = refined_segregants(mesh, _moved(mesh, one_far), sp.ions, sp.ranges, "Al", user)
    assert again.species == () and "B" not in again.peaks
    kept = refined_segregants(mesh, _moved(mesh, one_far), sp.ions, sp.ranges, "Al", ConcentrationBasis(), ("B",))
    assert kept.species == () and kept.kept == ("B",)


def test_the_run_reads_segregants_off_its_first_contour_without_the_specks(monkeypatch):
    """A low-contrast contour's noise specks are drawn where the iso species is high by chance; the run's segregant
    search reads the components the speck rule keeps (here the one sphere, every other component noise by
    construction), not the specks."""
    import apt_filters.refine.segregants as segregants
    from apt_filters.pipeline.config import SurfaceConfig
    from apt_filters.pipeline.surface import finished_surface
    from apt_filters.refine import remove_specks
    from tests.speck_specimens import contoured_sphere

    c = contoured_sphere(centre=(2.0, -1.0, -9.5), radius=2.0, contrast=0.10, width=0.2, box=22.0, efficiency=0.5,
                         iso=0.125, seed=1)
    kept, specks = remove_specks(c.mesh, fields=c.fields, mask=c.mask, ions=c.specimen.ions,
                                 ranges=c.specimen.ranges, species="Al", iso=0.125)
    assert specks.count >= 5, "noise draws components at this iso-value: the rule has work"
    read = []

    class Read(Exception):
        pass

    def spy(mesh, *args, **kwargs):
        read.append(mesh)
        raise Read

    monkeypatch.setattr(segregants, "find_segregants", spy)
    with pytest.raises(Read):
        finished_surface(c.fields, c.mask, c.specimen.ions, c.specimen.ranges, SurfaceConfig("Al", 0.125))
    assert np.array_equal(read[0].vertices, kept.vertices) and np.array_equal(read[0].faces, kept.faces)
