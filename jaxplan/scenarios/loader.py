"""Loader of the shared scenario JSON (see ``../shared/data/README.md``).

Host side (numpy). A scenario is moved into a local frame: every coordinate is
shifted so that the ego start (the first planning problem's initial position)
is the origin. Malformed files raise ``ScenarioError`` naming the file and field.
"""
from __future__ import annotations

import dataclasses
import glob
import json
import math
import os
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.types import Obstacles


# Sizes (length, width) for road users the files give without one.
DEFAULT_SIZE = {"pedestrian": (0.6, 0.6), "bicycle": (1.8, 0.6)}


class ScenarioError(ValueError):
    """A scenario file that cannot be read; the message names the file and field."""


@dataclasses.dataclass(frozen=True)
class Lane:
    """A lanelet: bounds and centre line ``(P, 2)`` in the local frame."""

    id: int
    left: np.ndarray
    right: np.ndarray
    center: np.ndarray
    successors: tuple
    predecessors: tuple
    adjacent_left: int | None
    adjacent_right: int | None
    speed_limit: float | None


@dataclasses.dataclass(frozen=True)
class EgoState:
    x: float
    y: float
    heading: float
    v: float
    a: float = 0.0
    t: float = 0.0


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One scenario in the local frame.

    Attributes:
        obstacles: ``Obstacles`` with boxes ``(K, T, 5)`` at times ``t = k * dt``
            from the ego start; static obstacles repeat their box.
        obstacle_ids: ``(K,)`` ids of the recorded vehicles.
        origin: ``(2,)`` the world position moved to the origin.
        goal: the first goal of the planning problem, coordinates shifted.
        skipped: ids of obstacles without a usable shape or trajectory.
        problem_id: id of the planning problem whose start is the ego.
    """

    id: str
    source: str
    tags: tuple
    dt: float
    lanes: tuple
    obstacles: Obstacles
    obstacle_ids: np.ndarray
    obstacle_types: tuple
    ego: EgoState
    goal: dict
    origin: np.ndarray
    skipped: tuple = ()
    problem_id: int = 0

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
        raise ScenarioError(f"{path}: field {where}.{key} should be {getattr(kind, '__name__', kind)}, "
                            f"got {type(val).__name__}")
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


def load_scenario(path: str, horizon: float | None = None) -> Scenario:
    """Read one scenario JSON file into the local frame.

    Args:
        path: file path.
        horizon: keep obstacle predictions up to this time (s); default all.
    """
    try:
        with open(path) as f:
            d = json.load(f)
    except json.JSONDecodeError as e:
        raise ScenarioError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except UnicodeDecodeError:
        raise ScenarioError(f"{path}: not a UTF-8 text file") from None
    return parse_scenario(d, path, horizon)


def parse_scenario(d: Any, path: str, horizon: float | None = None) -> Scenario:
    """Build a ``Scenario`` from an already parsed scenario object (see ``load_scenario``).

    Args:
        d: the scenario object of the shared JSON format.
        path: name used in error messages.
    """
    if not isinstance(d, dict):
        raise ScenarioError(f"{path}: top level should be an object")
    dt = _number(d, "dt", "scenario", path)
    if dt <= 0:
        raise ScenarioError(f"{path}: field scenario.dt must be positive")
    problems = _field(d, "planning_problems", "scenario", path, list)
    if not problems:
        raise ScenarioError(f"{path}: field scenario.planning_problems is empty")
    init = _field(problems[0], "initial_state", "planning_problems[0]", path, dict)
    pos = _points([_field(init, "position", "planning_problems[0].initial_state", path)],
                  "planning_problems[0].initial_state.position", path)[0]
    w = "planning_problems[0].initial_state"
    t0 = float(init.get("t", 0.0))
    ego = EgoState(0.0, 0.0, _number(init, "orientation", w, path), _number(init, "velocity", w, path),
                   float(init.get("acceleration", 0.0)), 0.0)
    origin = pos

    lanes = []
    for i, ln in enumerate(_field(d, "lanelets", "scenario", path, list)):
        where = f"lanelets[{i}]"
        left = _points(_field(ln, "left", where, path), f"{where}.left", path, 2) - origin
        right = _points(_field(ln, "right", where, path), f"{where}.right", path, 2) - origin
        if left.shape != right.shape:
            raise ScenarioError(f"{path}: field {where}.left and .right differ in length")
        adj = lambda k: (ln.get(k) or {}).get("ref") if isinstance(ln.get(k), dict) and \
            (ln.get(k) or {}).get("drivingDir", "same") == "same" else None
        lanes.append(Lane(int(_field(ln, "id", where, path)), left, right, 0.5 * (left + right),
                          tuple(ln.get("successors", [])), tuple(ln.get("predecessors", [])),
                          adj("adjacentLeft"), adj("adjacentRight"), ln.get("speed_limit")))

    boxes, valids, ids, types, skipped = [], [], [], [], []
    obstacles = _field(d, "obstacles", "scenario", path, list)
    n_steps = 1
    for o in obstacles:
        if "states" in o and o["states"]:
            n_steps = max(n_steps, len(o["states"]))
    if horizon is not None:
        n_steps = min(n_steps, int(round(horizon / dt)) + 1)
    t = np.arange(n_steps) * dt
    for i, o in enumerate(obstacles):
        where = f"obstacles[{i}]"
        oid = _field(o, "id", where, path)
        b = np.zeros((n_steps, 5))
        ok = np.zeros(n_steps, bool)
        if o.get("states"):
            if "length" not in o and o.get("type") in DEFAULT_SIZE:
                length, width = DEFAULT_SIZE[o["type"]]  # the format gives no size for these
            else:
                length, width = _number(o, "length", where, path), _number(o, "width", where, path)
            if length <= 0 or width <= 0:
                raise ScenarioError(f"{path}: field {where}.length/width must be positive")
            st = np.asarray(o["states"], dtype=np.float64)
            if st.ndim != 2 or st.shape[1] < 4 or not np.all(np.isfinite(st[:, :4])):
                raise ScenarioError(f"{path}: field {where}.states should be rows [t, x, y, theta, ...]")
            k = np.rint((st[:, 0] - t0) / dt).astype(int)
            keep = (k >= 0) & (k < n_steps)
            b[k[keep]] = np.column_stack([st[keep, 1] - origin[0], st[keep, 2] - origin[1],
                                          np.full(keep.sum(), length), np.full(keep.sum(), width),
                                          st[keep, 3]])
            ok[k[keep]] = True
        elif "polygon" in o:
            poly = _points(o["polygon"], f"{where}.polygon", path, 3) - origin
            try:
                b[:] = _min_area_box(poly)
            except ValueError:
                raise ScenarioError(f"{path}: field {where}.polygon is degenerate") from None
            ok[:] = True
        elif "center" in o:
            c = _points([o["center"]], f"{where}.center", path)[0] - origin
            length, width = _number(o, "length", where, path), _number(o, "width", where, path)
            if length <= 0 or width <= 0:
                raise ScenarioError(f"{path}: field {where}.length/width must be positive")
            b[:] = [c[0], c[1], length, width, _number(o, "orientation", where, path)]
            ok[:] = True
        else:
            skipped.append(oid)
            continue
        boxes.append(b)
        valids.append(ok)
        ids.append(oid)
        types.append(o.get("type", "unknown"))
    K = len(boxes)
    obs = Obstacles(jnp.asarray(np.array(boxes).reshape(K, n_steps, 5), jnp.float32),
                    jnp.asarray(np.array(valids, bool).reshape(K, n_steps)), jnp.asarray(t, jnp.float32))
    goals = _field(problems[0], "goals", "planning_problems[0]", path, list)
    goal = dict(goals[0]) if goals else {}
    if "rectangle" in goal:
        r = dict(goal["rectangle"])
        r["center"] = (np.asarray(r["center"], float) - origin).tolist()
        goal["rectangle"] = r
    return Scenario(str(d.get("id", os.path.basename(path))), str(d.get("source", "")),
                    tuple(d.get("tags", [])), dt, tuple(lanes), obs, np.asarray(ids), tuple(types),
                    ego, goal, origin, tuple(skipped), int(problems[0].get("id", 0)))


def load_dir(directory: str, pattern: str = "*.json", **kw) -> list[Scenario]:
    """Load every scenario file in ``directory`` (sorted by name)."""
    files = sorted(glob.glob(os.path.join(directory, pattern)))
    if not files:
        raise ScenarioError(f"{directory}: no scenario files matching {pattern}")
    return [load_scenario(f, **kw) for f in files]


def lane_at(scenario: Scenario, xy, heading: float | None = None) -> Lane:
    """The lane whose centre line passes closest to ``xy`` (heading-compatible if given)."""
    xy = np.asarray(xy, float)
    best, best_d = None, np.inf
    for ln in scenario.lanes:
        c = ln.center
        seg = c[1:] - c[:-1]
        L2 = np.maximum(np.sum(seg * seg, 1), 1e-12)
        u = np.clip(np.sum((xy - c[:-1]) * seg, 1) / L2, 0, 1)
        dist = np.linalg.norm(c[:-1] + u[:, None] * seg - xy, axis=1)
        j = int(np.argmin(dist))
        if heading is not None:
            h = math.atan2(seg[j, 1], seg[j, 0])
            if math.cos(h - heading) < 0.5:
                continue
        if dist[j] < best_d:
            best, best_d = ln, dist[j]
    if best is None:
        raise ScenarioError(f"scenario {scenario.id}: no lane near {xy.tolist()}")
    return best


def lane_polyline(scenario: Scenario, lane: Lane | int | None = None, max_length: float = 500.0,
                  back: float = 20.0) -> np.ndarray:
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


def lane_reference(scenario: Scenario, lane: Lane | int | None = None, max_length: float = 500.0,
                   back: float = 20.0) -> ReferenceLine:
    """``ReferenceLine`` along ``lane_polyline(scenario, lane, max_length, back)``."""
    return ReferenceLine.from_polyline(lane_polyline(scenario, lane, max_length, back))
