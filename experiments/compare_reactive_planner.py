"""Peer comparison: jaxplan's lattice planner vs the CommonRoad reactive planner, closed loop.

Both planners drive the same CommonRoad scenarios in closed loop: every cycle
(``--replan`` steps of 0.1 s, default 3 = 0.3 s, the peer's shipped replanning
frequency) each plans from the state it has reached, and the car follows the
first step(s) of the chosen trajectory exactly (perfect tracking, as in the
reactive planner's own examples). Every driven trajectory is then judged by one
referee that is neither planner:

* collisions: ``commonroad_dc`` (commonroad-drivability-checker) collision
  checker built from the scenario, against the ego's box (BMW 320i,
  4.508 m x 1.61 m, centred on the driven centre positions) at every step, and
  against one time-variant collision object of the whole drive;
* off road: the same box against ``create_road_boundary_obstacle`` (OBB rectangles);
* goal reached: ``PlanningProblem.goal.is_reached`` of commonroad-io on every
  driven state (time step, centre position, orientation, velocity).

Neither planner's own collision check counts for the verdict. jaxplan's drive is
judged up to the step its goal is first reached (the peer stops there).

Scenarios: the four CommonRoad 2020a XML files of ``../shared/data/commonroad2020a``
and ``--recorded N`` recorded-traffic files of ``../shared/data/commonroad2018a``
(JSON, every ``46 // N``-th file; converted to CommonRoad XML with commonroad-io
into a temporary folder). A scenario is simulated to the end of its goal time
interval (at most ``--max-steps``).

Both planners follow the same route: the reference path that
``commonroad_route_planner`` (the reactive planner's route planner) plans from the
start to the goal, extended 10 m straight backwards (the peer plans from the rear
axle, which can lie behind the route's first point). jaxplan's lattice uses it
as its reference line, resampled to 256 points (one compiled shape). Its lanes
(``--lanes auto``): the start lane and the lanes beside it in either direction
(the peer's lateral samples reach them too), at the start lane's width, with
lateral offsets that keep the car inside a lane (the lattice knows no road edge).

The peer is configured as its shipped scenario configurations: 2 s horizon
(``--peer-horizon-steps 20``), shortest sampled duration ``--peer-t-min 1.0``,
BMW 320i, sampling levels as shipped, single process (``--peer-workers N`` turns
on its multiprocessing kinematic check). jaxplan's horizon is ``--jaxplan-horizon``
(default 5 s, its default; 2 s matches the peer).

Setup: the peer pins commonroad-io 2024.x while jaxplan's venv has 2026.1 (a
different API), so the peer lives in its own virtual environment and this script
runs itself there as child processes (``--worker``): the XML conversion, the peer
and the referee; jaxplan runs in this process; trajectories go through JSON::

    python3 -m venv /tmp/peer-venv
    /tmp/peer-venv/bin/pip install commonroad-reactive-planner==2025.1

Run (from the repository root)::

    .venv/bin/python experiments/compare_reactive_planner.py \
        --peer-python /tmp/peer-venv/bin/python --recorded 4 --out /tmp/compare_reactive_planner.json

``--no-peer`` skips the peer's planning (jaxplan then follows ``lane_polyline``,
its start lane and first successors); the referee still needs the peer's venv.

Timings per planning cycle: wall time and process CPU time of one planning call
(jaxplan: ``plan`` + fetching the chosen trajectory, after a warm-up call per
scenario so compile time is excluded; the peer: its ``plan()``). Candidates per
cycle: jaxplan evaluates its whole lattice every cycle; the peer's count is the
sum of the trajectory bundles it sampled over the levels it tried that cycle. On
a shared machine the timings are noisy.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(os.path.dirname(ROOT), "shared", "data")
if not os.path.isdir(DATA):
    DATA = "/work/shared/data"

# BMW 320i (CommonRoad vehicle type 2), the reactive planner's default car.
CAR_LENGTH, CAR_WIDTH = 4.508, 1.61
CAR_WB_FRONT, CAR_WB_REAR = 1.1561957064, 1.4227170936


# ----------------------------------------------------------------------------- peer (child process)

def peer_run(xml: str, max_steps: int, replan: int, workers: int, horizon_steps: int, t_min: float) -> dict:
    """Closed loop of the reactive planner on one XML file (runs in the peer's venv)."""
    import logging
    import warnings

    warnings.simplefilter("ignore")
    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad_rp.reactive_planner import ReactivePlanner
    from commonroad_rp.utility.config import ReactivePlannerConfiguration
    from commonroad_rp.utility.utils_coordinate_system import create_coordinate_system, create_initial_ref_path

    logging.disable(logging.WARNING)
    sc, pps = CommonRoadFileReader(xml).open()
    pp = next(iter(pps.planning_problem_dict.values()))
    cfg = ReactivePlannerConfiguration()
    cfg.debug.logging_level = "ERROR"
    cfg.debug.multiproc = workers > 0
    cfg.debug.num_workers = max(1, workers)
    cfg.planning.time_steps_computation = horizon_steps
    cfg.planning.planning_horizon = horizon_steps * cfg.planning.dt
    cfg.planning.replanning_frequency = replan
    cfg.sampling.t_min = t_min
    cfg.update(scenario=sc, planning_problem=pp)
    out = {"scenario": os.path.basename(xml), "status": "ok", "cycles": [], "states": []}
    try:
        ref = np.asarray(create_initial_ref_path(sc.lanelet_network, pp), float)
        # the planner starts at the rear axle, up to 1.4 m behind the route's first point: extend the
        # route 10 m straight backwards so its curvilinear frame covers the start
        u = ref[0] - ref[1]
        ref = np.concatenate([ref[:1] + np.linspace(10.0, 1.0, 10)[:, None] * u / np.linalg.norm(u), ref])
        planner = ReactivePlanner(cfg)
        planner.set_reference_path(coordinate_system=create_coordinate_system(ref))
    except Exception as e:  # route or coordinate system failed: the peer cannot run here
        out.update(status=f"setup failed: {type(e).__name__}: {e}")
        return out
    out["reference_path"] = np.asarray(planner.reference_path, float).tolist()

    counted = []
    bundle_fn = planner._create_trajectory_bundle

    def counting_bundle(*a, **k):  # instrumentation only: how many candidates each level sampled
        b = bundle_fn(*a, **k)
        counted.append(len(b.trajectories))
        return b

    planner._create_trajectory_bundle = counting_bundle
    b = cfg.vehicle.wb_rear_axle

    def centre(s):
        th = float(s.orientation)
        return [int(s.time_step), float(s.position[0] + b * np.cos(th)), float(s.position[1] + b * np.sin(th)),
                th, float(s.velocity), float(getattr(s, "acceleration", 0.0) or 0.0)]

    planner.record_state_and_input(planner.x_0)
    optimal, since = None, replan
    for _ in range(max_steps):
        goal = planner.goal_reached
        if (goal() if callable(goal) else goal):
            out["status"] = "goal"
            break
        if since >= replan or optimal is None:
            planner.set_desired_velocity(current_speed=planner.x_0.velocity)
            counted.clear()
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                optimal = planner.plan()
            except Exception as e:
                out["status"] = f"plan raised {type(e).__name__}: {e}"
                break
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            out["cycles"].append({"wall_s": wall, "cpu_s": cpu, "candidates": int(sum(counted)), "levels": len(counted),
                                  "found": optimal is not None})
            if not optimal:
                out["status"] = "no trajectory"
                break
            since = 0
        since += 1
        nxt = optimal[0].state_list[since]
        planner.record_state_and_input(nxt)
        planner.reset(initial_state_cart=nxt, initial_state_curv=(optimal[1][since], optimal[2][since]),
                      collision_checker=planner.collision_checker, coordinate_system=planner.coordinate_system)
    out["states"] = [centre(s) for s in planner.record_state_list]
    return out


def prep_run(xmls: list, jsons: list, out_dir: str, cap: int) -> dict:
    """Convert recorded JSON to XML; steps to simulate and set speed of every scenario."""
    notes, out = [], list(xmls)
    for p in jsons:
        try:
            out.append(json_to_xml(p, out_dir))
        except Exception as e:
            notes.append(f"{os.path.basename(p)}: conversion to XML failed ({type(e).__name__}: {e})")
    info = {}
    for x in out:
        _sc, pp = _open(x)
        gs = pp.goal.state_list[0]
        ts = getattr(gs, "time_step", None)
        end = int(ts.end) if ts is not None and hasattr(ts, "end") else cap
        vel = getattr(gs, "velocity", None)
        v0 = float(pp.initial_state.velocity)
        # the set speed: the middle of the goal's speed interval, else the start speed (as the peer does)
        v_set = (0.5 * (vel.start + vel.end) if vel.start > 0 else 0.5 * vel.end) if vel is not None else v0
        side = []
        ids = _sc.lanelet_network.find_lanelet_by_position([np.asarray(pp.initial_state.position, float)])[0]
        if ids:
            ln = _sc.lanelet_network.find_lanelet_by_id(ids[0])
            side = [v for v, adj in ((-1, ln.adj_right), (1, ln.adj_left)) if adj is not None]
        info[x] = {"steps": max(1, min(cap, end - int(pp.initial_state.time_step))), "v_set": float(v_set),
                   "side_lanes": side}
    return {"xmls": out, "notes": notes, "info": info}


def worker_main(args) -> None:
    """Child-process entry (runs in the peer's venv)."""
    if args.worker == "peer":
        res = [peer_run(x, args.max_steps, args.replan, args.peer_workers, args.peer_horizon_steps,
                        args.peer_t_min) for x in args.xml]
    elif args.worker == "prep":
        res = prep_run(args.xml or [], args.json, os.path.dirname(args.worker_out), args.max_steps)
    else:
        job = json.load(open(args.worker_in))
        res = referee(job["xml"], job["states"])
    with open(args.worker_out, "w") as f:
        json.dump(res, f)


def child(python: str, worker: str, tmp: str, extra: list, job=None):
    """Run this script as ``worker`` under ``python``; its JSON result."""
    fd, out = tempfile.mkstemp(suffix=f".{worker}.json", dir=tmp)
    os.close(fd)
    cmd = [python, os.path.abspath(__file__), "--worker", worker, "--worker-out", out, *extra]
    if job is not None:
        with open(out + ".in", "w") as f:
            json.dump(job, f)
        cmd += ["--worker-in", out + ".in"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    try:
        with open(out) as f:
            return json.load(f)
    except (OSError, ValueError):
        err = "\n".join(ln for ln in r.stderr.splitlines() if "leaked" not in ln and "nanobind" not in ln)
        raise RuntimeError(f"{worker} child exited {r.returncode}: {err[-800:]}") from None


def judge(python: str, tmp: str, xml: str, states: list) -> dict:
    """``referee`` in the referee's environment."""
    return child(python, "referee", tmp, [], {"xml": xml, "states": states})


# ----------------------------------------------------------------------------- recorded traffic -> XML

def json_to_xml(path: str, out_dir: str) -> str:
    """Write a shared-format JSON scenario as a CommonRoad 2020a XML file (commonroad-io)."""
    import warnings

    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
    from commonroad.common.util import AngleInterval, Interval
    from commonroad.geometry.shape import Rectangle
    from commonroad.planning.goal import GoalRegion
    from commonroad.planning.planning_problem import PlanningProblem, PlanningProblemSet
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.lanelet import Lanelet, LaneletNetwork
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.scenario import Scenario, ScenarioID
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory

    d = json.load(open(path))
    dt = float(d["dt"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sid = ScenarioID.from_benchmark_id(d["id"], "2020a")
    sc = Scenario(dt, sid)
    lanelets = []
    for ln in d["lanelets"]:
        left, right = np.asarray(ln["left"], float), np.asarray(ln["right"], float)
        kw = {}
        for side, key in (("adjacentLeft", "adjacent_left"), ("adjacentRight", "adjacent_right")):
            if ln.get(side):
                kw[key] = int(ln[side]["ref"])
                kw[key + "_same_direction"] = ln[side].get("drivingDir", "same") == "same"
        lanelets.append(Lanelet(left, 0.5 * (left + right), right, int(ln["id"]),
                                predecessor=[int(i) for i in ln.get("predecessors", [])],
                                successor=[int(i) for i in ln.get("successors", [])], **kw))
    sc.add_objects(LaneletNetwork.create_from_lanelet_list(lanelets))
    types = {t.value: t for t in ObstacleType}
    used = {int(ln["id"]) for ln in d["lanelets"]}
    fresh = iter(range(max(used | {0}) + 1000, 10 ** 9))

    def unique(i: int) -> int:  # CommonRoad needs ids unique over lanelets, obstacles and problems
        i = next(fresh) if i in used else i
        used.add(i)
        return i

    for o in d["obstacles"]:
        st = [s for s in o.get("states") or [] if s[0] >= 0]
        if len(st) < 2:
            continue
        k = [int(round(s[0] / dt)) for s in st]
        states = [CustomState(time_step=k[i], position=np.array(st[i][1:3], float), orientation=float(st[i][3]),
                              velocity=float(st[i][4] or 0.0)) for i in range(len(st))]
        shape = Rectangle(float(o["length"]), float(o["width"]))
        init = InitialState(time_step=k[0], position=states[0].position, orientation=states[0].orientation,
                            velocity=states[0].velocity, acceleration=0.0, yaw_rate=0.0, slip_angle=0.0)
        pred = TrajectoryPrediction(Trajectory(k[1], states[1:]), shape)
        sc.add_objects(DynamicObstacle(unique(int(o["id"])), types.get(o.get("type"), ObstacleType.CAR), shape, init, pred))
    pps = []
    for p in d["planning_problems"]:
        s0 = p["initial_state"]
        init = InitialState(time_step=int(round(s0.get("t", 0.0) / dt)), position=np.array(s0["position"], float),
                            orientation=float(s0["orientation"]), velocity=float(s0["velocity"]),
                            acceleration=0.0, yaw_rate=float(s0.get("yaw_rate", 0.0) or 0.0),
                            slip_angle=float(s0.get("slip_angle", 0.0) or 0.0))
        g = p["goals"][0]
        gs = {"time_step": Interval(int(round(g["time"][0] / dt)), int(round(g["time"][1] / dt)))
              if "time" in g else Interval(0, 10 ** 6)}
        lanelets_of_goal = None
        if "rectangle" in g:
            r = g["rectangle"]
            gs["position"] = Rectangle(float(r["length"]), float(r["width"]), np.array(r["center"], float),
                                       float(r.get("orientation", 0.0)))
        elif "lanelets" in g:
            from commonroad.geometry.shape import ShapeGroup
            polys = [sc.lanelet_network.find_lanelet_by_id(i).polygon for i in g["lanelets"]]
            gs["position"] = ShapeGroup(polys) if len(polys) > 1 else polys[0]
            lanelets_of_goal = {0: list(g["lanelets"])}
        if "orientation" in g:
            gs["orientation"] = AngleInterval(*map(float, g["orientation"]))
        if "velocity" in g:
            gs["velocity"] = Interval(*map(float, g["velocity"]))
        pps.append(PlanningProblem(unique(int(p["id"])), init, GoalRegion([CustomState(**gs)], lanelets_of_goal)))
    os.makedirs(out_dir, exist_ok=True)
    xml = os.path.join(out_dir, d["id"] + ".xml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        CommonRoadFileWriter(sc, PlanningProblemSet(pps), author="jaxplan", affiliation="", source=d.get("source", ""),
                             tags=set()).write_to_file(xml, OverwriteExistingFile.ALWAYS)
    return xml


# ----------------------------------------------------------------------------- referee

def _open(xml: str):
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc, pps = CommonRoadFileReader(xml).open()
    return sc, next(iter(pps.planning_problem_dict.values()))


def referee(xml: str, states: list) -> dict:
    """Independent verdict on a driven trajectory ``[[time_step, x, y, theta, v, a], ...]`` (world, centre)."""
    from commonroad.geometry.shape import Rectangle
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState, KSState
    from commonroad.scenario.trajectory import Trajectory
    from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
    from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import (create_collision_checker,
                                                                                       create_collision_object)

    sc, pp = _open(xml)
    cc = create_collision_checker(sc)
    _, road = create_road_boundary_obstacle(sc, method="obb_rectangles")
    shape = Rectangle(CAR_LENGTH, CAR_WIDTH)
    first_collision, first_off_road, goal_step = None, None, None
    for k, x, y, th, v, _a in states:
        box = create_collision_object(Rectangle(CAR_LENGTH, CAR_WIDTH, np.array([x, y]), th))
        if first_collision is None and cc.time_slice(int(k)).collide(box):
            first_collision = int(k)
        if first_off_road is None and road.collide(box):
            first_off_road = int(k)
        if goal_step is None and pp.goal.is_reached(KSState(time_step=int(k), position=np.array([x, y]),
                                                             orientation=th, velocity=v, steering_angle=0.0)):
            goal_step = int(k)
    # the same verdict with one time-variant collision object of the whole trajectory
    cs = [CustomState(time_step=int(s[0]), position=np.array(s[1:3]), orientation=s[3], velocity=s[4]) for s in states]
    tv_collides = None
    if len(cs) >= 2:
        ego = DynamicObstacle(sc.generate_object_id(), ObstacleType.CAR, shape,
                              InitialState(time_step=cs[0].time_step, position=cs[0].position,
                                           orientation=cs[0].orientation, velocity=cs[0].velocity,
                                           acceleration=0.0, yaw_rate=0.0, slip_angle=0.0),
                              TrajectoryPrediction(Trajectory(cs[1].time_step, cs[1:]), shape))
        tv_collides = bool(cc.collide(create_collision_object(ego)))
    return {"collision": first_collision is not None or bool(tv_collides), "first_collision_step": first_collision,
            "tv_object_collides": tv_collides, "off_road": first_off_road is not None,
            "first_off_road_step": first_off_road, "goal_reached": goal_step is not None, "goal_step": goal_step}


# ----------------------------------------------------------------------------- jaxplan closed loop

N_REF = 256  # reference line samples (fixed: one compiled shape)


def _window(boxes: np.ndarray, valid: np.ndarray, static: np.ndarray, k: int, T: int):
    """Obstacle boxes ``(K, T, 5)`` seen from step ``k``; static ones held past the recording."""
    K, S = valid.shape
    b = np.zeros((K, T, 5), np.float32)
    b[..., 2:4] = 1.0
    ok = np.zeros((K, T), bool)
    n = max(0, min(T, S - k))
    b[:, :n], ok[:, :n] = boxes[:, k:k + n], valid[:, k:k + n]
    if n < T:
        b[static, n:] = boxes[static, -1][:, None]
        ok[static, n:] = True
    b[~ok] = [0.0, 0.0, 1.0, 1.0, 0.0]
    return b, ok


def jaxplan_config(sc, lanes: str = "auto", side_lanes=None, horizon: float = 5.0, lateral_time: float = 0.0):
    """The lattice for a scenario: the BMW 320i at its centre; with ``lanes="auto"`` only the
    lanes that exist beside the start lane (``side_lanes``, -1 right / +1 left, either driving
    direction, as the peer's lateral samples also reach them; default: jaxplan's same-direction
    neighbours), at that lane's width, with lateral offsets that keep the car inside its lane
    (the lattice itself knows no road edge)."""
    from jaxplan.lattice import LatticeConfig
    from jaxplan.scenarios.loader import lane_at
    from jaxplan.types import VehicleParams
    car = VehicleParams(length=CAR_LENGTH, width=CAR_WIDTH, wheelbase=CAR_WB_FRONT + CAR_WB_REAR,
                        rear_overhang=CAR_LENGTH / 2 - CAR_WB_REAR, reference="center")
    ln = lane_at(sc, [sc.ego.x, sc.ego.y], sc.ego.heading)
    width = float(np.mean(np.linalg.norm(ln.left - ln.right, axis=1)))
    if lanes == "auto" and side_lanes is not None:
        lanes = tuple(sorted({0, *side_lanes}))
    elif lanes == "auto":
        lanes = tuple(v for v, adj in ((-1, ln.adjacent_right), (0, 0), (1, ln.adjacent_left)) if adj is not None)
    else:
        lanes = tuple(int(v) for v in lanes.split(","))
    span = float(np.clip(0.5 * (width - CAR_WIDTH) - 0.1, 0.0, 1.0))
    return LatticeConfig(horizon=horizon, lanes=lanes, target_lane=0, vehicle=car, lane_width=round(width, 2),
                         offset_span=round(span, 2), lateral_time=min(lateral_time, horizon))


def jaxplan_run(xml: str, ref_world: np.ndarray | None, max_steps: int, replan: int, lanes: str,
                v_set: float, side_lanes=None, horizon: float = 5.0, lateral_time: float = 0.0) -> dict:
    """Closed loop of ``jaxplan.lattice.plan`` on one XML file (local frame inside, world coordinates out)."""
    import jax.numpy as jnp

    from jaxplan.geometry.frenet import ReferenceLine
    from jaxplan.lattice import PlanState, plan
    from jaxplan.scenarios.commonroad import load_commonroad
    from jaxplan.scenarios.loader import lane_polyline
    from jaxplan.scenarios.polylines import uniform_resample
    from jaxplan.types import Obstacles

    sc = load_commonroad(xml)
    config = jaxplan_config(sc, lanes, side_lanes, horizon, lateral_time)
    o = np.asarray(sc.origin, float)
    route = "peer route" if ref_world is not None else "lane_polyline"
    ref = (np.asarray(ref_world, float) - o) if ref_world is not None else lane_polyline(sc, max_length=600.0)
    try:
        ref_line = ReferenceLine.from_polyline(uniform_resample(ref, N_REF).astype(np.float32))
    except ValueError as e:  # e.g. the route turns back on itself: follow the start lane instead
        route = f"lane_polyline (route rejected: {e})"
        ref_line = ReferenceLine.from_polyline(uniform_resample(lane_polyline(sc, max_length=600.0), N_REF).astype(np.float32))
    boxes = np.asarray(sc.obstacles.boxes, np.float32)
    valid = np.asarray(sc.obstacles.valid, bool)
    if boxes.shape[0] == 0:
        boxes, valid = np.zeros((1, 1, 5), np.float32), np.zeros((1, 1), bool)
    static = valid.all(1) & (np.ptp(boxes[..., :2], axis=1).max(-1) < 1e-6) & (np.ptp(boxes[..., 4], axis=1) < 1e-6)
    T = config.n_steps
    t = jnp.arange(T, dtype=jnp.float32) * config.dt
    e = sc.ego
    x = np.array([e.x, e.y, e.heading, 0.0, e.v, 0.0], np.float64)  # x, y, theta, kappa, v, a (centre)
    k0 = int(round(e.t / sc.dt))

    def once(x, k):
        b, ok = _window(boxes, valid, static, k, T)
        st = PlanState(*(jnp.asarray(v, jnp.float32) for v in (*x[:3], x[3], x[4], np.clip(x[5], config.a_min,
                                                                                             config.a_max), v_set)),
                       d_crossroad=jnp.asarray(np.inf, jnp.float32))
        res = plan(st, ref_line, Obstacles(jnp.asarray(b), jnp.asarray(ok), t), config)
        tr = res.chosen_trajectory()
        return np.stack([np.asarray(f, np.float64) for f in (tr.x, tr.y, tr.theta, tr.kappa, tr.v, tr.a)], -1), res

    once(x, 0)  # warm-up: compile for this scenario's shapes
    states = [[k0, *x[:3], x[4], x[5]]]
    cycles, traj, since = [], None, replan
    for k in range(max_steps):
        if since >= replan or traj is None:
            t0, c0 = time.perf_counter(), time.process_time()
            traj, res = once(x, k)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            cycles.append({"step": k0 + k, "wall_s": wall, "cpu_s": cpu, "candidates": config.n_candidates, "mode": int(res.mode),
                           "own_check_collided": bool(np.asarray(res.collided)[int(res.chosen)])})
            since = 0
        since += 1
        x = traj[since].copy()
        states.append([k0 + k + 1, *x[:3], x[4], x[5]])
    world = [[s[0], s[1] + o[0], s[2] + o[1], s[3], s[4], s[5]] for s in states]
    return {"scenario": os.path.basename(xml), "status": "ok", "cycles": cycles, "states": world,
            "lanes": list(config.lanes), "lane_width": config.lane_width, "offset_span": config.offset_span,
            "horizon": config.horizon, "route": route}


# ----------------------------------------------------------------------------- driver

def _stats(cycles: list) -> dict:
    w = np.array([c["wall_s"] for c in cycles]) * 1e3
    n = np.array([c["candidates"] for c in cycles])
    if not len(w):
        return {"cycles": 0}
    cpu = np.array([c["cpu_s"] for c in cycles]) * 1e3
    return {"cycles": len(w), "ms_mean": float(w.mean()), "ms_median": float(np.median(w)),
            "cpu_ms_mean": float(cpu.mean()), "cpu_ms_median": float(np.median(cpu)),
            "ms_p90": float(np.percentile(w, 90)), "candidates_mean": float(n.mean()),
            "candidates_min": int(n.min()), "candidates_max": int(n.max())}


def truncate_at_goal(states: list, verdict: dict) -> list:
    return states if verdict["goal_step"] is None else [s for s in states if s[0] <= verdict["goal_step"]]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--xml", nargs="*", default=None, help="CommonRoad XML files (default: commonroad2020a)")
    ap.add_argument("--recorded", type=int, default=4, help="recorded-traffic JSON files to convert and add")
    ap.add_argument("--peer-python", default="/tmp/peer-venv/bin/python")
    ap.add_argument("--no-peer", action="store_true", help="jaxplan only (the referee still runs in --peer-python)")
    ap.add_argument("--peer-workers", type=int, default=0, help="peer multiprocessing workers (0 = off)")
    ap.add_argument("--peer-horizon-steps", type=int, default=20,
                    help="peer horizon in 0.1 s steps (20 as in the peer's shipped scenario configs)")
    ap.add_argument("--peer-t-min", type=float, default=1.0, help="peer shortest sampled duration (s)")
    ap.add_argument("--route", choices=("peer", "lane"), default="peer")
    ap.add_argument("--replan", type=int, default=3, help="re-plan every this many 0.1 s steps")
    ap.add_argument("--max-steps", type=int, default=150)
    ap.add_argument("--jaxplan-horizon", type=float, default=5.0, help="lattice horizon (s); jaxplan's default 5")
    ap.add_argument("--lateral-time", type=float, default=0.0,
                    help="lattice lateral_time (s): offset reached by then; 0 = over the horizon (default)")
    ap.add_argument("--lanes", default="auto", help="jaxplan lattice lanes, e.g. -1,0,1 (auto: those that exist)")
    ap.add_argument("--out", default="/tmp/compare_reactive_planner.json")
    ap.add_argument("--worker", choices=("peer", "prep", "referee"), help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    ap.add_argument("--worker-in", help=argparse.SUPPRESS)
    ap.add_argument("--json", nargs="*", default=[], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker_main(args)

    xmls = args.xml or sorted(glob.glob(os.path.join(DATA, "commonroad2020a", "*.xml")))
    rec = sorted(glob.glob(os.path.join(DATA, "commonroad2018a", "*.json")))
    rec = rec[:: max(1, len(rec) // max(1, args.recorded))][:args.recorded] if args.recorded > 0 else []
    if not os.path.exists(args.peer_python):
        sys.exit(f"{args.peer_python} not found: the peer and the referee (commonroad-io 2024 + "
                 "commonroad-drivability-checker) run there; see the setup in this script's docstring")
    tmp = tempfile.mkdtemp(prefix="cmp_rp_")
    prep = child(args.peer_python, "prep", tmp, ["--max-steps", str(args.max_steps), "--xml", *xmls,
                                                 "--json", *rec])
    notes, xmls, info = prep["notes"], prep["xmls"], prep["info"]
    steps = {x: info[x]["steps"] for x in xmls}

    peer = {}
    if not args.no_peer:
        for x in xmls:  # one child per scenario: a crash in one does not lose the others
            try:
                peer[x] = child(args.peer_python, "peer", tmp, [
                    "--max-steps", str(steps[x]), "--replan", str(args.replan), "--peer-workers",
                    str(args.peer_workers), "--peer-horizon-steps", str(args.peer_horizon_steps),
                    "--peer-t-min", str(args.peer_t_min), "--xml", x])[0]
            except RuntimeError as e:
                peer[x] = {"scenario": os.path.basename(x), "status": f"peer process failed: {e}",
                           "cycles": [], "states": []}
    elif args.route == "peer":
        args.route = "lane"

    rows = []
    for x in xmls:
        name = os.path.basename(x)[:-4]
        v_set = info[x]["v_set"]
        row = {"scenario": name, "steps": steps[x], "v_set": v_set}
        if x in peer:
            p = peer[x]
            row["peer"] = {"status": p["status"], **_stats(p["cycles"])}
            if p["states"]:
                row["peer"].update(judge(args.peer_python, tmp, x, p["states"]))
                row["peer"]["driven_steps"] = len(p["states"]) - 1
            row["peer"]["trajectory"] = p["states"]
            row["peer"]["levels"] = [c["levels"] for c in p["cycles"]]
        ref = None
        if args.route == "peer":
            ref = peer.get(x, {}).get("reference_path")
            if ref is None:
                row["jaxplan_route"] = "lane (peer gave no route)"
        try:
            j = jaxplan_run(x, ref, steps[x], args.replan, args.lanes, v_set, info[x].get("side_lanes"),
                           args.jaxplan_horizon, args.lateral_time)
            v = judge(args.peer_python, tmp, x, j["states"])
            # the peer stops at its goal; judge jaxplan's drive up to the goal step too
            v = judge(args.peer_python, tmp, x, truncate_at_goal(j["states"], v))
            # cycles after the goal step do not count (the peer stops there)
            cyc = [c for c in j["cycles"] if v["goal_step"] is None or c["step"] < v["goal_step"]]
            row["jaxplan"] = {"status": "goal" if v["goal_reached"] else "ok", **_stats(cyc), **v,
                              "driven_steps": len(truncate_at_goal(j["states"], v)) - 1,
                              "own_check_collided_cycles": int(sum(c["own_check_collided"] for c in cyc)),
                              "modes": [c["mode"] for c in cyc], "trajectory": j["states"],
                              **{k: j[k] for k in ("lanes", "lane_width", "offset_span", "horizon", "route")}}
        except Exception as e:
            row["jaxplan"] = {"status": f"failed: {type(e).__name__}: {e}"}
        rows.append(row)
        print(f"done {name}", flush=True)

    print_table(rows)
    out = {"rows": rows, "notes": notes, "args": vars(args),
           "cpu_count": os.cpu_count()}
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    for n in notes:
        print("note:", n)
    print(f"wrote {args.out}")
    return out


def print_table(rows: list) -> None:
    hdr = (f"{'scenario':28s} {'planner':8s} {'status':14s} {'goal':>4s} {'coll':>4s} {'offrd':>5s} {'steps':>5s} "
           f"{'cycles':>6s} {'ms mean':>8s} {'ms med':>7s} {'cpu med':>7s} {'cand':>6s}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        for who in ("peer", "jaxplan"):
            d = r.get(who)
            if d is None:
                continue
            yn = lambda k: "-" if k not in d else ("yes" if d[k] else "no")
            f = lambda k, fmt: format(d[k], fmt) if k in d else "-"
            print(f"{r['scenario'][:28]:28s} {who:8s} {d['status'][:14]:14s} {yn('goal_reached'):>4s} "
                  f"{yn('collision'):>4s} {yn('off_road'):>5s} {f('driven_steps', 'd'):>5s} {f('cycles', 'd'):>6s} "
                  f"{f('ms_mean', '.1f'):>8s} {f('ms_median', '.1f'):>7s} {f('cpu_ms_median', '.1f'):>7s} "
                  f"{f('candidates_mean', '.0f'):>6s}")


if __name__ == "__main__":
    main()
