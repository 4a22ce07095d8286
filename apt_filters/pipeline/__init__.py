"""The whole pipeline as one call (:func:`~apt_filters.pipeline.run.run_pipeline`): read -> audit ->
voxelize -> finished surface (:func:`~apt_filters.pipeline.surface.finished_surface`: contour, specks,
refinement, clean chain, remesh) -> objects -> proxigrams and excess -> exports and report."""
