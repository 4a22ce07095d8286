"""Range-file audit: check each range's label against the isotope patterns in the mass spectrum.

The audit never changes the ranges. It

1. histograms the m/z values and estimates a local background (:mod:`.spectrum`);
2. takes every labelled species at every charge state that puts an isotope inside one of its
   ranges, and fits their natural isotope patterns jointly to the spectrum (:mod:`.model`);
   the fit of each label alone gives its goodness-of-fit figures (G statistic, p-value,
   normalised residual);
3. explains the counts that the labels leave unexplained (in their windows and at the peaks
   found inside ranges) by adding, one at a time, the species
   from a candidate table (elements and common molecular ions, charges 1-3) that lowers the
   deviance most, judged on all its isotopes, less a small plausibility cost (extra atoms and
   charges, elements foreign to the range file and to H, C, N, O); counts that nothing explains
   are left out of a last refit and reported as unexplained;
4. reports, per range, the share of its ions that belongs to other species than its label (a
   wrong label names the best-fitting species), plus overlapping ranges, ranges on background
   only, isotopes of ranged species without a range, and peaks no range covers;
5. reports what the range-file reader met and did (:attr:`RangeTable.notes`: decimal commas,
   merged duplicates, unknown species...), each with its line.

:func:`~apt_filters.audit.fix.corrected_ranges` turns the findings into a corrected range file.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np
from scipy import stats

from apt_filters.audit.candidates import candidate_compositions
from apt_filters.audit.isotopes import Composition, canonical
from apt_filters.audit.model import (CandidatePool, Fit, Species, Windows, excess_clusters, explain_excess, fit,
                                    make_species, refit_without)
from apt_filters.audit.spectrum import Spectrum, build_spectrum, find_peaks
from apt_filters.core import jsontext
from apt_filters.core.errors import AptFiltersError
from apt_filters.io.formula import ELEMENTS
from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import Range, RangeTable

SEVERITIES = ("error", "warning", "info")
NOTE_SEVERITY = {"duplicate_index": "warning", "merged_overlap": "warning", "unknown_species": "warning",
                 "extra_ranges": "warning"}
"""Severity of each kind of reading note (:class:`~apt_filters.io.ranges.ReadNote`); the others are info."""


@dataclass(frozen=True)
class AuditSettings:
    """Thresholds of the audit.

    Attributes
    ----------
    resolution : float
        Mass resolving power m/Δm (FWHM); sets peak windows and isotope merging.
    min_halfwidth : float
        Smallest half-width of a peak window below its peak, Da (above it: twice this).
    charges : tuple of int
        Charge states considered for labels and candidates.
    z : float
        Significance in Poisson sigma for excess counts, uncovered peaks and missing isotopes.
    min_counts : float
        Fewest ions that make a finding.
    min_foreign_fraction : float
        Share of a range's ions from other species than its label that is reported.
    min_gain : float
        Smallest drop in deviance for which a candidate species is added to the model.
    max_added : int
        Most candidate species added.
    bin_width : float
        Histogram bin, Da.
    min_mz : float
        Peaks below this m/z (Da) are not reported as uncovered.
    max_mz : float
        The spectrum ends here (Da); ions above are left out.
    candidates : tuple of compositions or None
        Candidate table; None uses :func:`~apt_filters.audit.candidates.candidate_compositions`.
    """

    resolution: float = 500.0
    min_halfwidth: float = 0.05
    charges: tuple[int, ...] = (1, 2, 3)
    z: float = 5.0
    min_counts: float = 20.0
    min_foreign_fraction: float = 0.1
    min_gain: float = 50.0
    max_added: int = 12
    bin_width: float = 0.005
    min_mz: float = 0.5
    max_mz: float = 1000.0
    candidates: tuple[Composition, ...] | None = None


@dataclass(frozen=True)
class Finding:
    """One problem (or note) found in the range file.

    Attributes
    ----------
    severity : "error", "warning" or "info"
    kind : str
        ``overlap``, ``mislabelled``, ``foreign_species``, ``shared_peak``, ``label_not_in_range``,
        ``unknown_label``, ``unexplained_counts``, ``background_only``, ``missing_isotope``,
        ``uncovered_peak``, or a reading note's kind (``decimal_comma``, ``merged_overlap``...).
    range : int or None
        Index of the range in the range table's order (None for uncovered peaks and reading notes;
        these give the file's ``line`` in ``figures``).
    message : str
        One line for people.
    figures : dict
        Numbers behind the finding (counts in ions, m/z in Da, fractions 0-1, names).
    """

    severity: str
    kind: str
    range: int | None
    message: str
    figures: dict = field(default_factory=dict)


@dataclass(frozen=True)
class SpeciesFit:
    """Fit of one species/charge state.

    ``ions`` is the fitted number of ions in the final model; ``deviance``, ``dof``, ``p_value``
    and ``residual`` (sum of |observed - expected| over its peak windows divided by their net
    counts) judge its isotope pattern, for labels with the labels alone as model.
    """

    name: str
    composition: tuple[tuple[str, int], ...]
    charge: int
    labelled: bool
    ions: float
    deviance: float
    dof: int
    p_value: float | None
    residual: float | None


@dataclass
class AuditResult:
    """Outcome of :func:`audit_ranges`: findings, worst first, and the species fits."""

    findings: list[Finding]
    species: list[SpeciesFit]
    n_ions: int
    ranges: list[str]
    ions_source: str | None = None
    ranges_source: str | None = None

    @property
    def flagged(self) -> list[Finding]:
        """Errors and warnings (info notes left out)."""
        return [f for f in self.findings if f.severity != "info"]

    def flagged_ranges(self) -> set[int]:
        """Indices of ranges with an error or warning."""
        return {f.range for f in self.flagged if f.range is not None}

    def to_dict(self) -> dict:
        return {"ions_source": self.ions_source, "ranges_source": self.ranges_source, "n_ions": self.n_ions,
                "ranges": self.ranges, "findings": [asdict(f) for f in self.findings],
                "species": [asdict(s) for s in self.species]}

    def to_json(self) -> str:
        return jsontext.dumps(self.to_dict(), indent=2)

    def __str__(self) -> str:
        counts = {s: sum(f.severity == s for f in self.findings) for s in SEVERITIES}
        head = (f"range audit of {self.ranges_source or 'ranges'} against {self.ions_source or 'ions'} "
                f"({self.n_ions} ions, {len(self.ranges)} ranges): "
                + ", ".join(f"{n} {s}{'s' if n != 1 else ''}" for s, n in counts.items()))
        lines = [head] + [f"  {f.severity.upper():7s} {f.message}" for f in self.findings]
        added = [s for s in self.species if not s.labelled]
        if added:
            lines.append("  species found beyond the labels: "
                         + ", ".join(f"{s.name} ({s.ions:.0f} ions)" for s in added))
        return "\n".join(lines)



def audit_ranges(ions: IonTable | np.ndarray, ranges: RangeTable | Sequence[Range],
                 settings: AuditSettings = AuditSettings()) -> AuditResult:
    """Audit a range file against the mass spectrum of the ions.

    Parameters
    ----------
    ions : IonTable or (N,) array
        Ions, or their m/z in Da (a memory-map is read in chunks).
    ranges : RangeTable or sequence of Range
        The ranges to check; a plain sequence may contain overlaps (reported as errors),
        which a RangeTable refuses.
    settings : AuditSettings

    Returns
    -------
    AuditResult

    Notes
    -----
    Time: one pass over the m/z values plus a few hundred small model fits whose number does
    not grow with the ions (Si.pos, 945k ions: about 1 s; 2-3 s in a fresh process, which first
    builds the candidates' isotope patterns). Peak memory: the 0.005 Da histogram (8 bytes per bin) plus one 4M-ion chunk.
    """
    mz = ions.mz if isinstance(ions, IonTable) else np.asarray(ions)
    range_list = list(ranges.ranges if isinstance(ranges, RangeTable) else ranges)
    spectrum = build_spectrum(mz, settings.bin_width, settings.max_mz)
    windows = Windows(settings.resolution, settings.min_halfwidth)

    try:
        labels = [_label_species(r, settings, spectrum.max_mz) for r in range_list]
    except AptFiltersError as exc:
        raise AptFiltersError(str(exc), getattr(ranges, "source", None)) from None
    label_species = list({sp.key: sp for sps in labels for sp in sps}.values())
    labels_only = fit(label_species, windows, spectrum)
    label_compositions = {sp.composition for sp in label_species}
    pool = CandidatePool.build(_candidate_species(settings, spectrum.max_mz, label_compositions), windows, spectrum)
    apex, _ = find_peaks(spectrum, settings.z)
    ranged_peaks = apex[_in_any_range(apex, range_list)]
    final, _ = explain_excess(label_species, pool, windows, spectrum, ranged_peaks, z=settings.z,
                              min_counts=settings.min_counts, min_fraction=settings.min_foreign_fraction,
                              min_gain=settings.min_gain, max_added=settings.max_added)
    left = excess_clusters(final, settings.z, settings.min_counts, settings.min_foreign_fraction)
    if np.any(left):
        final = refit_without(final, left)

    findings = _overlaps(range_list) + [
        Finding(NOTE_SEVERITY.get(n.kind, "info"), n.kind, None,
                (f"line {n.line}: " if n.line is not None else "") + n.message, {"line": n.line})
        for n in getattr(ranges, "notes", [])]
    for index, r in enumerate(range_list):
        findings += _range_findings(index, r, labels[index], labels_only, final, spectrum, label_compositions, settings)
    missing = _missing_isotopes(final, label_compositions, range_list, spectrum, windows, settings)
    findings += missing + _uncovered_peaks(final, range_list, [f.figures["mz"] for f in missing], spectrum,
                                           windows, settings)
    findings.sort(key=lambda f: (SEVERITIES.index(f.severity), f.range if f.range is not None else len(range_list)))

    species = [_species_fit(sp, s, s < len(label_species), labels_only, final) for s, sp in enumerate(final.species)]
    return AuditResult(findings, species, int(len(mz)), [r.describe() for r in range_list],
                       ions_source=getattr(ions, "source", None),
                       ranges_source=getattr(ranges, "source", None))


def _label_species(r: Range, settings: AuditSettings, max_mz: float) -> list[Species]:
    """Charge states of the range's label that put an isotope inside the range (none for unknown species)."""
    if any(el not in ELEMENTS for el, _ in r.composition):
        return []
    out = []
    for charge in settings.charges:
        sp = make_species(r.composition, charge, settings.resolution, max_mz)
        if sp is not None and np.any((sp.mz >= r.lower) & (sp.mz <= r.upper)):
            out.append(sp)
    return out


def _candidate_species(settings: AuditSettings, max_mz: float, label_compositions: set) -> list[Species]:
    compositions = list(settings.candidates) if settings.candidates is not None else candidate_compositions()
    compositions = list(dict.fromkeys([canonical(c) for c in compositions] + sorted(label_compositions)))
    pool = (make_species(c, q, settings.resolution, max_mz) for c in compositions for q in settings.charges)
    return [sp for sp in pool if sp is not None]


def _overlaps(range_list: list[Range]) -> list[Finding]:
    out = []
    order = sorted(range(len(range_list)), key=lambda i: range_list[i].lower)
    for pos, i in enumerate(order):
        for j in order[pos + 1:]:
            a, b = range_list[i], range_list[j]
            if b.lower >= a.upper:
                break
            out.append(Finding("error", "overlap", i, f"ranges overlap: {a.describe()} and {b.describe()}",
                               {"other_range": j, "overlap_da": min(a.upper, b.upper) - b.lower}))
    return out


def _contributions(result: Fit, lower: float, upper: float) -> np.ndarray:
    """(n_species,) fitted ions of each species with peaks inside ``[lower, upper]``."""
    share = np.array([sp.abundance[(sp.mz >= lower) & (sp.mz <= upper)].sum() for sp in result.species])
    return result.amplitude * share


def _range_findings(index: int, r: Range, labels: list[Species], labels_only: Fit, final: Fit,
                    spectrum: Spectrum, label_compositions: set, settings: AuditSettings) -> list[Finding]:
    observed = float(spectrum.count(r.lower, r.upper))
    background = float(spectrum.expected_background(r.lower, r.upper))
    net = observed - background
    figures: dict = {"lower": r.lower, "upper": r.upper, "label": r.ion, "observed": observed,
                     "background": background}
    if net < max(3.0 * np.sqrt(max(background, 1.0)), 10.0):
        return [Finding("warning", "background_only", index,
                        f"{r.describe()}: no peak above background ({observed:.0f} ions, {background:.0f} expected "
                        f"from background)", figures)]
    contributions = _contributions(final, r.lower, r.upper)
    composition = canonical(r.composition)
    is_label = np.array([sp.composition == composition for sp in final.species])
    model_net = float(contributions.sum())
    foreign = float(contributions[~is_label].sum())
    best = int(np.argmax(contributions)) if model_net > 0 else None
    if best is not None:
        figures |= {"best_fit": final.species[best].name, "best_fit_charge": final.species[best].charge,
                    "best_fit_composition": final.species[best].composition}
    if labels:
        columns = np.array([s for s, sp in enumerate(labels_only.species) if sp.key in {l.key for l in labels}])
        figures |= _pattern_figures(labels_only, columns)
    out = []
    if any(el not in ELEMENTS for el, _ in r.composition):
        out.append(Finding("warning", "unknown_label", index,
                           f"{r.describe()}: {r.ion} is not a chemical formula, its isotopes cannot be checked"
                           + (f"; best fit {figures['best_fit']}" if best is not None else ""), figures))
    elif not labels:
        out.append(Finding("error", "label_not_in_range", index,
                           f"{r.describe()}: no isotope of {r.ion} at charge {_charges(settings)} lies in this range"
                           + (f"; best fit {figures['best_fit']}" if best is not None else ""), figures))
    elif model_net > 0 and foreign >= settings.min_counts and foreign >= settings.z * np.sqrt(observed) \
            and foreign >= settings.min_foreign_fraction * model_net:
        other = int(np.argmax(np.where(is_label, -1.0, contributions)))
        name = final.species[other].name
        fraction = foreign / model_net
        figures |= {"foreign_fraction": fraction, "foreign_ions": foreign, "foreign_species": name}
        if fraction >= 0.5:
            out.append(Finding("error", "mislabelled", index,
                               f"{r.describe()}: isotope pattern does not fit the label{_fit_text(figures)}; "
                               f"{fraction:.0%} of its ions are {name} (best fit {figures['best_fit']})", figures))
        elif final.species[other].composition not in label_compositions:
            out.append(Finding("warning", "foreign_species", index,
                               f"{r.describe()}: {fraction:.0%} of its ions are {name}, which no range labels"
                               f"{_fit_text(figures)}", figures))
        else:
            out.append(Finding("info", "shared_peak", index,
                               f"{r.describe()}: {fraction:.0%} of its ions are {name} (isotopes overlap)", figures))
    unexplained = _unexplained(final, r, settings)
    if unexplained > 0:
        figures = figures | {"unexplained_ions": unexplained}
        out.append(Finding("warning", "unexplained_counts", index,
                           f"{r.describe()}: {unexplained:.0f} ions fit neither the label nor any candidate species",
                           figures))
    return out


def _fit_text(figures: dict) -> str:
    """`` (label fit: G = 1234 on 3 dof, p = 1e-12, residual 45 %)`` from the range's pattern figures."""
    if figures.get("label_residual") is None:
        return ""
    p = figures["label_p_value"]
    return (f" (label fit: G = {figures['label_deviance']:.0f} on {figures['label_dof']} dof, "
            f"p = {'n/a' if p is None else f'{p:.1g}'}, residual {figures['label_residual']:.0%})")


def _charges(settings: AuditSettings) -> str:
    return f"{min(settings.charges)}-{max(settings.charges)}" if len(settings.charges) > 1 else str(settings.charges[0])


def _pattern_figures(result: Fit, columns: np.ndarray) -> dict:
    """Goodness of fit of the species ``columns`` on the clusters where they have peaks."""
    rows = np.any(result.design[:, columns] > 0, axis=1)
    deviance = result.deviance(columns)
    dof = int(rows.sum()) - len(columns)
    net = np.maximum(result.observed[rows] - result.background[rows], 0.0).sum()
    residual = float(np.abs(result.observed[rows] - result.expected[rows]).sum() / net) if net > 0 else None
    return {"label_deviance": deviance, "label_dof": dof,
            "label_p_value": float(stats.chi2.sf(deviance, dof)) if dof > 0 else None,
            "label_residual": residual}


def _unexplained(final: Fit, r: Range, settings: AuditSettings) -> float:
    """Ions in the range's clusters that the final model leaves significantly unexplained."""
    centre = 0.5 * (final.lo + final.hi)
    inside = (centre >= r.lower) & (centre <= r.upper)
    hot = inside & excess_clusters(final, settings.z, settings.min_counts, settings.min_foreign_fraction)
    return float((final.observed - final.expected)[hot].sum())


def _in_any_range(mz: np.ndarray, range_list: list[Range]) -> np.ndarray:
    inside = np.zeros(np.shape(mz), dtype=bool)
    for r in range_list:
        inside |= (mz >= r.lower) & (mz <= r.upper)
    return inside


def _missing_isotopes(final: Fit, label_compositions: set, range_list: list[Range], spectrum: Spectrum,
                      windows: Windows, settings: AuditSettings) -> list[Finding]:
    out = []
    for s, sp in enumerate(final.species):
        if sp.composition not in label_compositions:
            continue
        expected = final.amplitude[s] * sp.abundance
        lo, hi = windows.bounds(sp.mz)
        background = spectrum.expected_background(lo, hi)
        strong = (expected >= settings.min_counts) & (expected >= settings.z * np.sqrt(np.maximum(background, 1.0)))
        for k in np.flatnonzero(strong & ~_in_any_range(sp.mz, range_list)):
            observed = float(spectrum.count(lo[k], hi[k]))
            out.append(Finding("warning", "missing_isotope", None,
                               f"{sp.name} isotope at {sp.mz[k]:.2f} Da has no range "
                               f"({expected[k]:.0f} ions expected, {observed:.0f} observed)",
                               {"species": sp.name, "mz": float(sp.mz[k]), "expected": float(expected[k]),
                                "observed": observed, "background": float(background[k])}))
    return out


def _uncovered_peaks(final: Fit, range_list: list[Range], reported: list[float], spectrum: Spectrum,
                     windows: Windows, settings: AuditSettings) -> list[Finding]:
    """Peaks outside every range, except those already ``reported`` (m/z, Da) as missing isotopes."""
    apex, height = find_peaks(spectrum, settings.z)
    keep = (apex >= settings.min_mz) & ~_in_any_range(apex, range_list)
    apex, height = apex[keep], height[keep]
    lo, hi = windows.bounds(apex)
    observed = spectrum.count(lo, hi)
    background = spectrum.expected_background(lo, hi)
    net = observed - background
    out = []
    taken = list(zip(*windows.bounds(np.asarray(reported, dtype=np.float64))))
    for k in np.argsort(-height):
        if net[k] < settings.min_counts or net[k] < settings.z * np.sqrt(max(background[k], 1.0)):
            continue
        if any(a <= apex[k] <= b for a, b in taken):
            continue
        taken.append((lo[k], hi[k]))
        figures = {"mz": float(apex[k]), "lower": float(lo[k]), "upper": float(hi[k]),
                   "observed": float(observed[k]), "background": float(background[k]), "net": float(net[k])}
        contributions = _contributions(final, lo[k], hi[k])
        text = ""
        if contributions.sum() >= 0.5 * net[k]:
            name = final.species[int(np.argmax(contributions))].name
            figures["likely_species"] = name
            figures["likely_composition"] = final.species[int(np.argmax(contributions))].composition
            text = f", fits {name}"
        out.append(Finding("warning", "uncovered_peak", None,
                           f"peak at {apex[k]:.2f} Da ({net[k]:.0f} ions above background) lies in no range{text}",
                           figures))
    return sorted(out, key=lambda f: f.figures["mz"])


def _species_fit(sp: Species, s: int, labelled: bool, labels_only: Fit, final: Fit) -> SpeciesFit:
    """Labels are judged on the labels-only model (what the range file claims), added species on the final one."""
    figures = _pattern_figures(labels_only if labelled else final, np.array([s]))
    return SpeciesFit(sp.name, sp.composition, sp.charge, labelled, float(final.amplitude[s]),
                      figures["label_deviance"], figures["label_dof"], figures["label_p_value"],
                      figures["label_residual"])
