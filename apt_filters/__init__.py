"""apt-filters: atom probe tomography iso-surfaces, MeshLab filter chains and interface chemistry.

One package per step; the steps and their order are in docs/index.md ("The steps, in the order a
run takes them"). ``core`` holds what every step shares;
:func:`apt_filters.pipeline.surface.finished_surface` is the one way from ions to a finished surface.
"""

import warnings

__version__ = "0.1.0"

# numba probes Intel TBB first for its parallel loops and warns when the installed TBB is too
# old, then uses OpenMP: the warning says nothing a user can act on.
warnings.filterwarnings("ignore", message=r".*TBB threading layer.*")
