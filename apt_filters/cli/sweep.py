"""``apt-filters sweep``: the pipeline over a grid of analysis choices, on a Dask cluster."""

from __future__ import annotations

import argparse
from pathlib import Path

from apt_filters.cli.rangeopts import add_range_options
from apt_filters.core.errors import AptFiltersError

ORDER = 6


def _delocalization(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.replace(",", " ").split())
    except ValueError:
        values = ()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"a delocalization is three numbers 'X Y Z' (3 sigma, nm), got {text!r}")
    return values


def _run(args: argparse.Namespace) -> int:
    from apt_filters.pipeline import config as cfg
    from apt_filters.sweep import choice_grid, dask_client, run_sweep

    base = cfg.load(args.config) if args.config else cfg.PipelineConfig()
    isos = args.iso or []
    base = cfg.with_options(base, {"input": args.input, "range": args.range, "species": args.species,
                                   "iso": isos[0] if isos else None, "exclude": args.exclude,
                                   "method": args.method, "remesh": args.remesh, "efficiency": args.efficiency,
                                   "relabel": args.relabel, "unknown_species": args.unknown_species},
                            source="command line")
    if not base.surface:
        raise AptFiltersError("no iso-surface asked for: give --species with --iso, or --config")
    choices = choice_grid(isos=isos if len(isos) > 1 else (), voxels=args.voxel or (),
                          delocalizations=args.delocalization or (), kernels=args.kernel or ())
    if not args.quiet:
        print(f"sweep: {len(choices)} choices", flush=True)
    with dask_client(args.scheduler, workers=args.workers) as client:
        result = run_sweep(base, choices, args.out, client=client, keep_runs=args.keep_runs, force=args.force,
                           progress=not args.quiet)
    failed = [r for r in result.runs if r["status"] != "ok"]
    print(f"report: {Path(args.out) / 'report.html'} ({len(result.runs)} choices, {len(failed)} failed, "
          f"{result.wall_seconds:.1f} s)")
    for r in failed:
        print(f"  {r['tag']}: {r['error']}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "sweep", help="the pipeline over a grid of iso-values, voxels, delocalizations and kernels",
        description="Run the pipeline for every combination of the choices given (each list left out keeps the "
                    "base configuration's value), match objects across the choices by overlap, and write "
                    "OUT/sweep.csv (one row per choice and object, with counting errors), sweep.json and "
                    "report.html: per object and figure, the spread over the choices beside the counting error. "
                    "Runs go to a Dask cluster: a local one sized to this machine, or --scheduler ADDRESS.")
    p.add_argument("input", nargs="?", help="ion file (POS, EPOS, APT, CSV); optional with --config")
    p.add_argument("--range", "-r", help="range file (RRNG, RNG, ENV)")
    p.add_argument("--out", "-o", required=True, help="output folder (replaced only with --force)")
    p.add_argument("--config", help="base pipeline.toml; the options here override it")
    p.add_argument("--species", help="element whose iso-concentration surface is drawn")
    p.add_argument("--iso", type=float, nargs="+", metavar="C", help="iso-concentration fraction(s) to sweep")
    p.add_argument("--voxel", type=float, nargs="+", metavar="NM", help="voxel edge(s) in nm")
    p.add_argument("--delocalization", type=_delocalization, nargs="+", metavar="'X Y Z'",
                   help="gaussian delocalization(s), each three 3-sigma widths in nm, quoted: '3 3 1.5' '2 2 1'")
    p.add_argument("--kernel", choices=["gaussian", "sawtooth", "square"], nargs="+", help="transfer function(s)")
    p.add_argument("--exclude", nargs="+", help="elements left out of the concentration's denominator")
    p.add_argument("--method", choices=["dc", "mc"], help="contouring (default mc)")
    p.add_argument("--remesh", choices=["cvt", "none"], help="remesher (default cvt)")
    p.add_argument("--efficiency", type=float, help="detection efficiency (default 0.5)")
    add_range_options(p)
    p.add_argument("--scheduler", help="Dask scheduler address (tcp://host:8786) or scheduler file (.json); "
                                       "default: a local cluster, one worker per core")
    p.add_argument("--workers", type=int, help="local cluster: worker processes (default one per core)")
    p.add_argument("--keep-runs", action="store_true", help="keep each choice's full output in OUT/runs/<choice>/")
    p.add_argument("--force", action="store_true", help="replace an output folder apt-filters wrote")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines")
    p.set_defaults(func=_run)
