"""Checks of a run's inputs that take milliseconds, made before any heavy work or import.

The ion file must exist with a known extension; the range file is read (it is small) and
every species the configuration names (surfaces, ``exclude``, ``solutes``) is matched to the
range file's names case-insensitively (``ni`` -> ``Ni``, ``cr2o`` -> ``Cr2O``). A name that
matches nothing is refused with the valid names listed. This module imports only the
readers of :mod:`apt_filters.io` (numpy, periodictable), so a mistake is reported before
numba, scipy, pymeshlab, open3d or matplotlib are loaded.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from apt_filters.core.errors import AptFiltersError, InputError


def match_species(name: str, names: list[str], *, what: str, others: list[str] = ()) -> str:
    """The entry of ``names`` that ``name`` means, compared case-insensitively.

    Parameters
    ----------
    name : str
        What the user typed.
    names : list of str
        Valid names (e.g. the range file's elements).
    what : str
        What the name is for, in the error message ("iso-surface species").
    others : list of str
        Names of the range file that exist but are not valid here (e.g. molecular ions where an
        element is needed); named in the error so the user sees why.

    Raises
    ------
    AptFiltersError
        No match (or two names differing only in case, neither typed exactly), listing ``names``.
    """
    if name in names:
        return name
    hits = [n for n in names if n.lower() == name.lower()]
    if len(hits) == 1:
        return hits[0]
    if len(hits) > 1:
        raise AptFiltersError(f"{what} {name!r} is ambiguous: {', '.join(hits)} differ only in case")
    other = [n for n in others if n.lower() == name.lower()]
    because = f"{other[0]!r} is an ion of the range file, not an element" if other else f"unknown {what} {name!r}"
    raise AptFiltersError(f"{because}; valid names: {', '.join(names) or 'none'}")


def _check_file(path: str, kind: str) -> None:
    if not path:
        raise AptFiltersError(f"no {kind} given")
    if not os.path.exists(path):
        raise InputError("no such file", path)
    if not os.path.isfile(path):
        raise InputError("not a regular file", path)
    if not os.access(path, os.R_OK):
        raise InputError("not readable (permission denied)", path)


def config_ranges(config):
    """The range file of ``config`` as the run uses it: read with ``[input] unknown_species``, then
    relabelled by ``[input] relabel`` (see docs/io.md)."""
    from apt_filters.io import read_ranges
    from apt_filters.io.rangefiles import relabel

    ranges = read_ranges(config.input.ranges, unknown=config.input.unknown_species)
    return relabel(ranges, config.input.relabel, origin="[input] relabel, --relabel") if config.input.relabel \
        else ranges


def check_inputs(config):
    """Check the files of ``config`` (a ``PipelineConfig``) and return it with the species names
    spelled as the range file (relabelled) spells them. Reads the range file, nothing else.

    Raises
    ------
    AptFiltersError
        Missing or unreadable file, unknown ion file extension, unreadable range file, or a
        species that the range file does not name (message lists the valid names).
    """
    _check_file(config.input.ions, "ion file ([input] ions or IONS)")
    _check_file(config.input.ranges, "range file ([input] ranges or --range)")
    from apt_filters.io.readers import ion_format

    ion_format(config.input.ions)
    ranges = config_ranges(config)
    elements, ions = ranges.elements, ranges.ions
    source = Path(config.input.ranges).name
    try:
        surfaces = [dataclasses.replace(s, species=match_species(s.species, elements, what="iso-surface species",
                                                                 others=ions)) if s.species else s
                    for s in config.surface]
        exclude = [match_species(e, elements, what="species to exclude", others=ions) for e in config.voxel.exclude]
        solutes = [match_species(e, elements + [i for i in ions if i not in elements], what="solute")
                   for e in config.proxigram.solutes]
    except AptFiltersError as exc:
        raise AptFiltersError(f"{exc} (in {source})") from None
    return dataclasses.replace(config, surface=surfaces, voxel=dataclasses.replace(config.voxel, exclude=exclude),
                               proxigram=dataclasses.replace(config.proxigram, solutes=solutes))
