"""The audit acts: a corrected range file from its findings.

What is changed, and why, is written at the top of the file as comments, so that the file
explains itself to the next person who opens it:

- a range whose ions are mostly another species (``mislabelled``, ``label_not_in_range`` with a
  best fit) is relabelled with the best-fitting species (its bounds, colour and volume kept);
- what the reader already did (same-species overlaps merged, repeated ranges dropped,
  duplicate indices renumbered, decimal commas read) is listed, and the ranges are written as
  read, so the written file no longer has those quirks;
- peaks no range covers and ranges whose species is not a formula are only proposed: the
  proposals are comment lines (a ready ``Range`` line for each uncovered peak with a likely
  species), never ranges, so that the composition does not change unless someone accepts them.
"""

from __future__ import annotations

import os
from pathlib import Path

from apt_filters.audit.audit import AuditResult
from apt_filters.core.atomic import atomic_output
from apt_filters.io.ranges import Range, RangeTable, ion_name
from apt_filters.io.writers import format_rrng

RELABEL_KINDS = ("mislabelled", "label_not_in_range")
"""Finding kinds whose best fit replaces the range's label."""


def corrected_ranges(ranges: RangeTable, result: AuditResult) -> tuple[RangeTable, list[str], list[str]]:
    """Ranges with the audit's relabellings applied, what changed, and what is only proposed.

    Parameters
    ----------
    ranges : RangeTable
        The ranges the audit ran on (``result`` refers to them by index).
    result : AuditResult

    Returns
    -------
    table : RangeTable
        The corrected ranges, in the same order.
    changes : list of str
        One line per change (relabellings, then what the reader did).
    proposals : list of str
        One line per proposal, not applied (uncovered peaks, unknown species with a best fit).
    """
    new = list(ranges.ranges)
    changes, proposals = [], []
    for f in result.findings:
        comp = f.figures.get("best_fit_composition")
        if f.range is None or comp is None:
            if f.kind == "uncovered_peak":
                proposals.append(_peak_proposal(f.figures, ranges, len(new) + 1 + len(proposals)))
            continue
        r = ranges.ranges[f.range]
        if f.kind in RELABEL_KINDS:
            comp = tuple((el, int(n)) for el, n in comp)
            new[f.range] = Range(r.lower, r.upper, comp, color=r.color, volume=r.volume)
            share = f.figures.get("foreign_fraction")
            why = f"{share:.0%} of its ions fit {f.figures['best_fit']}" if share is not None else \
                f"no isotope of {r.ion} lies in it; best fit {f.figures['best_fit']}"
            changes.append(f"{r.describe()} relabelled {ion_name(comp)}: {why} ({f.kind})")
        elif f.kind == "unknown_label":
            proposals.append(f"{r.describe()}: {r.ion} is no chemical formula; its ions fit {f.figures['best_fit']}")
    changes += [(f"line {n.line}: " if n.line is not None else "") + n.message
                for n in ranges.notes if n.kind != "relabel"]
    changes += [n.message for n in ranges.notes if n.kind == "relabel"]
    return RangeTable(new, source=ranges.source), changes, proposals


def _peak_proposal(figures: dict, ranges: RangeTable, number: int) -> str:
    """One comment line: the peak, and a ``RangeK=`` line for its likely species, trimmed to its neighbours."""
    where = f"peak at {figures['mz']:.2f} Da ({figures['net']:.0f} ions above background)"
    comp = figures.get("likely_composition")
    if comp is None:
        return f"{where}: lies in no range; species not identified"
    lower = max([figures["lower"]] + [r.upper for r in ranges.ranges if r.upper <= figures["mz"]])
    upper = min([figures["upper"]] + [r.lower for r in ranges.ranges if r.lower >= figures["mz"]])
    atoms = " ".join(f"{el}:{n}" for el, n in comp)
    return f"{where} fits {figures['likely_species']}: Range{number}={lower:.4f} {upper:.4f} {atoms}"


def write_corrected_ranges(path: str | os.PathLike, ranges: RangeTable, result: AuditResult,
                           overwrite: bool = False) -> tuple[Path, list[str], list[str]]:
    """Write the corrected ranges as an RRNG file whose header comments say what changed and why.

    Returns the path, the changes and the proposals (as :func:`corrected_ranges`). The file is
    written atomically; an existing file is replaced only with ``overwrite``.
    """
    table, changes, proposals = corrected_ranges(ranges, result)
    source = os.path.basename(ranges.source) if ranges.source else "ranges"
    ions = os.path.basename(result.ions_source) if result.ions_source else "the ions"
    head = [f"; {source} corrected by apt-filters audit against {ions} ({result.n_ions} ions)",
            f"; {len(changes)} change(s):" if changes else "; no changes"]
    head += [f";   {line}" for line in changes]
    if proposals:
        head.append(f"; {len(proposals)} proposal(s), NOT applied (edit the ranges below to accept one):")
        head += [f";   {line}" for line in proposals]
    with atomic_output(path, overwrite) as tmp:
        tmp.write_text("\n".join(" ".join(line.split()) for line in head) + "\n" + format_rrng(table))
    return Path(path), changes, proposals
