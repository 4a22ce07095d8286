"""``apt-filters demo``: the main job on the built-in synthetic specimen.

Generates the default specimen into ``OUT/specimen`` (or reuses it: the same seed gives the
same files), runs the whole pipeline on it into ``OUT/run`` and prints what it found against
the ground truth.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from apt_filters.cli.options import add_output
from apt_filters.core.errors import AptFiltersError

ORDER = 1
DEFAULT_OUT = "demo-out"
DEMO_ISO = 0.15
"""Al iso-concentration: midway between the matrix (10 at.%) and gamma-prime (20 at.%)."""


def demo_specimen(outdir: str | Path = DEFAULT_OUT, seed: int = 0, force: bool = False) -> tuple[dict, bool]:
    """Make sure ``outdir`` holds the default specimen; return (its truth, whether it was reused).

    A folder holding truth.json of the default preset with this seed is reused as it is;
    any other truth.json there needs ``force``.
    """
    from apt_filters.pipeline.staging import staged_folder
    from apt_filters.synth import preset, write_specimen
    from apt_filters.synth.generate import FORMAT

    truth_file = Path(outdir) / "truth.json"
    if truth_file.is_file() and not force:
        try:
            truth = json.loads(truth_file.read_text())
        except (ValueError, UnicodeDecodeError) as exc:
            raise AptFiltersError(f"unreadable truth.json ({exc}); pass --force to regenerate", truth_file) from exc
        if isinstance(truth, dict) and (truth.get("format"), truth.get("name"), truth.get("seed")) == (FORMAT, "default", seed):
            return truth, True
        raise AptFiltersError("holds another specimen; pass --force to replace it", truth_file)
    with staged_folder(outdir, force=force) as stage:
        return write_specimen(stage, preset("default"), seed=seed, keep_ions=False).truth, False


def demo_config(specimen: Path):
    """The pipeline configuration of the demo: the defaults, with the gamma-prime Al iso-surface."""
    from apt_filters.pipeline.config import PipelineConfig, SurfaceConfig

    config = PipelineConfig(surface=[SurfaceConfig("Al", DEMO_ISO)])
    config.input.ions = str(specimen / "specimen.pos")
    config.input.ranges = str(specimen / "specimen.rrng")
    return config


def _run(args: argparse.Namespace) -> int:
    from apt_filters.cli.synth import report
    from apt_filters.pipeline.run import run_pipeline

    out = Path(args.output)
    specimen = out / "specimen"
    if out.is_dir() and any(out.iterdir()) and not specimen.is_dir() and not args.force:
        raise AptFiltersError("output folder holds something else; pass --force or choose -o/--output", out)
    truth, reused = demo_specimen(specimen, args.seed, args.force)
    report(specimen, truth, "reused" if reused else "wrote")
    result = run_pipeline(demo_config(specimen), out / "run", force=True, quiet=args.quiet, truth=truth)
    print(f"\nreport: {out / 'run' / 'report.html'}")
    # "ions hold": the B excess counted from the ions against the true surface and plateaus, over the true one
    print(f"{'feature':<28} {'volume/true':>11} {'area/true':>9} {'B excess/true':>13} {'(ions hold)':>11}")
    for row in result["truth"]:
        cells = [row.get("volume_ratio"), row.get("area_ratio"), row.get("excess_B_ratio"),
                 row.get("counted_excess_B_ratio")]
        text = [f"{c:.2f}" if c is not None else "-" for c in cells]
        print(f"{row['feature']:<28} {text[0]:>11} {text[1]:>9} {text[2]:>13} {text[3]:>11}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo", help="run apt-filters on the built-in synthetic specimen",
        description="Generate the built-in synthetic specimen (a conical tip with rotated cubes, spheres, a rod, "
                    "a plate and a flat interface, B segregated at every interface; ~3.4M ions) into OUT/specimen, "
                    "run the whole pipeline on it (Al iso-surface at 15 at.%, B left out of the concentration) into OUT/run, and print the objects' "
                    "volumes, areas and B excess over their true values.")
    add_output(p, f"output folder (default ./{DEFAULT_OUT})", default=DEFAULT_OUT)
    p.add_argument("--seed", type=int, default=0, help="random seed of the ions (default 0)")
    p.add_argument("--force", action="store_true", help="regenerate even if the folder holds a specimen")
    p.add_argument("--quiet", "-q", action="store_true", help="no step summaries")
    p.set_defaults(func=_run)
