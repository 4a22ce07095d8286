"""MeshLab integration: pymeshlab bridge, named filter chains recorded as ``.mlx`` scripts,
safe script replay, decimation and exports the MeshLab GUI shows well.

Importing this package checks that pymeshlab offers every filter we use (see
:mod:`apt_filters.meshlab.filters`) and fails with one clear :class:`AptFiltersError`
naming the missing system library if not.
"""

import pymeshlab as _pymeshlab

from apt_filters.meshlab.filters import check_filters as _check_filters

_check_filters(_pymeshlab.filter_list())
