"""``apt-filters remesh`` end to end on PLY files."""

import os

import numpy as np

from apt_filters.cli.main import main
from apt_filters.meshlab.bridge import read_mesh
from apt_filters.meshlab.exports import write_mesh
from apt_filters.core.distance import SurfaceDistance
from tests import remesh_shapes as shapes


def test_remesh_cli_round_trip(tmp_path, capsys):
    src = tmp_path / "in.ply"
    mesh = shapes.sphere(6.0)
    mesh.vertex_scalars["value"] = mesh.vertices[:, 0].copy()
    write_mesh(mesh, src, overwrite=False)
    out = tmp_path / "out.ply"
    assert main(["remesh", str(src), "-o", str(out), "--edge-length", "1.0"]) == 0
    result = read_mesh(out)
    assert result.n_faces > 100
    # the input surface's values at its closest point (the vertices straddle it)
    assert np.allclose(result.vertex_scalars["value"], SurfaceDistance(mesh).closest(result.vertices)[0][:, 0], atol=1e-3)
    assert main(["remesh", str(src), "-o", str(out)]) == 2  # exists, no --force
    assert "exists already" in capsys.readouterr().err
    assert main(["remesh", str(src), "-o", str(out), "--force", "--edge-length", "1.5"]) == 0
    assert read_mesh(out).n_faces < result.n_faces
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.ply", "out.ply"]  # no temporary files left


def test_remesh_cli_bad_input(tmp_path, capsys):
    cwd = os.getcwd()
    bad = tmp_path / "bad.ply"
    bad.write_text("this is not a mesh\n")
    assert main(["remesh", str(bad), "-o", str(tmp_path / "o.ply")]) == 2
    assert os.getcwd() == cwd  # pymeshlab moves into the folder of a file it fails to read
    err = capsys.readouterr().err.strip()
    assert "bad.ply" in err and len(err.splitlines()) == 1
    assert main(["remesh", str(tmp_path / "missing.ply"), "-o", str(tmp_path / "o.ply")]) == 2


# The ENO rotated box lost all 12 edges without bridging until dual contouring took rim crossings
# from the end whose tangent line holds there (now 12 either way); the box minus sphere's rims
# still have gaps.
def test_remesh_cli_bridge_gaps_finds_the_eno_box_minus_sphere_edges(tmp_path, capsys):
    src = tmp_path / "box_minus_sphere.ply"
    write_mesh(shapes.dual_contoured("box_minus_sphere", exact_normals=False), src, overwrite=False)
    assert main(["remesh", str(src), "-o", str(tmp_path / "plain.ply")]) == 0
    assert "6 feature curves" in capsys.readouterr().out  # gaps drop 9 of the 15 edges
    assert main(["remesh", str(src), "-o", str(tmp_path / "bridged.ply"), "--bridge-gaps"]) == 0
    assert "15 feature curves" in capsys.readouterr().out
