"""What users see: the report's numbers and summary, species names, and the MeshLab scene's files.

Every expected value is exact (counts placed by hand), so each check can fail."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from apt_filters.analysis.proxigram import Proxigram
from apt_filters.analysis.width import ProfileFit
from apt_filters.core.errors import AptFiltersError
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable
from apt_filters.meshlab.exports import POINTS_RENDERING, SIDE_VIEW, read_ply, write_ply, write_project
from apt_filters.pipeline.inputs import match_species
from apt_filters.pipeline.report import number, warnings_in_words, with_error
from apt_filters.pipeline.scene import layer_quotas, scene_species, vertex_composition, write_scene
from apt_filters.pipeline.summary import object_plateaus, surface_summary, window_composition
from tests.meshlab_shapes import sphere


@pytest.mark.parametrize("value, error, text", [
    (4.2834, 0.1234, "4.28 ± 0.12"), (4.2834, 0.0234, "4.28 ± 0.02"), (0.117, 0.0191, "0.117 ± 0.019"),
    (55.14, 0.31, "55.1 ± 0.3"), (-0.7, 0.66, "-0.7 ± 0.7"), (1234.6, 56.0, "1235 ± 56"),
    (float("nan"), 0.1, "—"), (None, None, "—"), (3.0, float("nan"), "3.00")])
def test_values_are_rounded_to_their_error(value, error, text):
    assert with_error(value, error) == text



def test_a_fraction_counted_at_zero_or_one_shows_the_rule_of_three_bound():
    # 0 of 48 atoms: no binomial error, but 3/48 bounds the fraction at 95 %
    assert with_error(0.0, 0.0, 100, atoms=48) == "0 (95 % bound < 6.25)"
    assert with_error(1.0, 0.0, 100, atoms=300) == "100 (95 % bound > 99.0)"
    assert with_error(0.5, 0.07, 100, atoms=48) == "50 ± 7"

def test_numbers_have_sensible_precision_and_no_reprs():
    assert number(np.float64(1008.4)) == "1,008"
    assert number(0.8912) == "0.891"
    assert number(12345) == "12,345"
    assert number(float("nan")) == "—" and number(None) == "—"
    assert number(True) == "yes"


def _proxigram(counts: np.ndarray, object_ids=(0, 1, 2), areas=(10.0, 20.0, 30.0)) -> Proxigram:
    """3 objects, 6 bins of 1 nm over ±3 nm, ions A (one A atom) and AB2 (an A and two B)."""
    k = len(object_ids)
    return Proxigram(edges=np.arange(-3.0, 3.5, 1.0), ions=["A", "AB2"], elements=["A", "B"],
                     element_matrix=np.array([[1, 0], [1, 2]]), colors={"A": None, "AB2": None},
                     object_ids=np.array(object_ids), counts=counts, unranged=np.zeros((k, 6), np.int64),
                     areas=np.array(areas, float), shell_volumes=np.ones((k, 6)))


def test_window_composition_counts_atoms_in_the_plateau_windows():
    counts = np.zeros((1, 6, 2), np.int64)
    counts[0, :3] = [90, 5]  # outside (s < 0): 90 A + 5 AB2 per bin -> A 95, B 10 atoms per bin
    counts[0, 3:] = [40, 30]  # inside: A 70, B 60 atoms per bin
    comp = window_composition(_proxigram(counts, (0,), (10.0,)), inner=1.0, outer=3.0)
    # windows |s| in [1, 3]: bin centres 1.5 and 2.5 on each side (two bins)
    assert comp["outside"]["atoms"] == 2 * 105 and comp["inside"]["atoms"] == 2 * 130
    assert comp["inside"]["fraction"]["B"] == pytest.approx(60 / 130)
    assert comp["outside"]["fraction"]["A"] == pytest.approx(95 / 105)
    c = 60 / 130
    assert comp["inside"]["error"]["B"] == pytest.approx(math.sqrt(c * (1 - c) / 260))


def test_an_object_thinner_than_the_windows_is_counted_in_its_deeper_half_and_said_so():
    counts = np.zeros((2, 6, 2), np.int64)
    counts[:, :3] = [100, 0]  # outside both: A only
    counts[0, 3:] = [40, 30]  # a thick object: A 70, B 60 atoms in every inside bin (centres 0.5, 1.5, 2.5 nm)
    counts[1, 3] = [10, 20]  # a thin one: A 30, B 40 atoms in its first inside bin (centre 0.5 nm) ...
    counts[1, 5] = [1, 0]  # ... and one A a bump put 2.5 nm deep: 1 of its 71 atoms, not its depth
    prox = _proxigram(counts, (0, 1), (10.0, 20.0))
    # the thick object's depth (90 % of its inside atoms within it) is 2.5 nm, twice the inner edge (1 nm) and
    # more: it keeps its window (1.5 and 2.5 nm); the thin one's is 0.5 nm: its window starts at 0.25 nm and
    # holds all its inside atoms
    [thick, thin] = object_plateaus(prox, inner=1.0, outer=3.0)
    assert (thick["from_nm"], thick["nearer"], thick["atoms"]) == (1.0, False, 2 * 130)
    assert (thin["from_nm"], thin["nearer"], thin["to_nm"], thin["atoms"]) == (0.25, True, 3.0, 71)
    assert thin["fraction"]["B"] == pytest.approx(40 / 71)
    assert thin["error"]["B"] == pytest.approx(math.sqrt(40 / 71 * 31 / 71 / 71))
    # pooled, each object counts in its own window
    both = window_composition(prox, inner=1.0, outer=3.0)
    assert both["inside"]["atoms"] == 2 * 130 + 71
    assert both["inside"]["fraction"]["B"] == pytest.approx((2 * 60 + 40) / (2 * 130 + 71))
    assert both["inside"]["nearer"] == [{"object_id": 1, "from_nm": 0.25}]
    assert both["outside"]["atoms"] == 2 * 2 * 100
    # the report says whose plateau may not be reached
    objects = [{"object_id": i, "status": "closed", "volume": 1.0, "area": 10.0, "sphericity": 1.0} for i in (0, 1)]
    summary = surface_summary(objects=objects, proxigram=prox, solutes=[], efficiency=0.5)
    words = warnings_in_words({"surfaces": [{"label": "A 50 %", "mesh": {}, "summary": summary,
                                             "plateaus": [thick, thin]}]})
    assert any("object 1 is counted from 0.25 nm" in w and "more than its counting error" in w for w in words), words


def test_a_window_counted_nearer_is_short_of_its_plateau_only_where_the_fitted_step_can_bias_it_beyond_its_noise():
    counts = np.zeros((1, 6, 2), np.int64)
    counts[0, :3] = [100, 0]
    counts[0, 3] = [10, 20]  # a thin object: B 40 of 70 + 1 atoms from 0.25 nm, error 0.059
    counts[0, 5] = [1, 0]
    prox = _proxigram(counts, (0,), (20.0,))

    def step(sigma):  # B from 0 outside to 0.6 inside, steepest at the surface
        return ProfileFit("B", 0.0, 0.01, 2.563 * sigma, 0.01, 0.0, sigma, sigma, 0.0, 0.6, 0.01, 0.01)

    # a 0.3 nm blur: at 0.25 nm the step is Phi(0.83) = 80 % reached, up to 0.12 of B mixed in (> 0.059)
    [wide] = object_plateaus(prox, inner=1.0, outer=3.0, step=step(0.3))
    assert wide["reached"] == pytest.approx(0.7977, abs=1e-4) and wide["nearer"] and wide["short"]
    # a 0.05 nm blur: reached to 1 - 3e-7, the window is the plateau within its noise
    [sharp] = object_plateaus(prox, inner=1.0, outer=3.0, step=step(0.05))
    assert sharp["reached"] > 0.999 and sharp["nearer"] and not sharp["short"]
    words = warnings_in_words({"surfaces": [{"label": "B", "mesh": {}, "summary": [], "plateaus": [wide]}]})
    assert any("80-80 % reached" in w for w in words), words
    assert not [w for w in warnings_in_words({"surfaces": [{"label": "B", "mesh": {}, "summary": [],
                                                            "plateaus": [sharp]}]}) if "counted from" in w]


def test_a_surface_contoured_at_a_grown_delocalization_says_so_and_why():
    grown = {"factor": 1.97, "ratio": 3.41, "needed": 3.33, "voxels": 1100, "limited": False}
    words = warnings_in_words({"surfaces": [{"label": "Mg 10 %", "mesh": {"noise_scale": grown}, "summary": []}]})
    assert any(w.startswith("Mg 10 %: contoured at 1.97× the delocalization") and "3.33" in w and "folds." not in w
               for w in words), words
    limited = warnings_in_words({"surfaces": [{"label": "Mg 10 %", "summary": [],
                                               "mesh": {"noise_scale": grown | {"factor": 2.0, "limited": True}}}]})
    assert any("may hold folds" in w for w in limited), limited
    kept = {"factor": 1.0, "ratio": 12.0, "needed": 3.3, "voxels": 900, "limited": False}
    assert not [w for w in warnings_in_words({"surfaces": [{"label": "Mg 10 %", "mesh": {"noise_scale": kept},
                                                            "summary": []}]}) if "delocalization" in w]


def test_summary_keeps_interior_and_edge_objects_apart_and_pools_them_as_all_objects():
    counts = np.zeros((3, 6, 2), np.int64)
    counts[:, :3] = [100, 0]
    counts[:, 3:] = [50, 50]
    counts[2, 3:] = [100, 0]  # the open object has no B inside
    objects = [{"object_id": 0, "status": "closed", "volume": 100.0, "area": 10.0, "sphericity": 0.9},
               {"object_id": 1, "status": "closed", "volume": 50.0, "area": 20.0, "sphericity": 0.7},
               {"object_id": 2, "status": "open", "volume": math.nan, "area": 30.0, "sphericity": math.nan}]
    rows = {r["group"]: r for r in surface_summary(objects=objects, proxigram=_proxigram(counts), solutes=["B"],
                                                   efficiency=0.5)}
    assert list(rows) == ["interior", "edge", "all"]
    assert rows["all"]["label"] == "all objects"
    assert rows["interior"]["objects"] == 2 and rows["interior"]["volume_nm3"] == 150.0
    assert rows["edge"]["volume_nm3"] is None and rows["edge"]["sphericity_mean"] is None
    assert rows["interior"]["sphericity_mean"] == pytest.approx(0.8)
    assert rows["interior"]["sphericity_sd"] == pytest.approx(math.sqrt(0.02))
    assert rows["all"]["area_nm2"] == 60.0
    # inside, per bin: a closed object 50 A + 50 AB2 = 100 A and 100 B atoms; the open one 100 A
    assert rows["interior"]["composition"]["inside"]["fraction"]["B"] == pytest.approx(0.5)
    assert rows["edge"]["composition"]["inside"]["fraction"]["B"] == 0.0
    assert rows["all"]["composition"]["inside"]["fraction"]["B"] == pytest.approx(200 / 500)
    assert set(rows["all"]["excess"]) == {"B"}


def test_summary_has_no_all_row_when_every_object_is_interior():
    counts = np.zeros((1, 6, 2), np.int64)
    counts[0] = [10, 1]
    rows = surface_summary(objects=[{"object_id": 0, "status": "closed", "volume": 1.0, "area": 10.0,
                                     "sphericity": 1.0}], proxigram=_proxigram(counts, (0,), (10.0,)),
                           solutes=[], efficiency=0.5)
    assert [r["group"] for r in rows] == ["interior"]


@pytest.mark.parametrize("typed, expected", [("ni", "Ni"), ("NI", "Ni"), ("Ni", "Ni"), ("cr2o", "Cr2O")])
def test_species_match_case_insensitively(typed, expected):
    assert match_species(typed, ["Ni", "Cr", "Cr2O"], what="species") == expected


def test_unknown_species_lists_the_valid_names():
    with pytest.raises(AptFiltersError, match="unknown iso-surface species 'Xe'; valid names: Ni, Cr"):
        match_species("Xe", ["Ni", "Cr"], what="iso-surface species")
    with pytest.raises(AptFiltersError, match="'CrO' is an ion of the range file, not an element"):
        match_species("cro", ["Cr", "O"], what="iso-surface species", others=["CrO"])
    with pytest.raises(AptFiltersError, match="ambiguous"):
        match_species("co", ["Co", "CO"], what="solute")


def test_layer_quotas_share_the_points_equally_and_draw_rare_species_whole():
    assert layer_quotas({"Si": 785_076, "Cu": 683, "Ni": 85_660}, total=30_000) == \
        {"Si": 14_659, "Cu": 683, "Ni": 14_658}
    assert layer_quotas({"a": 5, "b": 7}, total=100) == {"a": 5, "b": 7}


def _layered_ions(n: int = 60_000, seed: int = 0):
    """Ions in a 20 nm box: above z = 0 every fifth ion is B (20 at.% B), below none is."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-10, 10, (n, 3)).astype(np.float32)
    mz = np.full(n, 27.0, np.float32)  # Al
    above = np.flatnonzero(pos[:, 2] > 0)
    mz[above[::5]] = 10.5  # B
    ranges = RangeTable([Range(10.0, 11.0, (("B", 1),), "FF0000"), Range(26.5, 27.5, (("Al", 1),), "0000FF")])
    return IonTable(pos, mz), ranges


def test_vertex_composition_reads_the_local_fraction_from_the_nearest_ions():
    ions, ranges = _layered_ions()
    vertices = np.array([[0, 0, 6.0], [0, 0, -6.0], [0, 0, 0.0]])
    comp = vertex_composition(vertices=vertices, ions=ions, ranges=ranges, elements=["B", "Al"], k=300)
    above, below, middle = comp["B"]
    assert below == 0.0
    assert abs(above - 20.0) < 4 * math.sqrt(20 * 80 / 300)  # binomial sd of 300 ions: 2.3 at.%
    assert abs(middle - 10.0) < 4 * math.sqrt(10 * 90 / 300)
    np.testing.assert_allclose(comp["B"] + comp["Al"], 100.0)


def test_vertex_composition_is_the_nearest_ions_of_the_whole_box():
    """Searching only near the vertices gives the k nearest ranged ions of every ion in the box, also for
    vertices out in the sparse corner and beyond the ions, where the first reach holds too few."""
    from scipy.spatial import cKDTree

    ions, ranges = _layered_ions(40_000, seed=3)
    mz = ions.mz.copy()
    mz[::7] = 50.0  # unranged: never counted
    ions = IonTable(ions.positions, mz)
    rng = np.random.default_rng(4)
    vertices = np.concatenate([rng.uniform(-9, 9, (200, 3)), [[14.0, 14.0, 14.0], [10.0, -10.0, 0.5]]])
    comp = vertex_composition(vertices=vertices, ions=ions, ranges=ranges, elements=["B", "Al"], k=50)
    ranged = ranges.ion_index(mz) >= 0
    lo, hi = vertices.min(axis=0) - 5.0, vertices.max(axis=0) + 5.0
    pos = ions.positions.astype(np.float64)
    keep = ranged & np.all((pos >= lo) & (pos <= hi), axis=1)
    _, idx = cKDTree(pos[keep]).query(vertices, k=50)
    boron = 100 * (ranges.ion_index(mz[keep])[idx] == 0).mean(axis=1)
    np.testing.assert_allclose(comp["B"], boron, atol=1e-9)


def test_scene_colours_by_the_most_significant_excess():
    rows = [{"excess": {"B": {"gamma_atoms_nm2": 4.0, "error": 0.2}, "C": {"gamma_atoms_nm2": 1.0, "error": 0.01},
                        "O": None}}]
    assert scene_species("Al", rows) == "C"
    assert scene_species("Al", [{"excess": {}}]) == "Al"


def test_the_scene_writes_the_composition_as_vertex_quality_with_its_range(tmp_path):
    ions, ranges = _layered_ions()
    mesh = sphere(4.0, (0, 0, 0), subdiv=3)
    mesh.face_scalars["object_id"] = np.zeros(mesh.n_faces, np.int64)
    (tmp_path / "meshes").mkdir()
    scene = write_scene(folder=tmp_path, surfaces={"Al50": mesh}, species={"Al50": "B"}, ions=ions, ranges=ranges,
                        lod_faces=1000, view_points=5000)
    back = read_ply(tmp_path / "meshes" / "Al50.ply")
    b = back.vertex_scalars["at_pct_B"]
    top, bottom = mesh.vertices[:, 2] > 2, mesh.vertices[:, 2] < -2
    assert b[bottom].max() == 0.0 and abs(b[top].mean() - 20) < 2
    header = (tmp_path / "meshes" / "Al50.ply").read_bytes().split(b"end_header")[0].decode()
    lo, hi = scene["surfaces"][0]["limits"]
    assert "quality = B at.% among the 300 ranged ions nearest each vertex" in header
    assert lo == pytest.approx(np.percentile(b, 1)) and hi == pytest.approx(np.percentile(b, 99))
    # a level of detail above lod_faces faces, shown; the full mesh kept, hidden
    lod = read_ply(tmp_path / "meshes" / "Al50_lod.ply")
    assert lod.n_faces < mesh.n_faces and "at_pct_B" in lod.vertex_scalars
    project = ET.parse(tmp_path / "project.mlp").getroot()
    layers = {m.get("filename"): m for m in project.iter("MLMesh")}
    assert layers["meshes/Al50_lod.ply"].get("visible") == "1" and layers["meshes/Al50.ply"].get("visible") == "0"
    assert {"meshes/ions_B.ply", "meshes/ions_Al.ply"} <= set(layers)
    # Al is 95 % of the ions (the matrix): hidden on opening; B (5 %) shown
    assert layers["meshes/ions_Al.ply"].get("visible") == "0" and layers["meshes/ions_B.ply"].get("visible") == "1"
    assert layers["meshes/ions_B.ply"].find("RenderingOption").text == POINTS_RENDERING
    assert layers["meshes/ions_B.ply"].get("label").startswith("ions B (")
    assert sum(layer["drawn"] for layer in scene["ion_layers"]) == 5000
    assert (tmp_path / "legend.png").read_bytes()[:4] == b"\x89PNG"


def test_project_transform_and_rendering_string_lengths(tmp_path):
    # MeshLab reads 4 primitive bits, 4 x 9 attribute bits and 32 view flags, or ignores the option
    assert len(POINTS_RENDERING) == 4 + 4 * 9 + 32 and set(POINTS_RENDERING) == {"0", "1"}
    np.testing.assert_allclose(SIDE_VIEW[:3, :3] @ SIDE_VIEW[:3, :3].T, np.eye(3), atol=1e-12)
    assert SIDE_VIEW[1, 2] > 0.9, "data z is drawn (mostly) up"
    write_ply(sphere(), tmp_path / "s.ply")
    write_project(tmp_path / "p.mlp", [tmp_path / "s.ply"], transform=SIDE_VIEW)
    values = [float(v) for v in ET.parse(tmp_path / "p.mlp").getroot().find(".//MLMatrix44").text.split()]
    np.testing.assert_allclose(np.reshape(values, (4, 4)), SIDE_VIEW, atol=1e-6)
