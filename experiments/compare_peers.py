"""Peers in jaxplan's closed-loop harness: the CommonRoad reactive planner and Frenetix, one referee.

Every planner drives the same scenarios in closed loop: it re-plans every ``--replan`` steps of
0.1 s (default 3 = 0.3 s) from the state it has reached, and the car follows the chosen plan
exactly (perfect tracking). All follow the same route (the reference path of ``routes.json``),
get the same set speed, and drive the BMW 320i (4.508 m x 1.61 m, the reactive planner's and
Frenetix's car). A drive ends when the goal is reached (CommonRoad's rule, on the car's centre),
at the end of the goal's time interval, or after ``--max-steps``. When a planner finds no
trajectory (or raises), the car goes on along its previous plan and the planner tries again next
step; with no plan left, the car brakes straight ahead at 8 m/s^2 (to a stand) and the planner
tries again every step.

Peers, each in its own virtual environment (their pins conflict with jaxplan's commonroad-io
2026.1); this script runs itself there as child processes (``--worker``), trajectories go
through JSON files:

* ``reactive``: ``commonroad-reactive-planner==2025.1`` (pins commonroad-io 2024.x), configured
  as its shipped scenario configurations: 2 s horizon (``--reactive-horizon-steps 20``),
  shortest sampled duration ``--reactive-t-min 1.0``, its sampling levels and cost function;
  it plans from the rear axle, so the route is extended 10 m straight backwards.
* ``frenetix``: ``frenetix==0.4.0`` (the C++ sampler and cost/feasibility functions; the
  ``frenetix-motion-planner`` 2024.1.1 package needs Python < 3.11) with the sampling loop of
  Frenetix's motion planner written here: 3 s horizon, end times 1.1..3 s, lateral offsets
  -3..3 m, end speeds in [v - 0.5 a_max T, v + a_max T / 7] at sampling level 2, its shipped
  cost weights (jerk, velocity offset to the set speed, distance to the reference path,
  collision probability of the recorded futures), its feasibility checks (yaw rate,
  acceleration, curvature, curvature rate), then the cheapest candidate that
  commonroad-drivability-checker finds free of every obstacle and of the road boundary; none
  free: its "stopping" emergency choice (lowest end speed, shortest, nearest offset).

Both peers see every obstacle's recorded future (as CommonRoad benchmarks do), static ones at
every time. Set speed (the same for every planner, from the scenario, never the current speed):
the middle of the goal's speed interval where the goal gives one, else the speed limit of the
start lanelet, else the speed that reaches the goal region's centre along the route at the
middle of the goal's time interval (clipped to 2..36 m/s), else the start speed.

Route: ``--routes FILE`` (``{"routes": {key: [[x, y], ...]}}``, world coordinates), else built by
``ROUTE_BUILDER`` below: jaxplan's route (``jaxplan.scenarios.files.world_route``: the route to
the goal lanelets that jaxplan's planners drive on, in world coordinates), so every planner follows
the same route; ``ROUTE_BUILDER = None`` uses commonroad-route-planner's shortest reference path.

Scenarios: ``--scenarios`` takes files and folders (searched recursively, as
``jaxplan.scenarios.files.expand_paths`` does): shared JSON and CommonRoad 2020a XML, either
gzip-compressed (``.json.gz``, ``.xml.gz``; the peers' workers decompress in memory).
``--sample N --seed S`` drives ``jaxplan.scenarios.files.sample_files`` of the expanded list (seeded,
stratified by folder). The chosen files go to ``sample.json`` (``files``, ``keys``) and
``sample.txt`` (one a line), so jaxplan's planners can later drive exactly the same files:
``jaxplan drive $(cat OUT/sample.txt) --planner NAME --out DIR --replan-every 3 --max-steps 300``,
then ``--judge-only --drives NAME=DIR`` here (same ``--scenarios --sample --seed``).

Resume: a scene whose ``<peer>/<key>/cycles.json`` exists (written last, when the drive is over,
also when the peer found no plan or failed) is not driven again; ``--redo`` drives it again. The
scenario facts and routes are kept in ``prep.json`` and reused while the file list is the same.
An interrupted run is resumed by running the same command again.

Settings: every run prints, and ``report.md`` holds, a table of the settings that differ between
the planners (horizon, sampling, set speed rule, ...; jaxplan's road planners' horizon and car read
from jaxplan) with the reason, and of those that are equal.

A scene a peer cannot drive is never dropped: a setup failure (the scenario or its route cannot be
built) is a ``not run: ...`` status, a peer that raises at setup a ``setup failed: ...`` status, a
planning call that raises is recorded in ``cycles.json`` (the car goes on as when no plan is
found); the report lists every such scene with its reason.

Referee (``jaxplan.eval.referee``, commonroad-drivability-checker + commonroad-io's goal check)
judges every folder in the same run: the peers' and, with ``--drives LABEL=DIR`` or
``--jaxplan NAME``, jaxplan's ``jaxplan drive`` output. It runs under ``--referee-python``, an
environment with jaxplan's dependencies and ``jaxplan[referee]`` (commonroad-io < 2026); default
``/work/venvs/referee`` where it exists, else the interpreter running this script (jaxplan's venv
with ``jaxplan[referee]`` serves). The referee opens scenario files by name; here it reads
``.gz`` files too (decompressed in memory, the same scenario objects).

Outputs in ``--out``: ``<peer>/<key>/driven.json`` (the format ``jaxplan drive`` writes) and
``<peer>/<key>/cycles.json`` (status, wall and CPU time of each planning call, the drive's wall
time), ``sample.json`` and ``sample.txt`` (the files driven), ``prep.json``, ``routes.json``,
``scenarios.json`` (set speed, steps, setup notes), ``compare_peers.json`` (every verdict, the
summary, counts per scenario folder, the settings table) and ``report.md`` (the tables).
``<key>`` is the scenario id, made unique as ``jaxplan.scenarios.files.scenario_keys`` does.
Success: a judged drive that reached the goal with no collision and without leaving the road.

Setup (once)::

    python3 -m venv /work/venvs/reactive && /work/venvs/reactive/bin/pip install commonroad-reactive-planner==2025.1
    python3 -m venv /work/venvs/frenetix && /work/venvs/frenetix/bin/pip install frenetix==0.4.0 \\
        commonroad-io==2024.3 commonroad-drivability-checker==2025.4.0
    python3 -m venv /work/venvs/referee && /work/venvs/referee/bin/pip install -e '.[referee]' \\
        'commonroad-io==2024.3'

(or ``--referee-python .venv/bin/python`` where jaxplan's venv has ``jaxplan[referee]``).

Run (from the repository root; both peers on all 50 shared scenarios)::

    .venv/bin/python experiments/compare_peers.py --out results/peers

The final comparison with jaxplan's planners in the same run (``jaxplan drive`` runs first, under
this interpreter, on the same files, the sample where ``--sample`` is given, into
``results/peers/jaxplan-<name>``)::

    .venv/bin/python experiments/compare_peers.py --out results/peers --jaxplan lattice pathspeed

Judge existing folders only (no driving)::

    .venv/bin/python experiments/compare_peers.py --out results/peers --judge-only --drives lattice=results/drive

A seeded sample of the gzip-compressed dev set, peers only (long: run it in the background; the
same command resumes)::

    nice -n 10 .venv/bin/python experiments/compare_peers.py --scenarios ../shared/data/commonroad \\
        --sample 200 --seed 0 --max-steps 300 --out results/peers200 --referee-python .venv/bin/python

Timings are per planning call (wall and process CPU time, peers single-threaded); on a shared
machine they are noisy.
"""
from __future__ import annotations

import argparse
import copy
import importlib
import json
import math
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
DEFAULT_SCENARIOS = [os.path.join(DATA, "commonroad2018a"), os.path.join(DATA, "commonroad2020a")]

# The reference path every planner follows: "module:function" taking a scenario file and returning
# its route as (N, 2) world points, called in the referee's environment; None = commonroad-route-planner
# in the reactive planner's venv. Switch with this one line once jaxplan's route builder is on main, e.g.
ROUTE_BUILDER = "jaxplan.scenarios.files:world_route"  # the route every jaxplan planner drives on

# BMW 320i (CommonRoad vehicle type 2), the reactive planner's and Frenetix's default car.
CAR_LENGTH, CAR_WIDTH = 4.508, 1.61
DT = 0.1  # s: the harness's step
WB_REAR = 1.4227170936  # centre to rear axle
PEERS = ("reactive", "frenetix")
VENVS = {"reactive": "/work/venvs/reactive/bin/python", "frenetix": "/work/venvs/frenetix/bin/python",
         "referee": "/work/venvs/referee/bin/python"}


def _quiet():
    import logging
    import warnings

    warnings.simplefilter("ignore")
    logging.disable(logging.WARNING)


def _write_json(path: str, obj) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump(obj, f)


def _write_json_atomic(path: str, obj) -> None:
    """``_write_json`` through a temporary file, so an interrupted run leaves no half-written file."""
    tmp = path + ".part"
    _write_json(tmp, obj)
    os.replace(tmp, path)


def _read_xml_set(xml: str):
    """commonroad-io's ``(Scenario, PlanningProblemSet)`` of a CommonRoad XML file, ``.xml`` or
    gzip-compressed ``.xml.gz`` (decompressed in memory; the peers' venvs have no jaxplan)."""
    import gzip
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.common.util import FileFormat

    if xml.lower().endswith(".gz"):
        try:
            with gzip.open(xml, "rb") as f:
                src = f.read()
        except (OSError, EOFError) as e:
            raise ValueError(f"{xml}: not a readable gzip file ({e})") from None
    else:
        src = xml
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return CommonRoadFileReader(src, FileFormat.XML).open()


def _read_xml(xml: str):
    sc, pps = _read_xml_set(xml)
    problems = list(pps.planning_problem_dict.values())
    if not problems:
        raise ValueError(f"{xml}: no planning problem")
    return sc, problems[0]


# ----------------------------------------------------------------------------- prep (referee env)

def prep_worker(paths: list, out: str) -> dict:
    """Keys, CommonRoad XML for the peers, and each scenario's facts (runs with jaxplan importable)."""
    _quiet()
    sys.path.insert(0, ROOT)
    from jaxplan.scenarios.commonroad import _speed_limits, write_commonroad
    from jaxplan.scenarios.files import scenario_format, scenario_keys
    from jaxplan.scenarios.loader import read_bytes

    keys = scenario_keys(paths)
    info = {}
    for key, path in keys.items():
        row = {"path": os.path.abspath(path)}
        try:
            if scenario_format(path) == "json":
                d = json.loads(read_bytes(path))
                row["xml"] = write_commonroad(d, os.path.join(out, "_xml", key + ".xml"), path)
            else:
                row["xml"] = os.path.abspath(path)
            sc, pp = _read_xml(row["xml"])
            row.update(_facts(sc, pp, _speed_limits(sc)))
        except Exception as e:  # noqa: BLE001 - reported per scenario
            row["error"] = f"setup failed: {type(e).__name__}: {e}"
        if ROUTE_BUILDER and "error" not in row:
            mod, fn = ROUTE_BUILDER.split(":")
            try:
                row["route"] = np.asarray(getattr(importlib.import_module(mod), fn)(path), float).tolist()
            except Exception as e:  # noqa: BLE001
                row["route_error"] = f"{type(e).__name__}: {e}"
        info[key] = row
    return info


def _facts(sc, pp, limits: dict) -> dict:
    """Start step, goal windows and centre, start-lane speed limit of a CommonRoad scenario."""
    dt = float(sc.dt)
    st = pp.initial_state
    gs = pp.goal.state_list[0]
    ts = getattr(gs, "time_step", None)
    vel = getattr(gs, "velocity", None)
    centre = None
    if getattr(gs, "position", None) is not None:
        lanelets = (pp.goal.lanelets_of_goal_position or {}).get(0)
        if lanelets:
            pts = np.concatenate([sc.lanelet_network.find_lanelet_by_id(i).center_vertices for i in lanelets])
            centre = pts.mean(0).tolist()
        else:
            c = getattr(gs.position, "center", None)
            c = getattr(gs.position, "rect_center", None) if c is None else c
            if c is not None:
                centre = [float(c[0]), float(c[1])] if not hasattr(c, "x") else [float(c.x), float(c.y)]
    start = sc.lanelet_network.find_lanelet_by_position([np.asarray(st.position, float)])[0]
    lim = [limits[i] for i in start if i in limits]
    return {"dt": dt, "t0_step": int(st.time_step), "v0": float(st.velocity), "start": np.asarray(st.position, float).tolist(),
            "goal_steps": [int(ts.start), int(ts.end)] if ts is not None and hasattr(ts, "start") else None,
            "goal_velocity": [float(vel.start), float(vel.end)] if vel is not None and hasattr(vel, "start") else None,
            "goal_centre": centre, "speed_limit": min(lim) if lim else None, "start_lanelets": [int(i) for i in start]}


# ----------------------------------------------------------------------------- route (reactive env)

def route_worker(xmls: dict) -> dict:
    """commonroad-route-planner's shortest reference path per scenario (world points)."""
    _quiet()
    from commonroad_route_planner.reference_path_planner import ReferencePathPlanner
    from commonroad_route_planner.route_planner import RoutePlanner

    out = {}
    for key, xml in xmls.items():
        try:
            sc, pp = _read_xml(xml)
            routes = RoutePlanner(sc.lanelet_network, pp).plan_routes()
            ref = ReferencePathPlanner(sc.lanelet_network, pp, routes).plan_shortest_reference_path().reference_path
            out[key] = {"route": np.asarray(ref, float).tolist(), "route_from": "commonroad-route-planner"}
        except Exception as e:  # noqa: BLE001
            why = f"route planner failed ({type(e).__name__}: {str(e)[:120]})"
            try:
                out[key] = {"route": _lane_route(sc, pp).tolist(), "route_from": f"start lane and successors; {why}"}
            except Exception as e2:  # noqa: BLE001
                out[key] = {"error": f"{why}; no start lane either ({type(e2).__name__}: {e2})"}
    return out


def _lane_route(sc, pp, max_length: float = 600.0) -> np.ndarray:
    """Fallback route: the start lanelet (heading closest to the car's) and its first successors."""
    net = sc.lanelet_network
    p = np.asarray(pp.initial_state.position, float)
    ids = net.find_lanelet_by_position([p])[0]
    if not ids:
        raise ValueError("the start lies on no lanelet")

    def heading_gap(i):
        c = net.find_lanelet_by_id(i).center_vertices
        j = min(int(np.argmin(np.linalg.norm(c - p, axis=1))), len(c) - 2)
        d = c[j + 1] - c[j]
        return abs(math.remainder(math.atan2(d[1], d[0]) - float(pp.initial_state.orientation), 2 * math.pi))

    ln = net.find_lanelet_by_id(min(ids, key=heading_gap))
    pts, seen = [ln.center_vertices], {ln.lanelet_id}
    while ln.successor and sum(len(q) for q in pts) < 10000:
        ln = net.find_lanelet_by_id(ln.successor[0])
        if ln is None or ln.lanelet_id in seen:
            break
        seen.add(ln.lanelet_id)
        pts.append(ln.center_vertices[1:])
        r = np.concatenate(pts)
        if np.linalg.norm(np.diff(r, axis=0), axis=1).sum() > max_length:
            break
    r = np.concatenate(pts)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(s) > 1e-6])
    q = np.linspace(0.0, s[-1], max(2, int(s[-1] // 1.0) + 1))  # 1 m spacing, as the route planner's
    return np.column_stack([np.interp(q, s[keep], r[keep, 0]), np.interp(q, s[keep], r[keep, 1])])


def set_speed(facts: dict, route) -> tuple[float, str]:
    """The set speed every planner gets (see the module docstring) and where it came from."""
    gv = facts.get("goal_velocity")
    if gv is not None:
        v = 0.5 * (gv[0] + gv[1])
        if facts.get("speed_limit") is not None:
            v = min(v, facts["speed_limit"])
        return float(v), "goal speed interval"
    if facts.get("speed_limit") is not None:
        return float(facts["speed_limit"]), "speed limit"
    gs, centre = facts.get("goal_steps"), facts.get("goal_centre")
    if gs is not None and centre is not None and route is not None and len(route) > 1:
        r = np.asarray(route, float)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))])
        s_goal = s[int(np.argmin(np.linalg.norm(r - np.asarray(centre), axis=1)))]
        s_start = s[int(np.argmin(np.linalg.norm(r - np.asarray(facts["start"]), axis=1)))]
        t_mid = 0.5 * (gs[0] + gs[1]) * facts["dt"] - facts["t0_step"] * facts["dt"]
        if t_mid > 0 and s_goal > s_start:
            return float(np.clip((s_goal - s_start) / t_mid, 2.0, 36.0)), "route distance to goal / goal time"
    return float(facts["v0"]), "start speed (no speed limit or goal given)"


# ----------------------------------------------------------------------------- peers (their envs)

def _centre_row(k: int, dt: float, rear_x, rear_y, th, v, a) -> list:
    """A driven.json row from a rear-axle state."""
    return [round(k * dt, 6), float(rear_x + WB_REAR * math.cos(th)), float(rear_y + WB_REAR * math.sin(th)),
            float(th), float(v), float(a)]


BRAKE = 8.0  # m/s^2: the fallback when a planner has no plan left (straight ahead, then standing)


def _brake(x: tuple, dt: float) -> tuple:
    """One step of the fallback from rear-axle state ``(x, y, theta, v, a)``: brake straight ahead."""
    v1 = max(0.0, x[3] - BRAKE * dt)
    d = 0.5 * (x[3] + v1) * dt
    return (x[0] + d * math.cos(x[2]), x[1] + d * math.sin(x[2]), x[2], v1, -BRAKE if x[3] > 0 else 0.0)


def _goal_reached(pp, row: list, k: int) -> bool:
    from commonroad.scenario.state import KSState
    return bool(pp.goal.is_reached(KSState(time_step=int(k), position=np.array(row[1:3]),
                                           orientation=float(math.remainder(row[3], 2 * math.pi)),
                                           velocity=float(row[4]), steering_angle=0.0)))


def _crop_route(job: dict, start) -> np.ndarray:
    """The route up to 1 km past what the drive can reach (a route planner may return kilometres:
    DEU_Hhr-1_1's goal lies behind the start, at the end of a 4.6 km loop); its start as given."""
    r = np.asarray(job["route"], float)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))])
    near = s <= 200.0  # the route begins at the start lanelet; a loop's end may pass the start again
    s0 = s[near][int(np.argmin(np.linalg.norm(r[near] - np.asarray(start, float), axis=1)))]
    reach = (max(job["v_set"], job.get("v0", 0.0)) + 10.0) * job["steps"] * 0.1 + 100.0
    keep = s <= s0 + reach + 1000.0
    return r[keep] if keep.sum() >= 2 else r


def _extend_back(ref: np.ndarray, metres: float = 10.0) -> np.ndarray:
    """The route extended ``metres`` straight backwards (the peers plan from the rear axle, which can lie
    behind the route's first point)."""
    u = ref[0] - ref[1]
    return np.concatenate([ref[:1] + np.linspace(metres, 1.0, 10)[:, None] * u / np.linalg.norm(u), ref])


def reactive_worker(job: dict) -> dict:
    """Closed loop of the reactive planner on one scenario (runs in its venv)."""
    _quiet()
    from commonroad_rp.reactive_planner import ReactivePlanner
    from commonroad_rp.utility.config import ReactivePlannerConfiguration
    from commonroad_rp.utility.utils_coordinate_system import create_coordinate_system

    sc, pp = _read_xml(job["xml"])
    cfg = ReactivePlannerConfiguration()
    cfg.debug.logging_level = "ERROR"
    cfg.debug.multiproc = False
    cfg.planning.time_steps_computation = job["horizon_steps"]
    cfg.planning.planning_horizon = job["horizon_steps"] * cfg.planning.dt
    cfg.planning.replanning_frequency = job["replan"]
    cfg.sampling.t_min = job["t_min"]
    cfg.update(scenario=sc, planning_problem=pp)
    out = {"status": "ok", "cycles": [], "rows": []}
    try:
        planner = ReactivePlanner(cfg)
        route = _extend_back(_crop_route(job, pp.initial_state.position))
        planner.set_reference_path(coordinate_system=create_coordinate_system(route))
    except Exception as e:  # noqa: BLE001 - the peer cannot run here
        out["status"] = f"setup failed: {type(e).__name__}: {e}"
        return out
    dt, k0 = float(sc.dt), int(pp.initial_state.time_step)
    x = planner.x_0
    rows = [_centre_row(k0, dt, *x.position, x.orientation, x.velocity, getattr(x, "acceleration", 0.0) or 0.0)]
    plan, since, plan_ok = None, 0, False  # plan: (state list, curvilinear lon/lat); index driven last
    for k in range(k0, k0 + job["steps"]):
        if _goal_reached(pp, rows[-1], k):
            out["status"] = "goal"
            break
        if plan is None or since >= job["replan"] or not plan_ok:
            planner.set_desired_velocity(desired_velocity=job["v_set"], current_speed=planner.x_0.velocity)
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                res = planner.plan()
                err = None
            except Exception as e:  # noqa: BLE001
                res, err = None, f"{type(e).__name__}: {e}"
            out["cycles"].append({"step": k, "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                                  "found": bool(res), **({"error": err} if err else {})})
            plan_ok = bool(res)
            if res:
                plan, since = (res[0].state_list, res[1], res[2]), 0
        if plan is None or since + 1 >= len(plan[0]):  # no plan left: brake, plan again next step
            x = planner.x_0
            b = _brake((*x.position, x.orientation, x.velocity, getattr(x, "acceleration", 0.0) or 0.0), dt)
            nxt = copy.deepcopy(x)
            nxt.time_step, nxt.position, nxt.velocity, nxt.acceleration = k + 1, np.array(b[:2]), b[3], b[4]
            out["braked_steps"] = out.get("braked_steps", 0) + 1
            plan, curv = None, None
        else:
            since += 1
            nxt = plan[0][since]
            curv = (plan[1][since], plan[2][since])
        try:
            planner.reset(initial_state_cart=nxt, initial_state_curv=curv, collision_checker=planner.collision_checker,
                          coordinate_system=planner.coordinate_system)
        except Exception:  # noqa: BLE001 - the braked state lies outside its frame: it plans again next step
            planner.x_0, planner.x_0_cl = nxt, None
        rows.append(_centre_row(k + 1, dt, *nxt.position, nxt.orientation, nxt.velocity,
                                getattr(nxt, "acceleration", 0.0) or 0.0))
    else:
        if _goal_reached(pp, rows[-1], k0 + len(rows) - 1):
            out["status"] = "goal"
    out["rows"] = rows
    return out


class _FrenetixLoop:
    """Frenetix's sampling loop around ``frenetix`` 0.4.0 (after frenetix-motion-planner's
    ``ReactivePlannerCpp.plan``; the C++ functions are frenetix's own)."""

    HORIZON, T_MIN, D_MIN, D_MAX, LEVEL = 3.0, 1.1, -3.0, 3.0, 2
    WEIGHTS = {"lateral_jerk": 1.0, "longitudinal_jerk": 1.0, "velocity_offset": 1.0,
               "distance_to_reference_path": 3.0, "prediction": 200.0}

    def __init__(self, sc, pp, route: np.ndarray, v_set: float):
        import frenetix
        from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
        from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_checker
        from vehiclemodels.parameters_vehicle2 import parameters_vehicle2

        self.fx, self.sc, self.pp, self.v_set = frenetix, sc, pp, v_set
        self.car = parameters_vehicle2()
        self.wheelbase = self.car.a + self.car.b
        self.dt = float(sc.dt)
        self.N = int(round(self.HORIZON / self.dt))
        self.cs = frenetix.CoordinateSystemWrapper(np.ascontiguousarray(route, dtype=np.float64))
        self.cc = create_collision_checker(sc)
        _, road = create_road_boundary_obstacle(sc)
        self.cc.add_collision_object(road)

    def _handler(self, x0, k: int, low_v: bool):
        import frenetix.trajectory_functions as tf
        import frenetix.trajectory_functions.cost_functions as cf
        import frenetix.trajectory_functions.feasability_functions as ff

        c, w = self.car, self.WEIGHTS
        h = self.fx.TrajectoryHandler(dt=self.dt)
        h.add_feasability_function(ff.CheckYawRateConstraint(deltaMax=c.steering.max, wheelbase=self.wheelbase,
                                                             wholeTrajectory=False))
        h.add_feasability_function(ff.CheckAccelerationConstraint(switchingVelocity=c.longitudinal.v_switch,
                                                                  maxAcceleration=c.longitudinal.a_max,
                                                                  wholeTrajectory=False))
        h.add_feasability_function(ff.CheckCurvatureConstraint(deltaMax=c.steering.max, wheelbase=self.wheelbase,
                                                               wholeTrajectory=False))
        h.add_feasability_function(ff.CheckCurvatureRateConstraint(wheelbase=self.wheelbase,
                                                                   velocityDeltaMax=c.steering.v_max,
                                                                   wholeTrajectory=False))
        h.add_cost_function(cf.CalculateLateralJerkCost("lateral_jerk", w["lateral_jerk"]))
        h.add_cost_function(cf.CalculateLongitudinalJerkCost("longitudinal_jerk", w["longitudinal_jerk"]))
        h.add_cost_function(cf.CalculateDistanceToReferencePathCost("distance_to_reference_path",
                                                                    w["distance_to_reference_path"]))
        h.add_function(tf.FillCoordinates(lowVelocityMode=low_v, initialOrientation=float(x0[2]),
                                          coordinateSystem=self.cs, horizon=int(self.HORIZON)))
        h.add_cost_function(cf.CalculateCollisionProbabilityFast("prediction", w["prediction"], self._predictions(k),
                                                                 c.l, c.w, c.b))
        h.add_cost_function(cf.CalculateVelocityOffsetCost("velocity_offset", w["velocity_offset"], self.v_set,
                                                           self.dt, self.T_MIN, limit_to_t_min=False, norm_order=2))
        return h

    def _predictions(self, k: int) -> dict:
        """Every obstacle's recorded future over the horizon (static ones held), fixed small covariance."""
        cov = np.zeros((6, 6))
        cov[:2, :2] = 0.1 * np.eye(2)
        cov = np.asfortranarray(cov)
        out = {}
        for o in self.sc.obstacles:
            path = []
            for j in range(self.N + 1):
                occ = o.state_at_time(k + j) if o.obstacle_role.value == "dynamic" else o.initial_state
                if occ is None:
                    break
                th = float(occ.orientation)
                path.append(self.fx.PoseWithCovariance(np.array([*map(float, occ.position), 0.0]),
                                                       np.array([0.0, 0.0, math.sin(th / 2), math.cos(th / 2)]), cov))
            shape = o.obstacle_shape
            if len(path) > 1 and hasattr(shape, "length"):
                out[int(o.obstacle_id)] = self.fx.PredictedObject(int(o.obstacle_id), path, float(shape.length),
                                                                  float(shape.width))
        return out

    def _levels(self, v: float):
        """End times, speeds and offsets at Frenetix's sampling level (its density rule)."""
        a = self.car.longitudinal.a_max
        lo, hi = max(0.01, v - 0.5 * a * self.HORIZON), min(v + a / 7.0 * self.HORIZON, 36.0, self.car.longitudinal.v_max)
        n = 3
        for _ in range(self.LEVEL):
            n = 2 * n - 1
        step = int((1 / (self.LEVEL + 1)) / self.dt) * self.dt
        t1 = set(np.round(np.arange(self.T_MIN, self.HORIZON + self.dt, step), 2)) | {round(self.N * self.dt, 2)}
        t1 = {t for t in t1 if t <= self.HORIZON + 1e-9}
        return np.array(sorted(t1)), np.linspace(lo, hi, n), np.linspace(self.D_MIN, self.D_MAX, n)

    def collides(self, traj) -> bool:
        """Candidate's centre boxes from the next step on against every obstacle and the road boundary."""
        from commonroad_dc import pycrcc

        x, y, th = np.asarray(traj.cartesian.x), np.asarray(traj.cartesian.y), np.asarray(traj.cartesian.theta)
        tvo = pycrcc.TimeVariantCollisionObject(self.k + 1)
        for i in range(1, len(x)):
            tvo.append_obstacle(pycrcc.RectOBB(0.5 * self.car.l, 0.5 * self.car.w, float(th[i]),
                                               float(x[i] + self.car.b * math.cos(th[i])),
                                               float(y[i] + self.car.b * math.sin(th[i]))))
        return bool(self.cc.collide(tvo))

    def plan(self, x0, k: int, x_cl=None):
        """One planning cycle from rear-axle state ``x0 = (x, y, theta, v, a)`` at step ``k``.

        Returns:
            ``(trajectory sample or None, candidates sampled, mode)``.
        """
        self.k = k
        low_v = x0[3] < 2.0
        if x_cl is None:
            init = self.fx.TrajectorySample(x0=float(x0[0]), y0=float(x0[1]), orientation0=float(x0[2]),
                                            acceleration0=float(x0[4]), velocity0=float(x0[3]))
            self.fx.trajectory_functions.ComputeInitialState(coordinateSystem=self.cs, wheelBase=self.wheelbase,
                                                             steeringAngle=0.0, lowVelocityMode=low_v
                                                             ).evaluate_trajectory(init)
            c = init.curvilinear
            f0 = lambda a: float(np.asarray(a).ravel()[0])  # noqa: E731
            lon, lat = [f0(c.s), f0(c.s_dot), f0(c.s_ddot)], [f0(c.d), f0(c.d_dot), f0(c.d_ddot)]
        else:
            lon, lat = x_cl
        t1, v1, d1 = self._levels(x0[3])
        v1 = np.union1d(v1, [lon[1]])
        d1 = np.union1d(d1, [lat[0]])
        grid = np.array(np.meshgrid(t1, v1, d1, indexing="ij")).reshape(3, -1).T
        M = np.zeros((len(grid), 13))
        M[:, 1], M[:, 5], M[:, 10] = grid[:, 0], grid[:, 1], grid[:, 2]
        M[:, 2], M[:, 3], M[:, 4] = lon
        M[:, 7], M[:, 8], M[:, 9] = lat
        h = self._handler(x0, k, low_v)
        h.reset_Trajectories()
        h.generate_trajectories(M, low_v)
        h.evaluate_all_current_functions(True)
        feasible = [t for t in h.get_sorted_trajectories() if t.feasible]
        for t in feasible:
            if not self.collides(t):
                return t, len(M), "optimal"
        if feasible:  # Frenetix's "stopping" emergency mode
            stop = min(feasible, key=lambda t: (round(t.sampling_parameters[5], 6), round(t.sampling_parameters[1], 6),
                                                abs(t.sampling_parameters[10] - lat[0])))
            return stop, len(M), "stopping"
        return None, len(M), "none feasible"


def frenetix_worker(job: dict) -> dict:
    """Closed loop of the Frenetix sampling loop on one scenario (runs in its venv)."""
    _quiet()
    sc, pp = _read_xml(job["xml"])
    out = {"status": "ok", "cycles": [], "rows": []}
    try:
        loop = _FrenetixLoop(sc, pp, _extend_back(_crop_route(job, pp.initial_state.position)), job["v_set"])
    except Exception as e:  # noqa: BLE001
        out["status"] = f"setup failed: {type(e).__name__}: {e}"
        return out
    dt, k0 = float(sc.dt), int(pp.initial_state.time_step)
    s = pp.initial_state
    th = float(s.orientation)
    rear = np.asarray(s.position, float) - WB_REAR * np.array([math.cos(th), math.sin(th)])
    x = (rear[0], rear[1], th, float(s.velocity), float(getattr(s, "acceleration", 0.0) or 0.0))
    rows = [_centre_row(k0, dt, *x)]
    plan, since, x_cl, fresh = None, 0, None, False
    for k in range(k0, k0 + job["steps"]):
        if _goal_reached(pp, rows[-1], k):
            out["status"] = "goal"
            break
        if plan is None or since >= job["replan"] or not fresh:
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                res, n, mode = loop.plan(x, k, x_cl)
                err = None
            except Exception as e:  # noqa: BLE001
                res, n, mode, err = None, 0, "raised", f"{type(e).__name__}: {e}"
            out["cycles"].append({"step": k, "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                                  "found": res is not None, "candidates": n, "mode": mode,
                                  **({"error": err} if err else {})})
            fresh = res is not None
            if res is not None:
                c, cl = res.cartesian, res.curvilinear
                plan = (np.column_stack([c.x, c.y, c.theta, c.v, c.a]),
                        np.column_stack([cl.s, cl.s_dot, cl.s_ddot, cl.d, cl.d_dot, cl.d_ddot]))
                since = 0
        if plan is None or since + 1 >= len(plan[0]):  # no plan left: brake, plan again next step
            x, x_cl, plan = _brake(x, dt), None, None
            out["braked_steps"] = out.get("braked_steps", 0) + 1
        else:
            since += 1
            x = tuple(float(v) for v in plan[0][since])
            q = plan[1][since]
            x_cl = ([q[0], q[1], q[2]], [q[3], q[4], q[5]])
        rows.append(_centre_row(k + 1, dt, *x))
    else:
        if _goal_reached(pp, rows[-1], k0 + len(rows) - 1):
            out["status"] = "goal"
    out["rows"] = rows
    return out


# ----------------------------------------------------------------------------- referee (referee env)

def judge_worker(job: dict) -> dict:
    _quiet()
    sys.path.insert(0, ROOT)
    from jaxplan.eval import referee

    return referee.judge_folders(job["folders"], job["scenarios"])


# ----------------------------------------------------------------------------- orchestration

def child(python: str, worker: str, job, tmp: str, timeout: float | None = None):
    """Run this script as ``worker`` under ``python`` with ``job`` (JSON); its JSON result."""
    fd, out = tempfile.mkstemp(suffix=f".{worker}.json", dir=tmp)
    os.close(fd)
    with open(out + ".in", "w") as f:
        json.dump(job, f)
    cmd = [python, os.path.abspath(__file__), "--worker", worker, "--worker-in", out + ".in", "--worker-out", out]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"{worker} child ran past {timeout:.0f} s") from None
    try:
        with open(out) as f:
            return json.load(f)
    except (OSError, ValueError):
        err = "\n".join(ln for ln in r.stderr.splitlines() if "leaked" not in ln and "nanobind" not in ln)
        raise RuntimeError(f"{worker} child exited {r.returncode}: {err[-800:]}") from None


def worker_main(args) -> None:
    with open(args.worker_in) as f:
        job = json.load(f)
    fn = {"prep": lambda j: prep_worker(j["paths"], j["out"]), "route": lambda j: route_worker(j["xmls"]),
          "reactive": reactive_worker, "frenetix": frenetix_worker, "judge": judge_worker}[args.worker]
    _write_json(args.worker_out, fn(job))


def _stats(cycles: list) -> dict:
    w = np.array([c["wall_s"] for c in cycles]) * 1e3
    errors = [c["error"] for c in cycles if c.get("error")]
    failed = sum(not c["found"] for c in cycles)
    if not len(w):
        return {"cycles": 0}
    extra = {"cycles_without_plan": int(failed), **({"first_error": errors[0][:200]} if errors else {})}
    cpu = np.array([c["cpu_s"] for c in cycles]) * 1e3
    return {"cycles": int(len(w)), "plan_ms_median": float(np.median(w)), "plan_ms_mean": float(w.mean()),
            "plan_ms_p90": float(np.percentile(w, 90)), "cpu_ms_median": float(np.median(cpu)), **extra}


def select_files(paths: list, sample: int | None, seed: int) -> list:
    """The scenario files to drive: ``paths`` expanded (folders recursively, sorted), then, with
    ``sample``, ``jaxplan.scenarios.files.sample_files`` of them (seeded, stratified by folder)."""
    sys.path.insert(0, ROOT)
    from jaxplan.scenarios.files import expand_paths, sample_files

    try:
        files = [os.path.abspath(f) for f in expand_paths(paths)]
    except ValueError as e:
        sys.exit(f"--scenarios: {e}")
    if sample is not None:
        files = sample_files(files, sample, seed)
    return files


def _prep_cached(referee_py: str, files: list, out: str, tmp: str) -> dict:
    """``prep_worker`` over ``files``, kept in ``<out>/prep.json`` and reused while the file list is
    the same (a resumed run does not read every scenario again)."""
    cache = os.path.join(out, "prep.json")
    if os.path.exists(cache):
        try:
            with open(cache) as f:
                c = json.load(f)
            if c.get("files") == files and c.get("route_builder") == ROUTE_BUILDER:
                return c["info"]
        except (OSError, ValueError):
            pass
    info = child(referee_py, "prep", {"paths": files, "out": out}, tmp)
    _write_json_atomic(cache, {"files": files, "route_builder": ROUTE_BUILDER, "info": info})
    return info


def _finished(out: str, peer: str, key: str) -> dict | None:
    """The timing row of a drive already finished in ``out`` (its ``cycles.json``), else None."""
    f = os.path.join(out, peer, key, "cycles.json")
    try:
        with open(f) as fh:
            c = json.load(fh)
    except (OSError, ValueError):
        return None
    return {"status": c["status"], "braked_steps": c.get("braked_steps", 0), **_stats(c["cycles"]),
            **({"drive_wall_s": c["drive_wall_s"]} if "drive_wall_s" in c else {})}


def _folder_of(scen_row: dict) -> str:
    return os.path.basename(os.path.dirname(scen_row["path"]))


def _by_folder(verdicts: dict, scen: dict) -> dict:
    """Each planner's counts per scenario folder (``hand-crafted``, ``sumo``, ...)."""
    out: dict = {}
    for label, rows in verdicts["drives"].items():
        groups: dict = {}
        for r in rows:
            groups.setdefault(_folder_of(scen[r["scenario"]]), []).append(r)
        out[label] = {g: _counts(rs) for g, rs in sorted(groups.items())}
    return out


def _counts(rows: list) -> dict:
    """Counts as ``jaxplan.eval.referee.summarize`` gives them, plus ``success``: a judged drive
    that reached the goal with no collision and without leaving the road."""
    judged = [r for r in rows if "goal_reached" in r]
    c = lambda k: sum(bool(r[k]) for r in judged)  # noqa: E731
    ok = sum(r["goal_reached"] and not r["collided"] and not r["off_road"] for r in judged)
    return {"scenarios": len(rows), "judged": len(judged), "success": ok, "goal_reached": c("goal_reached"),
            "collided": c("collided"), "off_road": c("off_road"), "success_share": ok / len(rows) if rows else None}


def _jaxplan_planner_facts(names) -> dict:
    """``{name: {"horizon": s, "vehicle": "L x W, wheelbase"}}`` read from jaxplan's planners
    (their defaults as ``jaxplan drive`` builds them); an entry says why where they cannot be read."""
    out = {}
    try:
        sys.path.insert(0, ROOT)
        from jaxplan.planner import get_factory
    except Exception as e:  # noqa: BLE001 - the table then says so
        return {n: {"error": f"{type(e).__name__}: {e}"} for n in names}
    for n in names:
        try:
            p = get_factory(n)()
            v = p.vehicle
            out[n] = {"horizon": f"{float(p.horizon):g} s",
                      "vehicle": f"{float(v.length):g} m x {float(v.width):g} m, wheelbase {float(v.wheelbase):g} m"}
        except Exception as e:  # noqa: BLE001
            out[n] = {"error": f"{type(e).__name__}: {str(e)[:80]}"}
    return out


def settings_table(args, labels: list) -> dict:
    """The settings of every planner in the comparison: ``{"differ": [...], "equal": [...]}``, rows
    ``{"setting", <planner>: value, ..., "why"}``. jaxplan's road planners are listed too (their horizon
    and car read from jaxplan), so that a later ``jaxplan drive`` on ``sample.json``'s files is judged
    against the same table."""
    peers = [p for p in PEERS if p in labels]
    jp = ["lattice", "pathspeed"]
    extra = [lab for lab in labels if lab not in PEERS and lab.replace("jaxplan-", "") not in jp]
    facts = _jaxplan_planner_facts(jp)
    try:
        import importlib.util

        has_lights = importlib.util.find_spec("jaxplan.scenarios.lights") is not None
    except (ImportError, ValueError):
        has_lights = False
    lights = "read from the scene (jaxplan.scenarios.lights)" if has_lights else "not obeyed"
    cols = peers + [f"jaxplan {n}" for n in jp]
    hz = args.reactive_horizon_steps * 0.1

    def row(setting, values: dict, why: str):
        r = {"setting": setting}
        for c in cols:
            r[c] = values.get(c, values.get("*", "-"))
        r["why"] = why
        return r

    def jf(n, k):
        f = facts[n]
        return f.get(k, f"not read ({f.get('error', '?')})")

    differ = [
        row("planning horizon", {"reactive": f"{hz:g} s ({args.reactive_horizon_steps} steps)", "frenetix": "3 s",
                                 **{f"jaxplan {n}": jf(n, "horizon") for n in jp}},
            "each planner's shipped configuration (the reactive planner's scenario configurations use 2 s, "
            "Frenetix's 3 s); the horizon is part of how a planner plans, not of the harness"),
        row("sampling", {"reactive": f"its sampling levels 1..4 (first level with a feasible collision-free "
                                     f"candidate), end times {args.reactive_t_min:g}..{hz:g} s, offsets -3..3 m, "
                                     "velocity keeping",
                         "frenetix": "level 2: end times 1.1..3 s, 5 end speeds in [v - 0.5 a_max T, v + a_max T / 7] "
                                     "(and the current one), 5 offsets -3..3 m (and the current one)",
                         "jaxplan lattice": "jaxplan's lattice (LatticeConfig.road)",
                         "jaxplan pathspeed": "path then speed optimisation (no sampling)"},
            "each planner's own method and shipped settings"),
        row("set speed rule", {"reactive": "fixed per scenario (rule below), set with set_desired_velocity each cycle",
                               "frenetix": "fixed per scenario (rule below), velocity-offset cost",
                               "jaxplan lattice": "its own: speed limit ahead, bent to the goal's time and speed window, "
                                                  "capped for curves",
                               "jaxplan pathspeed": "its own: lowest speed limit ahead, lowered or raised to meet "
                                                    "the goal's time window"},
            "the peers take one desired speed from outside, jaxplan's planners compute theirs from the map in "
            "every cycle; the peers' fixed speed: the middle of the goal's speed interval (capped at the "
            "start lanelet's limit), else that limit, else route distance to the goal centre over the middle "
            "of the goal's time interval (2..36 m/s), else the start speed"),
        row("route start", {"reactive": "route extended 10 m straight backwards", "frenetix": "route extended 10 m "
                            "straight backwards", "*": "route as given"},
            "the peers plan from the rear axle, which can lie behind the route's first point"),
        row("collision check inside the planner",
            {"reactive": "its own (commonroad-drivability-checker: obstacles' recorded futures, road boundary)",
             "frenetix": "commonroad-drivability-checker on the ranked candidates (obstacles, road boundary); "
                         "collision-probability cost on the recorded futures",
             "jaxplan lattice": "jaxplan's own geometry", "jaxplan pathspeed": "jaxplan's own geometry"},
            "each planner's method"),
        row("cost function", {"reactive": "its shipped cost function", "frenetix": "its shipped weights (jerk, "
                              "velocity offset, distance to the reference path, collision probability)",
                              "jaxplan lattice": "jaxplan's", "jaxplan pathspeed": "jaxplan's"},
            "each planner's method"),
        row("no trajectory found", {"reactive": "go on along the previous plan, then brake at 8 m/s^2",
                                    "frenetix": "Frenetix's stopping choice among the feasible candidates; none "
                                                "feasible: previous plan, then brake at 8 m/s^2",
                                    "jaxplan lattice": "the planner's own fallback; a plan that is not finite: "
                                                       "brake at 8 m/s^2",
                                    "jaxplan pathspeed": "the planner's own fallback; a plan that is not finite: "
                                                         "brake at 8 m/s^2"},
            "Frenetix ships an emergency mode, the reactive planner none; the harness's brake is the same"),
    ]
    equal = [
        row("re-plan period", {"*": f"every {args.replan} steps of 0.1 s"}, "the harness"),
        row("tracking", {"*": "perfect (the car follows the chosen plan exactly)"}, "the harness"),
        row("step cap", {"*": f"end of the goal's time interval, at most --max-steps {args.max_steps}; ends at the goal"},
            "the harness"),
        row("time step", {"*": "0.1 s (the scenarios')"}, "the scenarios"),
        row("route", {"*": f"{ROUTE_BUILDER or 'commonroad-route-planner'} (routes.json)"},
            "one route per scenario for every planner"),
        row("vehicle", {"reactive": f"{CAR_LENGTH:g} m x {CAR_WIDTH:g} m, wheelbase 2.578 m",
                        "frenetix": f"{CAR_LENGTH:g} m x {CAR_WIDTH:g} m, wheelbase 2.578 m",
                        **{f"jaxplan {n}": jf(n, "vehicle") for n in jp}},
            "the BMW 320i (CommonRoad vehicle type 2), the peers' default car; the referee judges this box"),
        row("obstacles seen", {"*": "every obstacle's recorded future (static ones at every time)"},
            "as CommonRoad benchmarks give them"),
        row("traffic lights", {"reactive": "not obeyed", "frenetix": "not obeyed",
                               **{f"jaxplan {n}": lights for n in jp}},
            "neither peer reads traffic lights; the referee does not judge them (NGSIM Lankershim and SUMO maps "
            "have some)"),
        row("goal rule", {"*": "CommonRoad's goal check on the car's centre"}, "the referee's"),
    ]
    moved = [r for r in equal if len({str(r[c]) for c in cols}) > 1]  # a value read from jaxplan that differs
    differ += moved
    equal = [{"setting": r["setting"], "value": r[cols[0]], "why": r["why"]} for r in equal if r not in moved]
    return {"columns": cols, "differ": differ, "equal": equal, "other_folders": extra}


def render_settings(table: dict) -> str:
    cols = table["columns"]
    esc = lambda v: str(v).replace("|", "/")  # noqa: E731
    lines = ["### Settings that differ between the planners", "", "| setting | " + " | ".join(cols) + " | why |",
             "| --- | " + " | ".join("---" for _ in cols) + " | --- |"]
    lines += [f"| {r['setting']} | " + " | ".join(esc(r[c]) for c in cols) + f" | {esc(r['why'])} |"
              for r in table["differ"]]
    lines += ["", f"### Settings that are equal ({', '.join(cols)})", "", "| setting | value | why |",
              "| --- | --- | --- |"]
    lines += [f"| {r['setting']} | {esc(r['value'])} | {esc(r['why'])} |" for r in table["equal"]]
    if table.get("other_folders"):
        lines += ["", f"Also judged: {', '.join(table['other_folders'])} (drives of other planners: their settings "
                  "are their planners'; the harness rows hold where they were driven by `jaxplan drive` with the same "
                  "re-plan period and step cap)."]
    return "\n".join(lines) + "\n"


def _python_ok(p: str, what: str) -> str:
    if not os.path.exists(p):
        sys.exit(f"{p} not found: the {what} runs there; see the setup in this script's docstring")
    return p


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenarios", nargs="+", default=DEFAULT_SCENARIOS,
                    help="scenario files (.json, .xml, either .gz) or folders of them (searched recursively)")
    ap.add_argument("--sample", type=int, metavar="N",
                    help="drive a seeded sample of N of the files, stratified by folder (written to sample.json)")
    ap.add_argument("--seed", type=int, default=0, help="seed of --sample (default 0)")
    ap.add_argument("--redo", action="store_true",
                    help="drive again the scenes a peer has already finished in --out (default: skip them)")
    ap.add_argument("--out", default="results/peers")
    ap.add_argument("--peers", nargs="*", default=list(PEERS), choices=PEERS)
    ap.add_argument("--reactive-python", default=VENVS["reactive"])
    ap.add_argument("--frenetix-python", default=VENVS["frenetix"])
    ap.add_argument("--referee-python", default=None,
                    help=f"interpreter with jaxplan and jaxplan[referee] (default {VENVS['referee']} where it exists, "
                         "else this interpreter)")
    ap.add_argument("--routes", help="routes JSON {routes: {key: [[x, y], ...]}} (default: build them)")
    ap.add_argument("--drives", nargs="*", default=[], metavar="LABEL=DIR", help="more drive folders to judge")
    ap.add_argument("--jaxplan", nargs="*", default=[], metavar="PLANNER",
                    help="run `jaxplan drive --planner PLANNER` first (this interpreter) and judge it too")
    ap.add_argument("--judge-only", action="store_true", help="drive nothing; judge the folders already there")
    ap.add_argument("--only", nargs="*", help="scenario keys to run (default all)")
    ap.add_argument("--replan", type=int, default=3, help="re-plan every this many 0.1 s steps")
    ap.add_argument("--max-steps", type=int, default=300, help="step cap of a drive")
    ap.add_argument("--reactive-horizon-steps", type=int, default=20)
    ap.add_argument("--reactive-t-min", type=float, default=1.0)
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per peer drive")
    ap.add_argument("--worker", choices=("prep", "route", "reactive", "frenetix", "judge"), help=argparse.SUPPRESS)
    ap.add_argument("--worker-in", help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker_main(args)
    drives = {}
    for d in args.drives:
        if "=" not in d:
            sys.exit(f"--drives {d}: expected LABEL=DIR")
        label, folder = d.split("=", 1)
        if not os.path.isdir(folder):
            sys.exit(f"--drives {d}: {folder} is not a folder")
        drives[label] = folder
    if args.sample is not None and args.sample < 1:
        sys.exit(f"--sample {args.sample}: expected a sample size >= 1")
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix="compare_peers_")
    if args.referee_python is None:
        args.referee_python = VENVS["referee"] if os.path.exists(VENVS["referee"]) else sys.executable
    referee_py = _python_ok(args.referee_python, "referee (jaxplan + jaxplan[referee])")

    t_start = time.time()
    files = select_files(args.scenarios, args.sample, args.seed)
    info = _prep_cached(referee_py, files, out, tmp)
    if args.only:
        unknown = sorted(set(args.only) - set(info))
        if unknown:
            sys.exit(f"--only: no scenario {', '.join(unknown)} among the {len(info)} selected")
    keys = [k for k in info if not args.only or k in args.only]
    _write_json(os.path.join(out, "sample.json"), {
        "scenarios": [os.path.abspath(p) for p in args.scenarios], "sample": args.sample,
        "seed": args.seed if args.sample is not None else None, "n_files": len(files),
        "files": files, "keys": {k: info[k]["path"] for k in info},
        "drive_with": f"jaxplan drive $(cat {out}/sample.txt) --planner NAME --out DIR "
                      f"--replan-every {args.replan} --max-steps {args.max_steps}"})
    with open(os.path.join(out, "sample.txt"), "w") as f:
        f.write("".join(p + "\n" for p in files))
    print(f"{len(keys)} scenarios (file list: {out}/sample.json, sample.txt)", flush=True)
    folders0 = list(args.peers) + list(drives) + [f"jaxplan-{n}" for n in args.jaxplan]
    print(render_settings(settings_table(args, folders0)), flush=True)

    if args.routes:
        with open(args.routes) as f:
            given = json.load(f)["routes"]
        routes = {k: {"route": given[k]} if k in given else {"error": f"no route in {args.routes}"} for k in keys}
        source = args.routes
    elif ROUTE_BUILDER:
        routes = {k: {"route": info[k]["route"]} if "route" in info[k] else
                  {"error": info[k].get("route_error", info[k].get("error"))} for k in keys}
        source = ROUTE_BUILDER
    else:
        xmls = {k: info[k]["xml"] for k in keys if "xml" in info[k]}
        routes = child(_python_ok(args.reactive_python, "route planner"), "route", {"xmls": xmls}, tmp)
        source = "commonroad-route-planner (shortest reference path)"
    _write_json(os.path.join(out, "routes.json"), {"source": source,
                                                   "routes": {k: r["route"] for k, r in routes.items() if "route" in r}})
    scen = {}
    for k in keys:
        f = info[k]
        row = {"path": f["path"], "xml": f.get("xml")}
        notes = [n for n in (f.get("error"), routes.get(k, {}).get("error")) if n]
        if "error" not in f:
            v, why = set_speed(f, routes.get(k, {}).get("route"))
            end = f["goal_steps"][1] if f["goal_steps"] else f["t0_step"] + args.max_steps
            row.update(v_set=v, v_set_from=why, steps=int(max(1, min(args.max_steps, end - f["t0_step"]))),
                       **{n: f[n] for n in ("goal_steps", "goal_velocity", "speed_limit", "v0")})
        row["notes"] = notes
        row["route_from"] = routes.get(k, {}).get("route_from", source)
        scen[k] = row
    _write_json(os.path.join(out, "scenarios.json"), scen)

    timing = {}
    if not args.judge_only:
        pythons = {"reactive": args.reactive_python, "frenetix": args.frenetix_python}
        for peer in args.peers:
            py = _python_ok(pythons[peer], peer)
            timing[peer] = {}
            done = 0
            for k in keys:
                s = scen[k]
                if s["notes"]:
                    timing[peer][k] = {"status": "not run: " + "; ".join(s["notes"])}
                    continue
                prev = _finished(out, peer, k)
                if prev is not None and not args.redo:  # resume: this scene is driven already
                    timing[peer][k] = prev
                    done += 1
                    continue
                job = {"xml": s["xml"], "route": routes[k]["route"], "v_set": s["v_set"], "steps": s["steps"], "v0": s["v0"],
                       "replan": args.replan, "horizon_steps": args.reactive_horizon_steps,
                       "t_min": args.reactive_t_min}
                t0 = time.time()
                try:
                    res = child(py, peer, job, tmp, args.timeout)
                except RuntimeError as e:
                    res = {"status": f"peer process failed: {e}", "cycles": [], "rows": []}
                driven = os.path.join(out, peer, k, "driven.json")
                if res["rows"]:
                    _write_json_atomic(driven, {
                        "scenario": k, "planner": peer, "dt": info[k]["dt"],
                        "vehicle": {"length": CAR_LENGTH, "width": CAR_WIDTH}, "states": res["rows"]})
                elif os.path.exists(driven):  # --redo: no stale drive from an earlier run
                    os.remove(driven)
                braked = int(res.get("braked_steps", 0))
                # written last: a scene with cycles.json is finished (resume skips it)
                _write_json_atomic(os.path.join(out, peer, k, "cycles.json"), {
                    "status": res["status"], "cycles": res["cycles"], "braked_steps": braked,
                    "drive_wall_s": round(time.time() - t0, 3)})
                timing[peer][k] = {"status": res["status"], "braked_steps": braked, **_stats(res["cycles"]),
                                   "drive_wall_s": round(time.time() - t0, 3)}
                print(f"{peer:9s} {k:40s} {res['status'][:60]:60s} {len(res['rows']):4d} rows "
                      f"{timing[peer][k].get('plan_ms_median', float('nan')):8.1f} ms/cycle ({time.time() - t0:.0f} s)",
                      flush=True)
            if done:
                print(f"{peer}: {done} scenes already driven in {out}/{peer} (kept; --redo drives them again)",
                      flush=True)
        for name in args.jaxplan:
            folder = os.path.join(out, f"jaxplan-{name}")
            cmd = [sys.executable, "-m", "jaxplan", "drive", *files, "--planner", name, "--out", folder,
                   "--replan-every", str(args.replan), "--max-steps", str(args.max_steps)]
            print("running", " ".join(cmd[:4]), f"({len(files)} files)", " ".join(cmd[4 + len(files):]), flush=True)
            r = subprocess.run(cmd, cwd=ROOT)
            if r.returncode != 0:
                sys.exit(f"jaxplan drive --planner {name} exited {r.returncode}")
            drives[f"jaxplan-{name}"] = folder
    else:
        for peer in args.peers:
            for k in keys:
                prev = _finished(out, peer, k)
                if scen[k]["notes"]:
                    timing.setdefault(peer, {})[k] = {"status": "not run: " + "; ".join(scen[k]["notes"])}
                elif prev is not None:
                    timing.setdefault(peer, {})[k] = prev
                else:
                    timing.setdefault(peer, {})[k] = {"status": "not driven yet (no cycles.json in the output)"}
    folders = {p: os.path.join(out, p) for p in args.peers}
    folders.update(drives)
    verdicts = child(referee_py, "judge", {"folders": folders,
                                           "scenarios": {k: info[k]["path"] for k in keys}}, tmp)
    for label, folder in drives.items():  # jaxplan's own plan time per cycle, where its metrics say it
        timing[label] = _jaxplan_timing(folder, label)
    own = jaxplan_verdicts(folders, {k: info[k]["path"] for k in keys}, args.max_steps)
    result = {"scenarios": scen, "route_source": source, "verdicts": verdicts["drives"],
              "summary": _summary(verdicts, timing, scen), "by_folder": _by_folder(verdicts, scen),
              "verdict": {label: {k: v for k, v in o.items() if k != "rows"} for label, o in own.items()},
              "verdict_rows": {label: o["rows"] for label, o in own.items()},
              "agreement": agreement(verdicts["drives"], own),
              "settings": settings_table(args, list(folders)), "timing": timing, "args": vars(args),
              "cpu_count": os.cpu_count(), "wall_s": time.time() - t_start,
              "drive_wall_s": {p: round(sum(r.get("drive_wall_s", 0.0) for r in timing.get(p, {}).values()
                                            if isinstance(r, dict)), 1) for p in args.peers}}
    _write_json(os.path.join(out, "compare_peers.json"), result)
    try:
        plots = plot_drives(result, folders, out)
        print(f"{len(plots)} plots in {out}/plots")
    except ImportError as e:  # the plots need jaxplan's loader and matplotlib (this interpreter)
        print(f"no plots: {e}")
    report = render_report(result)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write(report)
    print(report)
    print(f"wrote {out}/compare_peers.json and {out}/report.md")
    return result


def plot_drives(res: dict, folders: dict, out: str) -> list:
    """A bird's-eye plot per scenario: lanes, obstacles at t = 0 (static filled), recorded paths,
    every planner's driven path, where it collided (x) and where it reached the goal (*)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon as Patch

    sys.path.insert(0, ROOT)
    from jaxplan.scenarios.commonroad import load_commonroad
    from jaxplan.scenarios.loader import load_scenario

    by = {label: {r["scenario"]: r for r in rows} for label, rows in res["verdicts"].items()}
    colours = dict(zip(folders, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    written = []
    for key, s in res["scenarios"].items():
        try:
            sc = load_scenario(s["path"]) if s["path"].endswith(".json") else load_commonroad(s["path"])
        except Exception:  # noqa: BLE001 - no plot for a scenario the loader refuses
            continue
        o = np.asarray(sc.origin)
        fig, ax = plt.subplots(figsize=(9, 6))
        for ln in sc.lanes:
            ax.add_patch(Patch(np.vstack([ln.left, ln.right[::-1]]) + o, closed=True, fc="0.93", ec="0.7", lw=0.5))
        boxes, valid, static = (np.asarray(sc.obstacles.boxes), np.asarray(sc.obstacles.valid),
                                np.asarray(sc.obstacles.static))
        for i in range(len(boxes)):
            ok = valid[i]
            if ok.any():
                b = boxes[i, np.argmax(ok)]
                c, sn = math.cos(b[4]), math.sin(b[4])
                corners = np.array([[c * u - sn * v, sn * u + c * v] for u, v in
                                    ((b[2] / 2, b[3] / 2), (-b[2] / 2, b[3] / 2), (-b[2] / 2, -b[3] / 2),
                                     (b[2] / 2, -b[3] / 2))]) + b[:2] + o
                ax.add_patch(Patch(corners, closed=True, fc="0.35" if static[i] else "none", ec="0.35", lw=0.8))
                if not static[i]:
                    ax.plot(boxes[i, ok, 0] + o[0], boxes[i, ok, 1] + o[1], color="0.6", lw=0.5)
        lo, hi = np.array([np.inf, np.inf]), -np.array([np.inf, np.inf])
        for label, folder in folders.items():
            f = os.path.join(folder, key, "driven.json")
            if not os.path.exists(f):
                continue
            with open(f) as fh:
                st = np.asarray(json.load(fh)["states"], float)
            v = by.get(label, {}).get(key, {})
            tag = ("goal" if v.get("goal_reached") else "no goal") + (", collision" if v.get("collided") else "") + \
                (", off road" if v.get("off_road") else "")
            ax.plot(st[:, 1], st[:, 2], color=colours[label], lw=1.8, label=f"{label} ({tag})")
            for when, marker in ((v.get("first_collision_time"), "x"), (v.get("goal_time"), "*")):
                if when is not None:
                    j = int(np.argmin(np.abs(st[:, 0] - when)))
                    ax.plot(st[j, 1], st[j, 2], marker, color=colours[label], ms=11, mew=2)
            lo, hi = np.minimum(lo, st[:, 1:3].min(0)), np.maximum(hi, st[:, 1:3].max(0))
        if np.all(np.isfinite(lo)):
            pad = max(25.0, 0.15 * float(np.max(hi - lo)))
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
        else:
            ax.autoscale()
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{key}: closed-loop drives (set speed {s.get('v_set', float('nan')):.1f} m/s)")
        ax.legend(loc="best", fontsize=8)
        path = os.path.join(out, "plots", key.replace("@", "_at_") + ".png")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fig.savefig(path, dpi=90, bbox_inches="tight")
        plt.close(fig)
        written.append(path)
    return written


def jaxplan_verdicts(folders: dict, paths: dict, max_steps: int) -> dict:
    """Every folder's drives judged by jaxplan's verdict (``jaxplan.sim.drive.judge_drives``: the
    metrics and the success rule ``jaxplan drive`` uses), the same code for every planner:
    ``{label: {"rows", "summary", "by_folder", "by_location", "missing"}}``."""
    sys.path.insert(0, ROOT)
    import dataclasses

    from jaxplan.scenarios.cache import load_many
    from jaxplan.sim.drive import judge_drives, summarize, summarize_by

    keys = list(paths)
    loaded = load_many([paths[k] for k in keys], progress=False)
    by_path = {r.path: r for r in loaded.records}
    records = [dataclasses.replace(by_path[paths[k]], name=k) for k in keys if paths[k] in by_path]
    out = {}
    for label, folder in folders.items():
        driven = {}
        for k in keys:
            f = os.path.join(folder, k, "driven.json")
            if os.path.exists(f):
                with open(f) as fh:
                    driven[k] = json.load(fh)
        rows = judge_drives(records, driven, label, max_steps)
        out[label] = {"rows": rows, "summary": summarize(rows), "by_folder": summarize_by(rows, "folder"),
                      "by_location": summarize_by(rows, "location"),
                      "missing": [k for k in keys if k not in driven]}
    return out


def agreement(referee_rows: dict, own: dict) -> dict:
    """Per planner: the drives on which the referee and jaxplan's verdict agree on collision (and its
    time), off road (and its time) and goal (and its time), and the disagreements."""
    out = {}
    for label, rows in referee_rows.items():
        mine = {r["scenario"]: r for r in own.get(label, {}).get("rows", [])}
        agree, differ = 0, []
        for v in rows:
            r = mine.get(v["scenario"])
            if r is None or "goal_reached" not in v:
                continue
            t = lambda key, ok: round(r[key] * DT, 6) if ok and r[key] is not None else None  # noqa: E731
            ours = {"collided": (bool(r["overlap.collided"]), t("overlap.first_step", r["overlap.collided"])),
                    "off_road": (bool(r["offroad.offroad"]), t("offroad.first_step", r["offroad.offroad"])),
                    "goal_reached": (bool(r["goal.reached"]), t("goal.step", r["goal.reached"]))}
            theirs = {"collided": (bool(v["collided"]), v["first_collision_time"]),
                      "off_road": (bool(v["off_road"]), v["first_off_road_time"]),
                      "goal_reached": (bool(v["goal_reached"]), v["goal_time"])}
            diff = {k: {"jaxplan": ours[k], "referee": theirs[k]} for k in ours if ours[k] != theirs[k]}
            if diff:
                differ.append({"scenario": v["scenario"], **diff})
            else:
                agree += 1
        out[label] = {"agree": agree, "judged": agree + len(differ), "disagreements": differ}
    return out


def _jaxplan_timing(folder: str, label: str) -> dict:
    """Plan time per cycle from ``jaxplan drive``'s ``metrics.json`` (``drive.<planner>.plan_ms_median``)."""
    f = os.path.join(folder, "metrics.json")
    if not os.path.exists(f):
        return {}
    with open(f) as fh:
        m = json.load(fh)
    flat, todo = {}, [("", m)]
    while todo:  # flat ("drive.lattice.plan_ms_median": ...) or nested metrics alike
        pre, d = todo.pop()
        for k, v in (d.items() if isinstance(d, dict) else ()):
            (todo.append((f"{pre}{k}.", v)) if isinstance(v, dict) else flat.__setitem__(f"{pre}{k}", v))
    vals = {k: v for k, v in flat.items() if k.endswith("plan_ms_median") and isinstance(v, (int, float))}
    return {"_all": {"plan_ms_median": next(iter(vals.values()))}} if vals else {}


def _summary(verdicts: dict, timing: dict, scen: dict) -> dict:
    out = {}
    for label, s in verdicts["summary"].items():
        t = timing.get(label, {})
        if "_all" in t:
            ms, cpu = t["_all"].get("plan_ms_median"), None
        else:
            ms, cpu = _median_over_cycles(t), _median_over_cycles(t, "cpu_ms_median")
        rows = verdicts["drives"][label]
        failed = {r["scenario"]: r.get("error") or timing.get(label, {}).get(r["scenario"], {}).get("status", "no drive")
                  for r in rows if "goal_reached" not in r}
        out[label] = {**s, "success": _counts(rows)["success"], "plan_ms_median": ms, "cpu_ms_median": cpu,
                      "not_judged": failed}
    return out


def _median_over_cycles(t: dict, key: str = "plan_ms_median"):
    """Median over scenarios of each drive's median time per planning cycle."""
    v = [r[key] for r in t.values() if isinstance(r, dict) and r.get(key) is not None]
    return float(np.median(v)) if v else None


def render_report(res: dict) -> str:
    fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    lines = ["# Peers in jaxplan's closed-loop harness", "",
             f"{len(res['scenarios'])} scenarios, re-plan every {res['args']['replan']} steps of 0.1 s, perfect tracking, "
             f"route: {res['route_source']}. Referee: commonroad-drivability-checker (collision with every obstacle, "
             "the box inside the lanelets) and commonroad-io's goal check, on every driven state.", "",
             "| planner | success | goal share (CommonRoad rule) | goals | collisions | off road | judged drives | "
             "plan time per cycle, median (ms) | CPU per cycle, median (ms) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for label, s in res["summary"].items():
        lines.append(f"| {label} | {s.get('success', '-')}/{s['scenarios']} | {fmt(s['goal_share'], '.1%')} | "
                     f"{s['goal_reached']}/{s['scenarios']} | "
                     f"{s['collided']} | {s['off_road']} | {s['judged']} | {fmt(s['plan_ms_median'], '.1f')} | "
                     f"{fmt(s['cpu_ms_median'], '.1f')} |")
    if res.get("verdict"):
        lines += ["", "## jaxplan's verdict: the same code for every planner", "",
                  "Success: goal reached (CommonRoad's rule), no collision at any step, never off road. At fault: some "
                  "obstacle's first contact was not a moving obstacle hitting the car squarely from behind "
                  "(`jaxplan.sim.metrics.overlap`).", "",
                  "| planner | drives | success | goal | collisions | at fault | off road | goal off map | "
                  "referee agrees |", "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
        for label, o in res["verdict"].items():
            s_ = o["summary"]
            ag = res.get("agreement", {}).get(label, {})
            lines.append(f"| {label} | {fmt(s_.get('scenes'), '.0f')} | {fmt(s_.get('success_share'), '.1%')} | "
                         f"{fmt(s_.get('goal_share'), '.1%')} | {fmt(s_.get('collisions'), '.0f')} | "
                         f"{fmt(s_.get('at_fault_collisions'), '.0f')} | {fmt(s_.get('offroad_share'), '.1%')} | "
                         f"{fmt(s_.get('goal_off_map'), '.0f')} | {ag.get('agree', '-')}/{ag.get('judged', '-')} |")
        lines += ["", "Per folder (success / goal / collisions / at fault):", "",
                  "| planner | " + " | ".join(sorted({g for o in res["verdict"].values() for g in o["by_folder"]})) + " |"]
        groups = sorted({g for o in res["verdict"].values() for g in o["by_folder"]})
        lines.append("| --- |" + " --- |" * len(groups))
        for label, o in res["verdict"].items():
            cells = []
            for g in groups:
                b = o["by_folder"].get(g)
                cells.append("-" if not b else f"{fmt(b.get('success_share'), '.0%')} / {fmt(b.get('goal_share'), '.0%')} / "
                             f"{fmt(b.get('collisions'), '.0f')} / {fmt(b.get('at_fault_collisions'), '.0f')} "
                             f"({fmt(b.get('scenes'), '.0f')})")
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        dis = [(label, d) for label, a in res.get("agreement", {}).items() for d in a["disagreements"]]
        if dis:
            lines += ["", "Where the referee and jaxplan's verdict disagree:", ""]
            lines += [f"- {label} {d['scenario']}: " + "; ".join(f"{k} jaxplan {v['jaxplan']} referee {v['referee']}"
                                                              for k, v in d.items() if k != "scenario")
                      for label, d in dis]
    if res.get("by_folder"):
        lines += ["", "## Per folder (referee)", "", "Success: a judged drive that reached the goal without a collision and "
                  "without leaving the road (count over the folder's scenarios).", "",
                  "| planner | folder | scenarios | success | goals | collisions | off road | judged |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for label, groups in res["by_folder"].items():
            for g, c in groups.items():
                lines.append(f"| {label} | {g} | {c['scenarios']} | {c['success']} ({fmt(c['success_share'], '.1%')}) | "
                             f"{c['goal_reached']} | {c['collided']} | {c['off_road']} | {c['judged']} |")
    lines += ["", "Goal share: drives whose state reached the goal (position, time, orientation, speed) at some step, "
              "over all scenarios (no drive = not reached). Collisions, off road: judged drives with a collision / "
              "with the car's box not inside the union of the lanelets (buffered 5 cm: map seams are road). "
              "Plan time: median over scenarios of each drive's "
              "median wall time of one planning call (CPU: process time); shared 2-core machine, rough.", ""]
    for label, s in res["summary"].items():
        if s["not_judged"]:
            lines += ["", f"Not judged ({label}, {len(s['not_judged'])}):", ""]
            lines += [f"- {k}: {v}" for k, v in s["not_judged"].items()]
    for label, t in res["timing"].items():
        bad = {k: r for k, r in t.items() if isinstance(r, dict) and (r.get("status") not in (None, "goal", "ok")
                                                                        or r.get("braked_steps"))}
        if bad:
            lines += ["", f"Drives where {label} had no plan (the car braked on the fallback), or did not run:", ""]
            lines += [f"- {k}: {r['status']}, {r.get('braked_steps', 0)} steps braking, "
                      f"{r.get('cycles_without_plan', 0)} of {r.get('cycles', 0)} planning calls without a plan"
                      + (f" (first error: {r['first_error']})" if r.get("first_error") else "") for k, r in bad.items()]
    if res.get("settings"):
        lines += ["", "## Settings", "", render_settings(res["settings"])]
    lines += ["", "## Per scenario", "", "| scenario | v_set (m/s) | " + " | ".join(res["summary"]) + " |",
              "| --- | --- | " + " | ".join("---" for _ in res["summary"]) + " |"]
    by = {label: {r["scenario"]: r for r in rows} for label, rows in res["verdicts"].items()}
    for k, s in res["scenarios"].items():
        cells = []
        for label in res["summary"]:
            r = by[label].get(k, {})
            if "goal_reached" not in r:
                cells.append("no drive" if r.get("missing") else "error")
                continue
            c = ("goal %.1fs" % r["goal_time"]) if r["goal_reached"] else "no goal"
            if r["collided"]:
                c += " · hit %s at %.1fs" % (",".join(map(str, r["collision_obstacles"])) or "?", r["first_collision_time"])
            if r["off_road"]:
                c += " · off road %.1fs" % r["first_off_road_time"]
            cells.append(c)
        lines.append(f"| {k} | {fmt(s.get('v_set'), '.1f')} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
