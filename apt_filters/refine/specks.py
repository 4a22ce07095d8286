"""The speck rule: connected surfaces too small to be objects are reported and removed.

Rule (default): a closed component enclosing less than ``min_volume`` = 10 nm³ is a speck, and
so is an open component (one cut by the specimen edge) with less than ``min_area`` = 10 nm² of
surface. 10 nm³ is a sphere of 1.34 nm radius: at the usual 1 nm voxels and 1 nm delocalization
such a blob is a fluctuation of the counts (the kernel alone spreads an ion over ~4 nm³), while
the smallest precipitate that can be measured, a 3 nm sphere, encloses 113 nm³ (still ~60 nm³
after the usual marching-cubes shrinkage).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apt_filters.contour.components import component_table
from apt_filters.core.mesh import TriMesh

MIN_VOLUME = 10.0
MIN_AREA = 10.0


@dataclass
class Specks:
    """What :func:`remove_specks` removed: component ids (of the input), their volumes and areas."""

    ids: list[int]
    volumes: list[float]
    areas: list[float]

    @property
    def count(self) -> int:
        return len(self.ids)


def remove_specks(mesh: TriMesh, min_volume: float = MIN_VOLUME, min_area: float = MIN_AREA) -> tuple[TriMesh, Specks]:
    """``mesh`` without its specks (see the module rule), unused vertices dropped, components relabelled."""
    labels = mesh.face_scalars.get("component")
    if labels is None:
        labels = mesh.face_components()
    small = [c for c in component_table(TriMesh(mesh.vertices, mesh.faces, face_scalars={"component": labels}))
             if (np.isfinite(c.volume) and abs(c.volume) < min_volume) or (not np.isfinite(c.volume) and c.area < min_area)]
    keep_face = ~np.isin(labels, [c.id for c in small])
    faces = mesh.faces[keep_face]
    used = np.zeros(mesh.n_vertices, dtype=bool)
    used[faces.ravel()] = True
    new_index = np.cumsum(used) - 1
    out = TriMesh(mesh.vertices[used], new_index[faces],
                  {k: v[used] for k, v in mesh.vertex_scalars.items()},
                  {k: v[keep_face] for k, v in mesh.face_scalars.items() if k != "component"})
    out.face_scalars["component"] = out.face_components()
    return out, Specks([c.id for c in small], [c.volume for c in small], [c.area for c in small])
