"""A pymeshlab user applying apt-filters steps to their own MeshSet.

Run: ``python scripts/pymeshlab_example.py OUTDIR``. It builds a noisy, badly welded
iso-surface-like mesh in a MeshSet the way a pymeshlab script would, then

1. runs apt-filters' ``clean`` and ``smooth`` chains on the MeshSet's current mesh, each
   recorded as a replayable ``.mlx`` (+ ``.json`` with the relative parameters) -- the user's
   MeshSet history is not mixed into the scripts -- and gets the results back in the MeshSet;
2. replays the ``clean`` script with MeshLab's own engine on the original mesh;
3. converts the result to a TriMesh for per-object statistics, and writes a coloured PLY and
   a MeshLab project (.mlp) opening it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pymeshlab

from apt_filters.analysis.objects import object_table
from apt_filters.meshlab.bridge import from_pymeshlab
from apt_filters.meshlab.chains import apply_chain_to_meshset
from apt_filters.meshlab.exports import write_ply, write_project
from apt_filters.meshlab.mlx import replay_on_meshset


def users_meshset() -> pymeshlab.MeshSet:
    """What a pymeshlab user might hold: two noisy blobs as an unwelded triangle soup and a speck."""
    ms = pymeshlab.MeshSet()
    ms.create_sphere(subdiv=4)
    ms.create_torus(hradius=3.0, vradius=1.0)
    ms.create_icosahedron()
    rng = np.random.default_rng(0)
    parts = []
    for i, (scale, shift) in enumerate([(5.0, (0, 0, 0)), (1.0, (15, 0, 0)), (0.02, (30, 0, 0))]):
        m = ms.mesh(i)
        v = m.vertex_matrix() * scale + shift
        v = v + rng.normal(0, 0.03 * scale, v.shape)
        parts.append(v[m.face_matrix()].reshape(-1, 3))  # unwelded: every face has its own vertices
    soup = np.concatenate(parts)
    ms.add_mesh(pymeshlab.Mesh(soup, np.arange(len(soup)).reshape(-1, 3), v_scalar_array=soup[:, 0].copy()),
                "iso-surface")
    return ms


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outdir", type=Path)
    args = parser.parse_args(argv)
    out = args.outdir
    out.mkdir(parents=True, exist_ok=True)

    ms = users_meshset()
    original = ms.current_mesh_id()
    n_faces = ms.current_mesh().face_number()
    run = apply_chain_to_meshset(ms, "clean", out / "clean.mlx")  # adds "iso-surface (clean)"
    cleaned = ms.current_mesh_id()
    apply_chain_to_meshset(ms, "smooth", out / "smooth.mlx")  # adds "iso-surface (clean) (smooth)"
    print(f"clean: {n_faces} -> {ms.mesh(cleaned).face_number()} faces ({len(run.resolved)} filters, "
          f"script clean.mlx); current mesh: {ms.current_mesh().label()!r}")

    again = pymeshlab.MeshSet()  # MeshLab's engine replays the script on the original mesh
    again.add_mesh(ms.mesh(original))
    replay_on_meshset(again, out / "clean.mlx")
    assert np.array_equal(again.current_mesh().vertex_matrix(), ms.mesh(cleaned).vertex_matrix())

    smoothed = from_pymeshlab(ms)  # current mesh -> TriMesh, vertex quality as "value"
    table = object_table(smoothed)
    table.write_csv(out / "objects.csv")
    for o in table.objects:
        print(f"object {o.object_id}: {o.status}, V = {o.volume:.1f} nm^3, sphericity {o.sphericity:.3f}, "
              f"genus {o.genus:g}")
    write_ply(smoothed, out / "smoothed.ply")
    write_project(out / "scene.mlp", [out / "smoothed.ply"], ["smoothed iso-surface"])
    print(f"open {out / 'scene.mlp'} in MeshLab; the MeshSet now holds {ms.mesh_number()} meshes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
