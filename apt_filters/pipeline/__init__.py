"""The whole pipeline as one call: read -> range -> audit -> voxelize -> contour -> clean ->
remesh -> objects -> proxigrams and excess -> exports and report."""
