"""A pymeshlab user's script calling apt-filters steps (scripts/meshset_from_ions.py)."""

import importlib.util

import numpy as np
import pymeshlab

from apt_filters.io import read_ions, read_ranges
from apt_filters.pipeline.config import PipelineConfig
from apt_filters.pipeline.surface import add_iso_surface
from tests.conftest import ROOT


def test_add_iso_surface_puts_the_real_interface_in_a_meshset(real_si, tmp_path):
    ions, ranges = read_ions(real_si / "Si.pos"), read_ranges(real_si / "Si.RRNG")
    ms = pymeshlab.MeshSet()
    ms.create_icosahedron()  # the user's own mesh stays
    config = PipelineConfig()
    config.remesh.method = "none"
    mesh = add_iso_surface(ms, ions, ranges, "Cr", 0.3, config=config, clean_script=tmp_path / "clean.mlx")
    assert ms.mesh_number() == 2 and ms.current_mesh().label() == "Cr 30 at.%"
    assert ms.current_mesh().face_number() == mesh.n_faces > 0
    assert (tmp_path / "clean.mlx").is_file()
    assert -19 < np.median(mesh.vertices[:, 2]) < -14, "the cap/Si interface near z = -16 nm"
    assert len(mesh.boundary_edges()) > 0, "open where it meets the specimen edge"


def test_example_script_runs(real_si, tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("example", ROOT / "scripts" / "meshset_from_ions.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    assert example.main([str(real_si / "Si.pos"), str(real_si / "Si.RRNG"), "Cr", "0.3", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "MeshSet mesh 'Cr 30 at.%'" in out and "after replaying clean.mlx" in out
    inside = float(out.split("beyond 1 nm inside: ")[1].split(" at.%")[0])
    assert inside > 30, "the cap side of the interface is Cr-rich as ranged"
    assert (tmp_path / "scene.mlp").is_file() and (tmp_path / "surface.ply").is_file()
