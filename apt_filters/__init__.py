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

# numba's parallel loops run on OpenMP, whose idle threads spin after every loop (GNU OpenMP: ~300k turns)
# before they sleep: the refinement runs thousands of short loops, and on a shared machine, where a thread
# waits for one that is not running, the spinning is CPU taken from the other processes (10M-ion
# refinement: benchmarks/results_refine_scale.md). Passive waiting sleeps at once; a user's setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
