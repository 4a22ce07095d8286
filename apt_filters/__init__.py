"""apt-filters: atom probe tomography iso-surfaces, MeshLab filter chains and interface chemistry.

One package per step; the steps and their order are in docs/index.md ("The steps, in the order a
run takes them"). ``core`` holds what every step shares;
:func:`apt_filters.pipeline.surface.finished_surface` is the one way from ions to a finished surface.
"""

import os
import warnings

__version__ = "0.1.0"

# numba probes Intel TBB first for its parallel loops and warns when the installed TBB is too
# old, then uses OpenMP: the warning says nothing a user can act on.
warnings.filterwarnings("ignore", message=r".*TBB threading layer.*")

# numba's parallel loops run on OpenMP (libgomp), whose idle threads spin at the end of every loop before they
# sleep; the refinement runs thousands of short loops between serial numpy steps, and on a shared 2-core machine
# the spinning is CPU taken from the serial work (gamma-prime refinement 22.0-22.2 -> 20.8-21.3 s CPU, wall alike,
# outputs identical). Set before any kernel loads libgomp; a value the user set wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
