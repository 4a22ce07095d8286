"""MeshLab integration: filter check, bridge, chains and their .mlx scripts, safe replay."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess

import numpy as np
import pymeshlab
import pytest

from apt_filters.cli.main import main
from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.mesh import TriMesh
from apt_filters.meshlab.bridge import AttributeNames, from_pymeshlab, to_meshset, to_pymeshlab
from apt_filters.meshlab.chains import (CHAINS, Chain, Percent, Step, apply_chain, apply_chain_to_meshset,
                                        chain_from_json, resolve)
from apt_filters.meshlab.exports import write_ply
from apt_filters.meshlab.filters import FILTERS, check_filters
from apt_filters.meshlab.mlx import parse_script, replay_file
from tests.meshlab_shapes import cut_below, merge, sphere


@pytest.fixture()
def scalar_sphere() -> TriMesh:
    """Radius-5 icosphere, 1280 faces, with distinct vertex and face values (x, z ordering visible)."""
    t = sphere(5.0, (1.0, 2.0, 3.0), subdiv=3)
    x, y, z = t.vertices.T
    return TriMesh(t.vertices, t.faces, {"value": x.copy(), "conc_Cr": 0.1 * z + 0.5},
                   {"object_id": np.arange(t.n_faces) % 4 + 1})


def _noisy(t: TriMesh, sigma: float, seed: int = 1) -> TriMesh:
    rng = np.random.default_rng(seed)
    return TriMesh(t.vertices + rng.normal(0, sigma, t.vertices.shape), t.faces, t.vertex_scalars, t.face_scalars)


# --- the filter check at import -------------------------------------------------------------

def test_filter_check_names_opengl_library_when_meshing_filters_hidden():
    available = [f for f in pymeshlab.filter_list() if not f.startswith("meshing_")]
    with pytest.raises(AptFiltersError, match="libopengl0"):
        check_filters(available)
    check_filters(pymeshlab.filter_list())  # the real installation passes


def test_allow_list_matches_the_names_meshlab_writes(tmp_path):
    ms = pymeshlab.MeshSet()
    ms.create_sphere(subdiv=2)
    ms.clear_filter_script()
    for f in FILTERS:
        getattr(ms, f)()
    ms.save_filter_script(str(tmp_path / "all.mlx"))
    assert re.findall(r'<filter name="([^"]+)"', (tmp_path / "all.mlx").read_text()) == list(FILTERS.values())
    assert not any(f.endswith("_gpu") for f in FILTERS)


# --- bridge ------------------------------------------------------------------------------------

def test_bridge_round_trip_keeps_every_scalar_and_colour(scalar_sphere):
    t = scalar_sphere
    t.vertex_scalars.update(red=np.linspace(0, 1, t.n_vertices), green=np.full(t.n_vertices, 0.5),
                            blue=np.zeros(t.n_vertices))
    m, names = to_pymeshlab(t)
    assert names.quality == "value" and names.vertex == (("conc_Cr", "<f8"),)
    np.testing.assert_array_equal(m.vertex_scalar_array(), t.vertex_scalars["value"])
    np.testing.assert_array_equal(m.face_scalar_array(), t.face_scalars["object_id"])  # face quality
    back = from_pymeshlab(m, names)
    np.testing.assert_array_equal(back.vertices, t.vertices)
    np.testing.assert_array_equal(back.faces, t.faces)
    for k, v in t.vertex_scalars.items():
        np.testing.assert_allclose(back.vertex_scalars[k], v, atol=0 if k not in ("red", "green", "blue") else 1 / 255)  # 8-bit colour
    assert back.face_scalars["object_id"].dtype == np.int64
    np.testing.assert_array_equal(back.face_scalars["object_id"], t.face_scalars["object_id"])


def test_bridge_without_layout_reads_quality_and_object_id(scalar_sphere):
    ms, _ = to_meshset(scalar_sphere, quality="conc_Cr")
    back = from_pymeshlab(ms)
    np.testing.assert_array_equal(back.vertex_scalars["value"], scalar_sphere.vertex_scalars["conc_Cr"])
    np.testing.assert_array_equal(back.face_scalars["object_id"], scalar_sphere.face_scalars["object_id"])
    assert AttributeNames.of(TriMesh(np.zeros((3, 3)), [[0, 1, 2]])).quality is None


def test_scalars_follow_vertices_through_a_deleting_filter(scalar_sphere):
    speck = sphere(0.02, (20, 0, 0), subdiv=0)  # 20 faces, box diagonal below 0.5 % of the whole one
    t = merge(scalar_sphere, speck)
    t = TriMesh(t.vertices, t.faces, {"value": t.vertices[:, 0].copy(), "zz": t.vertices[:, 2] * 2},
                {"object_id": np.r_[np.ones(scalar_sphere.n_faces, int), np.full(20, 9)]})
    out, _ = apply_chain(t, "clean")
    assert out.n_faces == scalar_sphere.n_faces
    np.testing.assert_array_equal(out.vertex_scalars["value"], out.vertices[:, 0])
    np.testing.assert_array_equal(out.vertex_scalars["zz"], out.vertices[:, 2] * 2)
    assert set(out.face_scalars["object_id"]) == {1}


# --- chains --------------------------------------------------------------------------------

def test_clean_chain_welds_removes_specks_and_degenerate_faces():
    s = sphere(5.0, subdiv=3)
    soup = TriMesh(s.vertices[s.faces].reshape(-1, 3), np.arange(3 * s.n_faces).reshape(-1, 3))  # unwelded
    degenerate = TriMesh(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]) + 50, [[0, 1, 2]])
    tiny = sphere(0.05, (30, 0, 0), subdiv=0)  # 20 faces, removed by diameter
    few_faces = sphere(3.0, (0, 30, 0), subdiv=0)  # large, but 20 faces ...
    few_faces = TriMesh(few_faces.vertices, few_faces.faces[:8])  # ... cut to 8 faces: removed by face count
    t = merge(soup, tiny, few_faces, degenerate)
    out, _ = apply_chain(t, "clean")
    assert (out.n_vertices, out.n_faces) == (s.n_vertices, s.n_faces)
    assert len(out.boundary_edges()) == 0 and out.non_manifold_edge_count() == 0
    assert out.signed_volume() == pytest.approx(s.signed_volume(), rel=1e-12)


def test_close_chain_closes_an_open_cap_to_a_watertight_proxy():
    s = sphere(5.0, subdiv=3)
    open_mesh = cut_below(s, -4.0)  # a hole at the south pole, rim near z = -4
    rim = open_mesh.vertices[np.unique(open_mesh.boundary_edges()), 2]
    assert len(rim) > 0
    open_mesh.face_scalars["object_id"] = np.full(open_mesh.n_faces, 3)
    out, _ = apply_chain(open_mesh, "close")
    assert len(out.boundary_edges()) == 0 and out.non_manifold_edge_count() == 0
    cap = out.face_scalars["cap"].astype(bool)
    assert cap.sum() == out.n_faces - open_mesh.n_faces and not cap[:open_mesh.n_faces].any()
    assert np.all(out.face_scalars["object_id"] == 3)  # caps take their surface's id
    smoothed, _ = apply_chain(out, "smooth")
    np.testing.assert_array_equal(smoothed.face_scalars["cap"], out.face_scalars["cap"])  # flags travel on
    np.testing.assert_array_equal(apply_chain(smoothed, "close")[0].face_scalars["cap"], out.face_scalars["cap"])
    h = 5.0 + rim.mean()  # height of the missing cap
    truth = 4 / 3 * np.pi * 125 - np.pi * h**2 * (15.0 - h) / 3
    assert out.signed_volume() == pytest.approx(truth, rel=0.01)


def test_smoothing_chains_reduce_noise_and_taubin_keeps_volume():
    s = sphere(5.0, subdiv=4)
    noisy = _noisy(s, 0.1)

    def radial_rms(t):
        return float(np.sqrt(np.mean((np.linalg.norm(t.vertices, axis=1) - 5.0) ** 2)))

    taubin, _ = apply_chain(noisy, "smooth")
    hc, _ = apply_chain(noisy, "smooth_hc")
    assert radial_rms(taubin) < 0.5 * radial_rms(noisy)
    assert radial_rms(hc) < 0.7 * radial_rms(noisy)
    assert taubin.signed_volume() == pytest.approx(4 / 3 * np.pi * 125, rel=0.02)


def test_decimate_chain_halves_faces_and_keeps_the_boundary():
    open_mesh = cut_below(sphere(5.0, subdiv=4), 0.0)
    out, _ = apply_chain(open_mesh, "decimate")
    assert out.n_faces == pytest.approx(open_mesh.n_faces / 2, rel=0.02)
    before = {tuple(v) for v in open_mesh.vertices[np.unique(open_mesh.boundary_edges())]}
    after = {tuple(v) for v in out.vertices[np.unique(out.boundary_edges())]}
    assert after == before


@pytest.mark.parametrize("name", list(CHAINS))
def test_saved_script_replays_bit_identically_and_loads_in_pymeshlab(name, tmp_path):
    t = _noisy(cut_below(sphere(5.0, (1, 2, 3), subdiv=3), 0.0), 0.05)
    t.vertex_scalars["value"] = t.vertices[:, 2].copy()
    out, run = apply_chain(t, name, tmp_path / f"{name}.mlx")
    script = tmp_path / f"{name}.mlx"
    names = re.findall(r'<filter name="([^"]+)"', script.read_text())
    assert names == [FILTERS[s.filter] for s in CHAINS[name].steps]  # the chain and nothing else

    write_ply(t, tmp_path / "in.ply")
    assert main(["replay", str(script), str(tmp_path / "in.ply"), "-o", str(tmp_path / "out.ply")]) == 0
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(tmp_path / "out.ply"))
    np.testing.assert_array_equal(ms.current_mesh().vertex_matrix(), out.vertices)
    np.testing.assert_array_equal(ms.current_mesh().face_matrix(), out.faces)

    ms = pymeshlab.MeshSet()  # MeshLab's own engine, no apt-filters in between
    ms.load_new_mesh(str(tmp_path / "in.ply"))
    ms.load_filter_script(str(script))
    ms.apply_filter_script()
    np.testing.assert_array_equal(ms.current_mesh().vertex_matrix(), out.vertices)

    record = json.loads(script.with_suffix(".json").read_text())
    assert chain_from_json(script.with_suffix(".json")) == CHAINS[name]
    assert [s["mlx_name"] for s in record["steps"]] == names


def test_relative_parameters_are_rederived_for_another_dataset(tmp_path):
    chain = Chain("c", "", (Step("meshing_remove_connected_component_by_diameter",
                                 {"mincomponentdiag": Percent(2.0), "removeunref": True}),))
    assert resolve(chain.steps[0].params, 100.0)["mincomponentdiag"] == 2.0
    small, run_small = apply_chain(sphere(1.0, subdiv=2), chain, tmp_path / "small.mlx")
    big, run_big = apply_chain(sphere(10.0, subdiv=2), chain_from_json(tmp_path / "small.json"), tmp_path / "big.mlx")
    ratio = run_big.resolved[0]["mincomponentdiag"] / run_small.resolved[0]["mincomponentdiag"]
    assert ratio == pytest.approx(10.0, rel=1e-5)
    value = re.search(r'name="MinComponentDiag"[^>]*value="([^"]+)"|value="([^"]+)"[^>]*name="MinComponentDiag"',
                      (tmp_path / "big.mlx").read_text())
    assert float(value.group(1) or value.group(2)) == run_big.resolved[0]["mincomponentdiag"]


def test_chain_refuses_to_overwrite_and_rejects_unknown_names(tmp_path, scalar_sphere):
    apply_chain(scalar_sphere, "smooth", tmp_path / "s.mlx")
    with pytest.raises(AptFiltersError, match="exists"):
        apply_chain(scalar_sphere, "smooth", tmp_path / "s.mlx")
    apply_chain(scalar_sphere, "smooth", tmp_path / "s.mlx", overwrite=True)
    with pytest.raises(AptFiltersError, match="unknown chain"):
        apply_chain(scalar_sphere, "polish")
    with pytest.raises(AptFiltersError, match="not one apt-filters allows"):
        Step("apply_filter_gpu_something")


# --- untrusted scripts ------------------------------------------------------------------------

BOMB = b"""<?xml version="1.0"?>
<!DOCTYPE FilterScript [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>
<FilterScript><filter name="Taubin Smooth"><Param name="mu" value="&b;" type="RichFloat"/></filter></FilterScript>"""
EXTERNAL = b"""<!DOCTYPE FilterScript SYSTEM "file:///etc/passwd"><FilterScript/>"""


@pytest.mark.parametrize("data, message", [
    (BOMB, "DTD or entity"),
    (EXTERNAL, "DTD or entity"),
    (b"<FilterScript><filter name='Remove Duplicate Faces'></FilterScript>", "malformed"),
    (b"<MeshLabProject/>", "not a MeshLab filter script"),
    (b"<FilterScript><filter name='Delete Everything Smartly'/></FilterScript>", "unknown filter.*Delete Everything"),
    (b"<FilterScript><xmlfilter name='Taubin Smooth'/></FilterScript>", "unknown filter"),
    (b"<?xml-stylesheet href='x'?><FilterScript/>", "processing instruction"),
    (BOMB.decode().replace('"1.0"', '"1.0" encoding="UTF-16"').encode("utf-16"), "not UTF-8"),
    (BOMB.decode().encode("utf-16-le"), "not UTF-8"),  # no BOM: expat would still sniff UTF-16
])
def test_unsafe_or_unknown_scripts_are_refused(data, message):
    with pytest.raises(InputError, match=message):
        parse_script(data, "x.mlx")


def test_replay_refuses_unknown_parameter_and_reports_one_line(tmp_path, scalar_sphere, capsys):
    write_ply(scalar_sphere, tmp_path / "in.ply")
    script = tmp_path / "bad.mlx"
    script.write_bytes(b'<!DOCTYPE FilterScript>\n<FilterScript><filter name="Taubin Smooth">'
                       b'<Param name="explode" value="1" type="RichInt"/></filter></FilterScript>')
    with pytest.raises(InputError, match="no parameter explode"):
        replay_file(script, tmp_path / "in.ply", tmp_path / "out.ply")
    script.write_bytes(BOMB)
    assert main(["replay", str(script), str(tmp_path / "in.ply"), "-o", str(tmp_path / "out.ply")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.mlx" in err and "DTD" in err
    assert not (tmp_path / "out.ply").exists()


def test_replay_never_overwrites_unless_forced(tmp_path, scalar_sphere):
    apply_chain(scalar_sphere, "smooth", tmp_path / "s.mlx")
    write_ply(scalar_sphere, tmp_path / "in.ply")
    before = (tmp_path / "in.ply").read_bytes()
    with pytest.raises(AptFiltersError, match="overwrite the input"):
        replay_file(tmp_path / "s.mlx", tmp_path / "in.ply", tmp_path / "in.ply", overwrite=True)
    replay_file(tmp_path / "s.mlx", tmp_path / "in.ply", tmp_path / "out.ply")
    with pytest.raises(AptFiltersError, match="exists"):
        replay_file(tmp_path / "s.mlx", tmp_path / "in.ply", tmp_path / "out.ply")
    replay_file(tmp_path / "s.mlx", tmp_path / "in.ply", tmp_path / "out.ply", overwrite=True)
    assert (tmp_path / "in.ply").read_bytes() == before


@pytest.mark.skipif(shutil.which("meshlabserver") is None or shutil.which("xvfb-run") is None,
                    reason="meshlabserver (Debian package meshlab) and xvfb-run not installed")
def test_meshlabserver_replays_our_script(tmp_path, scalar_sphere):
    out, _ = apply_chain(scalar_sphere, "smooth", tmp_path / "s.mlx")
    write_ply(scalar_sphere, tmp_path / "in.ply")
    subprocess.run(["xvfb-run", "-a", "meshlabserver", "-i", str(tmp_path / "in.ply"), "-o",
                    str(tmp_path / "out.ply"), "-s", str(tmp_path / "s.mlx")], check=True, timeout=120)
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(tmp_path / "out.ply"))
    np.testing.assert_allclose(ms.current_mesh().vertex_matrix(), out.vertices, atol=1e-5)


def test_pymeshlab_example_script_runs(tmp_path, capfd):
    import runpy

    from tests.conftest import ROOT

    example = runpy.run_path(str(ROOT / "scripts" / "pymeshlab_example.py"))
    assert example["main"]([str(tmp_path)]) == 0
    captured = capfd.readouterr()  # file-descriptor level: MeshLab's own echo would show here
    assert "object 1: closed" in captured.out and "genus 1" in captured.out
    assert "Reading filter" not in captured.out + captured.err
    assert {"clean.mlx", "clean.json", "smooth.mlx", "objects.csv", "smoothed.ply", "scene.mlp"} <= \
        {p.name for p in tmp_path.iterdir()}


def test_import_fails_clearly_without_the_meshing_filters(monkeypatch):
    import importlib

    import apt_filters.meshlab as package

    real = pymeshlab.filter_list()
    monkeypatch.setattr(pymeshlab, "filter_list", lambda: [f for f in real if not f.startswith("meshing_")])
    with pytest.raises(AptFiltersError, match="libopengl0"):
        importlib.reload(package)
    monkeypatch.undo()
    importlib.reload(package)


def test_chain_on_a_users_meshset_records_only_the_chain(tmp_path):
    ms = pymeshlab.MeshSet()
    ms.create_sphere(subdiv=3)  # the user's history: a creation filter and a smoothing
    ms.apply_coord_laplacian_smoothing()
    ms.current_mesh().add_vertex_custom_scalar_attribute(ms.current_mesh().vertex_matrix()[:, 2].copy(), "z")
    run = apply_chain_to_meshset(ms, "decimate", tmp_path / "d.mlx")
    assert ms.mesh_number() == 2 and ms.current_mesh().label().endswith("(decimate)")
    assert re.findall(r'<filter name="([^"]+)"', (tmp_path / "d.mlx").read_text()) == \
        ["Simplification: Quadric Edge Collapse Decimation"]
    m = ms.current_mesh()
    assert m.face_number() == ms.mesh(0).face_number() // 2
    assert run.resolved[0]["targetperc"] == 0.5
    z = m.vertex_custom_scalar_attribute_array("z")  # custom attributes stay inside MeshLab
    assert np.all(np.abs(z - m.vertex_matrix()[:, 2]) < 0.2)


def test_unreadable_mesh_is_one_error_and_leaves_the_working_directory(tmp_path, monkeypatch):
    from apt_filters.meshlab.bridge import load_mesh

    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "bad.ply").write_text("not a mesh\n")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match="bad.ply"):
        load_mesh("sub/bad.ply")
    assert os.getcwd() == str(tmp_path)
