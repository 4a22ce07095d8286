"""Small types shared by every pipeline step."""

from apt_filters.core.errors import AptFiltersError, InputError
from apt_filters.core.mesh import TriMesh
from apt_filters.core.atomic import atomic_output, atomic_write_bytes, atomic_write_text

__all__ = [
    "AptFiltersError",
    "InputError",
    "TriMesh",
    "atomic_output",
    "atomic_write_bytes",
    "atomic_write_text",
]
