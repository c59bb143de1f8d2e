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

# The planners load on first use: ``jaxplan.lattice.plan(...)`` or ``from jaxplan import speed``.
_SUBPACKAGES = ("bounds", "lattice", "speed", "parking", "replan", "tuning", "scenarios", "eval")


def __getattr__(name):
    if name in _SUBPACKAGES:
        import importlib

        return importlib.import_module(f"jaxplan.{name}")
    raise AttributeError(f"module 'jaxplan' has no attribute {name!r}")
