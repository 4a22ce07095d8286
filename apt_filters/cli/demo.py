"""``apt-filters demo``: the main job on the built-in synthetic specimen.

For now it generates the default specimen (or reuses the one already in the folder, since the
same seed gives the same files) and prints its summary.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from apt_filters.core.errors import AptFiltersError

ORDER = 1
DEFAULT_OUT = "demo-out"


def demo_specimen(outdir: str | Path = DEFAULT_OUT, seed: int = 0, force: bool = False) -> tuple[dict, bool]:
    """Make sure ``outdir`` holds the default specimen; return (its truth, whether it was reused).

    A folder holding truth.json of the default preset with this seed is reused as it is;
    any other truth.json there needs ``force``.
    """
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
    return write_specimen(outdir, preset("default"), seed=seed, overwrite=force, keep_ions=False).truth, False


def _run(args: argparse.Namespace) -> int:
    from apt_filters.cli.synth import report

    truth, reused = demo_specimen(args.out, args.seed, args.force)
    report(args.out, truth, "reused" if reused else "wrote")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo", help="run apt-filters on the built-in synthetic specimen",
        description="Generate the built-in synthetic specimen (a conical tip with rotated cubes, spheres, a rod, "
                    "a plate and a flat interface, B segregated at every interface; ~3.4M ions) into a folder "
                    "and print its summary: ion count, bounding box, composition, features with their true "
                    "volumes, areas and interfacial excess.")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output folder (default ./{DEFAULT_OUT})")
    p.add_argument("--seed", type=int, default=0, help="random seed of the ions (default 0)")
    p.add_argument("--force", action="store_true", help="regenerate even if the folder holds a specimen")
    p.set_defaults(func=_run)
