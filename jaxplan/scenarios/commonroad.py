"""Native CommonRoad XML (2020a) in and out, through ``commonroad-io``.

Optional: ``pip install jaxplan[commonroad]``. A CommonRoad scenario is converted to
the shared JSON object and parsed by ``loader.parse_scenario``, so both formats end in
the same ``Scenario`` (local frame, same checks, same errors).

What a file holds is read or refused out loud:

- traffic lights (cycle, offset, direction, active) and the lanelets' references to them and
  stop lines (``loader`` module docstring: the optional fields);
- every obstacle keeps its own shape as the smallest oriented box covering it (``cover_box``:
  rectangles exactly, circles as the square of their diameter, polygons and shape groups by their
  smallest covering box), turned to lie along the obstacle's heading;
- dynamic obstacles with a trajectory become recorded states; those with a set-based prediction
  become one box per occupied time step (``occupancies``; occupancies sharing a step are covered
  by one box); a shape that cannot be covered is refused with a line naming the obstacle;
- environment and phantom obstacles (commonroad-io 2022 and later) are not read: named on stderr.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.loader import parse_scenario, read_bytes
from jaxplan.scenarios.parse_obstacles import _min_area_box
from jaxplan.scenarios.scenario import Scenario


def _require():
    try:
        import commonroad  # noqa: F401
    except ImportError:
        raise ImportError("CommonRoad XML needs the optional extra: pip install 'jaxplan[commonroad]'") from None


def _point(p) -> np.ndarray:
    """A CommonRoad centre (array, shapely Point or None) as ``(2,)``."""
    if p is None or callable(p):
        return np.zeros(2)
    if hasattr(p, "x") and hasattr(p, "y"):
        return np.array([float(p.x), float(p.y)])
    return np.asarray(p, float).reshape(2)


def _shape_fields(shape) -> dict:
    """Length/width/centre/orientation of a CommonRoad shape or occupancy, or its polygon.

    Duck-typed: commonroad-io renamed its shape classes across releases.
    """
    group = getattr(shape, "occupancies", None) or getattr(shape, "shapes", None)
    if group:
        shape = group[0]
    if hasattr(shape, "length") and hasattr(shape, "width"):
        c = getattr(shape, "rect_center", None)
        c = getattr(shape, "center", None) if c is None else c
        c = _point(c)
        return {
            "length": float(shape.length),
            "width": float(shape.width),
            "center": c.tolist(),
            "orientation": float(getattr(shape, "orientation", 0.0) or 0.0),
        }
    if hasattr(shape, "radius"):
        c = _point(getattr(shape, "center", None))
        return {
            "length": 2 * float(shape.radius),
            "width": 2 * float(shape.radius),
            "center": c.tolist(),
            "orientation": 0.0,
        }
    if hasattr(shape, "vertices"):
        return {"polygon": np.asarray(shape.vertices, float).tolist()}
    raise ScenarioError(f"unsupported CommonRoad shape {type(shape).__name__}")


CIRCLE_SIDES = 16  # a circle inside a shape group is covered through its circumscribed 16-gon


def _outline(shape) -> np.ndarray:
    """``(N, 2)`` points whose covering box covers ``shape`` (a rectangle, circle, polygon or group)."""
    group = getattr(shape, "shapes", None) or getattr(shape, "occupancies", None)
    if group:
        return np.concatenate([_outline(s) for s in group])
    if hasattr(shape, "length") and hasattr(shape, "width"):
        c = getattr(shape, "rect_center", None)
        c = _point(getattr(shape, "center", None) if c is None else c)
        th = float(getattr(shape, "orientation", 0.0) or 0.0)
        u, w = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])
        hl, hw = 0.5 * float(shape.length), 0.5 * float(shape.width)
        return np.array([c + a * hl * u + b * hw * w for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
    if hasattr(shape, "radius"):
        a = np.arange(CIRCLE_SIDES) * 2 * np.pi / CIRCLE_SIDES
        r = float(shape.radius) / math.cos(np.pi / CIRCLE_SIDES)
        return _point(getattr(shape, "center", None)) + r * np.column_stack([np.cos(a), np.sin(a)])
    if hasattr(shape, "vertices"):
        return np.asarray(shape.vertices, float).reshape(-1, 2)
    raise ScenarioError(f"unsupported CommonRoad shape {type(shape).__name__}")


def _toward(box: np.ndarray, heading: float) -> np.ndarray:
    """The same box ``[x, y, length, width, theta]`` with ``theta`` the one of its four equivalent
    orientations (quarter turns, length and width swapped on odd ones) nearest ``heading``."""
    best: tuple[float, np.ndarray] | None = None
    for k in range(4):
        th = box[4] + k * np.pi / 2
        d = math.remainder(th - heading, 2 * np.pi)
        if best is None or abs(d) < abs(best[0]) - 1e-12:
            L, W = (box[2], box[3]) if k % 2 == 0 else (box[3], box[2])
            best = (d, np.array([box[0], box[1], L, W, heading + d]))
    assert best is not None  # the first of the four orientations always sets it
    return best[1]


def cover_box(shape, heading: float = 0.0) -> np.ndarray:
    """The smallest oriented box ``(5,)`` ``[x, y, length, width, theta]`` covering a CommonRoad shape:
    a rectangle itself, a circle the square of its diameter (at ``heading``), a polygon or a shape
    group the smallest box around their outlines (``parse_obstacles._min_area_box``); ``theta`` within 45 degrees
    of ``heading`` (length along it).

    Raises:
        ScenarioError: a shape kind commonroad-io has that is none of these, or a degenerate polygon.
    """
    group = getattr(shape, "shapes", None) or getattr(shape, "occupancies", None)
    if group and len(group) == 1:
        shape, group = group[0], None
    if not group and hasattr(shape, "radius") and not hasattr(shape, "length"):
        c, d = _point(getattr(shape, "center", None)), 2 * float(shape.radius)
        return np.array([c[0], c[1], d, d, heading])
    if not group and hasattr(shape, "length") and hasattr(shape, "width"):
        f = _shape_fields(shape)
        box = np.array([*f["center"], f["length"], f["width"], f["orientation"]])
    else:
        pts = _outline(shape)
        try:
            box = _min_area_box(pts)
        except ValueError:
            raise ScenarioError(f"degenerate {type(shape).__name__} (its points lie on a line)") from None
        if box[2] <= 1e-9 or box[3] <= 1e-9:
            raise ScenarioError(f"degenerate {type(shape).__name__} (its points lie on a line)")
    return _toward(box, heading)


def _placed(box: np.ndarray, x: float, y: float, theta: float) -> np.ndarray:
    """A box given in an obstacle's own frame, placed by its state ``(x, y, theta)``."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([x + c * box[0] - s * box[1], y + s * box[0] + c * box[1], box[2], box[3], box[4] + theta])


def _occupancy_rows(o, dt: float) -> list:
    """``[t, x, y, length, width, theta]`` per occupied time step of a set-based obstacle (its initial
    state's box first); occupancies that share a step are covered by one box."""
    init = o.initial_state
    hint = float(init.orientation)
    by_step: dict = {}
    by_step.setdefault(int(init.time_step), []).append(
        _placed(cover_box(o.obstacle_shape), float(init.position[0]), float(init.position[1]), hint)
    )
    for occ in o.prediction.occupancy_set:
        ts = occ.time_step
        steps = range(int(ts.start), int(ts.end) + 1) if hasattr(ts, "start") else [int(ts)]
        try:
            box = cover_box(occ.shape, hint)
        except ScenarioError as e:
            raise ScenarioError(f"dynamic obstacle {o.obstacle_id}: occupancy at time step {ts}: {e}") from None
        for k in steps:
            by_step.setdefault(k, []).append(box)
    rows = []
    for k in sorted(by_step):
        boxes = by_step[k]
        if len(boxes) > 1:
            corners = np.concatenate([_outline(_BoxShape(b)) for b in boxes])
            b = _toward(_min_area_box(corners), hint)
        else:
            b = boxes[0]
        rows.append([k * dt, float(b[0]), float(b[1]), float(b[2]), float(b[3]), float(b[4])])
    return rows


class _BoxShape:
    """A box ``[x, y, length, width, theta]`` seen as a rectangle shape (for ``_outline``)."""

    def __init__(self, b):
        self.center, self.length, self.width, self.orientation = np.asarray(b[:2]), b[2], b[3], b[4]


def _traffic_lights(net, dt: float) -> list:
    """The lanelet network's traffic lights as shared-format objects (times in seconds)."""
    out = []
    for tl in getattr(net, "traffic_lights", None) or ():
        cyc = getattr(tl, "traffic_light_cycle", None)
        elements = list(getattr(cyc, "cycle_elements", None) or ())
        active = tl.active is not False and getattr(cyc, "active", True) is not False and bool(elements)
        d = {
            "id": int(tl.traffic_light_id),
            "direction": tl.direction.value,
            "active": active,
            "time_offset": float(getattr(cyc, "time_offset", 0) or 0) * dt,
            "cycle": [{"color": e.state.value, "duration": float(e.duration) * dt} for e in elements],
        }
        pos = getattr(tl, "position", None)
        if pos is not None:
            d["position"] = [float(v) for v in np.asarray(pos, float).reshape(-1)[:2]]
        out.append(d)
    return out


def _lanelet_lights(ln, d: dict) -> None:
    """A lanelet's traffic light references and stop line, into its shared-format object ``d``."""
    refs = sorted(int(i) for i in (getattr(ln, "traffic_lights", None) or ()))
    if refs:
        d["traffic_lights"] = refs
    sl = getattr(ln, "stop_line", None)
    if sl is None:
        return
    line: dict[str, Any] = {"traffic_lights": sorted(int(i) for i in (getattr(sl, "traffic_light_ref", None) or ()))}
    if getattr(sl, "start", None) is not None and getattr(sl, "end", None) is not None:
        line["start"] = [float(v) for v in np.asarray(sl.start, float)[:2]]
        line["end"] = [float(v) for v in np.asarray(sl.end, float)[:2]]
    d["stop_line"] = line


def _goal(goal, dt: float, index: int = 0) -> dict:
    out: dict = {}
    lanelets = (goal.lanelets_of_goal_position or {}).get(index)
    if lanelets:
        out["lanelets"] = [int(i) for i in lanelets]
    st = goal.state_list[index] if len(goal.state_list or ()) > index else None
    if st is None:
        return out
    pos = getattr(st, "position", None)
    if pos is not None and not lanelets:
        group = getattr(pos, "shapes", None)
        shape = group[0] if group else pos  # a shape group: its first shape
        if hasattr(shape, "radius"):
            out["circle"] = {"center": _point(getattr(shape, "center", None)).tolist(), "radius": float(shape.radius)}
        else:
            f = _shape_fields(shape)
            if "center" in f:
                out["rectangle"] = f
            elif "polygon" in f:
                out["polygon"] = f["polygon"]
    ts = getattr(st, "time_step", None)
    if ts is not None and hasattr(ts, "start"):
        out["time"] = [float(ts.start) * dt, float(ts.end) * dt]
    for key in ("orientation", "velocity"):
        v = getattr(st, key, None)
        if v is not None and hasattr(v, "start"):
            out[key] = [float(v.start), float(v.end)]
    return out


def _speed_limits(scenario) -> dict:
    """Lanelet id -> speed limit (m/s): the smallest MAX_SPEED sign value the lanelet references."""
    net = scenario.lanelet_network
    out: dict = {}
    for ln in net.lanelets:
        for sid in ln.traffic_signs or ():
            sign = net.find_traffic_sign_by_id(sid)
            for el in getattr(sign, "traffic_sign_elements", None) or ():
                if getattr(el.traffic_sign_element_id, "name", "") == "MAX_SPEED" and el.additional_values:
                    v = float(el.additional_values[0])
                    out[int(ln.lanelet_id)] = min(v, out.get(int(ln.lanelet_id), v))
    return out


def commonroad_to_dict(scenario, planning_problems, id_map: dict | None = None, notes: list | None = None) -> dict:
    """A commonroad-io ``Scenario`` + ``PlanningProblemSet`` as the shared JSON object (see the module
    docstring for what becomes of lights and obstacle shapes).

    A lanelet's ``speed_limit`` is the smallest MAX_SPEED traffic sign it references.

    Args:
        id_map: CommonRoad obstacle id -> id to report (as filled by ``dict_to_commonroad``); default none.
        notes: if given, a line is appended for what is not read (environment and phantom obstacles).

    Raises:
        ScenarioError: naming the obstacle whose shape cannot be covered by a box.
    """
    id_map = id_map or {}
    dt = float(scenario.dt)
    limits = _speed_limits(scenario)
    lanelets = []
    for ln in scenario.lanelet_network.lanelets:
        d = {
            "id": int(ln.lanelet_id),
            "left": np.asarray(ln.left_vertices, float).tolist(),
            "right": np.asarray(ln.right_vertices, float).tolist(),
            "predecessors": [int(i) for i in ln.predecessor],
            "successors": [int(i) for i in ln.successor],
        }
        for side, ref, same in (
            ("adjacentLeft", ln.adj_left, ln.adj_left_same_direction),
            ("adjacentRight", ln.adj_right, ln.adj_right_same_direction),
        ):
            if ref is not None:
                d[side] = {"ref": int(ref), "drivingDir": "same" if same else "opposite"}
        if int(ln.lanelet_id) in limits:
            d["speed_limit"] = limits[int(ln.lanelet_id)]
        _lanelet_lights(ln, d)
        lanelets.append(d)
    obstacles = []
    for o in scenario.dynamic_obstacles:
        oid = int(id_map.get(o.obstacle_id, o.obstacle_id))
        pred = o.prediction
        out = {"id": oid, "role": "dynamic", "type": o.obstacle_type.value}
        try:
            if (
                pred is not None
                and getattr(pred, "trajectory", None) is None
                and getattr(pred, "occupancy_set", None) is not None
            ):  # a set-based prediction
                obstacles.append({**out, "occupancies": _occupancy_rows(o, dt)})
                continue
            box = cover_box(o.obstacle_shape)  # in the obstacle's frame, along its heading
        except ScenarioError as e:
            raise ScenarioError(f"dynamic obstacle {o.obstacle_id}: {e}") from None
        states = [o.initial_state] + list(getattr(getattr(pred, "trajectory", None), "state_list", []))
        rows = []
        for s in states:
            x, y, th = float(s.position[0]), float(s.position[1]), float(s.orientation)
            if np.any(np.abs(box[[0, 1, 4]]) > 1e-12):  # a shape off the state's point or turned: its box's pose
                x, y, _, _, th = _placed(box, x, y, th)
            rows.append(
                [
                    float(s.time_step) * dt,
                    float(x),
                    float(y),
                    float(th),
                    float(getattr(s, "velocity", 0.0) or 0.0),
                    float(getattr(s, "acceleration", 0.0) or 0.0),
                ]
            )
        obstacles.append({**out, "length": float(box[2]), "width": float(box[3]), "states": rows})
    for o in scenario.static_obstacles:
        st = o.initial_state
        shape = o.obstacle_shape
        if hasattr(shape, "vertices") and not hasattr(shape, "radius"):  # a polygon: its own outline, placed
            c, s = np.cos(st.orientation), np.sin(st.orientation)
            v = np.asarray(shape.vertices, float).reshape(-1, 2)
            f = {"polygon": (np.asarray(st.position, float)[:2] + v @ np.array([[c, s], [-s, c]])).tolist()}
        else:  # the shape is given around the origin, placed by the initial state
            try:
                b = _placed(cover_box(shape), float(st.position[0]), float(st.position[1]), float(st.orientation))
            except ScenarioError as e:
                raise ScenarioError(f"static obstacle {o.obstacle_id}: {e}") from None
            f = {
                "length": float(b[2]),
                "width": float(b[3]),
                "center": [float(b[0]), float(b[1])],
                "orientation": float(b[4]),
            }
        obstacles.append(
            {"id": int(id_map.get(o.obstacle_id, o.obstacle_id)), "role": "static", "type": o.obstacle_type.value, **f}
        )
    for kind, attr in (("environment", "environment_obstacle"), ("phantom", "phantom_obstacle")):
        left_out = list(getattr(scenario, attr, None) or ())
        if left_out and notes is not None:
            notes.append(f"{kind} obstacles {', '.join(str(x.obstacle_id) for x in left_out)} not read")
    problems = []
    for pp in planning_problems.planning_problem_dict.values():
        st = pp.initial_state
        problems.append(
            {
                "id": int(pp.planning_problem_id),
                "initial_state": {
                    "t": float(st.time_step) * dt,
                    "position": [float(v) for v in st.position],
                    "orientation": float(st.orientation),
                    "velocity": float(st.velocity),
                    "acceleration": float(getattr(st, "acceleration", 0.0) or 0.0),
                },
                "goals": [_goal(pp.goal, dt, i) for i in range(max(1, len(pp.goal.state_list or ())))],
            }
        )
    out = {
        "id": str(scenario.scenario_id),
        "source": "commonroad-xml",
        "tags": [t.value for t in (scenario.tags or [])],
        "dt": dt,
        "lanelets": lanelets,
        "obstacles": obstacles,
        "planning_problems": problems,
    }
    lights = _traffic_lights(scenario.lanelet_network, dt)
    if lights:
        out["traffic_lights"] = lights
    return out


class _Shapes:
    """Constructors of commonroad-io's shapes across its releases.

    2024.x has ``commonroad.geometry.shape`` (``Rectangle``, ``Polygon``, ``ShapeGroup``);
    2026.x splits them into obstacle shapes (placed by a state) and occupancies (placed areas).
    """

    def __init__(self):
        try:
            from commonroad.geometry import shape as old
        except ImportError:
            old = None
        self.old = old

    def obstacle_rect(self, length: float, width: float):
        if self.old:
            return self.old.Rectangle(length, width)
        from commonroad.geometry.obstacle_shapes.rect_obstacle_shape import RectObstacleShape

        return RectObstacleShape(width=width, length=length)

    def obstacle_polygon(self, vertices: np.ndarray):
        if self.old:
            return self.old.Polygon(np.asarray(vertices, float))
        from commonroad.geometry.obstacle_shapes.polygon_obstacle_shape import PolygonObstacleShape

        return PolygonObstacleShape(vertices=tuple(map(tuple, np.asarray(vertices, float).tolist())))

    def region_rect(self, length: float, width: float, center, orientation: float):
        if self.old:
            return self.old.Rectangle(length, width, np.asarray(center, float), orientation)
        import shapely
        from commonroad.geometry.occupancy.rect_occupancy import RectOccupancy

        return RectOccupancy(
            rect_center=shapely.Point(float(center[0]), float(center[1])),
            width=width,
            length=length,
            orientation=orientation,
        )

    def group(self, regions: list):
        if len(regions) == 1:
            return regions[0]
        if self.old:
            return self.old.ShapeGroup(list(regions))
        from commonroad.geometry.occupancy.occupancy_group import OccupancyGroup

        return OccupancyGroup(occupancies=tuple(regions))


def _country_signs(scenario_id):
    """The traffic sign id enum of the scenario's country (Zamunda and unknown countries: Germany's)."""
    import commonroad.scenario.traffic_sign as ts

    name = {
        "USA": "TrafficSignIDUsa",
        "ESP": "TrafficSignIDSpain",
        "CHN": "TrafficSignIDChina",
        "RUS": "TrafficSignIDRussia",
        "AUS": "TrafficSignIDAustralia",
    }.get(str(getattr(scenario_id, "country_id", "") or ""), "TrafficSignIDGermany")
    return getattr(ts, name, ts.TrafficSignIDGermany)


def dict_to_commonroad(d: dict, path: str = "scenario", id_map: dict | None = None):
    """The shared JSON object as a commonroad-io ``(Scenario, PlanningProblemSet)``: the inverse of
    ``commonroad_to_dict``.

    Lanelets keep their bounds, predecessors, successors and adjacency (with driving direction),
    their traffic light references and stop line; traffic lights keep their cycle, offset (time
    steps ``round(t / dt)``), direction and activity (CommonRoad needs a position: without one, the
    right end of the first lanelet naming the light); a lanelet's ``speed_limit`` becomes a virtual
    MAX_SPEED traffic sign it references. Dynamic
    obstacles keep their recorded trajectory (time step ``round(t / dt)``; an obstacle exists only
    while its recording lasts: one state means it is there at that step only), or their
    ``occupancies`` as a ``SetBasedPrediction`` of rectangles (the first row is the initial state); static ones
    (role ``static``: a ``center`` box, a ``polygon``, or their first recorded state) become
    ``StaticObstacle``s. Every goal of a planning problem becomes one goal state (rectangle or goal
    lanelets, time interval, orientation and velocity intervals where given). Obstacles without
    states or shape carry nothing to write and are left out, as ``parse_scenario`` skips them.

    Args:
        d: the scenario object (checked first with ``parse_scenario``, so bad input fails there).
        path: name used in error messages.
        id_map: if given, filled with CommonRoad id -> original id for obstacles renumbered because
            their id is already used by a lanelet or planning problem (CommonRoad ids are unique
            across a scenario); pass it to ``commonroad_to_dict`` to get the original ids back.

    Returns:
        ``(Scenario, PlanningProblemSet)``.

    Raises:
        ScenarioError: malformed input, an obstacle type CommonRoad does not know, a dynamic
            obstacle whose recording has gaps, or a goal without a time interval.
    """
    _require()
    import warnings

    from commonroad.common.common_lanelet import LineMarking, StopLine
    from commonroad.common.util import AngleInterval, Interval
    from commonroad.planning.goal import GoalRegion
    from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet
    from commonroad.prediction.prediction import Occupancy, SetBasedPrediction, TrajectoryPrediction
    from commonroad.scenario.lanelet import Lanelet, LaneletNetwork
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType, StaticObstacle
    from commonroad.scenario.scenario import Scenario as CRScenario
    from commonroad.scenario.scenario import ScenarioID, Tag
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.traffic_light import (
        TrafficLight,
        TrafficLightCycle,
        TrafficLightCycleElement,
        TrafficLightDirection,
        TrafficLightState,
    )
    from commonroad.scenario.traffic_sign import TrafficSign, TrafficSignElement
    from commonroad.scenario.trajectory import Trajectory as CRTrajectory

    from jaxplan.scenarios.parse_obstacles import DEFAULT_SIZE

    parse_scenario(d, path, quiet=True)  # every field check, with its message, before building anything
    shapes = _Shapes()
    dt = float(d["dt"])
    step = lambda t: int(round(float(t) / dt))  # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sid = ScenarioID.from_benchmark_id(str(d.get("id", "scenario")), "2020a")
    tags = set()
    for t in d.get("tags") or []:
        try:
            tags.add(Tag(t))
        except ValueError:  # a tag CommonRoad has no name for (e.g. 'lane_blocked'): not written
            pass
    sc = CRScenario(dt, sid, tags=tags or None)

    used = {int(ln["id"]) for ln in d["lanelets"]} | {int(p.get("id", 0)) for p in d["planning_problems"]}
    used |= {int(tl["id"]) for tl in d.get("traffic_lights") or []}
    fresh = iter(range(max(used | {int(o["id"]) for o in d["obstacles"]} | {0}) + 1, 1 << 62))
    signs = _country_signs(sid)
    lanelets, limits = [], []
    for ln in d["lanelets"]:
        left, right = np.asarray(ln["left"], float), np.asarray(ln["right"], float)
        kw: dict[str, Any] = {}
        for side, key in (("adjacentLeft", "adjacent_left"), ("adjacentRight", "adjacent_right")):
            if ln.get(side):
                kw[key] = int(ln[side]["ref"])
                kw[key + "_same_direction"] = ln[side].get("drivingDir", "same") == "same"
        lid = int(ln["id"])
        if ln.get("speed_limit") is not None:
            sign_id = next(fresh)
            used.add(sign_id)
            limits.append(
                TrafficSign(
                    sign_id,
                    [TrafficSignElement(signs.MAX_SPEED, [str(float(ln["speed_limit"]))])],
                    {lid},
                    right[0].copy(),
                    virtual=True,
                )
            )
        sl = ln.get("stop_line")
        if sl is not None:
            ends = [np.asarray(sl[k], float) if sl.get(k) is not None else None for k in ("start", "end")]
            kw["stop_line"] = StopLine(
                ends[0],
                ends[1],
                LineMarking.SOLID,
                traffic_light_ref=set(int(i) for i in sl.get("traffic_lights") or []) or None,
            )
        if ln.get("traffic_lights"):
            kw["traffic_lights"] = set(int(i) for i in ln["traffic_lights"])
        lanelets.append(
            Lanelet(
                left,
                0.5 * (left + right),
                right,
                lid,
                predecessor=[int(i) for i in ln.get("predecessors") or []],
                successor=[int(i) for i in ln.get("successors") or []],
                **kw,
            )
        )
    net = LaneletNetwork.create_from_lanelet_list(lanelets, cleanup_ids=False)
    for sign in limits:
        net.add_traffic_sign(sign, set(sign.first_occurrence))
    where_lit: dict[
        int, np.ndarray
    ] = {}  # a light without a position stands at the right end of the first lanelet naming it
    for ln in d["lanelets"]:
        for i in list(ln.get("traffic_lights") or []) + list((ln.get("stop_line") or {}).get("traffic_lights") or []):
            where_lit.setdefault(int(i), np.asarray(ln["right"][-1], float))
    for tl in d.get("traffic_lights") or []:
        cycle = TrafficLightCycle(
            [
                TrafficLightCycleElement(TrafficLightState(ph["color"]), step(ph["duration"]))
                for ph in tl.get("cycle") or []
            ],
            step(tl.get("time_offset") or 0.0),
            bool(tl.get("active", True)),
        )
        pos = (
            np.asarray(tl["position"], float)
            if tl.get("position") is not None
            else where_lit.get(int(tl["id"]), np.zeros(2))
        )
        net.add_traffic_light(
            TrafficLight(
                int(tl["id"]),
                pos,
                cycle,
                active=bool(tl.get("active", True)),
                direction=TrafficLightDirection(tl.get("direction", "all")),
            ),
            set(),
        )
    sc.add_objects(net)

    def unique(i: int) -> int:
        if i in used:
            j = next(fresh)
            if id_map is not None:
                id_map[j] = i
            i = j
        used.add(i)
        return i

    types = {t.value: t for t in ObstacleType}
    for i, o in enumerate(d["obstacles"]):
        where = f"obstacles[{i}]"
        kind = str(o.get("type", "unknown"))
        if kind not in types:
            raise ScenarioError(f"{path}: field {where}.type {kind!r} is not a CommonRoad obstacle type")
        otype = types[kind]
        if o.get("occupancies"):  # a set-based prediction: one rectangle per step
            rows = sorted(o["occupancies"], key=lambda r: r[0])
            k = [step(r[0]) for r in rows]
            x0, y0, len0, wid0, th0 = map(float, rows[0][1:6])
            init = InitialState(
                time_step=k[0],
                position=np.array([x0, y0]),
                orientation=th0,
                velocity=0.0,
                acceleration=0.0,
                yaw_rate=0.0,
                slip_angle=0.0,
            )
            occ = [
                Occupancy(k[j], shapes.region_rect(float(r[3]), float(r[4]), r[1:3], float(r[5])))
                for j, r in enumerate(rows)
                if j > 0
            ]
            pred = SetBasedPrediction(k[1], occ) if occ else None
            sc.add_objects(DynamicObstacle(unique(int(o["id"])), otype, shapes.obstacle_rect(len0, wid0), init, pred))
            continue
        st = [r for r in (o.get("states") or [])]
        # parse_scenario has checked that every rectangle has a size (given, or DEFAULT_SIZE by type);
        # NaN only for the shapes that need none (a polygon)
        length, width = (
            (float(o["length"]), float(o["width"])) if "length" in o else DEFAULT_SIZE.get(kind, (math.nan, math.nan))
        )
        if o.get("role", "dynamic") == "static" or not st:
            if "polygon" in o:
                shape = shapes.obstacle_polygon(o["polygon"])
                x, y, th = 0.0, 0.0, 0.0
            elif "center" in o:
                shape = shapes.obstacle_rect(length, width)
                (x, y), th = o["center"], float(o.get("orientation", 0.0))
            elif st:
                shape = shapes.obstacle_rect(length, width)
                x, y, th = st[0][1], st[0][2], st[0][3]
            else:
                continue  # no states and no shape: nothing to write (parse_scenario skips it too)
            init = InitialState(
                time_step=0,
                position=np.array([x, y], float),
                orientation=float(th),
                velocity=0.0,
                acceleration=0.0,
                yaw_rate=0.0,
                slip_angle=0.0,
            )
            sc.add_objects(StaticObstacle(unique(int(o["id"])), otype, shape, init))
            continue
        k = [step(r[0]) for r in st]
        if any(b - a != 1 for a, b in zip(k, k[1:])):
            raise ScenarioError(f"{path}: field {where}.states should be one row per dt without gaps")
        rows = [
            CustomState(
                time_step=k[j],
                position=np.array(r[1:3], float),
                orientation=float(r[3]),
                velocity=float(r[4] if len(r) > 4 and r[4] is not None else 0.0),
                acceleration=float(r[5] if len(r) > 5 and r[5] is not None else 0.0),
            )
            for j, r in enumerate(st)
        ]
        shape = shapes.obstacle_rect(length, width)
        init = InitialState(
            time_step=k[0],
            position=rows[0].position,
            orientation=rows[0].orientation,
            velocity=rows[0].velocity,
            acceleration=rows[0].acceleration,
            yaw_rate=0.0,
            slip_angle=0.0,
        )
        pred = TrajectoryPrediction(CRTrajectory(k[1], rows[1:]), shape) if len(rows) > 1 else None
        sc.add_objects(DynamicObstacle(unique(int(o["id"])), otype, shape, init, pred))

    problems = []
    for n, p in enumerate(d["planning_problems"]):
        s0 = p["initial_state"]
        opt = lambda key: float(s0.get(key) or 0.0)  # noqa: E731
        init = InitialState(
            time_step=step(s0.get("t", 0.0)),
            position=np.array(s0["position"], float),
            orientation=float(s0["orientation"]),
            velocity=float(s0["velocity"]),
            acceleration=opt("acceleration"),
            yaw_rate=opt("yaw_rate"),
            slip_angle=opt("slip_angle"),
        )
        states, goal_lanelets = [], {}
        for g_i, g in enumerate(p.get("goals") or []):
            where = f"planning_problems[{n}].goals[{g_i}]"
            if "time" not in g:
                raise ScenarioError(f"{path}: field {where}.time is missing (CommonRoad goals need a time interval)")
            gs = {"time_step": Interval(step(g["time"][0]), step(g["time"][1]))}
            if "rectangle" in g:
                r = g["rectangle"]
                gs["position"] = shapes.region_rect(
                    float(r["length"]), float(r["width"]), r["center"], float(r.get("orientation", 0.0) or 0.0)
                )
            elif g.get("lanelets"):
                ids = [int(i) for i in g["lanelets"]]
                missing = [i for i in ids if net.find_lanelet_by_id(i) is None]
                if missing:
                    raise ScenarioError(f"{path}: field {where}.lanelets names lanelets that do not exist: {missing}")
                gs["position"] = shapes.group([net.find_lanelet_by_id(i).polygon for i in ids])
                goal_lanelets[g_i] = ids
            if "orientation" in g:
                gs["orientation"] = AngleInterval(*map(float, g["orientation"]))
            if "velocity" in g:
                gs["velocity"] = Interval(*map(float, g["velocity"]))
            states.append(CustomState(**gs))
        problems.append(PlanningProblem(int(p.get("id", 0)), init, GoalRegion(states, goal_lanelets or None)))
    return sc, PlanningProblemSet(problems)


def write_commonroad(d: dict, path: str, name: str = "scenario", id_map: dict | None = None) -> str:
    """Write the shared JSON object as a CommonRoad 2020a XML file (see ``dict_to_commonroad``).

    Returns:
        ``path``.
    """
    import warnings

    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile

    sc, pps = dict_to_commonroad(d, name, id_map)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    kw = {}
    try:  # commonroad-io 2026 writes protobuf unless told otherwise
        from commonroad.common.file_writer import FileFormat

        kw["file_format"] = FileFormat.XML
    except ImportError:
        pass
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        CommonRoadFileWriter(
            sc, pps, author="jaxplan", affiliation="", source=str(d.get("source", "")), tags=set(sc.tags or ()), **kw
        ).write_to_file(path, OverwriteExistingFile.ALWAYS)
    return path


def read_commonroad(path: str):
    """commonroad-io's ``(Scenario, PlanningProblemSet)`` of a CommonRoad XML file (``.xml``, or
    gzip-compressed ``.xml.gz``).

    Raises:
        ScenarioError: naming the file, when it is missing or commonroad-io cannot read it;
        ImportError: without the ``commonroad`` extra.
    """
    _require()
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.common.util import FileFormat

    raw = read_bytes(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return CommonRoadFileReader(raw, FileFormat.XML).open()
    except Exception as e:  # commonroad-io raises many kinds on malformed XML
        raise ScenarioError(f"{path}: not a readable CommonRoad XML file ({type(e).__name__}: {e})") from None


def load_commonroad(path: str, horizon: float | None = None) -> Scenario:
    """Read a CommonRoad XML file (``.xml`` or ``.xml.gz``) into a ``Scenario`` (local frame at the ego start)."""
    sc, pps = read_commonroad(path)
    notes: list = []
    try:
        d = commonroad_to_dict(sc, pps, notes=notes)
    except ScenarioError as e:
        raise ScenarioError(f"{path}: {e}") from None
    return parse_scenario(d, path, horizon, notes=notes)


def write_solution(
    scenario: Scenario,
    trajectory,
    path: str,
    planning_problem_id: int | None = None,
    vehicle_type: str = "BMW_320i",
    cost_function: str = "SM1",
) -> str:
    """Write a planned trajectory as a CommonRoad solution file (kinematic single-track states).

    Args:
        scenario: the scenario it was planned in (its ``origin`` maps back to world coordinates).
        trajectory: ``jaxplan.types.Trajectory`` with 1-D fields at the scenario's ``dt``.
        path: output directory.
        planning_problem_id: default the first planning problem of the scenario file.

    Returns:
        The written file's path.
    """
    _require()
    import warnings

    from commonroad.common.solution import (
        CommonRoadSolutionWriter,
        CostFunction,
        PlanningProblemSolution,
        Solution,
        VehicleModel,
        VehicleType,
    )
    from commonroad.scenario.scenario import ScenarioID
    from commonroad.scenario.state import KSState
    from commonroad.scenario.trajectory import Trajectory as CRTrajectory

    x, y = np.asarray(trajectory.x, float), np.asarray(trajectory.y, float)
    th, v = np.asarray(trajectory.theta, float), np.asarray(trajectory.v, float)
    t = np.asarray(trajectory.t, float)
    steps = np.rint(t / scenario.dt).astype(int)
    wheelbase = 2.578  # BMW 320i, the solution's vehicle type
    steer = np.arctan(wheelbase * np.asarray(trajectory.kappa, float))
    states = [
        KSState(
            time_step=int(k),
            position=np.array([x[i] + scenario.origin[0], y[i] + scenario.origin[1]]),
            steering_angle=float(steer[i]),
            velocity=float(v[i]),
            orientation=float(th[i]),
        )
        for i, k in enumerate(steps)
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sid = ScenarioID.from_benchmark_id(scenario.id, "2020a")
    pps = PlanningProblemSolution(
        planning_problem_id=int(planning_problem_id if planning_problem_id is not None else scenario.problem_id),
        vehicle_model=VehicleModel.KS,
        vehicle_type=VehicleType[vehicle_type],
        cost_function=CostFunction[cost_function],
        trajectory=CRTrajectory(int(steps[0]), states),
    )
    os.makedirs(path, exist_ok=True)
    writer = CommonRoadSolutionWriter(Solution(sid, [pps]))
    fname = f"solution_{scenario.id}.xml"
    writer.write_to_file(output_path=path, filename=fname, overwrite=True)
    return os.path.join(path, fname)
