"""A picture of the iso-surfaces for the report (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apt_filters.core.atomic import atomic_output
from apt_filters.core.mesh import TriMesh


def render_surfaces(meshes: dict[str, TriMesh], path: Path, points: np.ndarray | None = None,
                    max_faces: int = 60_000) -> Path:
    """Write a PNG of ``meshes`` (label -> mesh) seen from the side, z (analysis direction) up.

    Faces are shaded by their normal's angle to the light; ``points`` (n, 3), e.g. a small
    sample of ions, are drawn as faint dots for context. Larger meshes are drawn with every
    k-th face so the picture stays quick.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=(6, 8), dpi=110)
    ax = fig.add_subplot(projection="3d")
    light = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
    colors = plt.get_cmap("tab10")
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k, (label, mesh) in enumerate(meshes.items()):
        faces = mesh.faces[:: max(1, mesh.n_faces // max_faces)]
        tris = mesh.vertices[faces]
        n = TriMesh(mesh.vertices, faces).face_normals()
        shade = 0.35 + 0.65 * np.abs(n @ light)[:, None]
        base = np.array(colors(k % 10)[:3])
        ax.add_collection3d(Poly3DCollection(tris, facecolors=np.clip(shade * base, 0, 1), linewidths=0, label=label))
        lo, hi = np.minimum(lo, mesh.vertices.min(0)), np.maximum(hi, mesh.vertices.max(0))
    if points is not None and len(points):
        ax.scatter(*points.T, s=0.2, c="0.6", alpha=0.25, depthshade=False)
        lo, hi = np.minimum(lo, points.min(0)), np.maximum(hi, points.max(0))
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for axis, name in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), range(3)):
        axis(centre[name] - half, centre[name] + half)
    ax.set_xlabel("x (nm)")
    ax.set_ylabel("y (nm)")
    ax.set_zlabel("z (nm)")
    ax.view_init(elev=12, azim=-60)
    ax.set_title(", ".join(meshes) + " iso-surface" + ("s" if len(meshes) > 1 else ""))
    with atomic_output(path, overwrite=True) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
    return path
