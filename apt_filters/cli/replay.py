"""``apt-filters replay SCRIPT.mlx MESH -o OUT``: replay a MeshLab filter script on a mesh."""

from __future__ import annotations

import argparse

from apt_filters.cli.options import add_output

ORDER = 60


def _run(args: argparse.Namespace) -> int:
    from apt_filters.meshlab.mlx import replay_file

    filters = replay_file(args.script, args.mesh, args.output, overwrite=args.force)
    print(f"{args.output}: {len(filters)} filters applied ({', '.join(f.mlx_name for f in filters)})")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "replay", help="replay a MeshLab .mlx filter script on a mesh",
        description="Replay a MeshLab .mlx filter script (as written by apt-filters chains or MeshLab) on a "
                    "mesh with MeshLab's own engine. The script is checked first: no DTD or entities, and only "
                    "the filters apt-filters knows (cleaning, hole closing, smoothing, decimation).")
    p.add_argument("script", help="MeshLab filter script (.mlx)")
    p.add_argument("mesh", help="input mesh (PLY, OBJ, STL, OFF; not modified)")
    add_output(p, "output mesh; format from the extension", metavar="OUT")
    p.add_argument("--force", action="store_true", help="overwrite OUTPUT if it exists")
    p.set_defaults(func=_run)
