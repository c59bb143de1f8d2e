"""The goal of a scenario object's first planning problem (the shared JSON format), in the local
frame: a rectangle, polygon, circle or goal lanelets (or any position), and the time, velocity and
orientation intervals. Malformed fields raise ``ScenarioError`` naming the file and field.
"""

from __future__ import annotations

import math

import numpy as np

from jaxplan.scenarios.fields import MAX_ANGLE, ScenarioError, _angle, _field, _ids, _number, _points
from jaxplan.scenarios.parse_obstacles import _size

GOAL_POSITIONS = ("rectangle", "polygon", "circle", "lanelets")  # goal regions the loaders understand
GOAL_INTERVALS = ("time", "velocity", "orientation")


def _interval(goal: dict, key: str, where: str, path: str) -> list:
    v = goal[key]
    ok = (
        isinstance(v, (list, tuple))
        and len(v) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
    )
    if not ok or v[0] > v[1]:
        raise ScenarioError(
            f"{path}: field {where}.{key} should be an interval [low, high] of finite numbers, got {v!r}"
        )
    if key == "orientation" and max(abs(v[0]), abs(v[1])) > MAX_ANGLE:  # like every other angle
        raise ScenarioError(
            f"{path}: field {where}.{key} should be an interval of angles within +-{MAX_ANGLE:g} rad, got {v!r}"
        )
    return [float(v[0]), float(v[1])]


def _goal(problem: dict, origin: np.ndarray, path: str, t0: float = 0.0) -> dict:
    """The first goal, in the local frame, its time interval relative to the start time ``t0``.

    A goal's position is a rectangle or a list of lanelets (CommonRoad's goal regions), or
    absent (any position). Other position kinds are refused, naming the field."""
    goals = _field(problem, "goals", "planning_problems[0]", path, list)
    goal = goals[0] if goals else {}
    where = "planning_problems[0].goals[0]"
    if not isinstance(goal, dict):
        raise ScenarioError(f"{path}: field {where} should be an object")
    goal = dict(goal)
    for key in ("position", "shape", "point"):
        if key in goal:
            raise ScenarioError(
                f"{path}: field {where}.{key}: a goal region must be one of {', '.join(GOAL_POSITIONS)}"
            )
    for key in GOAL_INTERVALS:
        if goal.get(key) is not None:
            goal[key] = _interval(goal, key, where, path)
        else:
            goal.pop(key, None)
    if "time" in goal:
        goal["time"] = [goal["time"][0] - t0, goal["time"][1] - t0]
    if "rectangle" in goal:
        r = _field(goal, "rectangle", where, path, dict)
        rw = f"{where}.rectangle"
        c = _points([_field(r, "center", rw, path)], f"{rw}.center", path)[0]
        length, width = _size(r, rw, path)
        orientation = _angle(r, "orientation", rw, path) if r.get("orientation") is not None else 0.0
        goal["rectangle"] = {
            "center": (c - origin).tolist(),
            "length": length,
            "width": width,
            "orientation": orientation,
        }
    if "polygon" in goal:
        goal["polygon"] = (_points(goal["polygon"], f"{where}.polygon", path, 3) - origin).tolist()
    if "circle" in goal:
        r = _field(goal, "circle", where, path, dict)
        c = _points([_field(r, "center", f"{where}.circle", path)], f"{where}.circle.center", path)[0]
        radius = _number(r, "radius", f"{where}.circle", path)
        if radius <= 0:
            raise ScenarioError(f"{path}: field {where}.circle.radius must be positive")
        goal["circle"] = {"center": (c - origin).tolist(), "radius": radius}
    if "lanelets" in goal:
        if not isinstance(goal["lanelets"], list) or not goal["lanelets"]:
            raise ScenarioError(f"{path}: field {where}.lanelets should be a non-empty list of lanelet ids")
        goal["lanelets"] = list(_ids(goal, "lanelets", where, path))
    return goal
