"""Binary PLY output of a :class:`~apt_filters.core.mesh.TriMesh` (readable by MeshLab and open3d)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from apt_filters.core.atomic import atomic_output
from apt_filters.core.mesh import TriMesh


def ply_bytes(mesh: TriMesh) -> bytes:
    """Little-endian binary PLY: double x, y, z per vertex; uchar count + int indices per face."""
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment apt-filters synthetic truth (nm)\n"
        f"element vertex {mesh.n_vertices}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {mesh.n_faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    faces = np.empty(mesh.n_faces, dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"] = 3
    faces["v"] = mesh.faces
    return header.encode("ascii") + mesh.vertices.astype("<f8").tobytes() + faces.tobytes()


def write_ply(path: str | os.PathLike, mesh: TriMesh, overwrite: bool = False) -> Path:
    """Write ``mesh`` as binary PLY, atomically."""
    with atomic_output(path, overwrite) as tmp:
        tmp.write_bytes(ply_bytes(mesh))
    return Path(path)
