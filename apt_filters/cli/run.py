"""``apt-filters run``: the whole pipeline on one ion file, into one output folder."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from apt_filters.cli.rangeopts import add_range_options
from apt_filters.core.errors import AptFiltersError

ORDER = 5


def build_config(args: argparse.Namespace):
    """The configuration: defaults, then ``--config``, then the options given on the command line."""
    from apt_filters.pipeline import config as cfg

    config = cfg.load(args.config) if args.config else cfg.PipelineConfig()
    if args.input:
        config.input.ions = str(args.input)
    if args.range:
        config.input.ranges = str(args.range)
    if args.relabel:
        config.input.relabel = list(args.relabel)
    if args.unknown_species:
        config.input.unknown_species = args.unknown_species
    if args.species or args.iso is not None or args.density is not None:
        if args.density is not None and (args.species or args.iso is not None):
            raise AptFiltersError("give --species with --iso, or --density, not both")
        if args.density is None and not (args.species and args.iso is not None):
            raise AptFiltersError("--species and --iso go together")
        species, iso = (args.species, args.iso) if args.density is None else ("", args.density)
        config.surface = [cfg.SurfaceConfig(species, iso)]
    overrides = {("voxel", "size"): args.voxel, ("voxel", "kernel"): args.kernel, ("voxel", "exclude"): args.exclude,
                 ("contour", "method"): args.method, ("remesh", "method"): args.remesh,
                 ("analysis", "efficiency"): args.efficiency, ("refine", "blur"): args.blur,
                 ("refine", "cross_fit"): False if args.no_cross_fit else None,
                 ("refine", "select_modes"): False if args.no_mode_selection else None,
                 ("refine", "facets"): False if args.no_facets else None,
                 ("refine", "marker"): False if args.no_marker else None}
    for (section, key), value in overrides.items():
        if value is not None:
            setattr(getattr(config, section), key, value)
    # Options pass the same checks as a configuration file.
    return cfg.from_dict(dataclasses.asdict(config), source="command line")


def _run(args: argparse.Namespace) -> int:
    from apt_filters.pipeline.run import run_pipeline

    config = build_config(args)
    report = run_pipeline(config, args.out, force=args.force, quiet=args.quiet, verbose=args.verbose)
    print(f"report: {Path(args.out) / 'report.html'}")
    for s in report["surfaces"]:
        print(f"  {s['label']}: {len(s['objects'])} objects, area {s['mesh']['area_nm2']:.1f} nm2")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run", help="ion file -> iso-surfaces, objects, proxigrams, excess and a report",
        description="Read, range, audit the range file, voxelize (1 nm voxels, 3x3x1.5 nm Gaussian delocalization), "
                    "contour (marching cubes), refine the surface against the ions, clean with a MeshLab chain (saved as .mlx), remesh (feature-preserving "
                    "CVT), measure objects, compute proxigrams (0.1 nm bins, edge polygons excluded) and interfacial "
                    "excess, and write meshes, a MeshLab project and report.json/report.html into OUT.")
    p.add_argument("input", nargs="?", help="ion file (POS, EPOS, APT, CSV); optional with --config")
    p.add_argument("--range", "-r", help="range file (RRNG, RNG, ENV)")
    add_range_options(p)
    p.add_argument("--out", "-o", required=True, help="output folder (replaced only with --force)")
    p.add_argument("--config", help="pipeline.toml; options given here override it")
    p.add_argument("--species", help="element whose iso-concentration surface is drawn (with --iso)")
    p.add_argument("--iso", type=float, help="iso-concentration as a fraction, e.g. 0.15 for 15 at.%%")
    p.add_argument("--density", type=float, help="iso-density in atoms/nm3 instead of a concentration")
    p.add_argument("--exclude", nargs="+", help="elements left out of the concentration's denominator")
    p.add_argument("--method", choices=["dc", "mc"], help="marching cubes (default) or dual contouring")
    p.add_argument("--kernel", choices=["gaussian", "sawtooth", "square"], help="transfer function (default gaussian)")
    p.add_argument("--voxel", type=float, help="voxel edge in nm (default 1.0)")
    p.add_argument("--remesh", choices=["cvt", "none"], help="remesher (default cvt)")
    p.add_argument("--efficiency", type=float, help="detection efficiency (default 0.5)")
    p.add_argument("--blur", type=float, nargs=2, metavar=("LATERAL", "DEPTH"),
                   help="reconstruction blur sigmas in nm whose curvature bias the refinement undoes "
                        "(default: lateral estimated from the ions, depth 0; 0 0: no correction)")
    p.add_argument("--no-cross-fit", action="store_true",
                   help="refinement plateaus against the surface the same ions placed (faster, biased)")
    p.add_argument("--no-mode-selection", action="store_true",
                   help="keep each object's refined shape (no cross-validated low-pass)")
    p.add_argument("--no-facets", action="store_true", help="keep edges as refined (no facet sharpening)")
    p.add_argument("--no-marker", action="store_true",
                   help="place objects by their step alone, not also by the peak of the excluded segregants")
    p.add_argument("--force", action="store_true", help="replace a non-empty output folder")
    loud = p.add_mutually_exclusive_group()
    loud.add_argument("--quiet", "-q", action="store_true", help="no step summaries")
    loud.add_argument("--verbose", "-v", action="store_true", help="also list every range-file finding")
    p.set_defaults(func=_run)
