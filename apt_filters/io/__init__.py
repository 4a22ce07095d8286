"""Reading and writing APT data: ion files (POS, EPOS, APT6, ATO, CSV), range files (RRNG, RNG, ENV), ranging."""

from apt_filters.io.ions import IonTable
from apt_filters.io.rangefiles import read_ranges, relabel
from apt_filters.io.ranges import UNRANGED, Range, RangeTable, ReadNote, ion_name
from apt_filters.io.readers import count_ions, iter_ion_chunks, map_ions, read_ions

__all__ = ["IonTable", "Range", "RangeTable", "ReadNote", "UNRANGED", "count_ions", "ion_name", "read_ions",
           "iter_ion_chunks", "map_ions", "read_ranges", "relabel"]
