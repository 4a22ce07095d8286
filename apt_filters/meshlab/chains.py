"""Named chains of MeshLab filters, parameters as data, recorded as ``.mlx`` scripts.

A :class:`Chain` is a tuple of :class:`Step` (pymeshlab filter name + parameters). A length
may be given as :class:`Percent` of the current mesh's bounding-box diagonal, as MeshLab's
GUI does; MeshLab freezes it to an absolute value in the script, so every applied chain
writes two files: ``NAME.mlx`` (the exact filters and absolute values, replayable by
MeshLab, pymeshlab and ``apt-filters replay``) and ``NAME.json`` beside it (the chain with
its relative parameters and the resolved values), from which :func:`chain_from_json`
re-derives the chain for another dataset.

Every parameter is passed explicitly and floats are rounded to the 6 significant digits
MeshLab writes, so replaying the script reproduces the chain's result bit for bit.
The chain runs on a fresh ``MeshSet`` holding only the input mesh, so the script records
the chain and nothing else (a MeshSet records every filter it ran, creation filters too).
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pymeshlab

from apt_filters.core import jsontext
from apt_filters.core.atomic import atomic_output, atomic_write_bytes, atomic_write_text
from apt_filters.core.errors import AptFiltersError
from apt_filters.core.mesh import TriMesh
from apt_filters.meshlab.bridge import OBJECT_ID, from_pymeshlab, to_meshset
from apt_filters.meshlab.filters import FILTERS, MESHLAB_2020
from apt_filters.meshlab.mlx import canonical_script


CAP = "cap"
"""Face scalar set by chains that close holes: 1 on the faces added (``apt_filters.analysis.objects``
then reports the object as a proxy)."""


@dataclass(frozen=True)
class Percent:
    """A length given as a percentage of the current mesh's bounding-box diagonal."""

    value: float


Param = bool | int | float | Percent


@dataclass(frozen=True)
class Step:
    """One MeshLab filter (pymeshlab name) with its parameters (pymeshlab names)."""

    filter: str
    params: Mapping[str, Param] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.filter not in FILTERS:
            raise AptFiltersError(f"filter {self.filter!r} is not one apt-filters allows in a chain")


@dataclass(frozen=True)
class Chain:
    """A named sequence of filter steps."""

    name: str
    description: str
    steps: tuple[Step, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "description": self.description,
                "steps": [{"filter": s.filter, "params": {k: _param_to_json(v) for k, v in s.params.items()}}
                          for s in self.steps]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Chain":
        return cls(str(data["name"]), str(data.get("description", "")),
                   tuple(Step(str(s["filter"]), {k: _param_from_json(v) for k, v in s["params"].items()})
                         for s in data["steps"]))


def _param_to_json(value: Param) -> Any:
    return {"percent": value.value} if isinstance(value, Percent) else value


def _param_from_json(value: Any) -> Param:
    if isinstance(value, dict):
        if set(value) != {"percent"}:
            raise AptFiltersError(f"chain parameter {value!r} is neither a number nor {{'percent': x}}")
        return Percent(float(value["percent"]))
    if not isinstance(value, (bool, int, float)):
        raise AptFiltersError(f"chain parameter {value!r} is not a number or boolean")
    return value


def meshlab_float(x: float) -> float:
    """``x`` rounded to the 6 significant digits MeshLab writes in a ``.mlx`` script."""
    return float(f"{x:.6g}")


def resolve(params: Mapping[str, Param], diagonal: float) -> dict[str, bool | int | float]:
    """Absolute parameter values for a mesh whose bounding-box diagonal is ``diagonal`` (nm)."""
    out: dict[str, bool | int | float] = {}
    for key, value in params.items():
        if isinstance(value, Percent):
            value = value.value / 100.0 * diagonal
        out[key] = meshlab_float(value) if isinstance(value, float) else value
    return out


def pymeshlab_args(values: Mapping[str, bool | int | float], step: Step) -> dict[str, Any]:
    """Keyword arguments for the pymeshlab filter of ``step`` from resolved ``values``."""
    # pymeshlab takes lengths of MeshLab's "AbsPerc" type as PureValue (absolute units)
    return {k: pymeshlab.PureValue(v) if isinstance(step.params[k], Percent) else v for k, v in values.items()}


CHAINS: dict[str, Chain] = {
    "clean": Chain("clean", "duplicates, zero-area faces, small pieces, non-manifold repair, coherent orientation", (
        Step("meshing_remove_duplicate_vertices"),
        Step("meshing_remove_duplicate_faces"),
        Step("meshing_remove_null_faces"),
        Step("meshing_remove_connected_component_by_face_number", {"mincomponentsize": 10, "removeunref": True}),
        Step("meshing_remove_connected_component_by_diameter", {"mincomponentdiag": Percent(0.5), "removeunref": True}),
        Step("meshing_repair_non_manifold_edges", {"method": 0}),
        Step("meshing_repair_non_manifold_vertices", {"vertdispratio": 0.0}),
        Step("meshing_re_orient_faces_coherently"),
        Step("meshing_remove_unreferenced_vertices"),
    )),
    "close": Chain("close", "close holes up to a boundary length (edges), for proxy volumes", (
        Step("meshing_close_holes", {"maxholesize": 100, "selected": False, "newfaceselected": True,
                                     "selfintersection": True, "refinehole": False,
                                     "refineholeedgelen": Percent(1.0)}),
    )),
    "smooth": Chain("smooth", "Taubin smoothing (no shrinkage)", (
        Step("apply_coord_taubin_smoothing", {"lambda_": 0.5, "mu": -0.53, "stepsmoothnum": 10, "selected": False}),
    )),
    "smooth_hc": Chain("smooth_hc", "HC Laplacian smoothing (the classic baseline)", (
        Step("apply_coord_hc_laplacian_smoothing"),
    )),
    "decimate": Chain("decimate", "quadric edge collapse to half the faces, boundary and topology kept", (
        Step("meshing_decimation_quadric_edge_collapse", {
            "targetfacenum": 0, "targetperc": 0.5, "qualitythr": 0.3, "preserveboundary": True,
            "boundaryweight": 1.0, "preservenormal": True, "preservetopology": True, "optimalplacement": True,
            "planarquadric": False, "planarweight": 0.001, "qualityweight": False, "autoclean": True,
            "selected": False}),
    )),
}
"""The named chains and their default parameters."""


def get_chain(chain: Chain | str) -> Chain:
    """A :class:`Chain`, or the one of :data:`CHAINS` with that name."""
    if isinstance(chain, Chain):
        return chain
    try:
        return CHAINS[chain]
    except KeyError:
        raise AptFiltersError(f"unknown chain {chain!r}; known: {', '.join(CHAINS)}") from None


@dataclass
class ChainRun:
    """What applying a chain did: the resolved (absolute) parameters of each step."""

    chain: Chain
    resolved: list[dict[str, bool | int | float]]
    diagonals: list[float]

    def record(self, mesh_label: str = "") -> dict[str, Any]:
        """JSON-able record: the chain with relative parameters plus the values MeshLab got."""
        data = self.chain.to_dict()
        for step, values, diag in zip(data["steps"], self.resolved, self.diagonals):
            step["mlx_name"] = FILTERS[step["filter"]]
            step["bbox_diagonal_nm"] = diag
            step["resolved"] = values
        data["mesh"] = mesh_label
        return data


def run_on_meshset(ms: pymeshlab.MeshSet, chain: Chain | str) -> ChainRun:
    """Apply ``chain`` to the current mesh of ``ms`` in place (no script is written).

    Percentages are resolved against the current mesh's bounding box at each step, as
    MeshLab does.
    """
    chain = get_chain(chain)
    resolved, diagonals = [], []
    for step in chain.steps:
        diag = float(ms.current_mesh().bounding_box().diagonal())
        values = resolve(step.params, diag)
        try:
            getattr(ms, step.filter)(**pymeshlab_args(values, step))
        except pymeshlab.PyMeshLabException as exc:
            raise AptFiltersError(f"chain {chain.name!r}: MeshLab filter {FILTERS[step.filter]!r} failed: {exc}") from exc
        resolved.append(values)
        diagonals.append(diag)
    return ChainRun(chain, resolved, diagonals)


MESHLAB_2020_SUFFIX = ".meshlab2020.mlx"
"""``NAME.mlx`` in MeshLab 2020.x's dialect is written as ``NAME.meshlab2020.mlx``."""


def meshlab2020_script(data: bytes) -> bytes:
    """A ``.mlx`` script of current MeshLab (pymeshlab) rewritten for MeshLab 2020.x.

    Filters MeshLab 2020.x names differently are renamed and the parameters it lacks are
    left out (:data:`apt_filters.meshlab.filters.MESHLAB_2020`); the rest is kept as it is.
    """
    root = ET.fromstring(data)
    for element in root:
        rule = MESHLAB_2020.get(element.get("name", ""))
        if rule is None:
            continue
        name, dropped = rule
        params = {p.get("name"): p for p in element}
        if isinstance(name, dict):  # one filter with a mode parameter was two filters in 2020.x
            key = dropped[0]
            name = name[f"{key}={params[key].get('value') if key in params else 0}"]
        element.set("name", name)
        for key in dropped:
            if key in params:
                element.remove(params[key])
    return b"<!DOCTYPE FilterScript>\n" + ET.tostring(root, encoding="utf-8", xml_declaration=False) + b"\n"


def save_script(ms: pymeshlab.MeshSet, run: ChainRun, script: str | os.PathLike, overwrite: bool = False,
                label: str = "") -> tuple[Path, Path]:
    """Write ``ms``'s filter script as ``script`` (.mlx), the chain record beside it (.json) and
    the script for MeshLab 2020.x (``meshlabserver`` of Debian 12) as ``*.meshlab2020.mlx``
    (:func:`meshlab2020_script`).

    ``ms`` must have run only the chain (see :func:`apply_chain`); every write is atomic.
    Returns the ``.mlx`` and ``.json`` paths.
    """
    script = Path(script)
    if script.suffix.lower() != ".mlx":
        raise AptFiltersError("a MeshLab filter script must end in .mlx", script)
    record = script.with_suffix(".json")
    legacy = script.with_name(script.stem + MESHLAB_2020_SUFFIX)
    for path in (script, record, legacy):  # refuse before writing any file
        if path.exists() and not overwrite:
            raise AptFiltersError("exists already; pass overwrite/--force to replace it", path)
    with atomic_output(script, overwrite) as tmp:
        ms.save_filter_script(str(tmp))
        tmp.write_bytes(canonical_script(tmp.read_bytes()))  # MeshLab's attribute order varies per process
    atomic_write_bytes(legacy, meshlab2020_script(script.read_bytes()), overwrite)
    atomic_write_text(record, jsontext.dumps(run.record(label), indent=1) + "\n", overwrite)
    return script, record


def apply_chain(mesh: TriMesh, chain: Chain | str, script: str | os.PathLike | None = None,
                overwrite: bool = False, quality: str | None = "value") -> tuple[TriMesh, ChainRun]:
    """Apply a chain to a :class:`TriMesh` and record it as ``script`` (.mlx + .json).

    Parameters
    ----------
    mesh : TriMesh
        Input, not modified. Its scalars travel through MeshLab (see :mod:`.bridge`).
    chain : Chain or str
        A chain or the name of one in :data:`CHAINS`.
    script : path, optional
        Where to write the ``.mlx``; the ``.json`` record goes beside it.
    overwrite : bool
        Replace existing script files.

    Returns
    -------
    TriMesh, ChainRun

    Memory: about three copies of the mesh (ours, MeshLab's, the result).
    """
    ms, names = to_meshset(mesh, quality=quality)
    run = _run_recorded(ms, chain, script, overwrite)
    out = from_pymeshlab(ms, names)
    if any(s.filter == "meshing_close_holes" and s.params.get("newfaceselected") for s in run.chain.steps):
        _flag_caps(out, ms.current_mesh().face_selection_array())
    return out, run


def apply_chain_to_meshset(ms: pymeshlab.MeshSet, chain: Chain | str, script: str | os.PathLike | None = None,
                           overwrite: bool = False) -> ChainRun:
    """For pymeshlab users: apply a chain to ``ms``'s current mesh, recorded as ``script``.

    The chain runs on a copy in a fresh MeshSet, so the script holds the chain only, not
    ``ms``'s history; the result is added to ``ms`` as a new current mesh labelled
    ``"<label> (<chain>)"``, with every MeshLab attribute (custom ones too) kept.
    """
    chain = get_chain(chain)
    source = ms.current_mesh()
    work = pymeshlab.MeshSet()
    work.add_mesh(source, source.label())
    run = _run_recorded(work, chain, script, overwrite)
    ms.add_mesh(work.current_mesh(), f"{source.label()} ({chain.name})")
    return run


def _run_recorded(ms: pymeshlab.MeshSet, chain: Chain | str, script: str | os.PathLike | None,
                  overwrite: bool) -> ChainRun:
    ms.clear_filter_script()
    run = run_on_meshset(ms, chain)
    if script is not None:
        save_script(ms, run, script, overwrite)
    return run


def _flag_caps(mesh: TriMesh, selected: np.ndarray) -> None:
    """Mark the faces Close Holes added (left selected) in face scalar ``cap``, and give them
    the ``object_id`` of the surface around them (MeshLab initialises it to 0)."""
    earlier = np.asarray(mesh.face_scalars.get(CAP, np.zeros(mesh.n_faces))) != 0  # caps of an earlier close
    mesh.face_scalars[CAP] = (earlier | selected).astype(np.int8)
    if OBJECT_ID in mesh.face_scalars and selected.any():
        # without hole refinement, every new face has only vertices of the hole's rim
        oid = mesh.face_scalars[OBJECT_ID]
        rim = np.zeros(mesh.n_vertices, dtype=oid.dtype)
        rim[mesh.faces[~selected].ravel()] = np.repeat(oid[~selected], 3)
        oid[selected] = rim[mesh.faces[selected, 0]]


def chain_from_json(path: str | os.PathLike) -> Chain:
    """Re-derive a chain (relative parameters) from the ``.json`` record of an applied chain."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return Chain.from_dict(data)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise AptFiltersError(f"not a chain record: {exc}", path) from exc
