"""Scenarios and scenes: the loaders (shared JSON, CommonRoad XML, either gzip-compressed), the
``Scene`` pytree every road planner and the simulator consume, and the built-in synthetic scenes.

Files to scenes: ``load_scenes(paths)`` (or ``load_records`` to keep each scene's scenario, route
and name); built-in ones: ``builtin_scenes``; a batch: ``stack_scenes``. The modules hold the rest
(``loader``, ``commonroad``, ``files``, ``route``, ``lights``, ``builtin``, ``cache``, ...).
"""

from jaxplan.scenarios.builtin import builtin_records, builtin_scenes
from jaxplan.scenarios.loader import Scenario, ScenarioError
from jaxplan.scenarios.scene import (
    Goal,
    Scene,
    SceneConfig,
    SceneRecord,
    build_scene,
    index_scene,
    load_records,
    load_scenes,
    stack_scenes,
)

__all__ = [
    "Goal",
    "Scenario",
    "ScenarioError",
    "Scene",
    "SceneConfig",
    "SceneRecord",
    "build_scene",
    "builtin_records",
    "builtin_scenes",
    "index_scene",
    "load_records",
    "load_scenes",
    "stack_scenes",
]
