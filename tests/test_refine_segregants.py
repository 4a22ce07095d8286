"""Segregants found from their peak at a first contour, and left out of the basis (refine.segregants)."""

import dataclasses

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
