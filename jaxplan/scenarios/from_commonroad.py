"""commonroad-io objects (a ``Scenario`` and its ``PlanningProblemSet``) as the shared JSON object
(``commonroad_to_dict``), which ``loader.parse_scenario`` then reads. What a scenario holds is
read or refused out loud:

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

from typing import Any

import numpy as np

from jaxplan.scenarios.commonroad_shapes import _outline, _placed, _point, _shape_fields, _toward, cover_box
from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.parse_obstacles import _min_area_box


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
