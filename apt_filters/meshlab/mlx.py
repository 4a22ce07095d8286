"""Reading and replaying MeshLab ``.mlx`` filter scripts from untrusted sources.

A script is XML. Before any XML parser sees it, the bytes are checked: no document type
definition other than MeshLab's bare ``<!DOCTYPE FilterScript>``, no entity declarations,
no processing instruction but the XML declaration, bounded size. Only then is it parsed
with ``xml.etree`` (expat, which fetches nothing) and every filter is checked against the
allow-list of :mod:`apt_filters.meshlab.filters` and every parameter against the filter's
pymeshlab parameters. Replay then hands the checked bytes (not the file, which could change
meanwhile) to MeshLab's own engine (``load_filter_script`` + ``apply_filter_script``).
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

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.meshlab.bridge import load_mesh, save_current_mesh
from apt_filters.meshlab.filters import MLX_NAMES

MAX_SCRIPT_BYTES = 1 << 20
"""Refuse scripts over 1 MiB: real ones are a few kB."""

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


def parse_script(data: bytes, path: str | os.PathLike | None = None) -> list[ScriptFilter]:
    """Parse checked ``.mlx`` bytes into the list of filters.

    Raises
    ------
    InputError
        Unsafe markup, malformed XML, not a ``FilterScript``, or a filter outside the allow-list.
    """
    check_markup(data, path)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise InputError(f"malformed filter script: {exc}", path) from None
    if root.tag != "FilterScript":
        raise InputError(f"not a MeshLab filter script (root element <{root.tag}>)", path)
    filters = []
    for element in root:
        name = element.get("name", "")
        if element.tag != "filter" or name not in MLX_NAMES:
            raise InputError(f"unknown filter <{element.tag} name={name!r}>; apt-filters replays only: "
                             + ", ".join(sorted(MLX_NAMES)), path)
        params = {}
        for p in element:
            if p.tag != "Param" or "name" not in p.attrib or "value" not in p.attrib:
                raise InputError(f"filter {name!r}: malformed parameter <{p.tag}>", path)
            params[p.get("name")] = p.get("value")
        filters.append(ScriptFilter(name, MLX_NAMES[name], params))
    return filters


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
    """Refuse parameters the filter does not have (``ms`` must hold a mesh)."""
    for f in filters:
        known = set(ms.filter_parameter_values(f.filter))
        unknown = [p for p in f.params if _python_param(p, known) is None]
        if unknown:
            raise InputError(f"filter {f.mlx_name!r} has no parameter {', '.join(unknown)}", path)


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


def replay_on_meshset(ms: pymeshlab.MeshSet, script: str | os.PathLike) -> list[ScriptFilter]:
    """Apply a checked ``.mlx`` script to the current mesh of ``ms`` with MeshLab's engine."""
    data, filters = read_script(script)
    check_params(ms, filters, script)
    with tempfile.TemporaryDirectory(prefix="apt-filters-mlx-") as tmp:
        checked = Path(tmp) / "script.mlx"
        checked.write_bytes(data)
        try:
            with _quiet():
                ms.load_filter_script(str(checked))
            ms.apply_filter_script()
        except pymeshlab.PyMeshLabException as exc:
            raise AptFiltersError(f"MeshLab could not apply the script: {exc}", script) from exc
    return filters


def replay_file(script: str | os.PathLike, mesh_in: str | os.PathLike, mesh_out: str | os.PathLike,
                overwrite: bool = False) -> list[ScriptFilter]:
    """Replay ``script`` on the mesh file ``mesh_in`` and save the result to ``mesh_out`` (atomic).

    The input is not modified. Memory: one copy of the mesh inside MeshLab.
    """
    if Path(mesh_out).resolve() == Path(mesh_in).resolve():
        raise AptFiltersError("output would overwrite the input mesh", mesh_out)
    ms = load_mesh(mesh_in)
    filters = replay_on_meshset(ms, script)
    save_current_mesh(ms, mesh_out, overwrite)
    return filters
