"""The MeshLab filters apt-filters uses, by pymeshlab name and MeshLab (``.mlx``) name.

pymeshlab exposes a filter as a snake-case method (``apply_coord_taubin_smoothing``) while a
``.mlx`` script names it as MeshLab's GUI does (``"Taubin Smooth"``). This table is the
allow-list: a script naming any other filter is refused, and at import every pymeshlab name
listed here must exist. pymeshlab silently drops its ``meshing_*`` filter plugin when the
system lacks libOpenGL, so a missing name is reported as that missing library rather than as
an obscure ``AttributeError`` later. No ``*_gpu`` filter is listed: they abort a headless
process.
"""

from __future__ import annotations

from typing import Iterable

from apt_filters.core.errors import AptFiltersError

FILTERS: dict[str, str] = {
    "meshing_remove_duplicate_vertices": "Remove Duplicate Vertices",
    "meshing_remove_duplicate_faces": "Remove Duplicate Faces",
    "meshing_remove_null_faces": "Remove Zero Area Faces",
    "meshing_remove_unreferenced_vertices": "Remove Unreferenced Vertices",
    "meshing_remove_connected_component_by_face_number": "Remove Isolated pieces (wrt Face Num.)",
    "meshing_remove_connected_component_by_diameter": "Remove Isolated pieces (wrt Diameter)",
    "meshing_repair_non_manifold_edges": "Repair non Manifold Edges",
    "meshing_repair_non_manifold_vertices": "Repair non Manifold Vertices by splitting",
    "meshing_re_orient_faces_coherently": "Re-Orient all faces coherently",
    "meshing_close_holes": "Close Holes",
    "apply_coord_taubin_smoothing": "Taubin Smooth",
    "apply_coord_hc_laplacian_smoothing": "HC Laplacian Smooth",
    "meshing_decimation_quadric_edge_collapse": "Simplification: Quadric Edge Collapse Decimation",
}
"""pymeshlab filter name -> MeshLab filter name as written in ``.mlx`` scripts."""

MLX_NAMES: dict[str, str] = {mlx: py for py, mlx in FILTERS.items()}
"""MeshLab filter name -> pymeshlab filter name."""

MESHLAB_2020: dict[str, tuple[str | dict[str, str], tuple[str, ...]]] = {
    "Repair non Manifold Edges": ({"method=0": "Repair non Manifold Edges by removing faces",
                                   "method=1": "Repair non Manifold Edges by splitting vertices"}, ("method",)),
    "Re-Orient all faces coherently": ("Re-Orient all faces coherentely", ()),
    "Close Holes": ("Close Holes", ("RefineHole", "RefineHoleEdgeLen")),
}
"""How MeshLab 2020.x (Debian's ``meshlabserver``) names the filters of :data:`FILTERS` that it
names differently, and the parameters it lacks: ``.mlx`` name -> (2020 name, or parameter
value -> 2020 name; parameters to leave out). Every other filter and parameter is the same in
both (the test that replays every chain in ``meshlabserver`` checks it)."""

OPENGL_HINT = "install the system library libopengl0 (Debian/Ubuntu: apt-get install libopengl0)"


def missing_filters(available: Iterable[str]) -> list[str]:
    """The filters of :data:`FILTERS` absent from ``available`` (pymeshlab names)."""
    have = set(available)
    return [name for name in FILTERS if name not in have]


def check_filters(available: Iterable[str]) -> None:
    """Raise :class:`AptFiltersError` naming the system library if a filter we use is missing.

    Parameters
    ----------
    available : iterable of str
        pymeshlab filter names, normally ``pymeshlab.filter_list()``.
    """
    missing = missing_filters(available)
    if missing:
        opengl = any(name.startswith("meshing_") for name in missing)
        cause = f"pymeshlab hides its meshing_* filters without libOpenGL: {OPENGL_HINT}" if opengl \
            else "upgrade pymeshlab"
        raise AptFiltersError(f"pymeshlab lacks the filters {', '.join(missing)}; {cause}")
