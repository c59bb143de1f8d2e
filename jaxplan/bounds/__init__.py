"""Contour-corner path bounds, their exact and centre-line counterparts, and a path planned inside them."""

from jaxplan.bounds.corners import (
    CASE_DEEPEST,
    CASE_DEGENERATE,
    CASE_NO_CORNER,
    CASE_NONE,
    CASE_OFF_EDGE,
    CASE_ON_EDGE,
    ContourConstruction,
    contour_avoid_distance,
    contour_construction,
)
from jaxplan.bounds.distance import exact_avoid_distance, overlap_interval
from jaxplan.bounds.frenet_bounds import METHODS, PathBounds, obstacle_contours, path_bounds

__all__ = [
    "CASE_DEEPEST",
    "CASE_DEGENERATE",
    "CASE_NONE",
    "CASE_NO_CORNER",
    "CASE_OFF_EDGE",
    "CASE_ON_EDGE",
    "METHODS",
    "ContourConstruction",
    "PathBounds",
    "contour_avoid_distance",
    "contour_construction",
    "exact_avoid_distance",
    "obstacle_contours",
    "overlap_interval",
    "path_bounds",
]
