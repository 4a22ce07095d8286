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
