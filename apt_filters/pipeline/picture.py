"""A picture of the iso-surfaces for the report (matplotlib, no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apt_filters.core.atomic import atomic_output
from apt_filters.core.mesh import TriMesh


def render_surfaces(meshes: dict[str, TriMesh], path: Path, points: np.ndarray | None = None,
                    max_faces: int = 60_000) -> Path:
    """Write a PNG of ``meshes`` (label -> mesh) seen from the side, z (analysis direction) up.

    Faces are shaded by their normal's angle to the light. A mesh with a face scalar
    ``object_id`` is drawn one colour per object (matplotlib ``tab10``, cycled), each object numbered
    at its centre as in the report's tables (prefixed by the mesh label when there are several
    meshes); otherwise one colour per mesh. ``points`` (n, 3), e.g. a small sample of ions,
    are drawn as faint dots for context. Larger meshes are drawn with every k-th face so the
    picture stays quick.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=(6, 8), dpi=110)
    ax = fig.add_subplot(projection="3d")
    ax.computed_zorder = False  # surfaces over the ions whatever their depth: the ions are context only
    light = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
    colors = plt.get_cmap("tab10")
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k, (label, mesh) in enumerate(meshes.items()):
        step = max(1, mesh.n_faces // max_faces)
        faces = mesh.faces[::step]
        tris = mesh.vertices[faces]
        n = TriMesh(mesh.vertices, faces).face_normals()
        shade = 0.35 + 0.65 * np.abs(n @ light)[:, None]
        objects = np.asarray(mesh.face_scalars.get("object_id", np.full(mesh.n_faces, k)))[::step].astype(int)
        base = np.array(colors.colors)[objects % colors.N, :3]
        ax.add_collection3d(Poly3DCollection(tris, facecolors=np.clip(shade * base, 0, 1), linewidths=0, label=label,
                                             zorder=2))
        if "object_id" in mesh.face_scalars:
            centres = tris.mean(axis=1)
            for obj in np.unique(objects):
                where = centres[objects == obj].mean(axis=0)
                name = f"{label} #{obj}" if len(meshes) > 1 else str(obj)
                ax.text(*where, name, fontsize=9, weight="bold", ha="center", va="center", zorder=10,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7})
        lo, hi = np.minimum(lo, mesh.vertices.min(0)), np.maximum(hi, mesh.vertices.max(0))
    if points is not None and len(points):
        ax.scatter(*points.T, s=0.15, c="0.55", alpha=0.12, depthshade=False, zorder=1)
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
