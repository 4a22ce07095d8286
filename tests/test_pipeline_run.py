"""``apt-filters run`` end to end: a small synthetic specimen against its truth, and the real Si data."""

import csv
import json
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from apt_filters.cli.main import main
from apt_filters.pipeline import config as cfg
from apt_filters.pipeline.report import with_error
from apt_filters.pipeline.run import run_pipeline
from apt_filters.synth import preset, write_specimen

OUTPUTS = ["report.json", "report.html", "config.toml", "project.mlp", "excess.json", "clean_Al15.mlx",
           "clean_Al15.json", "objects_Al15.csv", "objects_Al15.json", "proxigram_Al15.csv", "proxigram_Al15.png",
           "meshes/Al15.ply", "meshes/ions_Al.ply", "meshes/ions_B.ply", "clean_Al15.meshlab2020.mlx", "legend.png"]


@pytest.fixture(scope="module")
def specimen(tmp_path_factory):
    out = tmp_path_factory.mktemp("specimen")
    return out, write_specimen(out, preset("small"), seed=3, keep_ions=False).truth


@pytest.fixture(scope="module")
def small_run(specimen, tmp_path_factory):
    folder, truth = specimen
    config = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.15)])
    config.input.ions, config.input.ranges = str(folder / "specimen.pos"), str(folder / "specimen.rrng")
    out = tmp_path_factory.mktemp("run") / "out"
    return out, run_pipeline(config, out, quiet=True, truth=truth), truth


def test_run_writes_every_output(small_run):
    out, report, _ = small_run
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert json.loads((out / "report.json").read_text())["ions"]["count"] == report["ions"]["count"]
    assert not list(out.parent.glob(".*")), "no staging or claim folder left behind"
    text = (out / "report.json").read_text()
    assert "apt-filters-run" not in text and "apt-filters-tmp" not in text, "no path of the vanished staging folder"


def test_the_plateau_windows_come_from_the_fitted_width_and_are_reported(small_run):
    out, report, _ = small_run
    w = report["surfaces"][0]["interface"]
    step = w["step"]
    assert w["source"] == "fitted" and step["species"] == "Al" and 0 < step["width_error"] < step["width"]
    # beyond the step and the B shell's peak, the outer edge three times as far; the proxigram covers them
    assert w["inner_nm"] >= step["reach"] and w["outer_nm"] == pytest.approx(3 * w["inner_nm"])
    assert any(p["species"] == "B" and p["peak"] > 0 and w["inner_nm"] >= p["reach"] for p in w["peaks"])
    rows = list(csv.DictReader(open(out / "proxigram_Al15.csv")))
    assert max(float(r["bin_hi_nm"]) for r in rows) == pytest.approx(w["outer_nm"])
    assert all(list(e["window_nm"]) == [w["inner_nm"], w["outer_nm"]] for e in report["surfaces"][0]["excess"])
    assert "10–90 % width" in (out / "report.html").read_text()


def test_each_objects_inside_composition_is_reported_with_its_window(small_run):
    out, report, _ = small_run
    surface = report["surfaces"][0]
    inner, outer = surface["interface"]["inner_nm"], surface["interface"]["outer_nm"]
    plateaus = surface["plateaus"]
    assert sorted(p["object_id"] for p in plateaus) == sorted(o["object_id"] for o in surface["objects"])
    for p in plateaus:
        assert p["to_nm"] == outer and (p["from_nm"] < inner) == p["nearer"] and 0 < p["from_nm"] <= inner
        assert p["atoms"] > 0 and p["fraction"]["Al"] is not None
    assert "Inside composition per object" in (out / "report.html").read_text()


def test_the_segregant_found_and_the_basis_are_stated_at_the_top(small_run):
    # the defaults leave B (segregated in the small preset) out of the basis: the reader is told which species,
    # on what evidence, and that every concentration is of the others
    out, report, truth = small_run
    found = report["surfaces"][0]["mesh"]["refine"]["segregants"]
    assert list(found["species"]) == ["B"] and found["peaks"]["B"]["z"] > 5
    top = (out / "report.html").read_text().split("Check before use")[0].split("<ul class='run'>")[1]
    assert "Al15: segregant found at the first contour: B peaks at" in top
    assert "concentrations of all ranged species except B" in top


def test_report_numbers_against_the_truth(small_run):
    _, report, truth = small_run
    assert report["ions"]["count"] == truth["ions"]["total"]
    for element, fraction in truth["ions"]["composition"].items():
        assert report["composition"][element] == pytest.approx(fraction, abs=0.005)
    rows = {row["feature"]: row for row in report["truth"]}
    assert set(rows) == {"cube 6 nm", "sphere 3 nm"}
    for row in rows.values():
        assert row["object_id"] is not None, f"no object found at {row['feature']}"
        # Guards of what the default pipeline (with refinement) reaches today on this seed:
        # volume 0.88-1.03, area 0.85-1.12, excess 0.88-1.20 of the truth. Issue 9's targets
        # (±5%) are not reached yet; before refinement volumes were 0.6-0.8 (tighter than the
        # 0.45-1.05 this test used to accept).
        assert abs(row["volume_ratio"] - 1) < 0.15, row
        assert abs(row["area_ratio"] - 1) < 0.18, row
        assert abs(row["excess_B_ratio"] - 1) < 0.25, row
    surface = report["surfaces"][0]
    refine = surface["mesh"]["refine"]
    assert list(refine["segregants"]["species"]) == ["B"], "the B shell is found and left out of the basis"
    assert "except B" in refine["basis"]
    assert surface["mesh"]["boundary_edges"] == 0, "precipitates inside the box are closed"
    assert {o["status"] for o in surface["objects"]} == {"closed"}


def test_the_excess_the_ions_hold_is_counted_against_the_true_surfaces(small_run):
    """``counted_excess_B_ratio``: the run's own ions counted against each feature's shape rebuilt from truth.json
    equal the count against the generating specimen's exact SDF (the same ions, drawn again from the seed)."""
    from apt_filters.truth.specimen import true_plateaus
    from apt_filters.refine.composition import ion_atoms
    from apt_filters.truth import counted_truth
    from apt_filters.synth import generate
    from apt_filters.voxel import ConcentrationBasis

    _, report, truth = small_run
    sp = generate(preset("small"), seed=3)
    atoms = ion_atoms(sp.ions, sp.ranges, ConcentrationBasis())
    rows = {row["feature"]: row for row in report["truth"]}
    for i, feature in enumerate(truth["features"]):
        if not feature["bounded"]:
            continue
        plateaus = true_plateaus(feature, atoms.elements)
        count = counted_truth(sp.feature_sdf(i), sp.ions.positions, atoms.atoms, *plateaus)
        expected = count.excess_ions[atoms.elements.index("B")] / feature["excess"]["B"]["excess_ions"]
        assert rows[feature["name"]]["counted_excess_B_ratio"] == pytest.approx(expected, rel=1e-9)
        assert abs(expected - 1) < 0.26  # 4 Poisson sd of a 3 nm sphere's ~240 excess B ions


def test_counted_excess_leaves_out_shapes_truth_json_cannot_rebuild():
    """A custom shape (a callable SDF) has no parameters to rebuild: no counted excess, and no error."""

    from apt_filters.io.ions import IonTable
    from apt_filters.io.ranges import Range, RangeTable
    from apt_filters.truth.specimen import counted_excess
    from apt_filters.synth import CustomShape, Sphere

    rng = np.random.default_rng(0)
    positions = rng.uniform(-6, 6, (20000, 3)).astype(np.float32)
    radius = np.linalg.norm(positions, axis=1)
    mz = np.where(np.abs(radius - 3.0) < 0.3, 10.5, 26.5).astype(np.float32)  # B in a shell at r = 3, Al elsewhere
    ranges = RangeTable([Range(10.0, 11.0, (("B", 1),)), Range(26.0, 27.0, (("Al", 1),))])
    sphere = Sphere((0, 0, 0), 3.0)
    custom = CustomShape(sphere.sdf, (-3, -3, -3), (3, 3, 3), name="ball")
    feature = {"bounded": True, "segregation": [{"species": "B"}], "composition_inside": {"Al": 1.0},
               "composition_outside": {"Al": 1.0}, "excess": {"B": {"excess_ions": 100.0}}}
    truth = {"features": [{**feature, "index": 0, "shape": custom.params()},
                          {**feature, "index": 1, "shape": sphere.params()}]}
    counted = counted_excess(truth, IonTable(positions, mz), ranges)
    shell = np.sum(np.abs(radius - 3.0) < 0.3)
    assert counted == {(1, "B"): pytest.approx(shell / 100.0)}


def test_an_iso_value_with_only_specks_gives_an_empty_surface_and_says_so(specimen, tmp_path):
    folder, _ = specimen
    config = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.2)])
    config.input.ions, config.input.ranges = str(folder / "specimen.pos"), str(folder / "specimen.rrng")
    config.remesh.method = "none"
    report = run_pipeline(config, tmp_path / "o", quiet=True)
    surface = report["surfaces"][0]
    assert surface["mesh"]["faces"] == 0 and surface["objects"] == []
    assert any("no surface at this iso-value" in w for w in report["warnings"])
    assert (tmp_path / "o" / "report.html").is_file()


def test_rerun_with_saved_config_is_identical(small_run, tmp_path, monkeypatch):
    out, report, _ = small_run
    monkeypatch.chdir(tmp_path)  # config.toml holds absolute input paths: it works from anywhere
    assert Path(cfg.load(out / "config.toml").input.ions).is_absolute()
    again = tmp_path / "again"
    assert main(["run", "--config", str(out / "config.toml"), "--out", str(again), "--quiet"]) == 0
    second = json.loads((again / "report.json").read_text())
    first = json.loads((out / "report.json").read_text())
    for key in ("composition", "voxel", "surfaces", "inputs"):
        assert second[key] == first[key], key
    for name in ("meshes/Al15.ply", "meshes/ions_Al.ply", "clean_Al15.mlx", "proxigram_Al15.csv"):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name


def test_existing_output_needs_force(small_run, tmp_path, capsys):
    out, _, _ = small_run
    cfg_file = tmp_path / "config.toml"
    cfg_file.write_bytes((out / "config.toml").read_bytes())
    assert main(["run", "--config", str(cfg_file), "--out", str(out), "--quiet"]) == 2
    assert "not empty" in capsys.readouterr().err
    # the configuration inside the folder is an input of the run: even --force does not replace it
    assert main(["run", "--config", str(out / "config.toml"), "--out", str(out), "--quiet", "--force"]) == 2
    assert "holds the input" in capsys.readouterr().err


@pytest.mark.parametrize("args, problem", [
    (["--species", "Xe", "--iso", "0.1"], "unknown iso-surface species 'Xe'; valid names: "),
    (["--species", "al", "--iso", "0.15", "--exclude", "b", "xe"], "unknown species to exclude 'xe'"),
    (["--density", "1e6"], "iso = 1000000.0 is outside (0, 1000]"),
    (["--density", "500"], "outside the atomic density range"),
    (["--species", "Al"], "--species and --iso go together"),
    (["--voxel", "-1", "--species", "Al", "--iso", "0.15"], "voxel"),
    (["--species", "Al", "--iso", "0.15", "--exclude", "B", "--include", "B"], "both excluded from and included"),
])
def test_user_mistakes_are_one_line_and_exit_2(specimen, tmp_path, args, problem):
    folder, _ = specimen
    cmd = [sys.executable, "-m", "apt_filters", "run", str(folder / "specimen.pos"), "-r",
           str(folder / "specimen.rrng"), "-o", str(tmp_path / "o"), "-q", *args]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and problem in lines[0] and "Traceback" not in proc.stderr
    assert not (tmp_path / "o").exists(), "a failed run leaves no output"


class _Page(HTMLParser):
    """Headings, table cells and all text of a page, in order."""

    def __init__(self):
        super().__init__()
        self.headings, self.cells, self.text, self._tag = [], [], [], None

    def handle_starttag(self, tag, attrs):
        self._tag = tag

    def handle_data(self, data):
        self.text.append(data)
        if self._tag in ("h1", "h2", "h3"):
            self.headings.append(data.strip())
        if self._tag in ("td", "th"):
            self.cells.append(data.strip())


def test_report_html_is_for_a_reader(small_run):
    """Summary first, units on every figure, no Python reprs, no bare NaN, pooled row in words."""
    out, report, _ = small_run
    page = _Page()
    page.feed((out / "report.html").read_text())
    text = " ".join(page.text)
    order = [h for h in page.headings if h.startswith(("Al 15 at.%", "Against", "Pictures", "Details"))]
    assert order == ["Al 15 at.% iso-concentration surface (Al15)", "Against the ground truth (synthetic specimen)",
                     "Pictures", "Details"], page.headings
    for unit in ("volume (nm³)", "area (nm²)", "inside (at.%)", "outside (at.%)", "(atoms/nm²)"):
        assert any(unit in c for c in page.cells), unit
    for repr_ in ("np.float64", "{'", "array(", "None", "nan", "object_id -1"):
        assert repr_ not in text, repr_
    assert all(c != "-1" for c in page.cells)
    summary = report["surfaces"][0]["summary"]
    assert [r["label"] for r in summary] == ["interior objects (closed)"]  # the small specimen has no edge objects
    assert f"{summary[0]['objects']}" in page.cells
    gamma = summary[0]["excess"]["B"]
    assert with_error(gamma["gamma_atoms_nm2"], gamma["error"]) in page.cells


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium not installed (setup.sh --dev installs it)")
def test_report_renders_in_chromium(small_run, tmp_path):
    """Headless Chromium lays the page out (a screenshot of its first screen, not blank)."""
    out, _, _ = small_run
    shot = tmp_path / "first.png"
    subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                    "--disable-component-update", "--no-first-run", "--disable-sync",
                    f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}", "--window-size=1400,1000",
                    (out / "report.html").as_uri()], capture_output=True, timeout=120, check=True)
    import matplotlib.image

    pixels = matplotlib.image.imread(shot)
    assert pixels.shape[:2] == (1000, 1400)
    assert pixels[..., :3].std() > 0.05, "the first screen is not blank"


def test_run_on_real_si(si_run):
    _, report = si_run
    assert report["ions"]["count"] == 945_211
    assert any(f["severity"] == "error" and "57.819" in f["message"] and "Ni+" in f["message"]
               for f in report["audit"]), "the audit's Cr2O/Ni+ finding reaches the report"
    surface = report["surfaces"][0]
    assert surface["mesh"]["boundary_edges"] > 0, "the cap/Si interface meets the specimen edge: open"
    interface = max(surface["objects"], key=lambda o: o["area"])
    assert interface["status"] == "open"
    assert -19.0 < interface["centroid_z"] < -14.0, "flat interface near z = -16 nm"
    assert interface["obb_short"] < 0.15 * interface["obb_long"], "it is flat"
    c_map = next(m for m in surface["maps"] if m["solute"] == "C" and m["object_id"] == interface["object_id"])
    assert c_map["n_patches"] >= 2 and 0 <= c_map["p_value"] <= 1, "a C map across the interface, tested"


def test_a_remesher_failure_keeps_the_cleaned_mesh_and_warns(specimen, tmp_path, monkeypatch):
    import apt_filters.remesh

    def broken(*args, **kwargs):
        raise RuntimeError("synthetic failure")

    monkeypatch.setattr(apt_filters.remesh, "remesh", broken)
    folder, truth = specimen
    config = cfg.PipelineConfig(surface=[cfg.SurfaceConfig("Al", 0.15)])
    config.input.ions, config.input.ranges = str(folder / "specimen.pos"), str(folder / "specimen.rrng")
    config.analysis.audit = False
    config.refine.enabled = False  # what the remesher is handed does not matter: it fails on any mesh
    report = run_pipeline(config, tmp_path / "out", quiet=True)
    assert report["warnings"] == ["remeshing Al15 failed (RuntimeError: synthetic failure); the cleaned mesh is used"]
    assert report["surfaces"][0]["mesh"]["faces"] > 0


def test_maps_reach_the_ply_and_the_report(small_run):
    from apt_filters.meshlab.exports import read_ply

    out, report, _ = small_run
    rows = report["surfaces"][0]["maps"]
    assert {r["solute"] for r in rows} == {"B"} and all(r["n_patches"] >= 1 for r in rows)
    mesh = read_ply(out / "meshes" / "Al15.ply")
    for name in ("excess_B", "excess_B_sigma", "c_in_B", "c_out_B", "patch_radius_B"):
        assert name in mesh.vertex_scalars, name
    # one picture per object, its colour bar in detected atoms/nm²
    assert sorted(p.name for p in out.glob("map_Al15_*.png")) == sorted(
        f"map_Al15_{r['object_id']}.png" for r in rows)
    assert "Excess maps along the surface" in (out / "report.html").read_text()
    # MeshLab shows the map at once: it is the vertex quality, its meaning and range in the header
    header = (out / "meshes" / "Al15.ply").read_bytes().split(b"end_header")[0].decode()
    assert "quality = B interfacial excess map, detected atoms/nm2" in header
    [surface] = report["scene"]["surfaces"]
    lo, hi = surface["limits"]
    b = mesh.vertex_scalars["excess_B"]
    assert lo < np.nanmedian(b) < hi, "the colour range is set from the map's own values"
