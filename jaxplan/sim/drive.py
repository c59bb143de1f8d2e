"""``jaxplan drive``: scenario files in, closed-loop drives out (host side).

``drive(...)`` loads every scenario (``.json`` shared format, ``.xml`` CommonRoad, or the
built-in scenes), stacks them into one padded batch, drives each planner through
``rollout`` (split over every local device by ``jaxplan.eval.batch.sharded_map``), computes
the metrics and writes, per scenario, ``<scenario>/driven.json`` (the format below), a
bird's-eye PNG (``--animate``: a GIF too) and, for CommonRoad input, a solution file; then
``metrics.json`` (summary figures ``drive.<planner>.<figure>`` and one row per drive under
``rows``) and ``report.md``.

``driven.json``: ``{"scenario": key, "planner": name, "dt": 0.1, "vehicle": {"length": L,
"width": W}, "states": [[t, x, y, theta, v, a], ...]}``, ``(x, y)`` the centre of the car's
box in the scenario's own (world) coordinates, ``t`` from the scenario start, one row per
``dt`` from ``t = 0`` to the end of the drive. ``key`` is the scenario id, made unique over the
files of one run as ``jaxplan.scenarios.files.scenario_keys`` does (``<id>@<file name>`` for a
later file with the same id); the folder is named by it too.

With one planner the per-scenario folders are ``OUT/<scenario>/``; with several,
``OUT/<planner>/<scenario>/``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.planner import make_planner
from jaxplan.scenarios.files import scenario_format
from jaxplan.sim.metrics.registry import evaluate_batch
from jaxplan.sim.rollout import SimConfig, planner_program, rollout

DEFAULT_MAX_STEPS = 200  # 20 s at dt 0.1


@dataclasses.dataclass
class DriveResult:
    """What ``drive`` computed: per planner the metrics rows and the summary figures."""

    rows: dict
    summary: dict
    out: str


SUMMARY = (  # figure, metric key, how it aggregates over drives
    ("goal_share", "goal.reached", "mean"),
    ("collision_share", "overlap.collided", "mean"),
    ("at_fault_collisions", "overlap.at_fault", "sum"),
    ("offroad_share", "offroad.offroad", "mean"),
    ("max_abs_accel", "comfort.max_abs_accel", "max"),
    ("min_accel", "comfort.min_accel", "min"),
    ("max_abs_jerk", "comfort.max_abs_jerk", "max"),
    ("max_abs_lat_accel", "comfort.max_abs_lat_accel", "max"),
    ("max_abs_curvature", "comfort.max_abs_curvature", "max"),
    ("min_ttc", "ttc.min_ttc", "min"),
    ("progress_m_mean", "progress.route_m", "mean"),
)


def summarize(rows: list) -> dict:
    """Summary figures over drives (rows of per-drive metrics)."""
    if not rows:
        return {}
    col = lambda k: np.array([r[k] for r in rows], float)
    out = {}
    for name, key, how in SUMMARY:
        v = col(key)
        out[name] = float({"mean": np.mean, "sum": np.sum, "max": np.max, "min": np.min}[how](v))
    out["not_at_fault_collisions"] = float(np.sum(col("overlap.collided")) - np.sum(col("overlap.at_fault")))
    reached = col("goal.reached") > 0
    out["time_to_goal_mean"] = float(np.mean(col("goal.time")[reached])) if reached.any() else float("nan")
    out["plan_not_ok_share"] = float(np.mean(col("plan_not_ok_share")))
    out["fallback_cycles"] = float(np.sum(col("fallback_cycles")))
    out["replans_per_drive"] = float(np.mean(col("replans")))
    out["scenes"] = float(len(rows))
    return out


def n_steps_for(records, dt: float, cap: int) -> int:
    """Steps to simulate: up to the latest end of a goal's time interval, at most ``cap``."""
    ends = [float(np.asarray(r.scene.goal.time)[1]) for r in records]
    need = max(int(math.ceil(e / dt - 1e-6)) if math.isfinite(e) else cap for e in ends)
    return max(1, min(cap, need))


def time_plans(planner, batch, n: int) -> dict:
    """Wall time of one planning call on one scene (batch 1, compile excluded), median and
    90th percentile over the first ``n`` scenes at their start states (ms)."""
    from jaxplan.planner import EgoState

    times = []
    for i in range(n):
        sc = jax.tree_util.tree_map(lambda x: x[i], batch)
        ego = EgoState.from_box_centre(sc.start, planner.vehicle)
        jax.block_until_ready(_plan_once(planner, sc, ego))  # compiles once (same shapes), then warm
        t = time.perf_counter()
        jax.block_until_ready(_plan_once(planner, sc, ego))
        times.append(1e3 * (time.perf_counter() - t))
    return {"plan_ms_median": float(np.median(times)), "plan_ms_p90": float(np.percentile(times, 90))}


def _plan(planner, scene, ego):
    return planner.plan(scene, ego, 0)


def _plan_once(planner, scene, ego):
    """One planning call at step 0, compiled as ``rollout`` compiles the drive (the planner's options)."""
    return planner_program(planner, _plan, ("planner",))(planner, scene, ego)


def run_planner(planner, batch, config: SimConfig, chunk: int | None = None) -> tuple[dict, dict, dict]:
    """Drive every scene of ``batch`` (sharded over local devices, in chunks); returns
    (numpy log fields, numpy metrics, timing figures)."""
    from jaxplan.eval.batch import sharded_map

    B = int(batch.start.shape[0])
    chunk = chunk or B
    fn = lambda sc: rollout(planner, sc, config)  # rollout is jitted (planner and config static): cached
    take = lambda a, lo, hi: jax.tree_util.tree_map(lambda x: x[lo:hi], a)
    t0 = time.perf_counter()
    first = sharded_map(fn, take(batch, 0, min(B, chunk)), pad_to=min(B, chunk))
    t_first = time.perf_counter() - t0
    parts = [first]
    t1 = time.perf_counter()
    for lo in range(chunk, B, chunk):
        parts.append(sharded_map(fn, take(batch, lo, min(B, lo + chunk)), pad_to=chunk))
    if len(parts) == 1:  # time a second, warm run of the single chunk
        t1 = time.perf_counter()
        parts = [sharded_map(fn, take(batch, 0, B), pad_to=B)]
    t_run = time.perf_counter() - t1
    log = jax.tree_util.tree_map(lambda *a: np.concatenate(a), *parts)
    metrics = evaluate_batch(jax.tree_util.tree_map(jnp.asarray, log), batch, planner.vehicle)
    metrics = {k: np.asarray(v) for k, v in metrics.items()}
    steps = B * config.n_steps
    timing = {"compile_and_first_run_s": t_first, "run_s": t_run,
              "scenario_steps_per_s": steps / t_run if t_run > 0 else float("nan")}
    return log, metrics, timing


def _row(i, rec, planner_name, metrics, log) -> dict:
    row = {"planner": planner_name, "scenario": rec.name}
    for k, v in metrics.items():
        x = v[i]
        row[k] = bool(x) if x.dtype == bool else (int(x) if np.issubdtype(x.dtype, np.integer) else float(x))
    ok = np.asarray(log.plan_ok[i])
    row["plan_not_ok_share"] = float(1.0 - np.mean(ok))
    row["fallback_cycles"] = int(np.sum(log.fallback[i]))
    row["replans"] = int(np.sum(log.replanned[i]))
    row["end_time"] = float(np.asarray(log.t[i])[int(log.end_step[i])])
    return row


def _write_json(path: str, obj) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, allow_nan=True)
    os.replace(tmp, path)


def write_drive(folder: str, rec, planner_name: str, vehicle, log_i: dict, row: dict, animate: bool) -> None:
    """One drive's outputs: ``driven.json``, a PNG, a GIF (``animate``), a CommonRoad solution (XML input)."""
    from jaxplan.sim.plots import animate_drive, plot_drive

    os.makedirs(folder, exist_ok=True)
    n = int(log_i["end_step"]) + 1
    ox, oy = (float(c) for c in np.asarray(rec.scenario.origin, float))
    states = [[round(float(log_i["t"][k]), 6), float(log_i["x"][k]) + ox, float(log_i["y"][k]) + oy,
               float(log_i["heading"][k]), float(log_i["v"][k]), float(log_i["a"][k])] for k in range(n)]
    _write_json(os.path.join(folder, "driven.json"),
                {"scenario": rec.name, "planner": planner_name, "dt": float(rec.scenario.dt),
                 "vehicle": {"length": float(vehicle.length), "width": float(vehicle.width)}, "states": states})
    title = f"{rec.name}: {planner_name}"
    plot_drive(os.path.join(folder, "drive.png"), rec.scene, row, log_i, vehicle, title)
    if animate:
        animate_drive(os.path.join(folder, "drive.gif"), rec.scene, log_i, vehicle, title)
    if rec.path and scenario_format(rec.path) == "xml":
        from jaxplan.scenarios.commonroad import write_solution
        from jaxplan.types import Trajectory

        sl = slice(0, n)
        f = lambda k: np.asarray(log_i[k])[sl]
        traj = Trajectory(f("x"), f("y"), f("heading"), f("kappa"), f("v"), f("a"), f("t"), f("t") * 0, f("t") * 0 + 1)
        try:
            write_solution(rec.scenario, traj, folder)
        except Exception as e:  # the solution is an extra: say why it is missing, keep the drive
            print(f"jaxplan drive: {rec.name}: no CommonRoad solution written ({type(e).__name__}: {e})",
                  file=sys.stderr)


def drive(records, planners: list, out: str, config: SimConfig, animate: bool = False, planner_options=None,
          progress: bool = True, chunk: int | None = None, skipped: list = ()) -> DriveResult:
    """Drive ``records`` (``SceneRecord``s) with each planner name; write the outputs under ``out``."""
    from jaxplan.scenarios.scene import stack_scenes

    batch = stack_scenes([r.scene for r in records], min_steps=config.n_steps + 1)
    os.makedirs(out, exist_ok=True)
    all_rows, summary = {}, {}
    opts = planner_options or {}
    for name in planners:
        planner = make_planner(name, **opts.get(name, {}))
        config.validate(planner)
        log, metrics, timing = run_planner(planner, batch, config, chunk)
        rows = [_row(i, rec, name, metrics, log) for i, rec in enumerate(records)]
        summ = summarize(rows)
        summ.update(timing)
        summ.update(time_plans(planner, batch, min(len(records), 8)))
        summ["skipped_files"] = float(len(skipped))
        iterator = enumerate(records)
        if progress:
            from tqdm import tqdm

            iterator = tqdm(list(iterator), desc=f"writing {name}", unit="drive", leave=False)
        for i, rec in iterator:
            folder = os.path.join(out, rec.name) if len(planners) == 1 else os.path.join(out, name, rec.name)
            log_i = {k: np.asarray(getattr(log, k)[i]) for k in ("t", "x", "y", "heading", "v", "a", "kappa",
                                                                  "valid", "end_step")}
            write_drive(folder, rec, name, planner.vehicle, log_i, rows[i], animate)
        all_rows[name], summary[name] = rows, summ
    figures = {f"drive.{p}.{k}": v for p, s in summary.items() for k, v in s.items()}
    run = {"kind": "jaxplan drive", "planners": list(planners), "replan_every": config.replan_every,
           "replan": config.replan,
           "tracking": config.tracking, "n_steps": config.n_steps, "dt": config.dt,
           "scenarios": [r.name for r in records], "skipped_files": list(skipped)}
    _write_json(os.path.join(out, "metrics.json"),
                {**figures, "run": run, "rows": [r for p in planners for r in all_rows[p]]})
    from jaxplan.sim.report import write_drive_report

    write_drive_report(out, summary, all_rows, run)
    return DriveResult(all_rows, summary, out)
