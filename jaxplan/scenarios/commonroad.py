"""Native CommonRoad XML (2020a) in and out, through ``commonroad-io``.

Optional: ``pip install jaxplan[commonroad]``. A CommonRoad scenario is converted to
the shared JSON object and parsed by ``loader.parse_scenario``, so both formats end in
the same ``Scenario`` (local frame, same checks, same errors).
"""
from __future__ import annotations

import os

import numpy as np

from jaxplan.scenarios.loader import Scenario, ScenarioError, parse_scenario


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


def _goal(goal, dt: float) -> dict:
    out: dict = {}
    lanelets = goal.lanelets_of_goal_position or {}
    if lanelets:
        out["lanelets"] = [int(i) for ids in lanelets.values() for i in ids]
    st = goal.state_list[0] if goal.state_list else None
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


def commonroad_to_dict(scenario, planning_problems) -> dict:
    """A commonroad-io ``Scenario`` + ``PlanningProblemSet`` as the shared JSON object."""
    dt = float(scenario.dt)
    lanelets = []
    for ln in scenario.lanelet_network.lanelets:
        d = {"id": int(ln.lanelet_id), "left": np.asarray(ln.left_vertices, float).tolist(),
             "right": np.asarray(ln.right_vertices, float).tolist(),
             "predecessors": [int(i) for i in ln.predecessor], "successors": [int(i) for i in ln.successor]}
        for side, ref, same in (("adjacentLeft", ln.adj_left, ln.adj_left_same_direction),
                                ("adjacentRight", ln.adj_right, ln.adj_right_same_direction)):
            if ref is not None:
                d[side] = {"ref": int(ref), "drivingDir": "same" if same else "opposite"}
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
        obstacles.append({"id": int(o.obstacle_id), "role": "dynamic", "type": o.obstacle_type.value,
                          "length": f["length"], "width": f["width"], "states": rows})
    for o in scenario.static_obstacles:
        f = _shape_fields(o.obstacle_shape)
        if "center" in f:  # the shape is given around the origin, placed by the initial state
            st = o.initial_state
            c, s = np.cos(st.orientation), np.sin(st.orientation)
            cx, cy = f["center"]
            f["center"] = [float(st.position[0] + c * cx - s * cy), float(st.position[1] + s * cx + c * cy)]
            f["orientation"] = float(f["orientation"] + st.orientation)
        obstacles.append({"id": int(o.obstacle_id), "role": "static", "type": o.obstacle_type.value, **f})
    problems = []
    for pp in planning_problems.planning_problem_dict.values():
        st = pp.initial_state
        problems.append({"id": int(pp.planning_problem_id),
                         "initial_state": {"t": float(st.time_step) * dt,
                                           "position": [float(v) for v in st.position],
                                           "orientation": float(st.orientation), "velocity": float(st.velocity),
                                           "acceleration": float(getattr(st, "acceleration", 0.0) or 0.0)},
                         "goals": [_goal(pp.goal, dt)]})
    return {"id": str(scenario.scenario_id), "source": "commonroad-xml", "tags": [t.value for t in (scenario.tags or [])],
            "dt": dt, "lanelets": lanelets, "obstacles": obstacles, "planning_problems": problems}


def load_commonroad(path: str, horizon: float | None = None) -> Scenario:
    """Read a CommonRoad XML file into a ``Scenario`` (local frame at the ego start)."""
    _require()
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sc, pps = CommonRoadFileReader(path).open()
    except ScenarioError:
        raise
    except Exception as e:  # commonroad-io raises many kinds on malformed XML
        raise ScenarioError(f"{path}: not a readable CommonRoad XML file ({type(e).__name__}: {e})") from None
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
