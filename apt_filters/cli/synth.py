"""``apt-filters synth OUTDIR``: write a synthetic specimen with its ground truth."""

from __future__ import annotations

import argparse
import time

ORDER = 20


def ion_count(text: str) -> int:
    """Parse an ion count such as ``250000``, ``2.5e5`` or ``250_000``."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of ions: {text!r}") from None
    if not (value >= 1 and value < 1e12 and value == int(value)):
        raise argparse.ArgumentTypeError(f"number of ions must be a whole number between 1 and 1e12, got {text!r}")
    return int(value)


def report(outdir, truth: dict, verb: str) -> None:
    """Print a specimen's summary and what is in ``outdir``."""
    from apt_filters.synth import summary

    print(summary(truth))
    print(f"{verb} {outdir}/: specimen.pos, specimen.rrng, truth.json and {len(truth['features'])} true surfaces (PLY)")


def _run(args: argparse.Namespace) -> int:
    from apt_filters.pipeline.staging import staged_folder
    from apt_filters.synth import preset, write_specimen

    start = time.perf_counter()
    spec = preset(args.preset, args.ions)
    with staged_folder(args.outdir, force=args.force) as stage:
        specimen = write_specimen(stage, spec, seed=args.seed, keep_ions=False)
    report(args.outdir, specimen.truth, f"wrote in {time.perf_counter() - start:.1f} s")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "synth", help="write a synthetic specimen with known truth (POS, RRNG, truth.json, PLY surfaces)",
        description="Generate a synthetic APT specimen whose truth is known exactly: ions as POS, ranges as "
                    "RRNG, truth.json (every parameter, true compositions, volumes, areas, interfacial excess) "
                    "and the true surface of every feature as PLY. The same seed gives identical files. "
                    "Presets: default (the demo, ~3.4M ions), gamma-prime (rotated cubes and spheres in a "
                    "tip, ~1.2M ions), small (~270k ions, for tests).")
    p.add_argument("outdir", help="output folder (created; appears whole when every file is written)")
    p.add_argument("--preset", default="default", help="which specimen (default: default; the presets are named above)")
    p.add_argument("--ions", type=ion_count, default=None, metavar="N",
                   help="about N ions: the specimen is lengthened or shortened below its top (features stay put)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the ions (default 0)")
    p.add_argument("--force", action="store_true", help="replace OUTDIR if apt-filters wrote it before")
    p.set_defaults(func=_run)
