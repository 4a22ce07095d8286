"""The run report: ``report.json`` (every figure and parameter) and a self-contained
``report.html`` (plots inlined, tables, timings)."""

from __future__ import annotations

import base64
import hashlib
import html
import json
import os
import platform
from importlib import metadata
from pathlib import Path

from apt_filters import __version__
from apt_filters.core.atomic import atomic_write_text

DEPENDENCIES = ("numpy", "scipy", "pymeshlab", "open3d", "fast-simplification", "numba", "matplotlib", "tqdm")


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
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False, default=_jsonable) + "\n", overwrite=True)


def _jsonable(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def _table(rows: list[dict]) -> str:
    if not rows:
        return "<p><em>none</em></p>"
    keys = list(dict.fromkeys(k for row in rows for k in row))
    head = "".join(f"<th>{html.escape(str(k))}</th>" for k in keys)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_fmt(row.get(k, '')))}</td>" for k in keys) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v)
    return str(v)


def _image(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(path.name)}"><figcaption>{html.escape(path.name)}</figcaption></figure>'


def write_html(path: Path, title: str, sections: list[tuple[str, list[dict] | str]], images: list[Path]) -> None:
    """A self-contained page: ``sections`` are (heading, table rows or preformatted text)."""
    parts = [f"<h1>{html.escape(title)}</h1>"]
    for heading, content in sections:
        parts.append(f"<h2>{html.escape(heading)}</h2>")
        parts.append(_table(content) if isinstance(content, list) else f"<pre>{html.escape(content)}</pre>")
    if images:
        parts.append("<h2>Plots</h2>" + "".join(_image(p) for p in images))
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}img{max-width:100%}")
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")
    atomic_write_text(path, page, overwrite=True)
