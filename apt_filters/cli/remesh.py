"""``apt-filters remesh``: feature-preserving centroidal Voronoi remeshing of a PLY mesh."""

from __future__ import annotations

import argparse
from pathlib import Path

from apt_filters.cli.numbers import number
from apt_filters.cli.options import add_output
from apt_filters.core.atomic import refuse_inputs
from apt_filters.core.errors import AptFiltersError

ORDER = 70


def run(args: argparse.Namespace) -> int:
    from apt_filters.meshlab.bridge import read_mesh
    from apt_filters.meshlab.exports import write_mesh
    from apt_filters.remesh import remesh

    out = Path(args.output)
    refuse_inputs([out], [args.input])
    if out.exists() and not args.force:
        raise AptFiltersError("exists already; pass --force to replace it", out)
    mesh = read_mesh(Path(args.input))
    try:
        result = remesh(mesh, edge_length=args.edge_length, feature_angle=args.feature_angle,
                        bridge_gaps=args.bridge_gaps)
    except AptFiltersError as exc:
        raise AptFiltersError(str(exc), args.input) from exc
    write_mesh(result.mesh, out, overwrite=args.force)
    print(f"{out}: {result.mesh.n_vertices} vertices, {result.mesh.n_faces} triangles "
          f"(edge length {result.edge_length:.3g} nm, {result.n_curves} feature curves, {result.iterations} Lloyd steps)")
    if result.kept_input:  # components whose remesh would change the surface stay as they were
        print(f"{result.kept_input} of {len(result.checks)} components kept as given: "
              + "; ".join(", ".join(c.reasons) for c in result.checks if not c.ok))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "remesh", help="remesh a triangle mesh into near-equilateral triangles, keeping sharp features",
        description="Feature-preserving centroidal Voronoi (Lloyd) remeshing: near-equilateral triangles, "
                    "sharp edges, corners and open boundaries kept, vertex quality re-interpolated.")
    p.add_argument("input", metavar="IN.ply", help="input triangle mesh (PLY; any format MeshLab reads)")
    add_output(p, "output mesh (written atomically)", metavar="OUT.ply")
    p.add_argument("--edge-length", type=number("(0, 1000]", "nm"), default=None, metavar="L",
                   help="target edge length in nm (default: the input's mean edge length)")
    p.add_argument("--feature-angle", type=number("(0, 180]", "degrees"), default=40.0, metavar="A",
                   help="dihedral angle in degrees above which an edge is sharp (default 40; 180 = none)")
    p.add_argument("--bridge-gaps", action="store_true",
                   help="join gaps in creases whose bend is spread over two edges (dual-contouring meshes "
                        "with estimated normals; not for noisy iso-surfaces)")
    p.add_argument("--force", action="store_true", help="replace OUT.ply if it exists")
    p.set_defaults(func=run)
