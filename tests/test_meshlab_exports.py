"""Exports reload in pymeshlab with the same counts and attributes; decimation keeps boundaries."""

from __future__ import annotations

import threading

import numpy as np
import pymeshlab
import pytest

from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.meshlab.decimation import decimate
from apt_filters.meshlab import exports
from apt_filters.meshlab.exports import (colormap_rgba, read_ply, species_colors, write_ion_cloud, write_mesh,
                                         write_ply, write_project)
from tests.meshlab_shapes import cut_below, merge, sphere


@pytest.fixture()
def iso() -> TriMesh:
    a, b = sphere(4.0, (0, 0, 0), subdiv=3), sphere(2.0, (12, 1, -3), subdiv=2)
    t = merge(a, b)
    x, y, z = t.vertices.T
    return TriMesh(t.vertices, t.faces, {"value": x.copy(), "curvature": z * 0.25, "conc_Ni": y * 0.01},
                   {"object_id": np.r_[np.full(a.n_faces, 1), np.full(b.n_faces, 2)]})


@pytest.fixture()
def ions_ranges() -> tuple[IonTable, RangeTable]:
    rng = np.random.default_rng(3)
    n = 30_000
    pos = rng.uniform([-10, -5, 0], [10, 5, 40], (n, 3)).astype(np.float32)  # x, y, z extents differ
    mz = rng.choice([27.0, 28.0, 58.0, 99.0], n).astype(np.float32)  # 99 Da is unranged
    ranges = RangeTable([Range(26.5, 27.5, (("Al", 1),), "ff0000"), Range(27.6, 28.4, (("Si", 1),), None),
                         Range(57.5, 58.5, (("Cr", 1), ("O", 2)), "00ff00")])
    return IonTable(pos, mz), ranges


def _load(path) -> pymeshlab.MeshSet:
    """The file in a new MeshSet (keep the MeshSet alive while using its current mesh)."""
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(path))
    return ms


def test_ply_reloads_in_pymeshlab_with_quality_colour_and_object_id(tmp_path, iso):
    write_ply(iso, tmp_path / "iso.ply")
    ms = _load(tmp_path / "iso.ply")
    m = ms.current_mesh()
    assert (m.vertex_number(), m.face_number()) == (iso.n_vertices, iso.n_faces)
    np.testing.assert_array_equal(m.vertex_matrix(), iso.vertices)
    np.testing.assert_array_equal(m.face_matrix(), iso.faces)
    np.testing.assert_allclose(m.vertex_scalar_array(), iso.vertex_scalars["value"], rtol=1e-7)  # float32
    np.testing.assert_array_equal(m.face_scalar_array(), iso.face_scalars["object_id"])
    expected = colormap_rgba(iso.vertex_scalars["value"])
    np.testing.assert_allclose(m.vertex_color_matrix(), expected / 255.0, atol=1e-6)
    assert len(np.unique(expected[:, 0])) > 50  # a real colour ramp, not one colour

    back = read_ply(tmp_path / "iso.ply")  # the extra properties, which MeshLab ignores
    assert set(back.vertex_scalars) >= {"value", "curvature", "conc_Ni", "red"}
    np.testing.assert_allclose(back.vertex_scalars["curvature"], iso.vertex_scalars["curvature"], rtol=1e-6)
    np.testing.assert_array_equal(back.face_scalars["object_id"], iso.face_scalars["object_id"])


@pytest.mark.parametrize("ext", [".obj", ".stl", ".off", ".ply"])
def test_other_formats_reload_with_same_counts(tmp_path, iso, ext):
    write_mesh(iso, tmp_path / f"iso{ext}")
    ms = _load(tmp_path / f"iso{ext}")
    m = ms.current_mesh()
    assert m.face_number() == iso.n_faces
    assert m.vertex_number() == iso.n_vertices  # pymeshlab welds STL's per-face vertices on load
    assert TriMesh(m.vertex_matrix(), m.face_matrix()).signed_volume() == pytest.approx(iso.signed_volume(), rel=1e-6)


def test_exports_never_overwrite_unless_asked(tmp_path, iso):
    write_ply(iso, tmp_path / "a.ply")
    for write in (lambda **k: write_ply(iso, tmp_path / "a.ply", **k),
                  lambda **k: write_mesh(iso, tmp_path / "a.ply", **k)):
        with pytest.raises(AptFiltersError, match="exists"):
            write()
        write(overwrite=True)
    with pytest.raises(AptFiltersError, match="format"):
        write_mesh(iso, tmp_path / "a.vtk")
    assert [p.name for p in tmp_path.iterdir()] == ["a.ply"]  # no temporary left behind


def test_ion_cloud_colours_species_and_states_the_ratio(tmp_path, ions_ranges):
    ions, ranges = ions_ranges
    species = ranges.ion_index(ions.mz)
    n_ranged = int((species >= 0).sum())
    full = write_ion_cloud(ions, ranges, tmp_path / "all.ply")
    assert full.n_written == n_ranged and full.ratio == 1.0
    sub = write_ion_cloud(ions, ranges, tmp_path / "sub.ply", max_points=5000)
    assert sub.n_written == 5000 and sub.ratio == pytest.approx(5000 / n_ranged)
    header = (tmp_path / "sub.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"5000 of {n_ranged} ranged ions (sampling ratio {5000 / n_ranged:.6g})" in header

    ms = _load(tmp_path / "sub.ply")
    m = ms.current_mesh()
    assert m.vertex_number() == 5000 and m.face_number() == 0
    s = np.rint(m.vertex_scalar_array()).astype(int)
    rgb = np.rint(m.vertex_color_matrix()[:, :3] * 255).astype(int)
    np.testing.assert_array_equal(rgb, species_colors(ranges)[s])
    assert tuple(species_colors(ranges)[0]) == (255, 0, 0) and tuple(species_colors(ranges)[2]) == (0, 255, 0)
    # each written point is an input ion of that species (x, y, z order kept)
    lookup = {tuple(p): k for p, k in zip(ions.positions, species)}
    pts = m.vertex_matrix().astype(np.float32)
    assert all(lookup[tuple(p)] == k for p, k in zip(pts, s))
    assert np.ptp(pts[:, 2]) > 3 * np.ptp(pts[:, 1])


def test_ion_clouds_written_together_equal_each_written_alone(tmp_path, ions_ranges, monkeypatch):
    """One layer per species in the same two passes (several chunks): each file is the one its species alone
    gives, so a layer does not depend on which others are written with it."""
    ions, ranges = ions_ranges
    monkeypatch.setattr(exports, "CLOUD_CHUNK", len(ions) // 3 + 1)
    layers = {ion: (tmp_path / f"together_{k}.ply", 700 + 300 * k) for k, ion in enumerate(ranges.ions)}
    together = exports.write_ion_clouds(ions, ranges, layers, seed=5)
    assert list(together) == ranges.ions
    for k, ion in enumerate(ranges.ions):
        alone = write_ion_cloud(ions, ranges, tmp_path / f"alone_{k}.ply", max_points=700 + 300 * k, species=ion,
                                seed=5)
        assert (together[ion].n_written, together[ion].n_ions) == (alone.n_written, alone.n_ions)
        assert layers[ion][0].read_bytes() == alone.path.read_bytes()
        assert together[ion].n_written == min(700 + 300 * k, int((ranges.ion_index(ions.mz) == k).sum()))


def test_project_opens_iso_surface_and_ion_cloud_together(tmp_path, iso, ions_ranges):
    write_ply(iso, tmp_path / "iso.ply")
    cloud = write_ion_cloud(*ions_ranges, tmp_path / "ions.ply", max_points=2000)
    write_project(tmp_path / "scene.mlp", [tmp_path / "iso.ply", cloud.path], ["iso-surface", "ions"])
    ms = pymeshlab.MeshSet()
    ms.load_project(str(tmp_path / "scene.mlp"))
    assert ms.mesh_number() == 2
    counts = sorted((ms.mesh(i).vertex_number(), ms.mesh(i).face_number()) for i in range(2))
    assert counts == sorted([(iso.n_vertices, iso.n_faces), (2000, 0)])
    with pytest.raises(AptFiltersError, match="exists"):
        write_project(tmp_path / "scene.mlp", [tmp_path / "iso.ply"])
    with pytest.raises(AptFiltersError, match="not found"):
        write_project(tmp_path / "other.mlp", [tmp_path / "missing.ply"])


def test_decimation_keeps_boundary_loops_exactly_and_is_serialised():
    s = cut_below(sphere(5.0, subdiv=5), 0.0)  # open hemisphere-like surface
    s.vertex_scalars["value"] = s.vertices[:, 2].copy()
    s.face_scalars["object_id"] = np.full(s.n_faces, 7)
    results = [None] * 4

    def work(i):
        results[i] = decimate(s, 0.8)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(4)]
    [t.start() for t in threads]
    [t.join() for t in threads]
    for d in results:
        np.testing.assert_array_equal(d.vertices, results[0].vertices)  # no interference between calls
    d = results[0]
    assert d.n_faces == pytest.approx(0.2 * s.n_faces, rel=0.05)
    before = {tuple(v) for v in s.vertices[np.unique(s.boundary_edges())]}
    after = {tuple(v) for v in d.vertices[np.unique(d.boundary_edges())]}
    assert after == before and len(d.boundary_edges()) == len(s.boundary_edges())
    assert d.area() == pytest.approx(s.area(), rel=0.01)
    assert np.all(np.abs(d.vertex_scalars["value"] - d.vertices[:, 2]) < 0.5)  # nearest-vertex transfer
    assert set(d.face_scalars["object_id"]) == {7}
    with pytest.raises(AptFiltersError):
        decimate(s, 1.0)


def test_ion_cloud_sampling_is_uniform_across_chunks(tmp_path, ions_ranges, monkeypatch):
    import apt_filters.meshlab.exports as exports

    ions, ranges = ions_ranges
    monkeypatch.setattr(exports, "CLOUD_CHUNK", 7_000)  # 5 chunks, the last one short
    cloud = exports.write_ion_cloud(ions, ranges, tmp_path / "c.ply", max_points=6_000, include_unranged=True)
    assert (cloud.n_written, cloud.n_ions) == (6_000, len(ions))
    back = read_ply(tmp_path / "c.ply")
    lookup = {tuple(p): i for i, p in enumerate(ions.positions)}
    index = np.array([lookup[tuple(p)] for p in back.vertices.astype(np.float32)])
    assert np.all(np.diff(index) > 0)  # file order, no repeats
    per_chunk = np.bincount(index // 7_000)
    np.testing.assert_allclose(per_chunk / per_chunk.sum(), [7, 7, 7, 7, 2] / np.float64(30), atol=0.02)
    assert set(np.rint(back.vertex_scalars["quality"]).astype(int)) == {-1, 0, 1, 2}
    full = exports.write_ion_cloud(ions, ranges, tmp_path / "all.ply", include_unranged=True)
    assert full.n_written == len(ions) and full.ratio == 1.0


def test_explicit_vertex_colours_win_over_the_colour_map(tmp_path, iso):
    n = iso.n_vertices
    iso.vertex_scalars.update(red=np.ones(n), green=np.zeros(n), blue=np.full(n, 0.5))
    for cmap in ("viridis", None):
        write_ply(iso, tmp_path / f"{cmap}.ply", cmap=cmap)
        ms = _load(tmp_path / f"{cmap}.ply")
        rgba = np.rint(ms.current_mesh().vertex_color_matrix() * 255)
        assert np.all(rgba == [255, 0, 128, 255])
