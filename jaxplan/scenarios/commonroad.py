"""Native CommonRoad XML (2020a) in and out, through ``commonroad-io``.

Optional: ``pip install jaxplan[commonroad]``. A CommonRoad scenario is converted to
the shared JSON object and parsed by ``loader.parse_scenario``, so both formats end in
the same ``Scenario`` (local frame, same checks, same errors).
"""
from __future__ import annotations

import os

import numpy as np

from jaxplan.scenarios.loader import Scenario, ScenarioError, parse_scenario, read_bytes


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
        return {"length": float(shape.length), "width": float(shape.width),
                "center": c.tolist(), "orientation": float(getattr(shape, "orientation", 0.0) or 0.0)}
    if hasattr(shape, "radius"):
        c = _point(getattr(shape, "center", None))
        return {"length": 2 * float(shape.radius), "width": 2 * float(shape.radius),
                "center": c.tolist(), "orientation": 0.0}
    if hasattr(shape, "vertices"):
        return {"polygon": np.asarray(shape.vertices, float).tolist()}
    raise ScenarioError(f"unsupported CommonRoad shape {type(shape).__name__}")


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


def commonroad_to_dict(scenario, planning_problems, id_map: dict | None = None) -> dict:
    """A commonroad-io ``Scenario`` + ``PlanningProblemSet`` as the shared JSON object.

    A lanelet's ``speed_limit`` is the smallest MAX_SPEED traffic sign it references.

    Args:
        id_map: CommonRoad obstacle id -> id to report (as filled by ``dict_to_commonroad``); default none.
    """
    id_map = id_map or {}
    dt = float(scenario.dt)
    limits = _speed_limits(scenario)
    lanelets = []
    for ln in scenario.lanelet_network.lanelets:
        d = {"id": int(ln.lanelet_id), "left": np.asarray(ln.left_vertices, float).tolist(),
             "right": np.asarray(ln.right_vertices, float).tolist(),
             "predecessors": [int(i) for i in ln.predecessor], "successors": [int(i) for i in ln.successor]}
        for side, ref, same in (("adjacentLeft", ln.adj_left, ln.adj_left_same_direction),
                                ("adjacentRight", ln.adj_right, ln.adj_right_same_direction)):
            if ref is not None:
                d[side] = {"ref": int(ref), "drivingDir": "same" if same else "opposite"}
        if int(ln.lanelet_id) in limits:
            d["speed_limit"] = limits[int(ln.lanelet_id)]
        lanelets.append(d)
    obstacles = []
    for o in scenario.dynamic_obstacles:
        f = _shape_fields(o.obstacle_shape)
        if "polygon" in f:
            raise ScenarioError(f"dynamic obstacle {o.obstacle_id}: polygon shapes are not supported")
        states = [o.initial_state] + list(getattr(getattr(o.prediction, "trajectory", None), "state_list", []))
        rows = [[float(s.time_step) * dt, float(s.position[0]), float(s.position[1]), float(s.orientation),
                 float(getattr(s, "velocity", 0.0) or 0.0), float(getattr(s, "acceleration", 0.0) or 0.0)]
                for s in states]
        obstacles.append({"id": int(id_map.get(o.obstacle_id, o.obstacle_id)), "role": "dynamic",
                          "type": o.obstacle_type.value,
                          "length": f["length"], "width": f["width"], "states": rows})
    for o in scenario.static_obstacles:
        f = _shape_fields(o.obstacle_shape)
        if "center" in f:  # the shape is given around the origin, placed by the initial state
            st = o.initial_state
            c, s = np.cos(st.orientation), np.sin(st.orientation)
            cx, cy = f["center"]
            f["center"] = [float(st.position[0] + c * cx - s * cy), float(st.position[1] + s * cx + c * cy)]
            f["orientation"] = float(f["orientation"] + st.orientation)
        obstacles.append({"id": int(id_map.get(o.obstacle_id, o.obstacle_id)), "role": "static",
                          "type": o.obstacle_type.value, **f})
    problems = []
    for pp in planning_problems.planning_problem_dict.values():
        st = pp.initial_state
        problems.append({"id": int(pp.planning_problem_id),
                         "initial_state": {"t": float(st.time_step) * dt,
                                           "position": [float(v) for v in st.position],
                                           "orientation": float(st.orientation), "velocity": float(st.velocity),
                                           "acceleration": float(getattr(st, "acceleration", 0.0) or 0.0)},
                         "goals": [_goal(pp.goal, dt, i) for i in range(max(1, len(pp.goal.state_list or ())))]})
    return {"id": str(scenario.scenario_id), "source": "commonroad-xml", "tags": [t.value for t in (scenario.tags or [])],
            "dt": dt, "lanelets": lanelets, "obstacles": obstacles, "planning_problems": problems}


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
        return RectOccupancy(rect_center=shapely.Point(float(center[0]), float(center[1])), width=width,
                             length=length, orientation=orientation)

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

    name = {"USA": "TrafficSignIDUsa", "ESP": "TrafficSignIDSpain", "CHN": "TrafficSignIDChina",
            "RUS": "TrafficSignIDRussia", "AUS": "TrafficSignIDAustralia"}.get(
        str(getattr(scenario_id, "country_id", "") or ""), "TrafficSignIDGermany")
    return getattr(ts, name, ts.TrafficSignIDGermany)


def dict_to_commonroad(d: dict, path: str = "scenario", id_map: dict | None = None):
    """The shared JSON object as a commonroad-io ``(Scenario, PlanningProblemSet)``: the inverse of
    ``commonroad_to_dict``.

    Lanelets keep their bounds, predecessors, successors and adjacency (with driving direction);
    a lanelet's ``speed_limit`` becomes a virtual MAX_SPEED traffic sign it references. Dynamic
    obstacles keep their recorded trajectory (time step ``round(t / dt)``; an obstacle exists only
    while its recording lasts: one state means it is there at that step only); static ones
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

    from commonroad.common.util import AngleInterval, Interval
    from commonroad.planning.goal import GoalRegion
    from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.lanelet import Lanelet, LaneletNetwork
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType, StaticObstacle
    from commonroad.scenario.scenario import Scenario as CRScenario
    from commonroad.scenario.scenario import ScenarioID, Tag
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.traffic_sign import TrafficSign, TrafficSignElement
    from commonroad.scenario.trajectory import Trajectory as CRTrajectory

    from jaxplan.scenarios.loader import DEFAULT_SIZE

    parse_scenario(d, path)  # every field check, with its message, before building anything
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
    fresh = iter(range(max(used | {int(o["id"]) for o in d["obstacles"]} | {0}) + 1, 1 << 62))
    signs = _country_signs(sid)
    lanelets, limits = [], []
    for ln in d["lanelets"]:
        left, right = np.asarray(ln["left"], float), np.asarray(ln["right"], float)
        kw = {}
        for side, key in (("adjacentLeft", "adjacent_left"), ("adjacentRight", "adjacent_right")):
            if ln.get(side):
                kw[key] = int(ln[side]["ref"])
                kw[key + "_same_direction"] = ln[side].get("drivingDir", "same") == "same"
        lid = int(ln["id"])
        if ln.get("speed_limit") is not None:
            sign_id = next(fresh)
            used.add(sign_id)
            limits.append(TrafficSign(sign_id, [TrafficSignElement(signs.MAX_SPEED, [str(float(ln["speed_limit"]))])],
                                      {lid}, right[0].copy(), virtual=True))
        lanelets.append(Lanelet(left, 0.5 * (left + right), right, lid,
                                predecessor=[int(i) for i in ln.get("predecessors") or []],
                                successor=[int(i) for i in ln.get("successors") or []], **kw))
    net = LaneletNetwork.create_from_lanelet_list(lanelets, cleanup_ids=False)
    for sign in limits:
        net.add_traffic_sign(sign, set(sign.first_occurrence))
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
        st = [r for r in (o.get("states") or [])]
        length, width = ((float(o["length"]), float(o["width"])) if "length" in o
                         else DEFAULT_SIZE.get(kind, (None, None)))
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
            init = InitialState(time_step=0, position=np.array([x, y], float), orientation=float(th), velocity=0.0,
                                acceleration=0.0, yaw_rate=0.0, slip_angle=0.0)
            sc.add_objects(StaticObstacle(unique(int(o["id"])), otype, shape, init))
            continue
        k = [step(r[0]) for r in st]
        if any(b - a != 1 for a, b in zip(k, k[1:])):
            raise ScenarioError(f"{path}: field {where}.states should be one row per dt without gaps")
        rows = [CustomState(time_step=k[j], position=np.array(r[1:3], float), orientation=float(r[3]),
                            velocity=float(r[4] if len(r) > 4 and r[4] is not None else 0.0),
                            acceleration=float(r[5] if len(r) > 5 and r[5] is not None else 0.0))
                for j, r in enumerate(st)]
        shape = shapes.obstacle_rect(length, width)
        init = InitialState(time_step=k[0], position=rows[0].position, orientation=rows[0].orientation,
                            velocity=rows[0].velocity, acceleration=rows[0].acceleration, yaw_rate=0.0, slip_angle=0.0)
        pred = TrajectoryPrediction(CRTrajectory(k[1], rows[1:]), shape) if len(rows) > 1 else None
        sc.add_objects(DynamicObstacle(unique(int(o["id"])), otype, shape, init, pred))

    problems = []
    for n, p in enumerate(d["planning_problems"]):
        s0 = p["initial_state"]
        opt = lambda key: float(s0.get(key) or 0.0)  # noqa: E731
        init = InitialState(time_step=step(s0.get("t", 0.0)), position=np.array(s0["position"], float),
                            orientation=float(s0["orientation"]), velocity=float(s0["velocity"]),
                            acceleration=opt("acceleration"), yaw_rate=opt("yaw_rate"), slip_angle=opt("slip_angle"))
        states, goal_lanelets = [], {}
        for g_i, g in enumerate(p.get("goals") or []):
            where = f"planning_problems[{n}].goals[{g_i}]"
            if "time" not in g:
                raise ScenarioError(f"{path}: field {where}.time is missing (CommonRoad goals need a time interval)")
            gs = {"time_step": Interval(step(g["time"][0]), step(g["time"][1]))}
            if "rectangle" in g:
                r = g["rectangle"]
                gs["position"] = shapes.region_rect(float(r["length"]), float(r["width"]), r["center"],
                                                    float(r.get("orientation", 0.0) or 0.0))
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
        CommonRoadFileWriter(sc, pps, author="jaxplan", affiliation="", source=str(d.get("source", "")),
                             tags=set(sc.tags or ()), **kw).write_to_file(path, OverwriteExistingFile.ALWAYS)
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
    try:
        d = commonroad_to_dict(sc, pps)
    except ScenarioError as e:
        raise ScenarioError(f"{path}: {e}") from None
    return parse_scenario(d, path, horizon)


def write_solution(scenario: Scenario, trajectory, path: str, planning_problem_id: int | None = None,
                   vehicle_type: str = "BMW_320i", cost_function: str = "SM1") -> str:
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

    from commonroad.common.solution import (CommonRoadSolutionWriter, CostFunction, PlanningProblemSolution,
                                            Solution, VehicleModel, VehicleType)
    from commonroad.scenario.scenario import ScenarioID
    from commonroad.scenario.state import KSState
    from commonroad.scenario.trajectory import Trajectory as CRTrajectory

    x, y = np.asarray(trajectory.x, float), np.asarray(trajectory.y, float)
    th, v = np.asarray(trajectory.theta, float), np.asarray(trajectory.v, float)
    t = np.asarray(trajectory.t, float)
    steps = np.rint(t / scenario.dt).astype(int)
    wheelbase = 2.578  # BMW 320i, the solution's vehicle type
    steer = np.arctan(wheelbase * np.asarray(trajectory.kappa, float))
    states = [KSState(time_step=int(k), position=np.array([x[i] + scenario.origin[0], y[i] + scenario.origin[1]]),
                      steering_angle=float(steer[i]), velocity=float(v[i]), orientation=float(th[i]))
              for i, k in enumerate(steps)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sid = ScenarioID.from_benchmark_id(scenario.id, "2020a")
    pps = PlanningProblemSolution(planning_problem_id=int(planning_problem_id if planning_problem_id is not None
                                                          else scenario.problem_id),
                                  vehicle_model=VehicleModel.KS, vehicle_type=VehicleType[vehicle_type],
                                  cost_function=CostFunction[cost_function],
                                  trajectory=CRTrajectory(int(steps[0]), states))
    os.makedirs(path, exist_ok=True)
    writer = CommonRoadSolutionWriter(Solution(sid, [pps]))
    fname = f"solution_{scenario.id}.xml"
    writer.write_to_file(output_path=path, filename=fname, overwrite=True)
    return os.path.join(path, fname)
