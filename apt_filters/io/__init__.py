"""Reading and writing APT data: ion files (POS, EPOS, APT6, CSV), range files (RRNG, RNG, ENV), ranging."""

from apt_filters.io.ions import IonTable
from apt_filters.io.rangefiles import read_ranges
from apt_filters.io.ranges import UNRANGED, Range, RangeTable, ion_name
from apt_filters.io.readers import iter_ion_chunks, read_ions

__all__ = ["IonTable", "Range", "RangeTable", "UNRANGED", "ion_name", "read_ions", "iter_ion_chunks", "read_ranges"]
