"""The jobs the peer harness runs as child processes (``compare_peers.py --worker NAME``), each in
its own virtual environment: ``prep`` (scenario keys, CommonRoad XML, each scenario's facts and
jaxplan's route; the referee's environment), ``route`` (commonroad-route-planner's reference path;
the reactive planner's), ``reactive`` and ``frenetix`` (one closed-loop drive of a peer; its own)
and ``judge`` (the referee over every folder; the referee's). ``worker_main`` reads the job's
JSON, runs it and writes its JSON result.

The peers' environments have neither jaxplan nor its dependencies: this module and the ones it
imports use only the standard library and numpy at import time; jaxplan and the peers' packages
are imported inside the functions that need them."""

from __future__ import annotations

import copy
import importlib
import json
import math
import os
import sys
import time

import numpy as np

from .closed_loop import _brake, _centre_row, _crop_route, _extend_back, _goal_reached
from .config import ROOT, ROUTE_BUILDER, WB_REAR
from .files import _read_xml, _write_json
from .frenetix_loop import _FrenetixLoop


def _quiet():
    import logging
    import warnings

    warnings.simplefilter("ignore")
    logging.disable(logging.WARNING)


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
    return {
        "dt": dt,
        "t0_step": int(st.time_step),
        "v0": float(st.velocity),
        "start": np.asarray(st.position, float).tolist(),
        "goal_steps": [int(ts.start), int(ts.end)] if ts is not None and hasattr(ts, "start") else None,
        "goal_velocity": [float(vel.start), float(vel.end)] if vel is not None and hasattr(vel, "start") else None,
        "goal_centre": centre,
        "speed_limit": min(lim) if lim else None,
        "start_lanelets": [int(i) for i in start],
    }


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
            out["cycles"].append(
                {
                    "step": k,
                    "wall_s": time.perf_counter() - t0,
                    "cpu_s": time.process_time() - c0,
                    "found": bool(res),
                    **({"error": err} if err else {}),
                }
            )
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
            planner.reset(
                initial_state_cart=nxt,
                initial_state_curv=curv,
                collision_checker=planner.collision_checker,
                coordinate_system=planner.coordinate_system,
            )
        except Exception:  # noqa: BLE001 - the braked state lies outside its frame: it plans again next step
            planner.x_0, planner.x_0_cl = nxt, None
        rows.append(
            _centre_row(
                k + 1, dt, *nxt.position, nxt.orientation, nxt.velocity, getattr(nxt, "acceleration", 0.0) or 0.0
            )
        )
    else:
        if _goal_reached(pp, rows[-1], k0 + len(rows) - 1):
            out["status"] = "goal"
    out["rows"] = rows
    return out


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
            out["cycles"].append(
                {
                    "step": k,
                    "wall_s": time.perf_counter() - t0,
                    "cpu_s": time.process_time() - c0,
                    "found": res is not None,
                    "candidates": n,
                    "mode": mode,
                    **({"error": err} if err else {}),
                }
            )
            fresh = res is not None
            if res is not None:
                c, cl = res.cartesian, res.curvilinear
                plan = (
                    np.column_stack([c.x, c.y, c.theta, c.v, c.a]),
                    np.column_stack([cl.s, cl.s_dot, cl.s_ddot, cl.d, cl.d_dot, cl.d_ddot]),
                )
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


def judge_worker(job: dict) -> dict:
    _quiet()
    sys.path.insert(0, ROOT)
    from jaxplan.eval import referee

    return referee.judge_folders(job["folders"], job["scenarios"])


def worker_main(args) -> None:
    with open(args.worker_in) as f:
        job = json.load(f)
    fn = {
        "prep": lambda j: prep_worker(j["paths"], j["out"]),
        "route": lambda j: route_worker(j["xmls"]),
        "reactive": reactive_worker,
        "frenetix": frenetix_worker,
        "judge": judge_worker,
    }[args.worker]
    _write_json(args.worker_out, fn(job))
