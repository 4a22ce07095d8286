"""``apt-filters batch``: one analysis over the datasets of a TOML manifest, on a Dask cluster."""

from __future__ import annotations

import argparse
from pathlib import Path

ORDER = 7


def _run(args: argparse.Namespace) -> int:
    from apt_filters.sweep import dask_client, read_manifest, run_batch

    read_manifest(args.manifest)  # a malformed manifest is refused before a cluster starts
    with dask_client(args.scheduler, workers=args.workers) as client:
        rows = run_batch(args.manifest, args.out, client=client, force=args.force, progress=not args.quiet)
    failed = [r for r in rows if r["status"] != "ok"]
    print(f"report: {Path(args.out) / 'report.html'} ({len(rows)} datasets, {len(failed)} failed)")
    for r in failed:
        print(f"  {r['dataset']}: {r['error']}")
    return 1 if failed else 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "batch", help="one analysis over many datasets listed in a TOML manifest",
        description="Run the pipeline on every [[dataset]] of MANIFEST (input, range and any run option: species, "
                    "iso, density, exclude, voxel, kernel, delocalization, method, remesh, efficiency, blur, relabel, "
                    "config; [defaults] for all), each into OUT/runs/<name>/, and write OUT/batch.csv (one summary "
                    "row per dataset), objects.csv, batch.json and report.html. A dataset that fails fails its own "
                    "row (exit status 1); the others finish.")
    p.add_argument("manifest", help="batch manifest (TOML)")
    p.add_argument("--out", "-o", required=True, help="output folder (replaced only with --force)")
    p.add_argument("--scheduler", help="Dask scheduler address (tcp://host:8786) or scheduler file (.json); "
                                       "default: a local cluster, one worker per core")
    p.add_argument("--workers", type=int, help="local cluster: worker processes (default one per core)")
    p.add_argument("--force", action="store_true", help="replace an output folder apt-filters wrote")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    p.set_defaults(func=_run)
