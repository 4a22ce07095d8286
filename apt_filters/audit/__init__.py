"""Range-file audit: checks each range's label against the isotope patterns of the mass spectrum.

Entry point: :func:`audit_ranges` (ions or m/z + ranges -> :class:`AuditResult`). It never changes
the ranges.
"""

from apt_filters.audit.audit import AuditResult, AuditSettings, Finding, SpeciesFit, audit_ranges
from apt_filters.audit.candidates import COMMON_ELEMENTS, candidate_compositions
from apt_filters.audit.isotopes import isotope_pattern, species_name

__all__ = ["AuditResult", "AuditSettings", "Finding", "SpeciesFit", "audit_ranges", "COMMON_ELEMENTS",
           "candidate_compositions", "isotope_pattern", "species_name"]
