"""``apt-filters proxigram`` end to end on a synthetic specimen with known excess (apt_filters.synth)."""

import csv
import json

import numpy as np
import pytest

from apt_filters.cli.main import main
from apt_filters.meshlab.bridge import read_mesh
from apt_filters.core.mesh import TriMesh
from apt_filters.meshlab.exports import write_ply
from apt_filters.synth import preset, write_specimen


@pytest.fixture(scope="module")
def small_specimen(tmp_path_factory):
    """The 'small' preset (a flat layer, a rotated cube, a sphere; B at every interface) and one
    mesh holding all three true surfaces, so that each ion goes to its nearest object."""
    out = tmp_path_factory.mktemp("spec")
    spec = write_specimen(out, preset("small"), seed=3)
    meshes = [read_mesh(out / f["mesh"]["file"]) for f in spec.truth["features"]]
    offsets = np.cumsum([0] + [m.n_vertices for m in meshes])
    write_ply(TriMesh(np.concatenate([m.vertices for m in meshes]),
                      np.concatenate([m.faces + o for m, o in zip(meshes, offsets)])), out / "all.ply")
    return out, spec.truth


@pytest.mark.slow
def test_cli_proxigram_excess_matches_truth(small_specimen, capsys):
    folder, truth = small_specimen
    out = folder / "out"
    argv = [str(folder / "specimen.pos"), "-r", str(folder / "specimen.rrng"), "-m", str(folder / "all.ply"),
            "-o", str(out), "--solute", "B", "--range-nm", "2.5", "--iso", "0.15"]
    assert main(["proxigram", *argv]) == 0
    assert "at the open rim left out" in capsys.readouterr().out
    doc = json.loads((out / "excess.json").read_text())
    results = {r["object_id"]: r for r in doc["results"]}
    features = truth["features"]  # layer (open plane), cube, sphere: objects 0, 1, 2
    for k, feature in enumerate(features):
        est = results[k]["integration"]
        true = feature["excess"]["B"]["ions_per_nm2"]
        assert abs(est["gamma_detected"] - true) < 3 * est["gamma_detected_error"]
        assert results[k]["area"] == pytest.approx(feature["mesh"]["area_nm2"], rel=1e-6)
    pooled_truth = (sum(f["excess"]["B"]["excess_ions"] for f in features)
                    / sum(f["mesh"]["area_nm2"] for f in features))
    for method in ("integration", "cumulative"):
        assert results[-1][method]["gamma_detected"] == pytest.approx(pooled_truth, rel=0.10)
        assert results[-1][method]["gamma_atoms"] == pytest.approx(pooled_truth / truth["efficiency"], rel=0.10)
    rows = list(csv.DictReader(open(out / "proxigram.csv")))
    assert len(rows) == 50 and {r["object"] for r in rows} == {"-1"}
    # outside all three objects is the matrix: plateau within 1 at.% of it
    far = [r for r in rows if float(r["distance_nm"]) < -1.0]
    al = sum(int(r["atoms_Al"]) for r in far) / sum(int(r["n_atoms"]) for r in far)
    assert al == pytest.approx(truth["matrix_composition"]["Al"], abs=0.01)
    objects = list(csv.DictReader(open(out / "proxigram_objects.csv")))
    assert len(objects) == 150
    assert (out / "proxigram.png").read_bytes()[:4] == b"\x89PNG"
    # outputs are not replaced without --force
    assert main(["proxigram", *argv]) == 2
    assert "--force" in capsys.readouterr().err


def test_cli_bad_inputs(small_specimen, tmp_path, capsys):
    folder, _ = small_specimen
    base = [str(folder / "specimen.pos"), "-r", str(folder / "specimen.rrng"), "-o", str(tmp_path / "o")]
    assert main(["proxigram", *base, "-m", str(folder / "truth.json")]) == 2
    assert "truth.json: cannot read mesh: Unknown format" in capsys.readouterr().err
    bad = tmp_path / "bad.ply"
    bad.write_text("ply\nnot really\n")
    assert main(["proxigram", *base, "-m", str(bad)]) == 2
    assert "bad.ply: cannot read mesh" in capsys.readouterr().err
    assert main(["proxigram", *base, "-m", str(tmp_path / "missing.ply")]) == 2
    assert "missing.ply: mesh file not found" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_cli_proxigram_fits_its_windows_with_the_species(small_specimen, capsys):
    """--species: the windows and range from the fitted Al step of the Al-rich cube and sphere; their B excess
    still matches the truth."""
    folder, truth = small_specimen
    features = truth["features"][1:]  # the cube and the sphere (the layer below is Al-poor: another step)
    meshes = [read_mesh(folder / f["mesh"]["file"]) for f in features]
    write_ply(TriMesh(np.concatenate([m.vertices for m in meshes]),
                      np.concatenate([meshes[0].faces, meshes[1].faces + meshes[0].n_vertices])), folder / "two.ply")
    out = folder / "fitted"
    assert main(["proxigram", str(folder / "specimen.pos"), "-r", str(folder / "specimen.rrng"), "-m",
                 str(folder / "two.ply"), "-o", str(out), "--solute", "B", "--species", "al"]) == 0
    printed = capsys.readouterr().out
    assert "(fitted; Al 10-90 % width" in printed
    results = json.loads((out / "excess.json").read_text())["results"]
    inner, outer = results[0]["window_nm"]
    assert outer == pytest.approx(3 * inner) and f"±{outer:g} nm" in printed
    for k, feature in enumerate(features):
        est = results[k]["integration"]
        true = feature["excess"]["B"]["ions_per_nm2"]
        assert abs(est["gamma_detected"] - true) < 3 * est["gamma_detected_error"], (k, est, true)
