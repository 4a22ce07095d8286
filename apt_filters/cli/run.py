"""``apt-filters run``: the whole pipeline on one ion file, into one output folder."""

from __future__ import annotations

import argparse
from pathlib import Path

from apt_filters.cli.options import add_output
from apt_filters.cli.rangeopts import add_range_options

ORDER = 5


def build_config(args: argparse.Namespace):
    """The configuration: defaults, then ``--config``, then the options given on the command line."""
    from apt_filters.pipeline import config as cfg

    config = cfg.load(args.config) if args.config else cfg.PipelineConfig()
    for key, off in (("cross_fit", args.no_cross_fit), ("select_modes", args.no_mode_selection),
                     ("facets", args.no_facets), ("marker", args.no_marker)):
        if off:
            setattr(config.refine, key, False)
    options = {"input": args.input, "range": args.range, "species": args.species, "iso": args.iso,
               "density": args.density} | {name: getattr(args, name) for name in cfg.OPTIONS}
    return cfg.with_options(config, options, source="command line")


def _run(args: argparse.Namespace) -> int:
    from apt_filters.pipeline.inputs import check_inputs

    config = check_inputs(build_config(args))  # mistakes in milliseconds, before the heavy imports
    from apt_filters.pipeline.staging import check_output_folder

    # before any work: the configuration file is an input too
    check_output_folder(args.output, [config.input.ions, config.input.ranges, args.config], args.force)
    from apt_filters.pipeline.run import run_pipeline

    report = run_pipeline(config, args.output, force=args.force, quiet=args.quiet, verbose=args.verbose)
    print(f"report: {Path(args.output) / 'report.html'}")
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
    add_output(p, "output folder (replaced only with --force)")
    p.add_argument("--config", help="pipeline.toml; options given here override it")
    p.add_argument("--species", help="element whose iso-concentration surface is drawn (with --iso)")
    p.add_argument("--iso", type=float, help="iso-concentration as a fraction, e.g. 0.15 for 15 at.%%")
    p.add_argument("--density", type=float, help="iso-density in atoms/nm3 instead of a concentration")
    p.add_argument("--exclude", nargs="+", help="elements left out of the concentration's denominator "
                                                "(segregants found at the surface are left out anyway)")
    p.add_argument("--include", nargs="+", help="elements kept in the denominator even where they peak at the "
                                                "surface (default: such segregants are found and left out)")
    p.add_argument("--method", choices=["dc", "mc"], help="marching cubes (default) or dual contouring")
    p.add_argument("--kernel", choices=["gaussian", "sawtooth", "square"], help="transfer function (default gaussian)")
    p.add_argument("--voxel", type=float, help="voxel edge in nm (default 1.0)")
    p.add_argument("--delocalization", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="gaussian delocalization, 3 sigma per axis in nm (default 3 3 1.5, AP Suite's)")
    p.add_argument("--remesh", choices=["cvt", "none"], help="remesher (default cvt)")
    p.add_argument("--efficiency", type=float, help="detection efficiency (default 0.5)")
    p.add_argument("--memory-budget", type=float, metavar="GB",
                   help="memory the run may use (default: half of this machine's); larger ion tables are streamed")
    p.add_argument("--blur", type=float, nargs=2, metavar=("LATERAL", "DEPTH"),
                   help="reconstruction blur sigmas in nm whose curvature bias the refinement undoes "
                        "(default: lateral estimated from the ions, depth 0; 0 0: no correction)")
    p.add_argument("--speck-alpha", type=float, metavar="ALPHA",
                   help="family-wise error rate of the test that keeps a component as an object (default 0.001)")
    p.add_argument("--no-cross-fit", action="store_true",
                   help="refinement plateaus against the surface the same ions placed (faster, biased)")
    p.add_argument("--no-mode-selection", action="store_true",
                   help="keep each object's refined shape (no cross-validated low-pass)")
    p.add_argument("--no-facets", action="store_true", help="keep edges as refined (no facet sharpening)")
    p.add_argument("--no-marker", action="store_true",
                   help="place objects by their step alone, not also by the peak of the excluded segregants")
    p.add_argument("--plateau-inner", type=float, metavar="NM",
                   help="plateau windows start this far from the surface, nm (default: from the interface width "
                        "fitted on the proxigram)")
    p.add_argument("--proxigram-range", type=float, metavar="NM",
                   help="proxigram half range and outer edge of the plateau windows, nm (default: 3 x the inner edge)")
    p.add_argument("--force", action="store_true", help="replace an output folder apt-filters wrote before")
    loud = p.add_mutually_exclusive_group()
    loud.add_argument("--quiet", "-q", action="store_true", help="no step summaries")
    loud.add_argument("--verbose", "-v", action="store_true", help="also list every range-file finding")
    p.set_defaults(func=_run)
