"""Reading and replaying MeshLab ``.mlx`` filter scripts from untrusted sources.

A script is XML. Before any XML parser sees it, the bytes are checked: no document type
definition other than MeshLab's bare ``<!DOCTYPE FilterScript>``, no entity declarations,
no processing instruction but the XML declaration, bounded size. Only then is it parsed
with ``xml.etree`` (expat, which fetches nothing) and checked for shape and size: at most
three levels (``FilterScript > filter > Param``; MeshLab's own loader recurses and dies on
deep nesting), at most :data:`MAX_FILTERS` filters, each on the allow-list of
:mod:`apt_filters.meshlab.filters`, each parameter one the filter has (:data:`PARAMS`), given
once, of its type and inside its interval (``abc``, ``nan``, ``1e9`` smoothing steps are
refused; MeshLab would silently take its default, or run for hours). The work the script
asks for is estimated from the mesh before anything runs (:func:`script_work`) and refused
above :data:`MAX_WORK`. Replay then hands the checked bytes in canonical form (not the file,
which could change meanwhile) to MeshLab's own engine (``load_filter_script`` +
``apply_filter_script``), through a temporary file beside the output
(:func:`apt_filters.core.atomic.scratch_path`).

:func:`canonical_script` writes a script's attributes in one fixed order (MeshLab writes them
in the order of a hash table seeded per process), so the same chain gives the same bytes.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import sys
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import pymeshlab

from apt_filters.core.atomic import refuse_inputs, remove, scratch_path, signals_held, tidy
from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.numbers import within
from apt_filters.meshlab.bridge import load_mesh, save_current_mesh
from apt_filters.meshlab.filters import MLX_NAMES

MAX_SCRIPT_BYTES = 1 << 20
"""Refuse scripts over 1 MiB: real ones are a few kB."""
MAX_FILTERS = 100
"""Refuse scripts of more filters: apt-filters' chains have up to 13."""
MAX_SMOOTHING_STEPS = 10_000
"""Refuse scripts whose smoothing filters add up to more steps (MeshLab's default is 10 a filter)."""
MAX_WORK = 2e9
"""Refuse scripts over this many face visits (:func:`script_work`): ~3 minutes at the ~10^7 face
visits a second measured for Taubin smoothing; a 10-filter clean chain on a 10^6-face mesh is ~10^8."""
PASS_WORK = 10
"""Face visits per face of one pass of a filter other than Taubin smoothing (HC Laplacian, hole
closing, re-orienting and repairs measured 6-15x slower per face than one Taubin step)."""

_INT = r"[+-]?\d{1,10}"
PARAMS: dict[str, dict[str, tuple[str, str]]] = {
    "meshing_remove_connected_component_by_face_number": {"MinComponentSize": ("int", "[0, 2147483647]"),
                                                          "removeUnref": ("bool", "")},
    "meshing_remove_connected_component_by_diameter": {"MinComponentDiag": ("float", "[0, 1e12]"),
                                                       "removeUnref": ("bool", "")},
    "meshing_repair_non_manifold_edges": {"method": ("enum", "[0, 1]")},
    "meshing_repair_non_manifold_vertices": {"VertDispRatio": ("float", "[0, 1]")},
    "meshing_close_holes": {"MaxHoleSize": ("int", "[0, 2147483647]"), "Selected": ("bool", ""),
                            "NewFaceSelected": ("bool", ""), "SelfIntersection": ("bool", ""),
                            "RefineHole": ("bool", ""), "RefineHoleEdgeLen": ("float", "(0, 1e12]")},
    "apply_coord_taubin_smoothing": {"lambda": ("float", "(0, 1]"), "mu": ("float", "[-1, 0)"),
                                     "stepSmoothNum": ("int", "[0, 1000]"), "Selected": ("bool", "")},
    "meshing_decimation_quadric_edge_collapse": {
        "TargetFaceNum": ("int", "[0, 2147483647]"), "TargetPerc": ("float", "[0, 1]"),
        "QualityThr": ("float", "[0, 1]"), "PreserveBoundary": ("bool", ""), "BoundaryWeight": ("float", "[0, 1000]"),
        "PreserveNormal": ("bool", ""), "PreserveTopology": ("bool", ""), "OptimalPlacement": ("bool", ""),
        "PlanarQuadric": ("bool", ""), "PlanarWeight": ("float", "[0, 1000]"), "QualityWeight": ("bool", ""),
        "AutoClean": ("bool", ""), "Selected": ("bool", "")},
}
"""Per pymeshlab filter: parameter (MeshLab's name, as its scripts spell it; MeshLab ignores any other
spelling) -> (kind, interval). Filters absent here have no parameters. Kinds: ``int`` (decimal
digits), ``float`` (finite), ``bool`` (``true``/``false``), ``enum`` (an index). Intervals as in
:func:`apt_filters.core.numbers.within`, ``(``/``)`` open."""
RICH_TYPES = {"int": {"RichInt"}, "float": {"RichFloat", "RichAbsPerc", "RichDynamicFloat", "RichPercentage"},
              "bool": {"RichBool"}, "enum": {"RichEnum"}}
"""MeshLab's parameter types (the ``type`` attribute) each kind may be written as."""
ATTRIBUTE_ORDER = ("name", "value", "type", "description", "tooltip", "min", "max", "enum_cardinality")
"""Order of a ``<Param>``'s attributes in :func:`canonical_script`; others follow sorted."""
_NUMERIC_ATTRIBUTES = {"min", "max", "enum_cardinality"}
_TEXT_ATTRIBUTES = {"name", "value", "type", "description", "tooltip", "isxmlparam"}
_ENUM_VALUE = re.compile(r"enum_val\d{1,3}$")

_MARKUP_DECL = re.compile(rb"<!(?!--)")
_ALLOWED_DOCTYPE = re.compile(rb"<!DOCTYPE\s+FilterScript\s*>")
_PI = re.compile(rb"<\?(?!xml\s)")


@dataclass(frozen=True)
class ScriptFilter:
    """One filter of a script: MeshLab name, pymeshlab name, raw parameters (name -> value text)."""

    mlx_name: str
    filter: str
    params: dict[str, str]


def check_markup(data: bytes, path: str | os.PathLike | None = None) -> None:
    """Refuse DTDs, entity declarations and processing instructions (XML bombs, external entities)."""
    if len(data) > MAX_SCRIPT_BYTES:
        raise InputError(f"filter script larger than {MAX_SCRIPT_BYTES} bytes", path)
    # the byte checks below only see markup in an ASCII-compatible encoding: refuse UTF-16/32
    if b"\x00" in data or data.startswith((b"\xfe\xff", b"\xff\xfe")):
        raise InputError("filter script is not UTF-8 text; refused", path)
    stripped = _ALLOWED_DOCTYPE.sub(b"", data, count=1)
    if _MARKUP_DECL.search(stripped):
        raise InputError("filter script holds a DTD or entity declaration (<!DOCTYPE/<!ENTITY); refused", path)
    if _PI.search(stripped):
        raise InputError("filter script holds a processing instruction; refused", path)


def _parse_xml(data: bytes, path: str | os.PathLike | None) -> ET.Element:
    """Checked markup -> the ``<FilterScript>`` element."""
    check_markup(data, path)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise InputError(f"malformed filter script: {exc}", path) from None
    if root.tag != "FilterScript":
        raise InputError(f"not a MeshLab filter script (root element <{root.tag}>)", path)
    return root


def check_value(kind: str, interval: str, text: str) -> str | None:
    """Why ``text`` is not a valid value of a parameter of ``kind`` in ``interval``; None if it is."""
    if kind == "bool":
        return None if text in ("true", "false") else "is not true or false"
    if kind in ("int", "enum") and not re.fullmatch(_INT, text):
        return "is not a whole number"
    try:
        value = float(text)
    except ValueError:
        return "is not a number"
    return None if within(value, interval) else f"is outside {interval}"


def _check_attributes(filter_name: str, param: ET.Element, path) -> None:
    for key, text in param.attrib.items():
        if key in _NUMERIC_ATTRIBUTES and check_value("float", "[-1e300, 1e300]", text):
            raise InputError(f"filter {filter_name!r}: attribute {key}={text!r} is not a finite number", path)
        if key not in _NUMERIC_ATTRIBUTES | _TEXT_ATTRIBUTES and not _ENUM_VALUE.match(key):
            raise InputError(f"filter {filter_name!r}: unknown attribute {key!r} of <Param>", path)


def _check_param(f_name: str, py_filter: str, param: ET.Element, seen: set, path) -> tuple[str, str]:
    """Check one ``<Param>``; returns (its name, value text)."""
    if param.tag != "Param" or "name" not in param.attrib or "value" not in param.attrib:
        raise InputError(f"filter {f_name!r}: malformed parameter <{param.tag}>", path)
    if len(param):
        raise InputError(f"filter {f_name!r}: parameter {param.get('name')!r} holds nested elements", path)
    _check_attributes(f_name, param, path)
    name, text = param.get("name"), param.get("value")
    known = PARAMS.get(py_filter, {})
    if name not in known:
        spelt = [k for k in known if k.lower() == name.lower()]
        hint = f" (MeshLab spells it {spelt[0]})" if spelt else ""
        raise InputError(f"filter {f_name!r} has no parameter {name}{hint}", path)
    if name in seen:
        raise InputError(f"filter {f_name!r}: parameter {name} given twice", path)
    seen.add(name)
    kind, interval = known[name]
    if param.get("type") not in RICH_TYPES[kind]:
        raise InputError(f"filter {f_name!r}: parameter {name} has type {param.get('type')!r}, "
                         f"expected {' or '.join(sorted(RICH_TYPES[kind]))}", path)
    problem = check_value(kind, interval, text)
    if problem:
        raise InputError(f"filter {f_name!r}: {name}={text!r} {problem}", path)
    return name, text


def parse_script(data: bytes, path: str | os.PathLike | None = None) -> list[ScriptFilter]:
    """Parse and check ``.mlx`` bytes into the list of filters (see the module's description).

    Raises
    ------
    InputError
        Unsafe markup, malformed XML, not a ``FilterScript``, too many filters or smoothing
        steps, a filter outside the allow-list, nested parameters, or a parameter that is
        unknown, repeated, of the wrong type or outside its interval. One line.
    """
    root = _parse_xml(data, path)
    if len(root) > MAX_FILTERS:
        raise InputError(f"filter script of {len(root)} filters; apt-filters replays at most {MAX_FILTERS}", path)
    filters = []
    for element in root:
        name = element.get("name", "")
        if element.tag != "filter" or name not in MLX_NAMES:
            raise InputError(f"unknown filter <{element.tag} name={name!r}>; apt-filters replays only: "
                             + ", ".join(sorted(MLX_NAMES)), path)
        seen: set = set()
        params = dict(_check_param(name, MLX_NAMES[name], p, seen, path) for p in element)
        filters.append(ScriptFilter(name, MLX_NAMES[name], params))
    steps = sum(_smoothing_steps(f) for f in filters)
    if steps > MAX_SMOOTHING_STEPS:
        raise InputError(f"filter script of {steps:,} smoothing steps; apt-filters replays at most "
                         f"{MAX_SMOOTHING_STEPS:,}", path)
    return filters


def _smoothing_steps(f: ScriptFilter) -> int:
    if f.filter != "apply_coord_taubin_smoothing":
        return 0
    return int(f.params.get("stepSmoothNum", 10))  # MeshLab's default


def script_work(filters: list[ScriptFilter], n_faces: int) -> float:
    """Face visits the script needs on a mesh of ``n_faces`` (upper estimate; decimation only shrinks it).

    Taubin smoothing: one per face and step (its ``stepSmoothNum``); any other filter
    :data:`PASS_WORK` per face.
    """
    return float(n_faces) * sum(_smoothing_steps(f) if f.filter == "apply_coord_taubin_smoothing" else PASS_WORK
                                for f in filters)


def canonical_script(data: bytes) -> bytes:
    """A MeshLab script with every element's attributes in one fixed order (:data:`ATTRIBUTE_ORDER`).

    MeshLab writes a ``<Param>``'s attributes in the order of a hash table seeded per process;
    this gives the same bytes for the same script on every run.
    """
    root = _parse_xml(data, None)
    for element in root.iter():
        rank = {k: i for i, k in enumerate(ATTRIBUTE_ORDER)}
        items = sorted(element.attrib.items(), key=lambda kv: (rank.get(kv[0], len(rank)), kv[0]))
        element.attrib.clear()
        element.attrib.update(items)
    ET.indent(root, space=" ")
    return b"<!DOCTYPE FilterScript>\n" + ET.tostring(root, encoding="utf-8", xml_declaration=False) + b"\n"


def read_script(path: str | os.PathLike) -> tuple[bytes, list[ScriptFilter]]:
    """Read and check a ``.mlx`` file; returns its bytes and its filters."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_SCRIPT_BYTES + 1)
    except OSError as exc:
        raise InputError(f"cannot read filter script: {exc.strerror}", path) from None
    return data, parse_script(data, path)


def _python_param(mlx_param: str, known: set[str]) -> str | None:
    # pymeshlab lower-cases MeshLab's names and appends "_" to Python keywords (lambda -> lambda_)
    for candidate in (mlx_param.lower(), mlx_param.lower() + "_"):
        if candidate in known:
            return candidate
    return None


def check_params(ms: pymeshlab.MeshSet, filters: list[ScriptFilter], path: str | os.PathLike | None = None) -> None:
    """Refuse parameters this pymeshlab does not know (``ms`` must hold a mesh), and a script
    whose work on the current mesh exceeds :data:`MAX_WORK`."""
    for f in filters:
        known = set(ms.filter_parameter_values(f.filter))
        unknown = [p for p in f.params if _python_param(p, known) is None]
        if unknown:
            raise InputError(f"filter {f.mlx_name!r} has no parameter {', '.join(unknown)}", path)
    work = script_work(filters, ms.current_mesh().face_number())
    if work > MAX_WORK:
        raise InputError(f"filter script needs ~{work:.2g} face visits on this mesh of "
                         f"{ms.current_mesh().face_number():,} faces; apt-filters replays at most {MAX_WORK:.2g}", path)


@contextlib.contextmanager
def _quiet():
    """Silence C/C++ writes to file descriptors 1 and 2 (MeshLab echoes every filter it
    reads, through Qt's debug log); failures still arrive as exceptions."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in (1, 2)]
    try:
        with open(os.devnull, "wb") as null:
            for fd in (1, 2):
                os.dup2(null.fileno(), fd)
        yield
    finally:
        ctypes.CDLL(None).fflush(None)  # C stdio may buffer the echo: flush it into /dev/null
        for fd, copy in zip((1, 2), saved):
            os.dup2(copy, fd)
            os.close(copy)


def replay_on_meshset(ms: pymeshlab.MeshSet, script: str | os.PathLike,
                      workdir: str | os.PathLike | None = None) -> list[ScriptFilter]:
    """Apply a checked ``.mlx`` script to the current mesh of ``ms`` with MeshLab's engine.

    MeshLab reads scripts only from files: the checked bytes go to a temporary file in
    ``workdir`` (default: the system's temporary folder), removed at once; leftovers of killed
    runs there are tidied first.
    """
    data, filters = read_script(script)
    check_params(ms, filters, script)
    workdir = Path(tempfile.gettempdir() if workdir is None else workdir)
    tidy(workdir)
    checked = scratch_path(workdir / Path(script).name, ".mlx")
    try:
        checked.write_bytes(canonical_script(data))
        with _quiet():
            ms.load_filter_script(str(checked))
        ms.apply_filter_script()
    except pymeshlab.PyMeshLabException as exc:
        raise AptFiltersError(f"MeshLab could not apply the script: {exc}", script) from exc
    finally:
        with signals_held():
            remove(checked)
    return filters


def replay_file(script: str | os.PathLike, mesh_in: str | os.PathLike, mesh_out: str | os.PathLike,
                overwrite: bool = False) -> list[ScriptFilter]:
    """Replay ``script`` on the mesh file ``mesh_in`` and save the result to ``mesh_out`` (atomic).

    The input is not modified. Memory: one copy of the mesh inside MeshLab.
    """
    refuse_inputs([mesh_out], [mesh_in, script])
    if Path(mesh_out).exists() and not overwrite:
        raise AptFiltersError("exists already; pass overwrite/--force to replace it", mesh_out)
    read_script(script)  # a bad script is refused before the mesh is read
    ms = load_mesh(mesh_in)
    filters = replay_on_meshset(ms, script, workdir=Path(mesh_out).parent)
    save_current_mesh(ms, mesh_out, overwrite)
    return filters
