"""Loader of the shared scenario JSON (see ``../shared/data/README.md``).

Host side (numpy). A scenario is moved into a local frame: every coordinate is
shifted so that the ego start (the first planning problem's initial position)
is the origin. Malformed files raise ``ScenarioError`` naming the file and field.

Beyond the fields the shared format's README lists, the loader reads (all optional):

- ``traffic_lights``: ``[{"id", "direction", "active", "time_offset", "cycle", "position"}]``,
  CommonRoad's traffic lights: ``cycle`` is a list of phases ``{"color", "duration"}`` (colors
  ``LIGHT_COLORS``, durations in seconds, each at least one ``dt``) repeated from ``time_offset``
  (seconds on the scenario's clock) on, and before it; ``direction`` one of ``LIGHT_DIRECTIONS``
  (default ``all``); ``active`` (default true; an inactive light is ``inactive`` at every step).
- a lanelet's ``traffic_lights`` (ids of the lights it references) and ``stop_line``
  (``{"start", "end", "traffic_lights"}``; without points the line lies across the lanelet's end).
  A lanelet that references lights without a stop line stops at its end.
- an obstacle's ``occupancies`` instead of ``states``: rows ``[t, x, y, length, width, heading]``,
  one box per time step (CommonRoad's set-based predictions, each occupancy's covering box).

Obstacle types that ``jaxplan.scenarios.scene.OBSTACLE_TYPES`` does not name are read as
``unknown``; those types, and obstacles left out for want of a shape or a trajectory, are named
in one line on stderr per file.

The loader reads files and folders and puts a scenario together; its parts are read by
``parse_road`` (lanelets, traffic lights, stop lines), ``parse_obstacles``, ``parse_goal``, with
the field checks of ``fields``, into the types of ``scenario``.
"""

from __future__ import annotations

import glob
import gzip
import json
import os
import sys
from typing import Any

import numpy as np

from jaxplan.scenarios.fields import (
    MAX_ANGLE,
    MAX_DT,
    ScenarioError,
    _angle,
    _field,
    _int,
    _number,
    _points,
)
from jaxplan.scenarios.parse_goal import GOAL_INTERVALS, GOAL_POSITIONS, _goal
from jaxplan.scenarios.parse_obstacles import DEFAULT_SIZE, _obstacles
from jaxplan.scenarios.parse_road import _lanes, _traffic_lights
from jaxplan.scenarios.scenario import (
    LIGHT_COLORS,
    LIGHT_DIRECTIONS,
    EgoRecord,
    Lane,
    Scenario,
    TrafficLight,
    lane_at,
    lane_polyline,
    lane_reference,
)

__all__ = [
    "DEFAULT_SIZE",
    "GOAL_INTERVALS",
    "GOAL_POSITIONS",
    "LIGHT_COLORS",
    "LIGHT_DIRECTIONS",
    "MAX_ANGLE",
    "MAX_DT",
    "EgoRecord",
    "Lane",
    "Scenario",
    "ScenarioError",
    "TrafficLight",
    "lane_at",
    "lane_polyline",
    "lane_reference",
    "load_dir",
    "load_scenario",
    "parse_scenario",
    "read_bytes",
    "scenario_files",
]


def read_bytes(path: str) -> bytes:
    """The file's content, decompressed when its name ends in ``.gz``.

    Raises:
        ScenarioError: the file is missing, unreadable or not valid gzip.
    """
    try:
        if path.lower().endswith(".gz"):
            with gzip.open(path, "rb") as f:
                return f.read()
        with open(path, "rb") as f:
            return f.read()
    except FileNotFoundError:
        raise ScenarioError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ScenarioError(f"{path}: is a folder, not a scenario file") from None
    except PermissionError:
        raise ScenarioError(f"{path}: not readable (permission denied)") from None
    except (OSError, EOFError) as e:  # gzip.BadGzipFile is an OSError
        raise ScenarioError(f"{path}: not a readable gzip file ({e})") from None


def load_scenario(path: str, horizon: float | None = None) -> Scenario:
    """Read one scenario JSON file (``.json``, or gzip-compressed ``.json.gz``) into the local frame.

    Args:
        path: file path.
        horizon: keep obstacle predictions up to this time (s); default all.
    """
    raw = read_bytes(path)
    try:
        d = json.loads(raw)
    except json.JSONDecodeError as e:
        raise ScenarioError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: not a UTF-8 text file") from None
    return parse_scenario(d, path, horizon)


def parse_scenario(
    d: Any, path: str, horizon: float | None = None, notes: list | None = None, quiet: bool = False
) -> Scenario:
    """Build a ``Scenario`` from an already parsed scenario object (see ``load_scenario``).

    Args:
        d: the scenario object of the shared JSON format (with the optional fields of the module
            docstring: traffic lights, stop lines, occupancies).
        path: name used in error messages.
        horizon: keep obstacle predictions up to this time (s); default all.
        notes: what a converter already left out or changed (``commonroad_to_dict``); printed with
            this function's own (obstacles skipped, types read as ``unknown``) in one line on stderr.
        quiet: print nothing (a check of an object that is not being loaded).
    """
    if not isinstance(d, dict):
        raise ScenarioError(f"{path}: top level should be an object")
    dt = _number(d, "dt", "scenario", path)
    if not 0 < dt <= MAX_DT:
        raise ScenarioError(f"{path}: field scenario.dt must be positive and at most {MAX_DT:g} s, got {dt!r}")
    problems = _field(d, "planning_problems", "scenario", path, list)
    if not problems:
        raise ScenarioError(f"{path}: field scenario.planning_problems is empty")
    w = "planning_problems[0].initial_state"
    init = _field(problems[0], "initial_state", "planning_problems[0]", path, dict)
    origin = _points([_field(init, "position", w, path)], f"{w}.position", path)[0]
    t0 = _number(init, "t", w, path) if "t" in init else 0.0
    a0 = _number(init, "acceleration", w, path) if init.get("acceleration") is not None else 0.0
    v0 = _number(init, "velocity", w, path)
    if v0 < 0:
        raise ScenarioError(f"{path}: field {w}.velocity must be >= 0 (the car drives forward), got {v0:g}")
    ego = EgoRecord(0.0, 0.0, _angle(init, "orientation", w, path), v0, a0, 0.0)
    lights = _traffic_lights(d, dt, t0, origin, path)
    light_ids = {tl.id for tl in lights}

    lanes = _lanes(d, origin, light_ids, path)
    obs, ids, types, skipped, unknown_types = _obstacles(d, dt, t0, origin, horizon, path)
    notes = list(notes or [])
    if unknown_types:
        notes.append(f"obstacle types {', '.join(sorted(unknown_types))} read as 'unknown'")
    if skipped:
        notes.append(f"obstacles {', '.join(map(str, skipped))} left out (no shape and no trajectory)")
    if notes and not quiet:
        print(f"jaxplan: {path}: {'; '.join(notes)}", file=sys.stderr)
    tags = d.get("tags") or []
    return Scenario(
        str(d.get("id", os.path.basename(path))),
        str(d.get("source", "")),
        tuple(map(str, tags)) if isinstance(tags, list) else (),
        dt,
        tuple(lanes),
        obs,
        np.asarray(ids),
        tuple(types),
        ego,
        _goal(problems[0], origin, path, t0),
        origin,
        tuple(skipped),
        _int(problems[0], "id", "planning_problems[0]", path) if "id" in problems[0] else 0,
        lights,
    )


def scenario_files(directory: str, pattern: str = "*.json") -> list[str]:
    """The scenario files of a folder (sorted by name); a ``ScenarioError`` names a folder
    that does not exist, is a file, or holds no file matching ``pattern``."""
    if not os.path.exists(directory):
        raise ScenarioError(f"{directory}: no such folder")
    if not os.path.isdir(directory):
        raise ScenarioError(f"{directory}: is a file, not a folder of scenarios")
    files = sorted(f for f in glob.glob(os.path.join(directory, pattern)) if os.path.isfile(f))
    if not files:
        raise ScenarioError(f"{directory}: no scenario files matching {pattern}")
    return files


def load_dir(directory: str, pattern: str = "*.json", **kw) -> list[Scenario]:
    """Load every scenario file in ``directory`` (sorted by name); the first bad file raises.

    Suites use ``jaxplan.scenarios.files.load_folder``, which reads every format and skips bad
    files, naming them."""
    return [load_scenario(f, **kw) for f in scenario_files(directory, pattern)]
