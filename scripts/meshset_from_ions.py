"""From an APT file to iso-surfaces in a pymeshlab MeshSet, with apt-filters steps.

Run: ``python scripts/meshset_from_ions.py IONS RANGES SPECIES ISO OUTDIR``, e.g.
``python scripts/meshset_from_ions.py ../shared/data/real/apav-si/Si.pos ../shared/data/real/apav-si/Si.RRNG Cr 0.3 out``.

1. ``add_iso_surface`` voxelizes the ions (AP Suite's Gaussian, 1 nm voxels) and makes the
   finished surface as ``apt-filters run`` does (``finished_surface``: marching cubes, specks
   removed, refined against the ions, cleaned with the ``clean`` chain saved as ``clean.mlx``,
   remeshed by CVT), then adds it to the MeshSet;
2. the saved chain is applied again with MeshLab's own engine to the user's MeshSet
   (``replay_on_meshset``), as one would apply it to another dataset's surface;
3. the proxigram across the surface is computed from the TriMesh, and the MeshSet is saved
   as a MeshLab project.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pymeshlab

from apt_filters.analysis.proxigram import compute_proxigram
from apt_filters.io import read_ions, read_ranges
from apt_filters.meshlab.bridge import from_pymeshlab
from apt_filters.meshlab.exports import write_ply, write_project
from apt_filters.meshlab.mlx import replay_on_meshset
from apt_filters.pipeline.surface import add_iso_surface


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ions", type=Path)
    parser.add_argument("ranges", type=Path)
    parser.add_argument("species")
    parser.add_argument("iso", type=float)
    parser.add_argument("outdir", type=Path)
    args = parser.parse_args(argv)
    args.outdir.mkdir(parents=True, exist_ok=True)

    ions, ranges = read_ions(args.ions), read_ranges(args.ranges)
    ms = pymeshlab.MeshSet()
    surface = add_iso_surface(ms, ions, ranges, args.species, args.iso, clean_script=args.outdir / "clean.mlx")
    print(f"MeshSet mesh {ms.current_mesh().label()!r}: {ms.current_mesh().face_number()} faces, "
          f"area {surface.area():.1f} nm2")

    replay_on_meshset(ms, args.outdir / "clean.mlx")  # the saved chain, replayed by MeshLab
    print(f"after replaying clean.mlx: {ms.current_mesh().face_number()} faces")

    mesh = from_pymeshlab(ms)
    prox = compute_proxigram(ions, ranges, mesh, iso_value=args.iso)
    c, err = prox.pooled().concentration()
    inside = prox.centers > 1.0
    k = prox.elements.index(args.species)
    print(f"{args.species} beyond 1 nm inside: {100 * np.nanmean(c[0, inside, k]):.1f} at.%")
    write_ply(mesh, args.outdir / "surface.ply", overwrite=True)
    write_project(args.outdir / "scene.mlp", [args.outdir / "surface.ply"], overwrite=True)
    print(f"open {args.outdir / 'scene.mlp'} in MeshLab")
    return 0


if __name__ == "__main__":
    sys.exit(main())
