"""Interface chemistry across iso-surfaces: proximity histograms, excess, objects.

Distances to the surface come from :mod:`apt_filters.core.distance`.

- :mod:`.proxigram`: counts per distance bin, object and species; concentrations with binomial
  errors, shell volumes and densities; CSV and PNG;
- :mod:`.excess`: Gibbsian interfacial excess (proxigram integration, Krakauer–Seidman) per object
  and pooled, detection efficiencies of common instruments; JSON;
- :mod:`.maps`: the excess and plateau compositions per vertex (adaptive patches, errors), and a
  chi-square test of uniform segregation per object.
"""

from apt_filters.analysis.excess import (INSTRUMENT_EFFICIENCY, Excess, interfacial_excess, interface_position,
                                         write_excess_json)
from apt_filters.analysis.maps import SurfaceMaps, excess_maps
from apt_filters.analysis.proxigram import POOLED, Proxigram, compute_proxigram

__all__ = ["INSTRUMENT_EFFICIENCY", "POOLED", "Excess", "Proxigram", "SurfaceMaps", "compute_proxigram",
           "excess_maps", "interface_position", "interfacial_excess", "write_excess_json"]
