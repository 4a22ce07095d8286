"""Sweeps and batches: the pipeline over a grid of analysis choices or over many datasets, on Dask.

``run_sweep(base, choice_grid(...), out, client=...)`` runs one pipeline per choice (iso-value,
voxel, delocalization, kernel), matches objects across the choices by overlap and sets each
figure's spread over the choices beside its counting error; ``run_batch(manifest, out,
client=...)`` runs one analysis over the datasets of a TOML manifest, failures isolated.
``dask_client()`` gives a local cluster sized to the machine, or connects to any Dask scheduler.
The one-file map-reduce voxelization is :func:`apt_filters.voxel.distributed.voxelize_distributed`.
"""

from apt_filters.sweep.batch import read_manifest, run_batch
from apt_filters.sweep.choices import Choice, choice_grid
from apt_filters.sweep.cluster import dask_client
from apt_filters.sweep.match import match_objects
from apt_filters.sweep.sweep import SweepResult, run_sweep

__all__ = ["Choice", "SweepResult", "choice_grid", "dask_client", "match_objects", "read_manifest", "run_batch",
           "run_sweep"]
