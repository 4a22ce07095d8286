"""The table of species the audit may propose: elements and common molecular ions.

Molecular ions are generated combinatorially within a small formula space: ``M``, dimers
``M2``, and ``M_a X_b`` with ``X`` one of the common ligands (oxides, hydrides, carbides,
nitrides), which covers the metal oxides, hydrides and carbides seen in atom probe spectra.
"""

from __future__ import annotations

from apt_filters.audit.isotopes import Composition, canonical

COMMON_ELEMENTS: tuple[str, ...] = (
    "H", "Li", "Be", "B", "C", "N", "O", "F", "Na", "Mg", "Al", "Si", "P", "S", "Cl", "Ar", "K", "Ca",
    "Sc", "Ti", "V", "Cr", "Mn", "Fe", "Co", "Ni", "Cu", "Zn", "Ga", "Ge", "As", "Se", "Y", "Zr", "Nb",
    "Mo", "Ru", "Rh", "Pd", "Ag", "In", "Sn", "Sb", "Te", "La", "Ce", "Nd", "Gd", "Hf", "Ta", "W", "Re",
    "Ir", "Pt", "Au", "Pb", "Bi",
)
"""Elements common in atom probe specimens (metals, semiconductors, light impurities)."""

LIGANDS: tuple[str, ...] = ("H", "C", "N", "O")
"""Atoms that bind to a metal in molecular ions: hydrides, carbides, nitrides, oxides."""


def candidate_compositions(elements: tuple[str, ...] = COMMON_ELEMENTS, ligands: tuple[str, ...] = LIGANDS,
                           max_metal: int = 2, max_ligand: int = 3) -> list[Composition]:
    """All ``M_a X_b`` with ``1 <= a <= max_metal`` and ``0 <= b <= max_ligand``, canonical, no repeats.

    Returns
    -------
    list of composition tuples, e.g. ``(("Ni", 1),)``, ``(("Cr", 2), ("O", 1))``, ``(("H", 2),)``.
    """
    out: dict[Composition, None] = {}
    for metal in elements:
        for a in range(1, max_metal + 1):
            out[canonical(((metal, a),))] = None
            for ligand in ligands:
                for b in range(1, max_ligand + 1):
                    out[canonical(((metal, a), (ligand, b)))] = None
    return list(out)
