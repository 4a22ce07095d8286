"""The figures a reader looks for first, per iso-surface and per group of objects.

Objects fall in two groups that must not be pooled blindly: *interior* objects (closed: the
whole object lies inside the analysed volume, so its volume and shape are measured) and
objects *at the specimen edge* (open or capped proxies: cut by the edge of the data, so their
volume, area and shape are those of the part that was detected). A third row pools all objects.

For each group: number of objects, summed volume (closed and proxy objects) and area, mean
sphericity with its spread, the composition inside and outside the interface and the
interfacial excess of each solute. Composition is the pooled proxigram of the group's
objects, counted in the same plateau windows as the excess (``inner`` to ``outer`` nm from the
surface on each side, positive inside; inside, each object from half its own depth where that is
nearer, :func:`apt_filters.analysis.width.inside_windows`), with binomial standard errors
sqrt(c (1 - c) / N) (Hellman et al., Microsc. Microanal. 9 (2003) 399). :func:`object_plateaus` gives the
same inside composition per object with the window it was counted in. The excess is
:func:`apt_filters.analysis.excess.interfacial_excess` of that pooled profile (the
Krakauer–Seidman estimate, as the ground-truth comparison uses; atoms/nm², efficiency-corrected).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from apt_filters.analysis.excess import interfacial_excess
from apt_filters.analysis.proxigram import Proxigram
from apt_filters.analysis.width import ProfileFit, inside_starts

GROUPS = (("interior", "interior objects (closed)"),
          ("edge", "objects at the specimen edge (open)"),
          ("all", "all objects"))
"""Group key and the words the report shows for it."""


def _finite_or_none(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def _fractions(n: np.ndarray, elements: list[str]) -> dict:
    """``{"atoms", "fraction", "error"}`` of atom counts ``n`` (one per element), binomial errors; fractions
    None where there is no atom."""
    n = np.asarray(n, dtype=np.float64)
    total = float(n.sum())
    c = n / total if total > 0 else np.full(len(n), np.nan)
    err = np.sqrt(c * (1 - c) / total) if total > 0 else c
    return {"atoms": int(total), "fraction": {e: _finite_or_none(v) for e, v in zip(elements, c)},
            "error": {e: _finite_or_none(v) for e, v in zip(elements, err)}}


def window_composition(proxigram: Proxigram, inner: float, outer: float) -> dict[str, dict]:
    """Element composition of a group of objects inside and outside their surface, pooled.

    Outside, every object's window is ``inner`` to ``outer``; inside, each object's starts at ``inner`` or at
    half its own depth where that is nearer (:func:`~apt_filters.analysis.width.inside_windows`): a thin
    object's inside composition is that of its own deeper half, not of an empty window or of the few ions a
    bump of its surface put deeper than it reaches.

    Parameters
    ----------
    proxigram : Proxigram
        Per-object profiles (any number of objects; their windows' counts are summed).
    inner, outer : float
        |distance| window in nm on each side of the surface.

    Returns
    -------
    dict
        ``{"inside"|"outside": {"atoms": int, "fraction": {el: c}, "error": {el: sd}}}``;
        fractions None where the window holds no atom. ``inside`` also has ``nearer``: the objects whose
        window starts nearer than ``inner``, as ``[{"object_id", "from_nm"}]`` (their plateau may not be
        reached there).
    """
    counts = proxigram.species_counts("element")  # (k, b, s)
    s = proxigram.centers
    starts = inside_starts(proxigram=proxigram, inner=inner, outer=outer)
    inside = (s >= starts[:, None]) & (s <= outer)
    out = {"inside": _fractions(counts[inside].sum(axis=0), proxigram.elements),
           "outside": _fractions(counts[:, (s <= -inner) & (s >= -outer)].sum(axis=(0, 1)), proxigram.elements)}
    out["inside"]["nearer"] = [{"object_id": int(o), "from_nm": float(f)}
                               for o, f in zip(proxigram.object_ids, starts) if f < inner]
    return out


def object_plateaus(proxigram: Proxigram, inner: float, outer: float, step: ProfileFit | None = None) -> list[dict]:
    """Each object's inside composition and the window it is counted in (as :func:`window_composition`).

    An object counted nearer than ``inner`` may hold some of its interface in its window. With the pooled
    profile's fitted ``step`` (:class:`~apt_filters.analysis.width.ProfileFit`) that share is known: at the
    window's start the step is ``reached`` of the way from the outside plateau to the inside one, so the window
    can be off by at most (1 - reached) x the step's contrast. Where that exceeds the window's own counting
    error of the step's species the object is ``short`` of its plateau; where not, counting nearer costs less
    than the count's noise.

    Returns
    -------
    list of dict
        Per object of ``proxigram``: ``object_id``, ``from_nm`` and ``to_nm`` (its window), ``nearer`` (whether
        it starts nearer than ``inner``: the object is thinner than twice the windows' inner edge),
        ``reached`` (share of the fitted step reached at ``from_nm``; None without ``step``), ``short`` (nearer,
        and the step's remaining share may bias the window beyond its counting error, or no ``step`` or atom to
        tell), ``atoms``, ``fraction`` and ``error`` per element (None without atoms).
    """
    counts = proxigram.species_counts("element")
    s = proxigram.centers
    starts = inside_starts(proxigram=proxigram, inner=inner, outer=outer)
    out = []
    for o, f, c in zip(proxigram.object_ids, starts, counts):
        row = {"object_id": int(o), "from_nm": float(f), "to_nm": float(outer), "nearer": bool(f < inner),
               **_fractions(c[(s >= f) & (s <= outer)].sum(axis=0), proxigram.elements)}
        row["reached"] = None if step is None else step.reached(float(f))
        error = row["error"].get(step.species) if step is not None else None
        row["short"] = row["nearer"] and (error is None
                                          or (1 - row["reached"]) * abs(step.inside - step.outside) > error)
        out.append(row)
    return out


def surface_summary(*, objects: list[dict], proxigram: Proxigram, solutes: list[str], efficiency: float,
                    inner: float = 1.0, outer: float | None = None, fits: dict | None = None) -> list[dict]:
    """One row per group of objects (see module doc): geometry, composition and excess.

    Parameters
    ----------
    objects : list of dict
        Rows of :meth:`apt_filters.analysis.objects.ObjectTable.rows` (``status``, ``volume`` nm³,
        ``area`` nm², ``sphericity``).
    proxigram : Proxigram
        Per-object profiles with the same object numbering.
    solutes : list of str
        Elements or ions whose excess is reported.
    efficiency : float
        Detection efficiency for the excess in atoms.
    inner, outer : float
        Plateau windows, nm; ``outer`` defaults to the proxigram's extent.
    fits : dict, optional
        Solute -> its fit on the pooled profile, whose shapes give the levels of a group too thin for its
        windows (:meth:`apt_filters.analysis.width.Windows.fit_of`, :func:`apt_filters.analysis.excess.own_levels`).

    Returns
    -------
    list of dict
        Per group with at least one object: ``group``, ``label``, ``objects``, ``object_ids``,
        ``volume_nm3`` (None when no object of the group encloses a volume), ``area_nm2``,
        ``sphericity_mean``/``sphericity_sd`` (None without a closed object), ``composition``
        (:func:`window_composition`) and ``excess`` (solute -> ``{"gamma_atoms_nm2", "error"}``,
        None where a plateau window is empty).
    """
    outer = float(proxigram.edges[-1]) if outer is None else outer
    members = {"interior": [o for o in objects if o["status"] == "closed"],
               "edge": [o for o in objects if o["status"] != "closed"], "all": list(objects)}
    rows = []
    for key, label in GROUPS:
        group = members[key]
        if not group or (key == "all" and not (members["interior"] and members["edge"])):
            continue  # "all" would repeat the only non-empty group
        ids = [int(o["object_id"]) for o in group]
        keep = np.isin(proxigram.object_ids, ids)
        volumes = [o["volume"] for o in group if math.isfinite(o["volume"])]
        spher = np.array([o["sphericity"] for o in group if math.isfinite(o["sphericity"])])
        row = {"group": key, "label": label, "objects": len(group), "object_ids": ids,
               "volume_nm3": float(sum(volumes)) if volumes else None,
               "area_nm2": float(sum(o["area"] for o in group)),
               "sphericity_mean": float(spher.mean()) if len(spher) else None,
               "sphericity_sd": float(spher.std(ddof=1)) if len(spher) > 1 else None,
               "composition": None, "excess": {}}
        if keep.any():
            fields = ("object_ids", "counts", "unranged", "areas", "shell_volumes")
            profiles = replace(proxigram, **{f: getattr(proxigram, f)[keep] for f in fields})
            pooled = profiles.pooled()
            row["composition"] = window_composition(profiles, inner, outer)
            for solute in solutes:
                found = interfacial_excess(pooled, solute, efficiency, inner, outer, skip_unmeasurable=True,
                                           fit=(fits or {}).get(solute))
                est = found[0].cumulative if found else None
                row["excess"][solute] = None if est is None else {
                    "gamma_atoms_nm2": _finite_or_none(est.gamma_atoms),
                    "error": _finite_or_none(est.gamma_atoms_error)}
        rows.append(row)
    return rows
