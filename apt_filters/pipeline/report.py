"""The run report: ``report.json`` (every figure and parameter) and ``report.html``, a page
for the scientist who ran the job.

The page reads top-down in the order a reader asks: what was run, what to be careful about
(range-file errors, objects left out, figures whose error is as large as the figure), the
summary per iso-surface (geometry, composition inside/outside, excess; interior objects
apart from those cut by the specimen edge), then the pictures, then the details (every
object, the per-object excess, files, steps, versions). Numbers carry their unit in the
column header and are rounded to their error (two significant digits of the error when it
starts with 1, else one); a missing figure is shown as "—" with the reason on hover.
The page is self-contained (pictures inlined) and links the CSV/JSON files beside it.
"""

from __future__ import annotations

import base64
import hashlib
import html
import math
import os
import platform
from importlib import metadata
from pathlib import Path

from apt_filters import __version__
from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_write_text

DEPENDENCIES = ("numpy", "scipy", "pymeshlab", "open3d", "fast-simplification", "numba", "matplotlib", "tqdm")

DASH = "—"
"""Shown for a figure that does not exist; the reason goes in the cell's tooltip."""


def file_record(path: str | os.PathLike) -> dict:
    """Path, size in bytes and SHA-256 of an input file (read in 16 MiB blocks)."""
    path = Path(path)
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 24), b""):
            digest.update(block)
    return {"path": str(path), "bytes": path.stat().st_size, "sha256": digest.hexdigest()}


def versions() -> dict:
    """Versions of apt-filters, Python and the runtime dependencies."""
    out = {"apt-filters": __version__, "python": platform.python_version()}
    for name in DEPENDENCIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def write_json(path: Path, data: dict) -> None:
    """Strict JSON (:mod:`apt_filters.core.jsontext`), atomically."""
    atomic_write_text(path, jsontext.dumps(data, indent=2) + "\n", overwrite=True)


# --- numbers ---------------------------------------------------------------------------------

def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def number(v, digits: int = 3) -> str:
    """``v`` to ``digits`` significant digits (integers whole, thousands separated); "—" if missing."""
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return f"{v:,}"
    if not _finite(v):
        return DASH
    if v == 0:
        return "0"
    magnitude = math.floor(math.log10(abs(v)))
    if magnitude >= digits - 1:
        return f"{v:,.0f}"
    decimals = digits - 1 - magnitude
    return f"{v:.{decimals}f}" if magnitude >= -4 else f"{v:.{digits - 1}e}"


def with_error(v, err, scale: float = 1.0, *, atoms: int | None = None) -> str:
    """``v ± err`` (both times ``scale``) rounded to the error's leading digit (two if it is a 1).

    A fraction counted as 0 or 1 of ``atoms`` has no binomial error; it shows the one-sided 95 % bound of the
    rule of three (3 / ``atoms``; Hanley & Lippman-Hand 1983) instead of a zero error.
    """
    if not _finite(v):
        return DASH
    if atoms and not (_finite(err) and err > 0) and v in (0.0, 1.0):
        bound = v * scale + (3.0 if v == 0 else -3.0) / atoms * scale
        return f"{number(v * scale)} (95 % bound {'<' if v == 0 else '>'} {number(bound)})"
    v = v * scale
    if not _finite(err) or err <= 0:
        return number(v)
    err = err * scale
    lead = math.floor(math.log10(err))
    keep = 2 if f"{err:e}"[0] == "1" else 1
    decimals = max(0, keep - 1 - lead)
    return f"{v:.{decimals}f} ± {err:.{decimals}f}"


def _cell(value, reason: str = "") -> str:
    """A table cell; a missing value shows its reason on hover; words are left-aligned."""
    text = value if isinstance(value, str) else number(value)
    if text == DASH and reason:
        return f'<td title="{html.escape(reason)}">{DASH}</td>'
    words = isinstance(value, str) and not (text[:1].isdigit() or text[:1] in "-+−" or text == DASH)
    return f"<td class='t'>{html.escape(text)}</td>" if words else f"<td>{html.escape(text)}</td>"


def _table(header: list[str], rows: list[list[str]], cls: str = "", groups: list[tuple[str, int]] = ()) -> str:
    """``rows`` hold ready cells (``<td>...``) or plain values; ``groups`` (title, columns) adds a
    header row above ``header`` spanning its columns."""
    if not rows:
        return "<p class='none'>none</p>"
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    if groups:
        head = ("".join(f"<th colspan='{n}'>{html.escape(g)}</th>" for g, n in groups) + "</tr><tr>" + head)
    body = "".join("<tr>" + "".join(c if isinstance(c, str) and c.startswith("<td") else _cell(c) for c in row)
                   + "</tr>" for row in rows)
    return f"<div class='scroll'><table class='{cls}'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>"


def _image(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f"<figure><img src='data:image/png;base64,{data}' alt='{html.escape(caption)}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def _link(name: str, folder: Path) -> str:
    return f"<a href='{html.escape(name)}'>{html.escape(name)}</a>" if (folder / name).exists() else ""


# --- what was run -----------------------------------------------------------------------------

def surface_title(surface: dict) -> str:
    """``Cr 30 at.% iso-concentration surface`` or ``iso-density surface at 40 atoms/nm³``."""
    if surface["species"]:
        return f"{surface['species']} {100 * surface['iso']:g} at.% iso-concentration surface"
    return f"iso-density surface at {surface['iso']:g} atoms/nm³"


def _what_was_run(report: dict) -> str:
    cfg = report["config"]
    ions, ranges = (Path(f["path"]).name for f in report["inputs"])
    v = cfg["voxel"]
    kernel = (f"{v['kernel']} delocalization {' × '.join(f'{d:g}' for d in v['delocalization'])} nm"
              if v["kernel"] == "gaussian" else f"{v['kernel']} kernel")
    steps = [f"{number(report['ions']['count'])} ions of <b>{html.escape(ions)}</b>, "
             f"{100 * report['ions']['ranged_fraction']:.1f} % ranged by <b>{html.escape(ranges)}</b>",
             *([f"range labels changed: {html.escape(', '.join(cfg['input']['relabel']))}"]
               if cfg["input"].get("relabel") else []),
             f"voxels {v['size']:g} nm, {kernel}"
             + (f", {', '.join(v['exclude'])} left out of the concentration" if v["exclude"] else ""),
             ", ".join(html.escape(surface_title(s)) for s in report["surfaces"]),
             *filter(None, (_segregant_words(s) for s in report["surfaces"])),
             "contoured by " + {"mc": "marching cubes", "dc": "dual contouring"}[cfg["contour"]["method"]]
             + (", refined against the ions" if cfg["refine"]["enabled"] else "")
             + ", cleaned by a MeshLab chain"
             + (", remeshed (CVT)" if cfg["remesh"]["method"] == "cvt" else ""),
             f"detection efficiency {cfg['analysis']['efficiency']:g}; proxigram bins {cfg['proxigram']['bin']:g} nm; "
             + _windows_words(cfg["proxigram"])]
    return "<ul class='run'>" + "".join(f"<li>{s}</li>" for s in steps) + "</ul>"


def _segregant_words(surface: dict) -> str:
    """The basis a surface was drawn and refined in, where the run found segregants at it: the reader must know
    that its concentrations leave a species out, and why (refine.segregants)."""
    refine = surface["mesh"].get("refine") or {}
    found = refine.get("segregants") or {}
    if not found.get("species") and not found.get("kept"):
        return ""
    peaks = [f"{s} peaks at {100 * p['peak']:.1f} at.% against a plateau of {100 * p['plateau']:.1f} at.% "
             f"({p['z']:.0f} standard errors)" for s, p in ((s, found["peaks"][s]) for s in found["species"])]
    kept = [f"{', '.join(found['kept'])} kept in as asked"] if found.get("kept") else []
    return (f"{html.escape(surface['label'])}: segregant{'s' * (len(found['species']) != 1)} found at the first "
            f"contour: {html.escape('; '.join(peaks + kept))}; concentrations of {html.escape(refine['basis'])}"
            + (" (<code>--include</code> keeps a species in)" if found["species"] else ""))


def _windows_words(p: dict) -> str:
    given = [f"{words} {p[key]:g} nm" for key, words in (("inner", "plateau windows from"), ("extent", "range ±"))
             if p.get(key)]
    fitted = [words for key, words in (("inner", "plateau windows"), ("extent", "range")) if not p.get(key)]
    return ", ".join(given + ([" and ".join(fitted) + " from the fitted interface width"] if fitted else []))


def _interface(surface: dict) -> str:
    """One paragraph: the fitted interface width and position, and the plateau windows they set."""
    w = surface.get("interface")
    if not w:
        return ""
    words = (f"Plateau windows {w['inner_nm']:.3g}–{w['outer_nm']:.3g} nm from the surface on each side "
             f"({ {'fitted': 'set by the fitted width', 'given': 'as given'}.get(w['source'], w['source']) }); "
             "the excess is integrated between them.")
    s = w.get("step")
    if s:
        words = (f"Interface: {html.escape(s['species'])} 10–90 % width "
                 f"{with_error(s['width'], s['width_error'])} nm, its 50 % point "
                 f"{with_error(s['centre'], s['centre_error'])} nm from the surface (positive inside), "
                 f"fitted on the pooled proxigram (asymmetric error-function step). " + words)
    if w.get("note"):
        words += f" ({html.escape(w['note'])})"
    return f"<p>{words}</p>"


# --- warnings in words ------------------------------------------------------------------------

UNRELIABLE = 0.5
"""A figure whose standard error exceeds this fraction of its magnitude is flagged as unreliable."""

FEW_ATOMS = 100
"""A composition window holding fewer atoms than this is flagged (errors above ~5 at.%)."""


def warnings_in_words(report: dict) -> list[str]:
    """Plain sentences for whatever makes a figure of the report wrong or unreliable.

    Range-file errors of the audit first (every figure with the mislabelled species is wrong),
    then warnings of the run, objects left out (specks, objects without ions, objects too thin
    for an excess), objects whose inside composition is counted nearer than the plateau windows, and
    excess or composition figures too uncertain to use.
    """
    out = []
    audit = report.get("audit") or []
    errors = [f for f in audit if f["severity"] == "error"]
    wrong = [f for f in errors if f["kind"] == "mislabelled" and f["figures"].get("best_fit")]
    if wrong:
        ranges = "; ".join(f"{f['figures']['label']} at {f['figures']['lower']:.2f}–{f['figures']['upper']:.2f} Da "
                           f"holds {f['figures']['best_fit']} ({100 * f['figures'].get('foreign_fraction', 1):.0f} % "
                           "of its ions)" for f in wrong)
        out.append(f"The range file labels {len(wrong)} range{'s' * (len(wrong) > 1)} wrongly (isotope patterns "
                   f"do not fit): {ranges}. Compositions, surfaces and excess of these species are wrong "
                   "until the labels are corrected: run again with --relabel OLD=NEW (e.g. Cr2O=Ni) or a "
                   "corrected range file (apt-filters audit shows the fits).")
    out += [f"Range file: {f['message']}." for f in errors if f not in wrong]
    n_warn = sum(f["severity"] == "warning" for f in audit)
    if n_warn:
        out.append(f"The range file has {n_warn} further warning{'s' * (n_warn > 1)} (empty ranges, peaks "
                   "in no range), listed under Details.")
    out += list(report.get("warnings", []))
    for s in report["surfaces"]:
        label, mesh = s["label"], s["mesh"]
        refine = mesh.get("refine") or {}
        if refine.get("specks_removed"):
            n, test = refine["specks_removed"], refine.get("speck_test") or {}
            out.append(f"{label}: {n} of {test.get('components_tested', n)} pieces removed before refinement as "
                       f"specks: their ions differ across them no more than noise does at this iso-value "
                       f"(family-wise p > {test.get('alpha', 0.001):g}); not in the tables.")
        grown = mesh.get("noise_scale") or {}
        if grown.get("factor", 1.0) > 1.0:
            out.append(f"{label}: contoured at {grown['factor']:.2f}× the delocalization: at the one given, this "
                       "interface's counting noise outran its gradient and its contour folded into handles and "
                       f"tunnels (gradient-to-noise ratio {grown['ratio']:.2f} at the grown kernel, "
                       f"{grown['needed']:.2f} keeps one sheet over its {grown['voxels']} voxels); the composition, "
                       "proxigram and excess are counted from the ions as always."
                       + (" Still short at the largest growth: the surface may hold folds." if grown.get("limited")
                          else ""))
        if mesh.get("objects_dropped"):
            out.append(f"{label}: {mesh['objects_dropped']} object(s) enclosing no ion left out of the tables.")
        thin = mesh.get("objects_without_excess") or []
        if thin:
            out.append(f"{label}: no excess for object{'s' * (len(thin) > 1)} {', '.join(map(str, thin))}: "
                       "too thin, or cut by the edge exclusion, to hold ions in a plateau window.")
        short = [p for p in s.get("plateaus") or [] if p.get("short")]
        if short:
            ids = ", ".join(str(p["object_id"]) for p in short)
            starts = ", ".join(f"{p['from_nm']:.2g}" for p in short)
            reached = [p["reached"] for p in short if p["reached"] is not None]
            how = (f", where the fitted interface step is {100 * min(reached):.0f}-{100 * max(reached):.0f} % "
                   "reached" if reached else "")
            out.append(f"{label}: the inside composition of object{'s' * (len(short) > 1)} {ids} is counted from "
                       f"{starts} nm (half {'their' if len(short) > 1 else 'its'} depth, nearer than the plateau "
                       f"windows){how}: the interface may bias it by more than its counting error.")
        for row in s.get("summary", []):
            where = f"{label}, {row['label']}"
            for solute, e in row["excess"].items():
                if e is None:
                    out.append(f"{where}: no {solute} excess (a plateau window holds no ion).")
                elif _finite(e["gamma_atoms_nm2"]) and _finite(e["error"]) and \
                        e["error"] > UNRELIABLE * abs(e["gamma_atoms_nm2"]):
                    out.append(f"{where}: the {solute} excess ({with_error(e['gamma_atoms_nm2'], e['error'])} "
                               "atoms/nm²) is not distinguishable from zero at this counting noise.")
            comp = row["composition"] or {}
            for side, part in comp.items():
                if part["atoms"] < FEW_ATOMS:
                    out.append(f"{where}: the composition {side} rests on {part['atoms']} atoms only.")
    return out


# --- summary ----------------------------------------------------------------------------------

def _summary(surface: dict) -> str:
    rows = surface.get("summary", [])
    if not rows:
        return "<p class='none'>no objects</p>"
    geometry = _table(["objects", "count", "volume (nm³)", "area (nm²)", "sphericity (mean ± sd)"], [
        [r["label"], r["objects"],
         _cell(r["volume_nm3"], "open objects enclose no volume: they are cut by the specimen edge"),
         r["area_nm2"],
         _cell(with_error(r["sphericity_mean"], r["sphericity_sd"]) if r["sphericity_sd"] is not None
               else r["sphericity_mean"], "sphericity needs a closed object")]
        for r in rows], "summary")
    elements = list(dict.fromkeys(e for r in rows if r["composition"] for e in r["composition"]["inside"]["fraction"]))
    comp_header = ["element"] + ["inside (at.%)", "outside (at.%)"] * len(rows)
    comp_rows = []
    for e in elements:
        cells = [e]
        for r in rows:
            for side in ("inside", "outside"):
                part = (r["composition"] or {}).get(side)
                cells.append(_cell(with_error(part["fraction"][e], part["error"][e], 100) if part else DASH,
                                   "no ions of these objects in this window"))
        comp_rows.append(cells)
    solutes = list(dict.fromkeys(k for r in rows for k in r["excess"]))
    excess_rows = [[s] + [_cell(with_error(r["excess"][s]["gamma_atoms_nm2"], r["excess"][s]["error"])
                                if r["excess"].get(s) else DASH, "a plateau window holds no ion")
                          for r in rows] for s in solutes]
    excess = (_table(["solute"] + [f"{r['label']} (atoms/nm²)" for r in rows], excess_rows, "summary")
              if solutes else "<p class='none'>no solute below 10 % overall</p>")
    return (f"<div class='cards'><div><h3>Objects</h3>{geometry}</div>"
            f"<div><h3>Interfacial excess Γ</h3>{excess}</div></div>" + _interface(surface)
            + "<h3>Composition inside and outside the interface</h3>"
            + _table(comp_header, comp_rows, "summary", [("", 1)] + [(r["label"], 2) for r in rows]))


# --- details ----------------------------------------------------------------------------------

OBJECT_COLUMNS = (("object_id", "object", ""), ("status", "status", ""), ("area", "area (nm²)", ""),
                  ("volume", "volume (nm³)", "open: cut by the specimen edge, encloses no volume"),
                  ("equivalent_radius", "equivalent radius (nm)", "needs a volume"),
                  ("sphericity", "sphericity", "needs a closed object"),
                  ("centroid_x", "x (nm)", ""), ("centroid_y", "y (nm)", ""), ("centroid_z", "z (nm)", ""),
                  ("obb_long", "length (nm)", ""), ("obb_mid", "width (nm)", ""), ("obb_short", "thickness (nm)", ""),
                  ("genus", "genus", ""), ("edge_distance", "to edge (nm)", "no specimen hull"),
                  ("n_ions", "ions inside", "open objects have no inside"),
                  ("p_value", "p (family-wise)", "not tested: refinement off or a density surface"),
                  ("z", "z (null spreads)", "not tested: refinement off or a density surface"))
"""(key, header, reason a value is missing); ``area`` and ``volume`` are shown with their counting errors
(``area_se``, ``volume_se``) where the run measured them."""


def _objects(surface: dict) -> str:
    objects = surface["objects"]
    elements = list(dict.fromkeys(k[5:] for o in objects for k in o if k.startswith("frac_")))
    header = [h for _, h, _ in OBJECT_COLUMNS] + [f"{e} inside (at.%)" for e in elements]
    rows = []
    for o in objects:
        cells = []
        for key, _, reason in OBJECT_COLUMNS:
            value = o.get(key)
            if key == "n_ions" and (value is None or value < 0):
                value = None
            if key in ("area", "volume") and _finite(value) and _finite(o.get(f"{key}_se")):
                value = with_error(value, o[f"{key}_se"])  # rounded to its counting error
            if key == "p_value" and _finite(value):
                value = f"{value:.1e}" if value < 0.01 else f"{value:.2f}"
            cells.append(_cell(value, reason))
        cells += [_cell(100 * o[f"frac_{e}"] if _finite(o.get(f"frac_{e}")) else None, "no ions inside")
                  for e in elements]
        rows.append(cells)
    return _table(header, rows)


def _plateaus(surface: dict) -> str:
    """Each object's inside composition and the window it was counted in."""
    plateaus = surface.get("plateaus") or []
    elements = list(dict.fromkeys(e for p in plateaus for e in p["fraction"]))
    rows = [[p["object_id"],
             f"{number(p['from_nm'])}–{number(p['to_nm'])}" + _nearer(p),
             p["atoms"]] + [_cell(with_error(p["fraction"][e], p["error"][e], 100, atoms=p["atoms"])
                                  if p["atoms"] else None, "no atom in the window") for e in elements]
            for p in plateaus]
    return _table(["object", "window (nm)", "atoms"] + [f"{e} (at.%)" for e in elements], rows)


def _nearer(plateau: dict) -> str:
    """How an object's window counted nearer than the plateau windows reaches its plateau, in words."""
    if not plateau["nearer"]:
        return ""
    reached = plateau.get("reached")
    share = "" if reached is None else f"; step {100 * reached:.1f} % reached"
    return f" (half its depth{share}{': short of the plateau' if plateau.get('short') else ''})"


def _excess_per_object(surface: dict) -> str:
    rows = []
    for e in surface["excess"]:
        who = "all objects" if e["object_id"] < 0 else str(e["object_id"])
        rows.append([who, e["solute"], e["area"],
                     with_error(e["cumulative"]["gamma_atoms"], e["cumulative"]["gamma_atoms_error"]),
                     with_error(e["integration"]["gamma_atoms"], e["integration"]["gamma_atoms_error"]),
                     *(with_error(e[side]["value"], e[side]["error"], 100, atoms=e[side]["n_ions"])
                       for side in ("matrix", "precipitate"))])
    return _table(["object", "solute", "area (nm²)", "Γ Krakauer–Seidman (atoms/nm²)",
                   "Γ proxigram integral (atoms/nm²)", "outside plateau (at.%)", "inside plateau (at.%)"], rows)


def _truth(rows: list[dict]) -> str:
    """Measured over true per feature: ratios first, then the true values (units in the headers)."""
    solutes = list(dict.fromkeys(k[len("true_excess_"):-len("_atoms_nm2")] for r in rows for k in r
                                 if k.startswith("true_excess_")))
    several = len({r["surface"] for r in rows}) > 1
    header = (["surface"] * several + ["feature", "object", "volume / true", "area / true"]
              + [h for s in solutes for h in (f"{s} excess / true", f"{s} the ions hold / true")]
              + ["true volume (nm³)", "true area (nm²)"] + [f"true {s} excess (atoms/nm²)" for s in solutes])
    missing = "no object of this surface at the feature"
    body = []
    for r in rows:
        cells = [r["surface"]] * several + [r["feature"], _cell(r["object_id"], missing),
                                            _cell(r.get("volume_ratio"), missing), _cell(r.get("area_ratio"), missing)]
        for s in solutes:
            cells += [_cell(r.get(f"excess_{s}_ratio"), "no excess measured for this object"),
                      _cell(r.get(f"counted_excess_{s}_ratio"), "not counted")]
        cells += [r["true_volume_nm3"], r["true_area_nm2"]] + [_cell(r.get(f"true_excess_{s}_atoms_nm2"))
                                                               for s in solutes]
        body.append(cells)
    return _table(header, body) + ("<p class='note'>“the ions hold”: the solute the run's own ions hold, counted "
                                   "against the true surface and plateaus, over the true excess: the counting "
                                   "noise no method can remove.</p>")


def _details(report: dict, folder: Path) -> str:
    parts = []
    for s in report["surfaces"]:
        parts.append(f"<h3>Objects of the {html.escape(surface_title(s))} ({html.escape(s['label'])})</h3>")
        parts.append(_objects(s))
        parts.append(f"<h3>Inside composition per object at {html.escape(s['label'])}</h3>")
        parts.append(_plateaus(s))
        parts.append(f"<h3>Interfacial excess per object at {html.escape(s['label'])}</h3>")
        parts.append(_excess_per_object(s))
    parts.append("<h3>Composition of the specimen (ranged ions, atoms)</h3>")
    parts.append(_table(["element", "at.%"], [[e, 100 * c] for e, c in report["composition"].items()]))
    if report.get("range_file"):
        parts.append("<h3>Range file as read</h3>")
        parts.append(_table(["line", "kind", "what was done"],
                            [[_cell(n["line"], "not tied to one line"), n["kind"], n["message"]]
                             for n in report["range_file"]]))
    if "audit" in report:
        parts.append("<h3>Range-file audit</h3>")
        parts.append(_table(["severity", "finding"], [[f["severity"], f["message"]] for f in report["audit"]]))
    files = sorted({p.relative_to(folder).as_posix() for p in folder.glob("*")
                    if p.suffix in {".csv", ".json", ".mlx", ".mlp", ".toml", ".png"} and p.name != "report.html"}
                   | {p.relative_to(folder).as_posix() for p in folder.glob("meshes/*")})
    parts.append("<h3>Files</h3><p class='files'>" + " · ".join(_link(f, folder) for f in files) + "</p>")
    parts.append("<h3>Inputs</h3>" + _table(["file", "size (MB)", "SHA-256"],
                                            [[f["path"], f["bytes"] / 1e6, f["sha256"]] for f in report["inputs"]]))
    parts.append("<h3>Steps</h3>" + _table(["step", "time (s)", "peak memory (MiB)", "what it found"],
                                           [[r["step"], r["seconds"], r["peak_mib"], r["summary"].split("\n")[0]]
                                            for r in report["steps"]]))
    parts.append("<h3>Versions</h3>" + _table(["package", "version"],
                                              [[k, v or "not installed"] for k, v in report["apt-filters"].items()]))
    return "".join(parts)


STYLE = """
body{font-family:system-ui,sans-serif;max-width:1300px;margin:1em auto;padding:0 1em;color:#222;font-size:14px}
h1{font-size:1.5em;margin:.2em 0}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.2em}
h3{font-size:1em;margin:.8em 0 .3em}
ul.run{margin:.2em 0;padding-left:1.2em;color:#444}
.warn{background:#fff4e5;border-left:4px solid #e69500;padding:.3em 1em;margin:.6em 0}
.warn li{margin:.15em 0}
table{border-collapse:collapse;font-variant-numeric:tabular-nums}
td,th{border:1px solid #ddd;padding:2px 7px;text-align:right;white-space:nowrap}
th{background:#f3f3f3;font-weight:600}td:first-child,th:first-child,td.t{text-align:left}
table.summary td{font-size:1.05em}table.wrap th{white-space:normal;min-width:4em}
.scroll{overflow-x:auto;max-width:100%}
.cards{display:flex;gap:2em;flex-wrap:wrap}
figure{display:inline-block;margin:.5em;vertical-align:top}figure img{max-height:620px;max-width:100%}
figcaption{font-size:.9em;color:#555;max-width:600px}
.none{color:#777;font-style:italic}.note{color:#555;font-size:.9em;margin:.3em 0}.files a{margin-right:.3em}
"""


def write_html(path: Path, report: dict, pictures: list[tuple[Path, str]]) -> Path:
    """Write the reader's page for ``report`` (the content of report.json) beside its files.

    ``pictures`` are (PNG, caption) pairs, inlined in this order.
    """
    folder = Path(path).parent
    names = ", ".join(Path(f["path"]).name for f in report["inputs"][:1])
    parts = [f"<h1>apt-filters report: {html.escape(names)}</h1>", _what_was_run(report)]
    warnings = warnings_in_words(report)
    if warnings:
        parts.append("<div class='warn'><b>Check before use</b><ul>"
                     + "".join(f"<li>{html.escape(w)}</li>" for w in warnings) + "</ul></div>")
    for s in report["surfaces"]:
        parts.append(f"<h2>{html.escape(surface_title(s))} ({html.escape(s['label'])})</h2>{_summary(s)}"
                     + _maps(s.get("maps") or []))
    if report.get("truth"):
        parts.append("<h2>Against the ground truth (synthetic specimen)</h2>" + _truth(report["truth"]))
    parts.append("<h2>Pictures</h2>" + "".join(_image(p, c) for p, c in pictures if p.exists()))
    parts.append("<h2>Details</h2>" + _details(report, folder))
    page = (f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>apt-filters report: "
            f"{html.escape(names)}</title><style>{STYLE}</style></head><body>{''.join(parts)}</body></html>\n")
    return atomic_write_text(path, page, overwrite=True)


def _maps(rows: list[dict]) -> str:
    """The excess maps' statistics per solute and object (analysis.maps), with the test of uniform segregation."""
    if not rows:
        return ""
    def num(v, f=".3g"):
        return "-" if v is None else format(v, f)
    header = ["solute", "object", "excess (detected atoms/nm²)", "map mean", "map 5th-95th %", "patch error level",
              "median patch radius (nm)", "disjoint patches", "chi² / dof", "p (uniform)", "verdict",
              "spread beyond noise (detected atoms/nm²)"]
    body = [[r["solute"], str(r["object_id"]), f"{num(r['excess'])} ± {num(r['excess_sigma'], '.2g')}",
             num(r["map_mean"]), f"{num(r['map_p5'])} to {num(r['map_p95'])}", num(r["target_sigma"], ".2g"),
             num(r["median_radius"], ".2g"), str(r["n_patches"]),
             f"{num(r['chi2'], '.3g')} / {r['dof']}" if r["dof"] else "-", num(r["p_value"], ".2g"),
             "-" if r["p_value"] is None else "varies" if r["p_value"] < 0.05 else "uniform within noise",
             num(r["spread"], ".2g")] for r in rows]
    return ("<h3>Excess maps along the surface</h3><p>Local excess per vertex from a patch around it; p: chi-square "
            "test of uniform segregation over disjoint patches (below 0.05: the map varies more than counting "
            "noise).</p>" + _table(header, body, "wrap"))


def write_page(path: Path, title: str, sections: list[tuple[str, object]],
               pictures: list[tuple[Path, str]] = ()) -> Path:
    """A page in the report's style for the commands that gather runs (sweep, batch).

    ``sections`` are (heading, content): a paragraph (str) or a table ``(header, rows)`` as
    :func:`_table` takes it. ``pictures`` are (PNG, caption) pairs, inlined after the sections.
    """
    parts = [f"<h1>{html.escape(title)}</h1>"]
    for heading, content in sections:
        body = f"<p>{html.escape(content)}</p>" if isinstance(content, str) else _table(*content)
        parts.append(f"<h2>{html.escape(heading)}</h2>{body}")
    if pictures:
        parts.append("<h2>Pictures</h2>" + "".join(_image(p, c) for p, c in pictures if p.exists()))
    page = (f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}</style></head><body>{''.join(parts)}</body></html>\n")
    return atomic_write_text(path, page, overwrite=True)
