"""Iso-surfaces: marching cubes (baseline) and dual contouring (sharp features), open at the specimen edge."""

from apt_filters.contour.components import Component, component_table, label_components
from apt_filters.contour.dual_contouring import dual_contouring, surface_nets
from apt_filters.contour.marching_cubes import marching_cubes

__all__ = ["Component", "component_table", "dual_contouring", "label_components", "marching_cubes", "surface_nets"]
