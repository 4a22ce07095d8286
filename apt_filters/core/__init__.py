"""Small types shared by every pipeline step, and the geometry layer.

- :mod:`.mesh`: :class:`TriMesh` and its cached :class:`Topology` (edges, face pairs, components,
  boundary, genus);
- :mod:`.distance`: the one signed-distance engine (positive along the normals, i.e. outside the
  region above the iso-value);
- :mod:`.nearby`: the ions near a surface, selected in one streamed pass and reused;
- :mod:`.triangle`: the closest point on a triangle (numba kernel).
"""

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.mesh import Topology, TriMesh
from apt_filters.core.atomic import atomic_output, atomic_write_bytes, atomic_write_text

__all__ = [
    "AptFiltersError",
    "InputError",
    "Topology",
    "TriMesh",
    "atomic_output",
    "atomic_write_bytes",
    "atomic_write_text",
]
