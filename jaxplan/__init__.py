"""jaxplan: batched, jit-compiled, differentiable motion-planning kernels in JAX.

The public surface, all under ``jaxplan.``:

- geometry core and pytrees (imported with the package): ``ReferenceLine``, ``box_corners``,
  ``vehicle_corners``, ``has_overlap``, ``separation``, ``overlap_polygon``, ``polygon_area``,
  ``to_frenet``, ``to_cartesian``, ``headings_from_path``; ``VehicleParams``, ``Obstacles``,
  ``Polygon``, ``Trajectory``;
- scenes (``jaxplan.scenarios``): ``Scene``, ``SceneConfig``, ``SceneRecord``, ``load_scenes``,
  ``load_records``, ``builtin_scenes``, ``stack_scenes``, ``index_scene``;
- planners (``jaxplan.planner``): ``Planner``, ``make_planner``, ``planner_names``,
  ``register_planner``, ``EgoState``, ``PlanOutput``;
- closed loop and metrics (``jaxplan.sim``): ``SimConfig``, ``rollout``, ``ChunkedRollout``,
  ``DriveLog``, ``driven_scene``, ``evaluate``, ``evaluate_batch``, ``METRICS``.

Everything past the geometry core loads on first use (``jaxplan.rollout`` imports
``jaxplan.sim``), so ``import jaxplan`` stays cheap; so do the planner packages
(``jaxplan.lattice``, ``jaxplan.speed``, ...).
"""

from jaxplan import geometry as geometry
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

# Loaded on first use: name -> the module that defines it.
_LAZY = {
    # scenes
    "Scene": "jaxplan.scenarios",
    "SceneConfig": "jaxplan.scenarios",
    "SceneRecord": "jaxplan.scenarios",
    "load_scenes": "jaxplan.scenarios",
    "load_records": "jaxplan.scenarios",
    "stack_scenes": "jaxplan.scenarios",
    "index_scene": "jaxplan.scenarios",
    "builtin_scenes": "jaxplan.scenarios",
    # planners
    "Planner": "jaxplan.planner",
    "EgoState": "jaxplan.planner",
    "PlanOutput": "jaxplan.planner",
    "make_planner": "jaxplan.planner",
    "planner_names": "jaxplan.planner",
    "register_planner": "jaxplan.planner",
    # closed loop and metrics
    "SimConfig": "jaxplan.sim",
    "DriveLog": "jaxplan.sim",
    "rollout": "jaxplan.sim",
    "ChunkedRollout": "jaxplan.sim",
    "driven_scene": "jaxplan.sim",
    "evaluate": "jaxplan.sim",
    "evaluate_batch": "jaxplan.sim",
    "METRICS": "jaxplan.sim",
}

# The planners and the rest load on first use: ``jaxplan.lattice.plan(...)`` or ``from jaxplan import speed``.
_SUBPACKAGES = (
    "bounds",
    "lattice",
    "speed",
    "parking",
    "replan",
    "tuning",
    "scenarios",
    "eval",
    "sim",
    "baselines",
    "models",
    "planner",
)

__all__ = [  # the eager names above and every name in _LAZY (tests/test_public_api.py checks)
    "METRICS",
    "ChunkedRollout",
    "DriveLog",
    "EgoState",
    "Obstacles",
    "PlanOutput",
    "Planner",
    "Polygon",
    "ReferenceLine",
    "Scene",
    "SceneConfig",
    "SceneRecord",
    "SimConfig",
    "Trajectory",
    "VehicleParams",
    "box_corners",
    "builtin_scenes",
    "driven_scene",
    "evaluate",
    "evaluate_batch",
    "has_overlap",
    "headings_from_path",
    "index_scene",
    "load_records",
    "load_scenes",
    "make_planner",
    "overlap_polygon",
    "planner_names",
    "polygon_area",
    "register_planner",
    "rollout",
    "separation",
    "stack_scenes",
    "to_cartesian",
    "to_frenet",
    "vehicle_corners",
]


def __getattr__(name):
    import importlib

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # the next access is a plain attribute
        return value
    if name in _SUBPACKAGES:
        return importlib.import_module(f"jaxplan.{name}")
    raise AttributeError(f"module 'jaxplan' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__) | set(_SUBPACKAGES))
