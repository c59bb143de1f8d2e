"""``jaxplan drive``: scenario files in, closed-loop drives out (host side), for a handful of
scenes or thousands.

``drive(records, planners, out, config)`` drives every ``SceneRecord`` with every planner:

- **grouped by size**: scenes are padded to size classes (``jaxplan.sim.sizes``) and driven
  group by group in batches of ``batch_size`` (split over every local device), so a batch is
  not padded to its largest member and a new file reuses a compiled program;
- **resumable**: every finished drive is a row of ``OUT/rows.jsonl`` (``jaxplan.sim.store``);
  the same command started again skips what is done; other settings or files in the same
  folder are refused with one line;
- **bounded memory**: a batch's logs are written and dropped before the next;
- **progress**: a bar with drives done, drives per minute and the time left;
- **judged by one verdict** (``jaxplan.sim.verdict``): per drive the metrics, ``success`` and,
  for a drive that did not succeed, why.

Outputs, per drive: ``<scenario>/driven.json`` (``OUT/<planner>/<scenario>/`` with several
planners), a bird's-eye PNG (``plots``: ``all``, ``failed`` or ``none``; ``auto`` = all up to
50 drives, else the failed ones), with ``animate`` a GIF, for CommonRoad input a solution
file; for the run ``metrics.json`` (strict JSON: summary figures ``drive.<planner>.<figure>``,
per-folder and per-location tables, the timing split into parse, compile and drive, one row
per drive under ``rows``) and ``report.md``.

``driven.json``: ``{"scenario": key, "planner": name, "dt": 0.1, "vehicle": {"length": L,
"width": W}, "states": [[t, x, y, theta, v, a], ...]}``, ``(x, y)`` the centre of the car's
box in the scenario's own (world) coordinates, ``t`` from the scenario start, one row per
``dt`` from ``t = 0`` to the end of the drive. ``key`` is the scenario id, made unique over the
files of one run as ``jaxplan.scenarios.files.scenario_keys`` does (``<id>@<file name>`` for a
later file with the same id).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.planner import EMERGENCY_LAT_ACCEL, check_params, make_planner
from jaxplan.scenarios.files import location, scenario_format
from jaxplan.sim import sizes, verdict
from jaxplan.sim.devices import place, sharded_map
from jaxplan.sim.metrics.registry import evaluate_batch
from jaxplan.sim.rollout import ChunkedRollout, DriveLog, SimConfig, driven_scene, planner_program, rollout
from jaxplan.sim.store import RunStore, write_json
from jaxplan.types import Obstacles

DEFAULT_MAX_STEPS = 200  # 20 s at dt 0.1
DEFAULT_BATCH = 16
CHUNK_CYCLES = 6  # planning cycles per compiled call; a batch stops after the chunk in which its last drive ends


@dataclasses.dataclass
class DriveResult:
    """What ``drive`` computed: per planner the metrics rows and the summary figures, and the
    run's timing (``parse_s``, ``compile_s``, ``drive_s``, ``write_s``, ``wall_s``)."""

    rows: dict
    summary: dict
    out: str
    timing: dict = dataclasses.field(default_factory=dict)


SUMMARY = (  # figure, row key, how it aggregates over drives
    ("success_share", "success", "mean"),
    ("goal_share", "goal.reached", "mean"),
    ("collision_share", "overlap.collided", "mean"),
    ("at_fault_collisions", "overlap.at_fault", "sum"),
    ("offroad_share", "offroad.offroad", "mean"),
    ("red_light_crossings", "redlight.crossings", "sum"),
    ("goal_off_map", "goal.off_map", "sum"),
    ("max_abs_accel", "comfort.max_abs_accel", "max"),
    ("min_accel", "comfort.min_accel", "min"),
    ("max_abs_jerk", "comfort.max_abs_jerk", "max"),
    ("max_abs_lat_accel", "comfort.max_abs_lat_accel", "max"),
    ("max_abs_curvature", "comfort.max_abs_curvature", "max"),
    ("min_ttc", "ttc.min_ttc", "min"),
    ("blind_zone_s", "blindzone.time_s", "sum"),
    ("progress_m_mean", "progress.route_m", "mean"),
)


def summarize(rows: list) -> dict:
    """Summary figures over drives (rows of per-drive metrics); figures whose key no row has are left out."""
    if not rows:
        return {}
    out: dict[str, Any] = {}
    reduce: dict[str, Callable[[np.ndarray], Any]] = {"mean": np.mean, "sum": np.sum, "max": np.max, "min": np.min}
    for name, key, how in SUMMARY:
        vals = [r[key] for r in rows if r.get(key) is not None]
        if key not in rows[0] and not vals:
            continue
        v = np.array(vals, float)
        out[name] = float(reduce[how](v)) if len(v) else None
    col = lambda k: np.array([float(r.get(k) or 0.0) for r in rows])  # noqa: E731
    out["collisions"] = float(np.sum(col("overlap.collided")))
    if "comfort.lat_accel_floor" in rows[0]:  # drives over the emergency lateral limit, and those whose road allowed it
        over = col("comfort.max_abs_lat_accel") > EMERGENCY_LAT_ACCEL
        out["lat_accel_over_limit"] = float(np.sum(over))
        allowed = col("comfort.lat_accel_floor") <= EMERGENCY_LAT_ACCEL
        out["lat_accel_over_limit_avoidable"] = float(np.sum(over & allowed))
    out["not_at_fault_collisions"] = float(np.sum(col("overlap.collided")) - np.sum(col("overlap.at_fault")))
    reached = col("goal.reached") > 0
    times = np.array([r.get("goal.time") if r.get("goal.time") is not None else np.inf for r in rows], float)
    out["time_to_goal_mean"] = float(np.mean(times[reached])) if reached.any() else None
    known = [r for r in rows if r.get("plan_not_ok_share") is not None]  # (not known of other planners' drives)
    out["plan_not_ok_share"] = float(np.mean([r["plan_not_ok_share"] for r in known])) if known else None
    out["fallback_cycles"] = float(sum(r["fallback_cycles"] for r in known)) if known else None
    out["replans_per_drive"] = float(np.mean([r["replans"] for r in known])) if known else None
    out["scenes"] = float(len(rows))
    return out


def summarize_by(rows: list, key: str) -> dict:
    """``{value of row[key]: summarize(rows with it)}``, in sorted order."""
    groups: dict = {}
    for r in rows:
        groups.setdefault(r.get(key, ""), []).append(r)
    return {g: summarize(groups[g]) for g in sorted(groups)}


def scene_steps(record, dt: float, cap: int) -> int:
    """Steps to simulate one scene: up to the end of its goal's time interval, at most ``cap``."""
    e = float(np.asarray(record.scene.goal.time)[1])
    need = int(math.ceil(e / dt - 1e-6)) if math.isfinite(e) else cap
    return max(1, min(cap, need))


def n_steps_for(records, dt: float, cap: int) -> int:
    """Steps to simulate a batch: up to the latest end of a goal's time interval, at most ``cap``."""
    return max(scene_steps(r, dt, cap) for r in records)


def time_plans(planner, batch, n: int, params=None) -> dict:
    """Wall time of one planning call on one scene (batch 1, compile excluded), median and
    90th percentile over the first ``n`` scenes at their start states (ms)."""
    from jaxplan.planner import EgoState

    params = check_params(planner, params)
    times = []
    for i in range(n):
        sc = jax.tree_util.tree_map(lambda x: x[i], batch)
        ego = EgoState.from_box_centre(sc.start, planner.vehicle)
        jax.block_until_ready(plan_once_compiled(planner, params, sc, ego))  # compiles once (same shapes), then warm
        t = time.perf_counter()
        jax.block_until_ready(plan_once_compiled(planner, params, sc, ego))
        times.append(1e3 * (time.perf_counter() - t))
    return {"plan_ms_median": float(np.median(times)), "plan_ms_p90": float(np.percentile(times, 90))}


def plan_at_start(planner, params, scene, ego):
    """The planner's plan at step 0 of ``scene`` from ``ego`` (the call ``time_plans`` times)."""
    return planner.plan(params, scene, ego, 0)


def plan_once_compiled(planner, params, scene, ego):
    """One planning call at step 0, compiled as ``rollout`` compiles the drive (the planner's options)."""
    return planner_program(planner, plan_at_start, ("planner",))(planner, params, scene, ego)


def run_planner(planner, batch, config: SimConfig, chunk: int | None = None, params=None) -> tuple:
    """Drive every scene of an in-memory ``batch`` (sharded over local devices, in chunks of
    ``chunk`` scenes) with the planner's ``params`` (default its own); returns (numpy ``DriveLog``,
    numpy metrics, timing figures)."""
    B = int(batch.start.shape[0])
    chunk = chunk or B
    fn = lambda sc: rollout(planner, sc, config, params)  # noqa: E731  (rollout is jitted: cached)
    take = lambda a, lo, hi: jax.tree_util.tree_map(lambda x: x[lo:hi], a)  # noqa: E731
    t0 = time.perf_counter()
    parts = [sharded_map(fn, take(batch, lo, min(B, lo + chunk)), pad_to=chunk) for lo in range(0, B, chunk)]
    t_run = time.perf_counter() - t0
    log = jax.tree_util.tree_map(lambda *a: np.concatenate(a), *parts)
    jlog = jax.tree_util.tree_map(jnp.asarray, log)  # (an in-memory batch: judged as one)
    metrics = evaluate_batch(jlog, driven_scene(jlog, batch), planner.vehicle)
    metrics = {k: np.asarray(v) for k, v in metrics.items()}
    steps = B * config.n_steps
    timing = {"run_s": t_run, "scenario_steps_per_s": steps / t_run if t_run > 0 else float("nan")}
    return log, metrics, timing


def _value(x):
    x = np.asarray(x)
    return bool(x) if x.dtype == bool else (int(x) if np.issubdtype(x.dtype, np.integer) else float(x))


def _row(i, rec, planner_name, metrics, log, every: int = 1) -> dict:
    """One drive's row: its metrics, planning figures over the cycles up to its end (``every``:
    steps per cycle), its end time and verdict."""
    row = {"planner": planner_name, "scenario": rec.name, "folder": _folder(rec), "location": location(rec.name)}
    for k, v in metrics.items():
        row[k] = _value(v[i])
    cycles = int(log.end_step[i]) // every + 1
    ok = np.asarray(log.plan_ok[i])[:cycles]
    row["plan_not_ok_share"] = float(1.0 - np.mean(ok))
    row["fallback_cycles"] = int(np.sum(np.asarray(log.fallback[i])[:cycles]))
    row["replans"] = int(np.sum(log.replanned[i]))
    row["end_time"] = float(np.asarray(log.t[i])[int(log.end_step[i])])
    row["success"] = verdict.success(row)
    row["outcome"] = verdict.outcome(row)
    return row


def _folder(rec) -> str:
    """The folder a scene's file lies in (its name), or ``builtin`` for generated scenes."""
    return os.path.basename(os.path.dirname(os.path.abspath(rec.path))) if rec.path else "builtin"


def write_drive(
    folder: str, rec, planner_name: str, vehicle, log_i: dict, row: dict, animate: bool, plot: bool = True, scene=None
) -> None:
    """One drive's outputs: ``driven.json``, a PNG (``plot``), a GIF (``animate``), a CommonRoad
    solution (XML input). ``scene``: the scene as driven (default the record's)."""
    from jaxplan.sim.plots import animate_drive, plot_drive

    os.makedirs(folder, exist_ok=True)
    scene = rec.scene if scene is None else scene
    n = int(log_i["end_step"]) + 1
    ox, oy = (float(c) for c in np.asarray(rec.scenario.origin, float))
    states = [
        [
            round(float(log_i["t"][k]), 6),
            float(log_i["x"][k]) + ox,
            float(log_i["y"][k]) + oy,
            float(log_i["heading"][k]),
            float(log_i["v"][k]),
            float(log_i["a"][k]),
        ]
        for k in range(n)
    ]
    write_json(
        os.path.join(folder, "driven.json"),
        {
            "scenario": rec.name,
            "planner": planner_name,
            "dt": float(rec.scenario.dt),
            "vehicle": {"length": float(vehicle.length), "width": float(vehicle.width)},
            "states": states,
        },
        indent=None,
    )
    title = f"{rec.name}: {planner_name}"
    if plot:
        plot_drive(os.path.join(folder, "drive.png"), scene, row, log_i, vehicle, title)
    if animate:
        animate_drive(os.path.join(folder, "drive.gif"), scene, log_i, vehicle, title)
    if rec.path and scenario_format(rec.path) == "xml":
        from jaxplan.scenarios.commonroad import write_solution
        from jaxplan.types import Trajectory

        sl = slice(0, n)
        f = lambda k: np.asarray(log_i[k])[sl]  # noqa: E731
        traj = Trajectory(f("x"), f("y"), f("heading"), f("kappa"), f("v"), f("a"), f("t"), f("t") * 0, f("t") * 0 + 1)
        try:
            write_solution(rec.scenario, traj, folder)
        except Exception as e:  # the solution is an extra: say why it is missing, keep the drive
            print(
                f"jaxplan drive: {rec.name}: no CommonRoad solution written ({type(e).__name__}: {e})", file=sys.stderr
            )


def record_digest(rec) -> str:
    """A digest of what a scene is: its file's bytes, or (generated scenes) its arrays."""
    from jaxplan.scenarios.cache import file_digest

    if rec.path and os.path.isfile(rec.path):
        return file_digest(rec.path)
    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(rec.scene):
        a = np.ascontiguousarray(np.asarray(leaf))
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _code_fingerprint() -> str:
    """SHA-256 of the library's source (a resumed run must be driven by the same code)."""
    import jaxplan

    root = os.path.dirname(jaxplan.__file__)
    h = hashlib.sha256()
    for d, _, files in sorted(os.walk(root)):
        for f in sorted(files):
            if f.endswith(".py"):
                with open(os.path.join(d, f), "rb") as fh:
                    h.update(os.path.relpath(os.path.join(d, f), root).encode() + b"\0" + fh.read())
    return h.hexdigest()[:16]


def run_settings(
    planners: list,
    config: SimConfig,
    planner_options: dict | None = None,
    run_info: dict | None = None,
    planner_params: dict | None = None,
) -> dict:
    """Everything that decides a run's drives (``jaxplan.sim.store.RunStore`` matches it on resume):
    the planners, their options and params, the simulation settings, the library's code, the
    caller's settings."""
    out = {
        "planners": list(planners),
        "sim": dataclasses.asdict(config),
        "planner_options": {k: repr(sorted(v.items())) for k, v in (planner_options or {}).items()},
        "code": _code_fingerprint(),
        **(run_info or {}),
    }
    if planner_params:
        out["planner_params"] = {k: repr(sorted(v.items())) for k, v in planner_params.items()}
    return out


def _judge(log: DriveLog, records, run: dict, vehicle, batch_size: int):
    """The metrics of a batch of drives (numpy ``log``, leading axis over ``records``), each scene and its
    traffic padded to the run's sizes (``sizes.run_sizes``), the outlines' vertices to the batch's class
    and the steps to the class of the batch's longest drive: a few metrics programs serve a run.
    Returns ``(the scenes as driven (numpy), {metric: (B,) numpy})``."""
    from jaxplan.scenarios.batch import scene_sizes, stack_scenes

    # the run's sizes, but the outlines' vertices at the batch's own class (the metrics' work grows with them)
    v_class = max(sizes.size_class(scene_sizes(r.scene)["V"], sizes.CLASSES["V"]) for r in records)
    batch = stack_scenes([r.scene for r in records], min_sizes=dict(run, V=v_class))
    K = int(batch.obstacles.boxes.shape[1])
    # the steps up to the batch's last drive's end, rounded up to a class (a few metrics programs per run)
    N = int(np.asarray(log.t).shape[1])
    n = min(N, sizes.size_class(int(np.max(log.end_step)) + 1, sizes.CLASSES["T"]))
    if n < N:
        cut_n = lambda a: a[:, :n] if np.ndim(a) >= 2 and np.shape(a)[1] == N else a  # noqa: E731
        log = dataclasses.replace(
            log, **{f: cut_n(getattr(log, f)) for f in ("t", "x", "y", "heading", "v", "a", "kappa", "valid")}
        )
        log = dataclasses.replace(
            log,
            traffic=dataclasses.replace(
                log.traffic,
                boxes=log.traffic.boxes[:, :, :n],
                valid=log.traffic.valid[:, :, :n],
                t=log.traffic.t[:, :n],
            ),
        )
    tr = log.traffic
    pad = K - tr.boxes.shape[1]
    if pad > 0:  # the traffic of the drive's obstacle class, padded with absent obstacles
        tr = dataclasses.replace(
            tr,
            boxes=np.concatenate([tr.boxes, np.repeat(np.ones_like(tr.boxes[:, :1]), pad, 1)], 1),
            valid=np.concatenate([tr.valid, np.zeros(tr.valid.shape[:1] + (pad,) + tr.valid.shape[2:], bool)], 1),
            static=np.concatenate([tr.static, np.zeros((tr.static.shape[0], pad), bool)], 1),
        )
    full = dataclasses.replace(log, traffic=tr)
    placed, B = place((full, batch), pad_to=batch_size)
    jlog, jbatch = placed
    judged = driven_scene(jlog, jbatch)
    metrics = evaluate_batch(jlog, judged, vehicle)
    cut = lambda a: np.asarray(a)[:B]  # noqa: E731
    return jax.tree_util.tree_map(cut, judged), {k: cut(v) for k, v in metrics.items()}


def _plots_for(policy: str, n_drives: int, row: dict) -> bool:
    if policy == "auto":
        policy = "all" if n_drives <= 50 else "failed"
    return policy == "all" or (policy == "failed" and not row["success"])


def describe_last_plans(planner, info: dict, step: int, every: int) -> str:
    """What the planner said (``planner.describe``, "" without one) of the last seven plans that
    drove the car up to ``step``: cycle ``c`` plans at step ``c every`` and drives the ``every``
    steps after it, so a plan made at ``step`` itself is left out.

    Args:
        info: one drive's ``DriveLog.info``, numpy arrays ``(C, ...)`` (C cycles).
        step: the drive's step to describe up to (its end, or its first collision).
        every: steps per cycle (``SimConfig.replan_every``).
    """
    fn = getattr(planner, "describe", None)
    if fn is None or not info:
        return ""
    c = min(max(step - 1, 0) // every, next(iter(info.values())).shape[0] - 1)
    lo = max(0, c - 6)
    return fn({k: np.asarray(v)[lo : c + 1] for k, v in info.items()})


def drive(
    records,
    planners: list,
    out: str,
    config: SimConfig,
    animate: bool = False,
    planner_options=None,
    progress: bool = True,
    batch_size: int = DEFAULT_BATCH,
    plots: str = "auto",
    fresh: bool = False,
    skipped: Sequence[str] = (),
    run_info: dict | None = None,
    parse_s: float = 0.0,
    planner_params: dict | None = None,
) -> DriveResult:
    """Drive ``records`` (``SceneRecord``s) with each planner name; write the outputs under ``out``.

    Args:
        records: the scenes (names unique: ``jaxplan.scenarios.files.unique_names``).
        planners: planner names (``jaxplan.planner.make_planner``).
        out: output folder; a run there with the same settings and scenes is resumed.
        config: ``SimConfig``; its ``n_steps`` is the step cap: each scene is driven to the end of
            its goal's time interval, at most that.
        animate: also a GIF per drive.
        planner_options: ``{planner name: {option: value}}`` for ``make_planner``.
        planner_params: ``{planner name: {param: value}}`` for the planner's ``init_params`` (e.g.
            cost weights from ``jaxplan tune``); the others drive with their defaults.
        progress: show a progress bar on stderr.
        batch_size: scenes per batch (per compiled program call).
        plots: ``auto``, ``all``, ``failed`` or ``none`` (per-drive PNGs).
        fresh: discard a previous run in ``out``.
        skipped: files that could not be loaded (named in the report).
        run_info: settings of the caller to record with the run (and to match on resume).
        parse_s: seconds spent loading the scenes (for the timing split).

    Raises:
        jaxplan.sim.store.RunMismatch: ``out`` holds a run with other settings or scenes.
    """
    from tqdm import tqdm

    from jaxplan.scenarios.batch import stack_scenes

    if plots not in ("auto", "all", "failed", "none"):
        raise ValueError(f"plots must be auto, all, failed or none, got {plots!r}")
    t_wall = time.perf_counter()
    opts = planner_options or {}
    made = {name: make_planner(name, **opts.get(name, {})) for name in planners}
    values = planner_params or {}
    params = {name: p.init_params(values.get(name)) for name, p in made.items()}
    for p in made.values():
        config.validate(p)
    settings = run_settings(planners, config, opts, run_info, values)
    store = RunStore(out, settings, {r.name: record_digest(r) for r in records}, fresh=fresh)
    folder_of = (
        (lambda name, rec: os.path.join(out, rec.name))
        if len(planners) == 1
        else (lambda name, rec: os.path.join(out, name, rec.name))
    )
    pending = {name: [r for r in records if not store.done(name, r.name)] for name in planners}
    total = sum(len(v) for v in pending.values())
    n_drives = len(records) * len(planners)
    timing = {
        "parse_s": parse_s,
        "compile_s": 0.0,
        "drive_s": 0.0,
        "metrics_s": 0.0,
        "write_s": 0.0,
        "drives": total,
        "resumed_drives": n_drives - total,
    }
    bar = tqdm(total=total, desc="driving", unit="drive", disable=not progress, file=sys.stderr, dynamic_ncols=True)
    dt = config.dt
    run = sizes.run_sizes([r.scene for r in records])
    try:
        for name, planner in made.items():
            driver = ChunkedRollout(planner, config, CHUNK_CYCLES, params[name])
            groups: dict = {}
            for r in pending[name]:
                groups.setdefault(sizes.obstacle_class(r.scene), []).append(r)
            for k_class, recs in sorted(groups.items()):
                recs = sorted(recs, key=lambda r: scene_steps(r, dt, config.n_steps))  # similar lengths together
                for lo in range(0, len(recs), batch_size):
                    part = recs[lo : lo + batch_size]
                    batch = stack_scenes([r.scene for r in part], min_sizes=dict(run, K=k_class))
                    placed, B = place(sizes.for_drive(batch), pad_to=batch_size)
                    timing["compile_s"] += driver.compile(placed)
                    need = max(scene_steps(r, dt, config.n_steps) for r in part)
                    t0 = time.perf_counter()
                    log = driver(placed, cycles=-(-need // config.replan_every))
                    log = jax.tree_util.tree_map(lambda y: y[:B], log)
                    timing["drive_s"] += time.perf_counter() - t0
                    t0 = time.perf_counter()
                    judged, metrics = _judge(log, part, run, planner.vehicle, batch_size)
                    timing["metrics_s"] += time.perf_counter() - t0
                    t0 = time.perf_counter()
                    for i, rec in enumerate(part):
                        row = _row(i, rec, name, metrics, log, config.replan_every)
                        log_i = {
                            k: np.asarray(getattr(log, k)[i])
                            for k in ("t", "x", "y", "heading", "v", "a", "kappa", "valid", "end_step")
                        }
                        scene_i = jax.tree_util.tree_map(lambda a: np.asarray(a)[i], judged)
                        info_i = jax.tree_util.tree_map(lambda a: np.asarray(a)[i], log.info)
                        # the plans that drove the car into the collision or off the road, else to its end
                        end = int(log_i["end_step"])
                        miss = verdict.first_miss_step(row, end)
                        said = describe_last_plans(planner, info_i, miss, config.replan_every)
                        if said and miss < end:
                            said = f"up to t = {float(log_i['t'][miss]):.1f} s, {said}"
                        row["why"] = verdict.explain(row, log_i, scene_i, rec.scenario.obstacle_types, said)
                        row["obstacle_class"] = k_class
                        write_drive(
                            folder_of(name, rec),
                            rec,
                            name,
                            planner.vehicle,
                            log_i,
                            row,
                            animate,
                            plot=_plots_for(plots, n_drives, row),
                            scene=scene_i,
                        )
                        store.add(row)
                        bar.update(1)
                    timing["write_s"] += time.perf_counter() - t0
                    if bar.n and bar.format_dict.get("elapsed"):
                        bar.set_postfix_str(f"{60.0 * bar.n / bar.format_dict['elapsed']:.0f} drives/min")
            timing[f"programs.{name}"] = len(groups)
    finally:
        bar.close()
        store.close()
    timing["wall_s"] = time.perf_counter() - t_wall + parse_s
    all_rows = {name: store.rows(name) for name in planners}
    summary = {name: summarize(rows) for name, rows in all_rows.items()}
    for name in planners:
        summary[name]["skipped_files"] = float(len(skipped))
    by_folder = {name: summarize_by(rows, "folder") for name, rows in all_rows.items()}
    by_location = {name: summarize_by(rows, "location") for name, rows in all_rows.items()}
    figures = {f"drive.{p}.{k}": v for p, s in summary.items() for k, v in s.items()}
    run = {
        "kind": "jaxplan drive",
        "planners": list(planners),
        **{k: v for k, v in settings.items() if k != "sim"},
        "replan_every": config.replan_every,
        "replan": config.replan,
        "tracking": config.tracking,
        "n_steps": config.n_steps,
        "dt": config.dt,
        "batch_size": batch_size,
        "scenarios": [r.name for r in records],
        "skipped_files": list(skipped),
    }
    for k in ("agents", "prediction"):
        if hasattr(config, k):
            run[k] = getattr(config, k)
    write_json(
        os.path.join(out, "metrics.json"),
        {
            **figures,
            "run": run,
            "timing": timing,
            "by_folder": by_folder,
            "by_location": by_location,
            "rows": [r for p in planners for r in all_rows[p]],
        },
    )
    from jaxplan.sim.report import write_drive_report

    write_drive_report(out, summary, all_rows, run, timing, by_folder, by_location)
    return DriveResult(all_rows, summary, out, timing)


def judge_drives(
    records, driven: dict, planner_name: str, max_steps: int | None = None, batch_size: int = DEFAULT_BATCH
) -> list:
    """Judge drives made by any planner (``driven.json`` objects, e.g. a peer's) with the same metrics
    and verdict as ``drive``: one row per record that has a drive (in the records' order).

    Args:
        records: ``SceneRecord``s (names as the drives' ``scenario`` keys).
        driven: ``{scenario key: driven.json object}`` (states in world coordinates, box centre, one row
            per ``dt`` from ``t = 0``; see the module docstring); the traffic is taken as recorded.
        planner_name: the ``planner`` of the rows.
        max_steps: the drives' step cap (default: the longest drive's).
    """
    from jaxplan.planner import SIM_VEHICLE

    todo = [r for r in records if r.name in driven]
    if not todo:
        return []
    states = {}
    for r in todo:
        st = np.asarray(driven[r.name].get("states"), float)
        if st.ndim != 2 or st.shape[1] < 5 or len(st) < 1 or not np.all(np.isfinite(st[:, :5])):
            raise ValueError(f"{r.name}: driven states should be finite rows of [t, x, y, theta, v, ...]")
        states[r.name] = st
    N = (max_steps or max(len(st) - 1 for st in states.values())) + 1
    run = sizes.run_sizes([r.scene for r in todo])
    groups: dict = {}
    for r in todo:
        d = driven[r.name]["vehicle"]
        veh = dataclasses.replace(SIM_VEHICLE, length=float(d["length"]), width=float(d["width"]))
        groups.setdefault(veh, []).append(r)
    rows = {}
    dt = float(todo[0].scenario.dt)
    for veh, recs in groups.items():
        for lo in range(0, len(recs), batch_size):
            part = recs[lo : lo + batch_size]
            cols = {k: np.zeros((len(part), N)) for k in ("x", "y", "heading", "v", "a", "kappa")}
            valid = np.zeros((len(part), N), bool)
            end = np.zeros(len(part), int)
            boxes, there, static = [], [], []
            for i, r in enumerate(part):
                st = states[r.name]
                m = min(len(st), N)
                o = np.asarray(r.scenario.origin, float)
                for j, k in enumerate(("x", "y", "heading", "v")):
                    col = st[:m, j + 1] - (o[j] if j < 2 else 0.0)
                    cols[k][i, :m], cols[k][i, m:] = col, col[-1]
                if st.shape[1] > 5:
                    cols["a"][i, :m] = st[:m, 5]
                valid[i, :m] = True
                end[i] = m - 1
                w = jax.tree_util.tree_map(jnp.asarray, r.scene.obstacles).window(0, N)  # the recorded traffic
                boxes.append(np.asarray(w.boxes))
                there.append(np.asarray(w.valid))
                static.append(np.asarray(w.static))
            K = max(b.shape[0] for b in boxes)
            pad = lambda a, fill: np.concatenate([a, np.full((K - a.shape[0],) + a.shape[1:], fill, a.dtype)])  # noqa: E731
            traffic = Obstacles(
                np.stack([pad(b, 1.0) for b in boxes]),
                np.stack([pad(v, False) for v in there]),
                np.broadcast_to(np.arange(N) * dt, (len(part), N)),
                np.stack([pad(s_, False) for s_ in static]),
            )
            t = np.broadcast_to(np.arange(N) * dt, (len(part), N))
            one = np.ones((len(part), 1), bool)
            log = DriveLog(
                t,
                cols["x"],
                cols["y"],
                cols["heading"],
                cols["v"],
                cols["a"],
                cols["kappa"],
                valid,
                end,
                one,
                ~one,
                one,
                {},
                traffic,
            )
            judged, metrics = _judge(log, part, run, veh, batch_size)
            for i, r in enumerate(part):
                row = _row(i, r, planner_name, metrics, log)
                for k in ("plan_not_ok_share", "fallback_cycles", "replans"):  # not known of another planner
                    row[k] = None
                log_i = {k: np.asarray(getattr(log, k)[i]) for k in ("t", "x", "y", "heading", "v", "end_step")}
                scene_i = jax.tree_util.tree_map(lambda a: np.asarray(a)[i], judged)
                row["why"] = verdict.explain(row, log_i, scene_i, r.scenario.obstacle_types)
                rows[r.name] = row
    return [rows[r.name] for r in todo]
