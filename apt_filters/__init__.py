"""apt-filters: atom probe tomography iso-surfaces, MeshLab filter chains and interface chemistry.

The pipeline flows one way, one package per step::

    io -> voxel -> contour -> meshlab / remesh -> analysis -> cli

``core`` holds the few types every step shares (errors, :class:`~apt_filters.core.mesh.TriMesh`,
atomic file output).
"""

import warnings

__version__ = "0.1.0"

# numba probes Intel TBB first for its parallel loops and warns when the installed TBB is too
# old, then uses OpenMP: the warning says nothing a user can act on.
warnings.filterwarnings("ignore", message=r".*TBB threading layer.*")
