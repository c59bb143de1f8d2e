"""The shared JSON object as commonroad-io objects (``dict_to_commonroad``, the inverse of
``commonroad_to_dict``): lanelets, traffic lights and speed-limit signs, obstacles with their
trajectories or set-based predictions, planning problems and their goals. Needs the optional
``commonroad`` extra (``_require`` says so when it is missing).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from jaxplan.scenarios.commonroad_shapes import _Shapes
from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.loader import parse_scenario
from jaxplan.scenarios.parse_obstacles import DEFAULT_SIZE


def _require():
    try:
        import commonroad  # noqa: F401
    except ImportError:
        raise ImportError("CommonRoad XML needs the optional extra: pip install 'jaxplan[commonroad]'") from None


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
