"""Scenarios and scenes: the loaders (shared JSON, CommonRoad XML, either gzip-compressed), the
``Scene`` pytree every road planner and the simulator consume, and the built-in synthetic scenes.

Files to scenes: ``load_scenes(paths)`` (or ``load_records`` to keep each scene's scenario, route
and name); built-in ones: ``builtin_scenes``; a batch: ``stack_scenes``. The modules hold the rest
(``scene`` the types, ``build`` scenes from scenarios, ``batch`` batches of scenes, ``files``,
``loader``, ``commonroad``, ``route``, ``lights``, ``builtin``, ``cache``, ...).
"""

from jaxplan.scenarios.batch import index_scene, stack_scenes
from jaxplan.scenarios.build import build_scene
from jaxplan.scenarios.builtin import builtin_records, builtin_scenes
from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.files import load_records, load_scenes
from jaxplan.scenarios.scenario import Scenario
from jaxplan.scenarios.scene import Goal, Scene, SceneConfig, SceneRecord

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
