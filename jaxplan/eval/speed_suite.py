"""Suite ``speed``: the ``pathspeed`` planner in closed loop, with and without the non-blocking
boundaries.

Every scene is driven by ``jaxplan.sim.rollout`` (re-plan every 0.3 s, exact tracking,
recorded traffic as recorded) twice: by ``PathSpeedPlanner()`` and by
``PathSpeedPlanner(nonblocking=False)``, which differ only in the weights of the
non-blocking boundaries (no-bypass, blind zone, keep-clear: zero without). Scenes:
``--scenarios`` (folders or files of recorded scenarios, comma-separated; the shared data
is ``../shared/data/commonroad2018a`` and ``commonroad2020a``), else the built-in scenes.
Figures, measured on the driven states with the geometry core (not the planner's model):

* ``blind_zone_s``: time the car's box overlaps a moving obstacle's blind zone (the drive
  metric ``blindzone``'s zone, with the planner's ``blind_back`` and ``blind_front``);
* ``forbidden_overtakes``: obstacles the planner decided not to bypass (at some cycle)
  whose front the car's front then passed (along the obstacle's heading), having been
  behind it at that cycle;
* ``collisions``, ``at_fault``: the drive metric ``overlap``; ``max_abs_accel``: the drive
  metric ``comfort`` (finite differences of the driven speeds);
* ``time_to_goal_s`` over the drives that reach the goal in both variants, and
  ``travel_time_ratio`` (with / without) on them; ``goal_share``.

The claim: with non-blocking boundaries at least 50 % less blind-zone time, no
forbidden overtake, no more collisions, at most 10 % more travel time.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.sim.metrics.blindzone import blind_zone_steps

CLAIM_BLIND_REDUCTION = 0.5
CLAIM_TIME_RATIO = 1.10


def recorded_scenes(directories, n: int | None = None) -> tuple[list, int]:
    """``(records, skipped_files)``: the ``SceneRecord``s of the recorded scenarios in
    ``directories`` (a folder or a list of them; read by ``load_folder``, the one loading
    path of the suites, each file that fails named on stderr and counted; a scenario whose
    route cannot be built counts as skipped), at most ``n``, names unique."""
    import sys

    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.files import load_folder, unique_names
    from jaxplan.scenarios.route import RouteError
    from jaxplan.scenarios.scene import SceneRecord

    recs: list[SceneRecord] = []
    skipped = 0
    for d in [directories] if isinstance(directories, str) else directories:
        folder = load_folder(d)
        skipped += len(folder.skipped)
        pairs = list(zip(folder.files, folder.scenarios))
        for f, sc in pairs:
            if n is not None and len(recs) >= n:
                break
            try:
                scene, route = build_scene(sc)
            except RouteError as e:
                print(f"jaxplan: speed: skipping {f}: {e}", file=sys.stderr)
                skipped += 1
                continue
            recs.append(SceneRecord(sc.id, scene, sc, route, f))
    return unique_names(recs), skipped


def _records(args: SuiteArgs) -> tuple[list, str, int | None]:
    if args.scenarios:
        recs, skipped = recorded_scenes([p for p in args.scenarios.split(",") if p], args.n)
        return recs, "recorded.", skipped
    from jaxplan.scenarios.builtin import builtin_records

    recs = builtin_records(quick=args.quick, seed=args.seed)
    return (recs[: args.n] if args.n else recs), "builtin.", None


@jax.jit
def _blind_zone_steps(x, y, heading, valid, boxes, ok, moving, length, width, back, front):
    """``(B, N)`` bool: the car's box (centres ``x, y (B, N)``) in the blind zone of a moving
    obstacle (``boxes (B, K, N, 5)``; the drive metric's ``blind_zone_steps``)."""
    car = jnp.stack([x, y, jnp.full_like(x, length), jnp.full_like(x, width), heading], -1)  # (B, N, 5)
    steps = jax.vmap(blind_zone_steps, in_axes=(0, 0, 0, None, None))(car, boxes, ok & moving[..., None], back, front)
    return steps & valid


def _forbidden_overtakes(log, boxes, ok, no_bypass, vehicle, replan: int) -> np.ndarray:
    """``(B,)`` count of obstacles decided not to bypass whose front the car's front passed
    after that decision (behind it at the decision)."""
    B, N = log["x"].shape
    L = boxes[..., 2]
    c, s = np.cos(boxes[..., 4]), np.sin(boxes[..., 4])
    half = 0.5 * vehicle.length
    fx = log["x"] + half * np.cos(log["heading"])
    fy = log["y"] + half * np.sin(log["heading"])
    ofx, ofy = boxes[..., 0] + 0.5 * L * c, boxes[..., 1] + 0.5 * L * s
    ahead = ((fx[:, None] - ofx) * c + (fy[:, None] - ofy) * s > 0) & ok & log["valid"][:, None]  # (B, K, N)
    out = np.zeros(B, int)
    for b in range(B):
        for k in np.nonzero(no_bypass[b].any(0))[0]:
            c0 = int(np.argmax(no_bypass[b, :, k]))
            n0 = min(c0 * replan, N - 1)
            if not ahead[b, k, n0] and ahead[b, k, n0:].any():
                out[b] += 1
    return out


def _measure(records, planner, batch, config, log, metrics) -> dict:
    from jaxplan.speed.nonblocking import obstacle_speed

    N = log["x"].shape[1]
    obs = jax.vmap(lambda o: o.window(0, N))(batch.obstacles)
    boxes, ok = np.asarray(obs.boxes), np.asarray(obs.valid)
    moving = np.asarray(jax.vmap(obstacle_speed)(obs)) > planner.speed.v_moving
    veh, sp = planner.vehicle, planner.speed
    blind = np.asarray(
        _blind_zone_steps(
            log["x"],
            log["y"],
            log["heading"],
            log["valid"],
            boxes,
            ok,
            moving,
            float(veh.length),
            float(veh.width),
            sp.blind_back,
            sp.blind_front,
        )
    )
    nb = np.asarray(log["info"]["no_bypass"])
    dt = config.dt
    return {
        "blind_s": blind.sum(1) * dt,
        "forbidden": _forbidden_overtakes(log, boxes, ok, nb, veh, config.replan_every),
        "collided": metrics["overlap.collided"],
        "at_fault": metrics["overlap.at_fault"],
        "reached": metrics["goal.reached"],
        "t_goal": metrics["goal.time"],
        "max_abs_accel": metrics["comfort.max_abs_accel"],
        "progress": metrics["progress.route_m"],
        "v": log["v"],
        "valid": log["valid"],
    }


def _summary(prefix: str, mw: dict, mo: dict) -> dict:
    out = {}
    for tag, m in (("with", mw), ("without", mo)):
        out[f"{prefix}{tag}.blind_zone_s"] = round(float(m["blind_s"].sum()), 2)
        out[f"{prefix}{tag}.forbidden_overtakes"] = int(m["forbidden"].sum())
        out[f"{prefix}{tag}.collisions"] = int(m["collided"].sum())
        out[f"{prefix}{tag}.at_fault_collisions"] = int(m["at_fault"].sum())
        out[f"{prefix}{tag}.goal_share"] = round(float(m["reached"].mean()), 4)
        out[f"{prefix}{tag}.max_abs_accel"] = round(float(m["max_abs_accel"].max()), 3)
        out[f"{prefix}{tag}.progress_mean_m"] = round(float(m["progress"].mean()), 2)
    both = mw["reached"] & mo["reached"]
    out[f"{prefix}reached_goal_both"] = int(both.sum())
    if both.any():
        tw, to = float(mw["t_goal"][both].mean()), float(mo["t_goal"][both].mean())
        out[f"{prefix}with.time_to_goal_s"] = round(tw, 3)
        out[f"{prefix}without.time_to_goal_s"] = round(to, 3)
        out[f"{prefix}travel_time_ratio"] = round(tw / to, 4)
    bo = float(mo["blind_s"].sum())
    out[f"{prefix}blind_zone_reduction"] = round(1 - float(mw["blind_s"].sum()) / bo, 4) if bo > 0 else float("nan")
    red = out[f"{prefix}blind_zone_reduction"]
    ratio = out.get(f"{prefix}travel_time_ratio", float("nan"))
    holds = (
        red >= CLAIM_BLIND_REDUCTION
        and out[f"{prefix}with.forbidden_overtakes"] == 0
        and out[f"{prefix}with.collisions"] <= out[f"{prefix}without.collisions"]
        and ratio <= CLAIM_TIME_RATIO
    )
    out[f"{prefix}claim_holds"] = int(bool(holds))
    return out


def _per_scene(records, mw, mo) -> list:
    rows = []
    for i, r in enumerate(records):
        rows.append(
            {
                "scenario": r.name,
                "blind_with": float(mw["blind_s"][i]),
                "blind_without": float(mo["blind_s"][i]),
                "forbidden_with": int(mw["forbidden"][i]),
                "forbidden_without": int(mo["forbidden"][i]),
                "collided_with": bool(mw["collided"][i]),
                "collided_without": bool(mo["collided"][i]),
                "t_goal_with": float(mw["t_goal"][i]),
                "t_goal_without": float(mo["t_goal"][i]),
                "max_abs_accel_with": float(mw["max_abs_accel"][i]),
            }
        )
    return rows


def _plot(out_dir, records, mw, mo, config, planner, batch):
    """Speed over time of the drives whose blind-zone time differs most, and the ST graph of
    the first plan of the first of them (boundaries, decisions, the DP's and QP's profiles)."""
    import matplotlib.pyplot as plt

    diff = np.abs(mw["blind_s"] - mo["blind_s"])
    idx = list(np.argsort(-diff)[:4])
    fig, axes = plt.subplots(1, len(idx), figsize=(4.2 * len(idx), 3.4), squeeze=False)
    for ax, i in zip(axes[0], idx):
        n = int(mw["valid"][i].sum())
        m2 = int(mo["valid"][i].sum())
        ax.plot(np.arange(n) * config.dt, mw["v"][i, :n], "k", label="with non-blocking")
        ax.plot(np.arange(m2) * config.dt, mo["v"][i, :m2], "--", color="tab:orange", label="without")
        ax.set_title(f"{records[i].name}\nblind zone {mw['blind_s'][i]:.1f} s vs {mo['blind_s'][i]:.1f} s", fontsize=8)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("v (m/s)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "speed_profiles.png"), dpi=90)
    plt.close(fig)
    plot_st_graph(
        os.path.join(out_dir, "speed_st_graph.png"),
        planner,
        jax.tree_util.tree_map(lambda x: x[idx[0]], batch),
        records[idx[0]].name,
    )


def plot_st_graph(path: str, planner, scene, title: str, step: int = 0) -> str:
    """The ST graph of one plan (``jaxplan.speed.plot.draw_st``) at ``step`` of ``scene``."""
    import matplotlib.pyplot as plt

    from jaxplan.planner import EgoState
    from jaxplan.speed.plot import cycle, draw_st

    ego = EgoState.from_box_centre(scene.start, planner.vehicle)
    c = cycle(planner, scene, ego, step)
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    draw_st(ax, planner, c["plan"], c["profile"])
    ax.set_title(f"{title}: ST graph at t = {step * float(scene.dt):.1f} s", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


@register("speed")
def speed_suite(args: SuiteArgs) -> dict:
    import json

    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.sim.drive import DEFAULT_MAX_STEPS, n_steps_for, run_planner
    from jaxplan.sim.rollout import SimConfig
    from jaxplan.speed.planner import PathSpeedPlanner

    records, prefix, skipped = _records(args)
    if not records:
        raise ValueError("speed suite: no scenes")
    config = SimConfig(n_steps=n_steps_for(records, 0.1, DEFAULT_MAX_STEPS))
    batch = stack_scenes([r.scene for r in records], min_steps=config.n_steps + 1)
    res = {}
    for tag, planner in (("with", PathSpeedPlanner()), ("without", PathSpeedPlanner(nonblocking=False))):
        log, metrics, _ = run_planner(planner, batch, config)
        log = {
            k: (np.asarray(getattr(log, k)) if k != "info" else jax.tree_util.tree_map(np.asarray, log.info))
            for k in ("x", "y", "heading", "v", "valid", "info")
        }
        res[tag] = _measure(records, planner, batch, config, log, metrics)
    m = _summary(prefix, res["with"], res["without"])
    m[f"{prefix}scenes"] = len(records)
    if skipped is not None:
        m["skipped_files"] = skipped
    with open(os.path.join(args.out, "speed_scenes.json"), "w") as f:
        json.dump(_per_scene(records, res["with"], res["without"]), f, indent=1)
    _plot(args.out, records, res["with"], res["without"], config, PathSpeedPlanner(), batch)
    return m
