"""jaxplan: batched, jit-compiled, differentiable motion-planning kernels in JAX."""
from jaxplan import geometry
from jaxplan.geometry import (
    ReferenceLine,
    box_corners,
    has_overlap,
    headings_from_path,
    overlap_polygon,
    polygon_area,
    separation,
    to_cartesian,
    to_frenet,
    vehicle_corners,
)
from jaxplan.types import Obstacles, Polygon, Trajectory, VehicleParams

__version__ = "0.1.0"
