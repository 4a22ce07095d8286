"""``apt-filters info FILE [--range R] [--json]``: what an ion file holds.

Ion count, bounding box, m/z span and, with a range file, the ranged fraction and the
composition by element (molecular ions decomposed into their atoms). The file is streamed
in chunks (:func:`apt_filters.io.iter_ion_chunks`), so 10^9-ion files need one chunk of memory.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from apt_filters.io import RangeTable, iter_ion_chunks, read_ranges
from apt_filters.io.readers import ion_format

ORDER = 10
FORMAT_NAMES = {"pos": "POS", "epos": "EPOS", "apt6": "APT6 (AP Suite)", "text": "text table"}


@dataclass
class IonSummary:
    """Streaming summary of an ion file.

    Attributes
    ----------
    ions : int
        Number of ions.
    lower, upper : (3,) float64
        Bounding box corners in nm (x, y, z).
    mz_min, mz_max : float
        m/z span in Da.
    ion_counts : dict[str, int]
        Ions per ranged species (empty without a range table).
    atoms : dict[str, int]
        Atoms per element, molecular ions counted by their atoms.
    """

    ions: int = 0
    lower: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    upper: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    mz_min: float = np.inf
    mz_max: float = -np.inf
    ion_counts: dict[str, int] = field(default_factory=dict)
    atoms: dict[str, int] = field(default_factory=dict)

    @property
    def ranged(self) -> int:
        return sum(self.ion_counts.values())

    def composition(self) -> dict[str, float]:
        """Atomic fraction per element (sums to 1), largest first."""
        total = sum(self.atoms.values())
        fractions = {el: n / total for el, n in self.atoms.items()} if total else {}
        return dict(sorted(fractions.items(), key=lambda kv: -kv[1]))


def summarize(path: str | Path, ranges: RangeTable | None = None, chunk_size: int = 1 << 22) -> IonSummary:
    """Count, bounds, m/z span and (with ``ranges``) species and element counts of an ion file.

    Peak memory: one chunk of ``chunk_size`` ions (16 B/ion) plus its (N,) int32 ranging.
    """
    s = IonSummary()
    per_ion = np.zeros(len(ranges.ions) + 1 if ranges else 1, dtype=np.int64)  # slot 0: unranged
    for chunk in iter_ion_chunks(path, chunk_size):
        s.ions += len(chunk)
        s.lower = np.minimum(s.lower, chunk.positions.min(axis=0))
        s.upper = np.maximum(s.upper, chunk.positions.max(axis=0))
        s.mz_min = min(s.mz_min, float(chunk.mz.min()))
        s.mz_max = max(s.mz_max, float(chunk.mz.max()))
        if ranges:
            per_ion += np.bincount(ranges.ion_index(chunk.mz) + 1, minlength=len(per_ion))
    if ranges:
        s.ion_counts = dict(zip(ranges.ions, per_ion[1:].tolist()))
        atoms = per_ion[1:] @ ranges.element_matrix()
        s.atoms = dict(zip(ranges.elements, atoms.tolist()))
    return s


def _as_json(path: str, summary: IonSummary, ranges: RangeTable | None) -> dict:
    out = {
        "file": path,
        "format": ion_format(path),
        "ions": summary.ions,
        "bounds_nm": {"lower": summary.lower.tolist(), "upper": summary.upper.tolist()},
        "mz_da": [summary.mz_min, summary.mz_max],
    }
    if ranges:
        out.update({
            "range_file": ranges.source,
            "ranges": len(ranges),
            "ranged_ions": summary.ranged,
            "ranged_fraction": summary.ranged / summary.ions,
            "ion_counts": summary.ion_counts,
            "atoms": summary.atoms,
            "composition": summary.composition(),
        })
    return out


def _as_text(path: str, summary: IonSummary, ranges: RangeTable | None) -> str:
    axes = "   ".join(f"{a} {lo:.3f} .. {hi:.3f}" for a, lo, hi in zip("xyz", summary.lower, summary.upper))
    lines = [
        f"{path}: {FORMAT_NAMES[ion_format(path)]}, {summary.ions:,} ions",
        f"  bounds (nm)   {axes}",
        f"  m/z (Da)      {summary.mz_min:.3f} .. {summary.mz_max:.3f}",
    ]
    if ranges:
        lines += [
            f"  ranges        {ranges.source}: {len(ranges)} ranges, {len(ranges.ions)} ions, "
            f"{len(ranges.elements)} elements",
            f"  ranged        {summary.ranged:,} ions ({100 * summary.ranged / summary.ions:.2f} %)",
            "  composition   at.% (molecular ions decomposed into atoms)",
        ]
        lines += [f"    {el:<3} {100 * frac:7.3f}   ({summary.atoms[el]:,} atoms)"
                  for el, frac in summary.composition().items()]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    ranges = read_ranges(args.range_file) if args.range_file else None
    summary = summarize(args.file, ranges)
    if args.json:
        print(json.dumps(_as_json(args.file, summary, ranges), indent=2))
    else:
        print(_as_text(args.file, summary, ranges))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "info", help="summarise an ion file (count, bounds, m/z, composition)",
        description="Summarise an APT ion file: ion count, bounding box (nm), m/z span (Da) and, with a "
                    "range file, the ranged fraction and the composition by element (at.%; molecular "
                    "ions decomposed into atoms). The file is streamed in chunks.")
    p.add_argument("file", metavar="FILE", help="ion file: .pos, .epos, .apt (AP Suite APT6), .csv or .txt")
    p.add_argument("--range", "-r", dest="range_file", metavar="R",
                   help="range file (.rrng, .rng or .env) for ranged fraction and composition")
    p.add_argument("--json", action="store_true", help="print JSON instead of text (composition as fractions)")
    p.set_defaults(func=run)
