"""Iso-surfaces: marching cubes (baseline) and dual contouring (sharp features), open at the specimen edge."""

from apt_filters.contour.components import Component, component_table, label_components
from apt_filters.contour.marching_cubes import marching_cubes

__all__ = ["Component", "component_table", "label_components", "marching_cubes"]
