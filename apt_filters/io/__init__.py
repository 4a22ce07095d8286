"""Reading and writing APT data: ion files (POS, EPOS, APT6, CSV), range files (RRNG, RNG, ENV), ranging."""

from apt_filters.io.ions import IonTable
from apt_filters.io.ranges import UNRANGED, Range, RangeTable, ion_name

__all__ = ["IonTable", "Range", "RangeTable", "UNRANGED", "ion_name"]
