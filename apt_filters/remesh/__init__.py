"""Remeshing: feature-preserving centroidal Voronoi (Lloyd) remesher.

``remesh(mesh, edge_length=...)`` turns a sliver-rich iso-surface into near-equilateral
triangles while keeping sharp edges, corners and open boundaries; ``quality`` holds the
measures used to judge it.
"""

from apt_filters.remesh.remesh import RemeshResult, remesh

__all__ = ["RemeshResult", "remesh"]
