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
"""

from __future__ import annotations

import dataclasses
import glob
import gzip
import json
import math
import os
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.scenarios.polylines import nearest_on_polyline
from jaxplan.types import FLOAT32_MAX_COORD, Obstacles

# Sizes (length, width) for road users the files give without one.
DEFAULT_SIZE = {"pedestrian": (0.6, 0.6), "bicycle": (1.8, 0.6)}

# CommonRoad's traffic light colors and directions (the values its XML and commonroad-io use).
LIGHT_COLORS = ("green", "yellow", "red", "redYellow", "inactive")
LIGHT_DIRECTIONS = {
    "right": ("right",),
    "straight": ("straight",),
    "left": ("left",),
    "leftStraight": ("left", "straight"),
    "straightRight": ("straight", "right"),
    "leftRight": ("left", "right"),
    "all": ("left", "straight", "right"),
}


class ScenarioError(ValueError):
    """A scenario file that cannot be read; the message names the file and field."""


@dataclasses.dataclass(frozen=True)
class Lane:
    """A lanelet: bounds and centre line ``(P, 2)`` in the local frame.

    ``adjacent_left`` / ``adjacent_right``: the neighbour driven the same way (a lane one
    may change into); ``opposite_left`` / ``opposite_right``: a neighbour driven the other way.
    """

    id: int
    left: np.ndarray
    right: np.ndarray
    center: np.ndarray
    successors: tuple
    predecessors: tuple
    adjacent_left: int | None
    adjacent_right: int | None
    speed_limit: float | None
    opposite_left: int | None = None  # the neighbour on the left driven the other way
    opposite_right: int | None = None
    traffic_lights: tuple = ()  # ids of the lights governing the lanelet (its own and its stop line's)
    stop_line: np.ndarray | None = None  # (2, 2) where they govern: the stop line, else the lanelet's end


@dataclasses.dataclass(frozen=True)
class EgoRecord:
    x: float
    y: float
    heading: float
    v: float
    a: float = 0.0
    t: float = 0.0


@dataclasses.dataclass(frozen=True)
class TrafficLight:
    """A traffic light on the scene's clock (step 0 = the ego's start).

    Attributes:
        id: its id.
        direction: one of ``LIGHT_DIRECTIONS`` (the movements it governs).
        active: False: ``inactive`` at every step.
        colors: the colors of the cycle's phases (``LIGHT_COLORS``).
        durations: each phase's length in steps (>= 1).
        offset: the step at which a cycle begins (the cycle repeats before and after it).
        position: ``(2,)`` where the light stands (local frame), or None.
    """

    id: int
    direction: str
    active: bool
    colors: tuple
    durations: tuple
    offset: int
    position: np.ndarray | None = None

    @property
    def period(self) -> int:
        """Steps of one cycle."""
        return int(sum(self.durations))

    def color_codes(self, steps) -> np.ndarray:
        """``(...)`` indices into ``LIGHT_COLORS`` of the light's color at integer scene ``steps (...)``
        (commonroad-io's ``TrafficLightCycle.get_state_at_time_step`` on the scene's clock)."""
        steps = np.asarray(steps, np.int64)
        if not self.active or not self.colors:
            return np.full(steps.shape, LIGHT_COLORS.index("inactive"), np.int32)
        ends = np.cumsum(self.durations)
        phase = np.searchsorted(ends, np.mod(steps - self.offset, self.period), side="right")
        return np.array([LIGHT_COLORS.index(c) for c in self.colors], np.int32)[phase]

    def color_at(self, step: int) -> str:
        """The light's color at scene step ``step``."""
        return LIGHT_COLORS[int(self.color_codes(step))]


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One scenario in the local frame.

    Attributes:
        obstacles: ``Obstacles`` with boxes ``(K, T, 5)`` at times ``t = k * dt``
            from the ego start; static obstacles (role ``static``, or given by a polygon
            or centre) repeat their box and carry ``static = True``, so they are held
            over any horizon; dynamic ones are invalid where their recording has no state.
        obstacle_ids: ``(K,)`` ids of the recorded vehicles.
        origin: ``(2,)`` the world position moved to the origin.
        goal: the first goal of the planning problem, coordinates shifted.
        skipped: ids of obstacles without a usable shape or trajectory.
        problem_id: id of the planning problem whose start is the ego.
        traffic_lights: ``TrafficLight``s of the map (lanelets name the ones governing them).
    """

    id: str
    source: str
    tags: tuple
    dt: float
    lanes: tuple
    obstacles: Obstacles
    obstacle_ids: np.ndarray
    obstacle_types: tuple
    ego: EgoRecord
    goal: dict
    origin: np.ndarray
    skipped: tuple = ()
    problem_id: int = 0
    traffic_lights: tuple = ()

    def lane(self, lane_id: int) -> Lane:
        for ln in self.lanes:
            if ln.id == lane_id:
                return ln
        raise KeyError(lane_id)


def _field(obj: dict, key: str, where: str, path: str, kind=None):
    if not isinstance(obj, dict) or key not in obj:
        raise ScenarioError(f"{path}: missing field {where}.{key}")
    val = obj[key]
    if kind is not None and not isinstance(val, kind):
        raise ScenarioError(
            f"{path}: field {where}.{key} should be {getattr(kind, '__name__', kind)}, got {type(val).__name__}"
        )
    return val


def _points(val, where: str, path: str, min_len: int = 1) -> np.ndarray:
    try:
        a = np.asarray(val, dtype=np.float64)
    except (TypeError, ValueError):
        raise ScenarioError(f"{path}: field {where} is not a list of [x, y] points") from None
    if a.ndim != 2 or a.shape[1] != 2 or len(a) < min_len:
        raise ScenarioError(f"{path}: field {where} should be >= {min_len} [x, y] points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ScenarioError(f"{path}: field {where} contains NaN or inf")
    return a


def _number(obj, key, where, path) -> float:
    v = _field(obj, key, where, path)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ScenarioError(f"{path}: field {where}.{key} should be a finite number, got {v!r}")
    return float(v)


# Bounds on fields that float32 arrays hold later (beyond them a scene would hold inf, or nonsense).
MAX_DT = 10.0  # s: the time step
MAX_ANGLE = 1e4  # rad: headings (unwrapped recordings turn a few times at most)


def _angle(obj, key, where, path) -> float:
    v = _number(obj, key, where, path)
    if abs(v) > MAX_ANGLE:
        raise ScenarioError(f"{path}: field {where}.{key} should be an angle within +-{MAX_ANGLE:g} rad, got {v!r}")
    return v


def _min_area_box(poly: np.ndarray) -> np.ndarray:
    """Smallest oriented box ``(5,)`` around a polygon (edge-aligned search)."""
    p = poly[:-1] if np.allclose(poly[0], poly[-1]) else poly
    best = None
    for i in range(len(p)):
        e = p[(i + 1) % len(p)] - p[i]
        if np.linalg.norm(e) < 1e-9:
            continue
        th = math.atan2(e[1], e[0])
        c, s = math.cos(th), math.sin(th)
        u = p @ np.array([c, s])
        w = p @ np.array([-s, c])
        area = np.ptp(u) * np.ptp(w)
        if best is None or area < best[0]:
            cu, cw = 0.5 * (u.max() + u.min()), 0.5 * (w.max() + w.min())
            best = (area, [cu * c - cw * s, cu * s + cw * c, np.ptp(u), np.ptp(w), th])
    if best is None:
        raise ValueError("degenerate polygon")
    return np.asarray(best[1])


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


def _int(obj, key, where, path) -> int:
    v = _field(obj, key, where, path)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v):
        raise ScenarioError(f"{path}: field {where}.{key} should be an integer, got {v!r}")
    return int(v)


def _ids(obj, key, where, path) -> tuple:
    """An optional list of integer ids (missing or null means none)."""
    v = obj.get(key) if isinstance(obj, dict) else None
    if v is None:
        return ()
    if not isinstance(v, list):
        raise ScenarioError(f"{path}: field {where}.{key} should be a list of ids")
    return tuple(_int({key: x}, key, where, path) for x in v)


def _adjacent(ln: dict, key: str, where: str, path: str, same: bool = True) -> int | None:
    """Id of the neighbour lanelet driven the same way (``same``) or the other way, or None."""
    v = ln.get(key)
    if v is None:
        return None
    if not isinstance(v, dict):
        raise ScenarioError(f"{path}: field {where}.{key} should be an object")
    direction = v.get("drivingDir", "same")
    if direction not in ("same", "opposite"):
        raise ScenarioError(f"{path}: field {where}.{key}.drivingDir should be 'same' or 'opposite', got {direction!r}")
    if (direction == "same") != same:
        return None
    return _int(v, "ref", f"{where}.{key}", path)


def _size(o, where, path) -> tuple[float, float]:
    kind = o.get("type")
    if "length" not in o and isinstance(kind, str) and kind in DEFAULT_SIZE:
        return DEFAULT_SIZE[kind]  # the format gives no size for these
    length, width = _number(o, "length", where, path), _number(o, "width", where, path)
    if length <= 0 or width <= 0:
        raise ScenarioError(f"{path}: field {where}.length/width must be positive")
    if max(length, width) > FLOAT32_MAX_COORD:
        raise ScenarioError(
            f"{path}: field {where}.length/width must be at most {FLOAT32_MAX_COORD:g} m, got {length!r} / {width!r}"
        )
    return length, width


def _states(o, where, path) -> np.ndarray:
    st = o["states"]
    try:
        st = np.asarray(st, dtype=np.float64)
    except (TypeError, ValueError):
        st = None
    if st is None or st.ndim != 2 or st.shape[1] < 4 or not np.all(np.isfinite(st[:, :4])):
        raise ScenarioError(f"{path}: field {where}.states should be rows of finite [t, x, y, theta, ...]")
    if np.abs(st[:, 3]).max() > MAX_ANGLE:
        raise ScenarioError(f"{path}: field {where}.states has a heading (column 3) beyond +-{MAX_ANGLE:g} rad")
    return st


def _occupancies(o, where, path) -> np.ndarray:
    """``(N, 6)`` rows ``[t, x, y, length, width, heading]`` of an obstacle's ``occupancies``."""
    rows = o["occupancies"]
    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.ndim != 2 or a.shape[1] != 6 or not len(a) or not np.all(np.isfinite(a)):
        raise ScenarioError(
            f"{path}: field {where}.occupancies should be rows of finite [t, x, y, length, width, heading]"
        )
    if np.any(a[:, 3:5] <= 0) or a[:, 3:5].max() > FLOAT32_MAX_COORD:
        raise ScenarioError(
            f"{path}: field {where}.occupancies has a length or width that is not positive "
            f"or above {FLOAT32_MAX_COORD:g} m"
        )
    if np.abs(a[:, 5]).max() > MAX_ANGLE:
        raise ScenarioError(f"{path}: field {where}.occupancies has a heading (column 5) beyond +-{MAX_ANGLE:g} rad")
    return a


def _traffic_lights(d: dict, dt: float, t0: float, origin: np.ndarray, path: str) -> tuple:
    """The scenario's ``TrafficLight``s (optional field ``traffic_lights``), on the scene's clock."""
    raw = d.get("traffic_lights")
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError(f"{path}: field scenario.traffic_lights should be a list of objects")
    out, seen = [], set()
    for i, tl in enumerate(raw):
        where = f"traffic_lights[{i}]"
        if not isinstance(tl, dict):
            raise ScenarioError(f"{path}: field {where} should be an object")
        lid = _int(tl, "id", where, path)
        if lid in seen:
            raise ScenarioError(f"{path}: field {where}.id {lid} is used by another traffic light")
        seen.add(lid)
        direction = tl.get("direction", "all")
        if direction not in LIGHT_DIRECTIONS:
            raise ScenarioError(
                f"{path}: field {where}.direction should be one of {', '.join(LIGHT_DIRECTIONS)}, got {direction!r}"
            )
        active = tl.get("active", True)
        if not isinstance(active, bool):
            raise ScenarioError(f"{path}: field {where}.active should be true or false, got {active!r}")
        offset = _number(tl, "time_offset", where, path) if tl.get("time_offset") is not None else 0.0
        cycle = tl.get("cycle") or []
        if not isinstance(cycle, list):
            raise ScenarioError(f"{path}: field {where}.cycle should be a list of {{color, duration}} phases")
        if active and not cycle:
            raise ScenarioError(f"{path}: field {where}.cycle is empty (an active light needs its phases)")
        colors, durations = [], []
        for j, ph in enumerate(cycle):
            w = f"{where}.cycle[{j}]"
            if not isinstance(ph, dict):
                raise ScenarioError(f"{path}: field {w} should be an object {{color, duration}}")
            color = ph.get("color")
            if color not in LIGHT_COLORS:
                raise ScenarioError(
                    f"{path}: field {w}.color should be one of {', '.join(LIGHT_COLORS)}, got {color!r}"
                )
            dur = _number(ph, "duration", w, path)
            steps = int(round(dur / dt))
            if dur <= 0 or steps < 1 or steps > 1e7:
                raise ScenarioError(
                    f"{path}: field {w}.duration should be at least one time step ({dt:g} s) and finite, got {dur!r}"
                )
            colors.append(color)
            durations.append(steps)
        pos = None
        if tl.get("position") is not None:
            pos = _points([tl["position"]], f"{where}.position", path)[0] - origin
        out.append(
            TrafficLight(lid, direction, active, tuple(colors), tuple(durations), int(round((offset - t0) / dt)), pos)
        )
    return tuple(out)


def _lane_lights(
    ln: dict, where: str, path: str, left: np.ndarray, right: np.ndarray, origin: np.ndarray, known: set
) -> tuple:
    """``(light ids, stop line (2, 2) or None)`` of a lanelet (optional ``traffic_lights`` and ``stop_line``)."""
    ids = set(_ids(ln, "traffic_lights", where, path))
    sl = ln.get("stop_line")
    line = None
    if sl is not None:
        w = f"{where}.stop_line"
        if not isinstance(sl, dict):
            raise ScenarioError(f"{path}: field {w} should be an object {{start, end, traffic_lights}}")
        ids |= set(_ids(sl, "traffic_lights", w, path))
        has = [sl.get(k) is not None for k in ("start", "end")]
        if any(has) and not all(has):
            raise ScenarioError(f"{path}: field {w} gives only one of start and end")
        if all(has):
            line = (
                np.stack([_points([sl["start"]], f"{w}.start", path)[0], _points([sl["end"]], f"{w}.end", path)[0]])
                - origin
            )
    missing = sorted(ids - known)
    if missing:
        raise ScenarioError(f"{path}: field {where}.traffic_lights names traffic lights that do not exist: {missing}")
    if line is None and (sl is not None or ids):  # the line lies across the lanelet's end
        line = np.stack([left[-1], right[-1]])
    return tuple(sorted(ids)), line


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

    lanes = []
    for i, ln in enumerate(_field(d, "lanelets", "scenario", path, list)):
        where = f"lanelets[{i}]"
        left = _points(_field(ln, "left", where, path), f"{where}.left", path, 2) - origin
        right = _points(_field(ln, "right", where, path), f"{where}.right", path, 2) - origin
        if left.shape != right.shape:
            raise ScenarioError(f"{path}: field {where}.left and .right differ in length")
        limit = ln.get("speed_limit")
        if limit is not None:
            limit = _number(ln, "speed_limit", where, path)
        refs, stop_line = _lane_lights(ln, where, path, left, right, origin, light_ids)
        lanes.append(
            Lane(
                _int(ln, "id", where, path),
                left,
                right,
                0.5 * (left + right),
                _ids(ln, "successors", where, path),
                _ids(ln, "predecessors", where, path),
                _adjacent(ln, "adjacentLeft", where, path),
                _adjacent(ln, "adjacentRight", where, path),
                limit,
                _adjacent(ln, "adjacentLeft", where, path, same=False),
                _adjacent(ln, "adjacentRight", where, path, same=False),
                refs,
                stop_line,
            )
        )

    obstacles = _field(d, "obstacles", "scenario", path, list)
    for i, o in enumerate(obstacles):
        if not isinstance(o, dict):
            raise ScenarioError(f"{path}: field obstacles[{i}] should be an object")
    occupied = {}
    for i, o in enumerate(obstacles):
        if o.get("occupancies") is not None:
            if o.get("states"):
                raise ScenarioError(f"{path}: field obstacles[{i}] gives both states and occupancies (one of them)")
            occupied[i] = _occupancies(o, f"obstacles[{i}]", path)
    states = {i: _states(o, f"obstacles[{i}]", path) for i, o in enumerate(obstacles) if o.get("states")}
    n_steps = max(
        [1]
        + [len(st) for st in states.values()]
        + [int(np.rint((oc[:, 0].max() - t0) / dt)) + 1 for oc in occupied.values()]
    )
    if horizon is not None:
        n_steps = min(n_steps, int(round(horizon / dt)) + 1)
    t = np.arange(n_steps) * dt
    boxes, valids, statics, ids, types, skipped = [], [], [], [], [], []
    from jaxplan.scenarios.scene import OBSTACLE_TYPES as known_types

    unknown_types = set()
    for i, o in enumerate(obstacles):
        where = f"obstacles[{i}]"
        oid = _int(o, "id", where, path)
        role = o.get("role", "dynamic")
        if role not in ("dynamic", "static"):
            raise ScenarioError(f"{path}: field {where}.role should be 'dynamic' or 'static', got {role!r}")
        b = np.zeros((n_steps, 5))
        ok = np.zeros(n_steps, bool)
        static = role == "static" or (i not in states and i not in occupied)  # polygon / centre: no motion
        if i in occupied:  # one box per step (set-based predictions)
            if role == "static":
                raise ScenarioError(f"{path}: field {where}.occupancies belong to a dynamic obstacle, not a static one")
            oc = occupied[i]
            k = np.rint((oc[:, 0] - t0) / dt).astype(int)
            if len(np.unique(k)) != len(k):
                raise ScenarioError(f"{path}: field {where}.occupancies has two rows for one time step")
            keep = (k >= 0) & (k < n_steps)
            b[k[keep]] = np.column_stack([oc[keep, 1] - origin[0], oc[keep, 2] - origin[1], oc[keep, 3:6]])
            ok[k[keep]] = True
        elif i in states and static:  # a static obstacle: its first recorded pose, held at every time
            length, width = _size(o, where, path)
            st = states[i]
            b[:] = [st[0, 1] - origin[0], st[0, 2] - origin[1], length, width, st[0, 3]]
            ok[:] = True
        elif i in states:
            length, width = _size(o, where, path)
            st = states[i]
            k = np.rint((st[:, 0] - t0) / dt)
            keep = (k >= 0) & (k < n_steps)
            k = k[keep].astype(int)
            b[k] = np.column_stack(
                [
                    st[keep, 1] - origin[0],
                    st[keep, 2] - origin[1],
                    np.full(keep.sum(), length),
                    np.full(keep.sum(), width),
                    st[keep, 3],
                ]
            )
            ok[k] = True
        elif "polygon" in o:
            poly = _points(o["polygon"], f"{where}.polygon", path, 3) - origin
            try:
                b[:] = _min_area_box(poly)
            except ValueError:
                raise ScenarioError(f"{path}: field {where}.polygon is degenerate") from None
            ok[:] = True
        elif "center" in o:
            c = _points([o["center"]], f"{where}.center", path)[0] - origin
            length, width = _size(o, where, path)
            b[:] = [c[0], c[1], length, width, _angle(o, "orientation", where, path)]
            ok[:] = True
        else:
            skipped.append(oid)
            continue
        if np.abs(b[ok][:, :2]).max(initial=0.0) > FLOAT32_MAX_COORD:
            raise ScenarioError(f"{path}: field {where} lies more than {FLOAT32_MAX_COORD:.0e} m from the ego start")
        boxes.append(b)
        valids.append(ok)
        statics.append(static)
        ids.append(oid)
        kind = str(o.get("type", "unknown"))
        if kind not in known_types:
            unknown_types.add(kind)
            kind = "unknown"
        types.append(kind)
    notes = list(notes or [])
    if unknown_types:
        notes.append(f"obstacle types {', '.join(sorted(unknown_types))} read as 'unknown'")
    if skipped:
        notes.append(f"obstacles {', '.join(map(str, skipped))} left out (no shape and no trajectory)")
    if notes and not quiet:
        import sys

        print(f"jaxplan: {path}: {'; '.join(notes)}", file=sys.stderr)
    K = len(boxes)
    obs = Obstacles(
        jnp.asarray(np.array(boxes).reshape(K, n_steps, 5), jnp.float32),
        jnp.asarray(np.array(valids, bool).reshape(K, n_steps)),
        jnp.asarray(t, jnp.float32),
        jnp.asarray(np.array(statics, bool).reshape(K)),
    )
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

    Suites use ``load_folder``, which skips bad files and names them."""
    return [load_scenario(f, **kw) for f in scenario_files(directory, pattern)]


@dataclasses.dataclass(frozen=True)
class Folder:
    """Scenarios loaded from a folder by ``load_folder``.

    Attributes:
        directory: the folder.
        scenarios: the scenarios that loaded, in file-name order.
        files: their files.
        skipped: ``(file, reason)`` of every file that did not load.
    """

    directory: str
    scenarios: tuple
    files: tuple
    skipped: tuple

    def __len__(self) -> int:
        return len(self.scenarios)


def load_folder(
    directory: str, pattern: str = "*.json", horizon: float | None = None, limit: int | None = None, stderr=None
) -> Folder:
    """Every loadable scenario of a folder; each file that fails is named on stderr and counted.

    The one loading path of every suite that reads ``--scenarios DIR`` (their metrics
    report ``skipped_files = len(folder.skipped)``).

    Args:
        directory: folder of scenario files.
        pattern: file-name pattern.
        horizon: keep obstacle predictions up to this time (s); default all.
        limit: read at most this many files (the first by name).
        stderr: where skipped files are named (default ``sys.stderr``).

    Raises:
        ScenarioError: the folder does not exist, holds no matching file, or none of them loads.
    """
    import sys

    out = sys.stderr if stderr is None else stderr
    files = scenario_files(directory, pattern)[:limit]
    scenarios, loaded, skipped = [], [], []
    for f in files:
        try:
            scenarios.append(load_scenario(f, horizon=horizon))
            loaded.append(f)
        except ScenarioError as e:
            skipped.append((f, str(e)))
            print(f"jaxplan: skipping {e}", file=out)
    if not scenarios:
        raise ScenarioError(
            f"{directory}: none of its {len(files)} scenario files could be loaded (first: {skipped[0][1]})"
        )
    return Folder(directory, tuple(scenarios), tuple(loaded), tuple(skipped))


def first_loadable(directory: str, pattern: str = "*.json") -> str:
    """The first file of a folder that loads (a cheap check before heavy work); a
    ``ScenarioError`` names the folder when none does."""
    files = scenario_files(directory, pattern)
    first = None
    for f in files:
        try:
            load_scenario(f)
            return f
        except ScenarioError as e:
            first = first or str(e)
    raise ScenarioError(f"{directory}: none of its {len(files)} scenario files could be loaded (first: {first})")


def lane_at(scenario: Scenario, xy, heading: float | None = None) -> Lane:
    """The lane whose centre line passes closest to ``xy`` (heading-compatible if given)."""
    xy = np.asarray(xy, float)
    best, best_d = None, np.inf
    for ln in scenario.lanes:
        j, _, dist = nearest_on_polyline(ln.center, xy)
        if heading is not None:
            seg = ln.center[j + 1] - ln.center[j]
            if math.cos(math.atan2(seg[1], seg[0]) - heading) < 0.5:
                continue
        if dist < best_d:
            best, best_d = ln, dist
    if best is None:
        raise ScenarioError(f"scenario {scenario.id}: no lane near {xy.tolist()}")
    return best


def lane_polyline(
    scenario: Scenario, lane: Lane | int | None = None, max_length: float = 500.0, back: float = 20.0
) -> np.ndarray:
    """Centre-line points ``(P, 2)`` along a lane, following one predecessor back (when
    ``back > 0``) and successors forward (first unvisited one each time) up to ``max_length``.

    Default lane: the one at the ego start.
    """
    if lane is None:
        lane = lane_at(scenario, [scenario.ego.x, scenario.ego.y], scenario.ego.heading)
    elif isinstance(lane, int):
        lane = scenario.lane(lane)
    by_id = {ln.id: ln for ln in scenario.lanes}
    pts = [lane.center]
    seen = {lane.id}
    cur = lane
    if cur.predecessors and cur.predecessors[0] in by_id and back > 0:
        pts.insert(0, by_id[cur.predecessors[0]].center)
        seen.add(cur.predecessors[0])
    total = sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in pts)
    while total < max_length and cur.successors:
        nxt = next((by_id[s] for s in cur.successors if s in by_id and s not in seen), None)
        if nxt is None:
            break
        pts.append(nxt.center)
        seen.add(nxt.id)
        total += np.linalg.norm(np.diff(nxt.center, axis=0), axis=1).sum()
        cur = nxt
    return np.concatenate(pts)


def lane_reference(
    scenario: Scenario, lane: Lane | int | None = None, max_length: float = 500.0, back: float = 20.0
) -> ReferenceLine:
    """``ReferenceLine`` along ``lane_polyline(scenario, lane, max_length, back)``."""
    return ReferenceLine.from_polyline(lane_polyline(scenario, lane, max_length, back))
