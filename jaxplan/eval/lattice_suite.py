"""Suite ``lattice``: the candidate lattice on synthetic traffic and (``--scenarios DIR``) recorded traffic.

Synthetic scenes on a straight three-lane road (lanes 3.5 m apart, ego in the
middle lane at the origin): following, cut-in, slow leader, congestion, lane
change (lane-change mode, target lane to the left, slow leader ahead) and an urban
crossroad stop. A drawn scene is kept only when in-lane braking at 5 m/s^2 from
t = 0 survives it (``braking_survives``), so every figure is over scenes a planner
can survive; figures are means over every scene of a kind. Recorded scenes: ego = the planning problem's start, reference =
the centre line of its lane, obstacles = the recorded vehicles (their actual
futures stand in for predictions).

Figures: share of scenes whose chosen trajectory is collision-free over the
horizon; share where speed variation found a collision-free candidate and the
fixed-speed candidates (end speed = current speed) had none (what speed variation adds);
candidates per scene; time per plan. Plots: the candidate fan coloured by cost
with the obstacles over time, and the chosen trajectory.
"""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.compile_options import NO_YNN, jit
from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.geometry import ReferenceLine
from jaxplan.lattice import MODE_NAMES, CostWeights, LatticeConfig, PlanState, plan, plan_batch
from jaxplan.scenarios.polylines import uniform_resample
from jaxplan.types import Obstacles, at_times_jit

KINDS = ("following", "cut_in", "slow_leader", "congestion", "lane_change", "crossroad")
# the road lattice on the three lanes (dense collision check: it compiles faster and costs little here)
NORMAL = LatticeConfig.road(lanes=(-1, 0, 1), near_budget=0.0, near_k=0)
LANE_CHANGE = LatticeConfig.road(lanes=(0, 1), target_lane=1, near_budget=0.0, near_k=0)
SURVIVAL_DECEL = 5.0  # m/s^2: a scene is kept when in-lane braking at this deceleration from t = 0 survives it
K_SYN = 32  # obstacles per scene (padded), shared with the recorded scenes: one compiled plan
N_REF = 231  # reference line points, likewise
LANE = 3.5


def _car(t, x0, y0, vx, vy=0.0, length=4.6, width=1.8):
    x, y = x0 + vx * t, y0 + vy * t
    return np.stack([x, y, np.full_like(t, length), np.full_like(t, width), np.arctan2(vy + 0 * t, vx + 1e-9)], -1)


def synthetic_scene(kind, rng, T, dt):
    """One scene: (state kwargs, boxes (k, T, 5))."""
    t = np.arange(T) * dt
    v0 = rng.uniform(10, 25) if kind != "crossroad" else rng.uniform(6, 12)
    cars, d_cross = [], np.inf
    if kind == "following":
        cars.append(_car(t, rng.uniform(20, 40), 0, v0 - rng.uniform(0, 3)))
    elif kind == "cut_in":
        vx, t_in = v0 - rng.uniform(2, 6), rng.uniform(0.5, 2.0)
        y = np.clip(LANE - LANE * (t - 0.3) / t_in, 0, LANE)  # from the left lane into ours
        b = _car(t, rng.uniform(8, 20), 0, vx)
        b[:, 1] = y
        b[:, 4] = np.arctan2(np.gradient(y, dt), vx)
        cars.append(b)
    elif kind == "slow_leader":
        cars.append(_car(t, rng.uniform(40, 70), 0, rng.uniform(0, 4)))
    elif kind == "congestion":
        for lane in (-1, 0, 1):
            x = rng.uniform(15, 30)
            for _ in range(2 if lane else 1):
                cars.append(_car(t, x, lane * LANE, rng.uniform(1, 6)))
                x += rng.uniform(10, 15)
    elif kind == "lane_change":
        cars.append(_car(t, rng.uniform(30, 50), 0, rng.uniform(2, 6)))
        cars.append(_car(t, rng.uniform(-40, -25), LANE, v0 + rng.uniform(0, 3)))
    elif kind == "crossroad":
        d_cross = rng.uniform(25, 45)
        cars.append(_car(t, d_cross + rng.uniform(2, 10), -LANE, 0.0))  # parked beyond the crossroad
    return dict(v=v0, d_crossroad=d_cross), np.array(cars).reshape(-1, T, 5)


def _pad(boxes, K, T, t):
    k = len(boxes)
    b = np.concatenate([boxes, np.tile([0, 0, 1.0, 1.0, 0], (K - k, T, 1))], 0) if k < K else boxes[:K]
    v = np.arange(K)[:, None] < k
    return Obstacles(jnp.asarray(b, jnp.float32), jnp.asarray(np.broadcast_to(v, (K, T))), jnp.asarray(t, jnp.float32))


def _stack(xs):
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *xs)


def _road():
    xs = np.linspace(-60, 400, N_REF)
    return ReferenceLine.from_polyline(np.stack([xs, np.zeros_like(xs)], 1))


def _outcome(res, cfg):
    """Per-scene figures from a (batched) LatticeResult."""
    col = np.asarray(res.collided)
    chosen = np.asarray(res.chosen)
    lvl = np.asarray(res.candidates.level)
    zero = int(np.argmin(np.abs(np.asarray(cfg.speed_deltas_kmh))))
    fixed = (np.asarray(res.candidates.speed_index) == zero) & (lvl == 0)
    free = ~col
    return {
        "chosen_free": ~np.take_along_axis(col, chosen[..., None], -1)[..., 0],
        "fixed_free": (free & fixed).any(-1),
        "any_free": free.any(-1),
        "level0_free": (free & (lvl == 0)).any(-1),
        "mode": np.asarray(res.mode),
        "ok": np.asarray(res.ok),
    }


def braking_survives(state, ref, obs, cfg) -> bool:
    """In-lane braking at ``SURVIVAL_DECEL`` from ``t = 0`` (the ``brake`` planner's path: along the
    line at the car's offset) touches no obstacle over the horizon (geometry core's SAT)."""
    from jaxplan.baselines.route_follow import follow_route
    from jaxplan.lattice.risk import min_separation, trajectory_boxes
    from jaxplan.models.braking import braking_profile
    from jaxplan.planner import EgoState

    t = jnp.arange(cfg.n_steps, dtype=jnp.float32) * cfg.dt
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    ego = EgoState(f(state.x), f(state.y), f(state.heading), f(state.v), f(state.a), f(state.kappa))
    ds, v, a = braking_profile(ego.v, -SURVIVAL_DECEL, t)
    tr = follow_route(ref, ego, ds, v, a, t)
    sep = min_separation(trajectory_boxes(tr, cfg.vehicle)[None], obs)
    return bool(np.asarray(sep).min() >= 0)


def _run_synthetic(n_per_kind, seed):
    rng = np.random.default_rng(seed)
    ref = _road()
    groups = {NORMAL: [k for k in KINDS if k != "lane_change"], LANE_CHANGE: ["lane_change"]}
    rows, results, timing = [], {}, {}
    for cfg, kinds in groups.items():
        T = cfg.n_steps
        t = np.arange(T) * cfg.dt
        states, obs, labels = [], [], []
        for kind in kinds:
            kept = 0
            for _ in range(50 * n_per_kind):  # keep only scenes that in-lane braking survives
                if kept == n_per_kind:
                    break
                kw, boxes = synthetic_scene(kind, rng, T, cfg.dt)
                st = PlanState.make(
                    0.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.03, 0.03), kw["v"], d_crossroad=kw["d_crossroad"]
                )
                o = _pad(boxes, K_SYN, T, t)
                if not braking_survives(st, ref, o, cfg):
                    continue
                states.append(st)
                obs.append(o)
                labels.append(kind)
                kept += 1
            if kept < n_per_kind:
                raise RuntimeError(f"lattice suite: only {kept} {kind} scenes that braking survives")
        B = len(states)
        S, O, R = _stack(states), _stack(obs), _stack([ref] * B)
        w = CostWeights()
        t0 = time.perf_counter()
        res = jax.block_until_ready(plan_batch(S, R, O, cfg, w))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = jax.block_until_ready(plan_batch(S, R, O, cfg, w))
        timing[cfg] = (first, (time.perf_counter() - t0) / B, B)
        o = _outcome(res, cfg)
        o["kind"] = np.array(labels)
        rows.append(o)
        for kind in kinds:
            idx = np.nonzero(o["kind"] == kind)[0]
            results[kind] = (
                jax.tree_util.tree_map(lambda a: a[idx], res),
                cfg,
                [states[i] for i in idx],
                [obs[i] for i in idx],
            )
    table = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    return table, results, timing


def recorded_obstacles(sc, cfg: LatticeConfig = NORMAL, k_max: int = K_SYN) -> Obstacles:
    """The ``k_max`` recorded obstacles nearest the ego start, read at the planner's times
    ``k * cfg.dt`` (``Obstacles.at_times``: any recording step; static obstacles held over the
    whole horizon, dynamic ones gone when their recording ends), padded to ``k_max``."""
    T = cfg.n_steps
    t = np.arange(T) * cfg.dt
    obs = at_times_jit(sc.obstacles, jnp.asarray(t, sc.obstacles.boxes.dtype))
    b, v, st = np.asarray(obs.boxes), np.asarray(obs.valid), np.asarray(obs.static)
    d0 = np.where(v.any(1), np.min(np.where(v, np.hypot(b[..., 0], b[..., 1]), np.inf), 1), np.inf)
    keep = np.argsort(d0)[:k_max]
    bb = np.tile([0, 0, 1.0, 1.0, 0], (k_max, T, 1))
    vv = np.zeros((k_max, T), bool)
    ss = np.zeros(k_max, bool)
    bb[: len(keep)], vv[: len(keep)], ss[: len(keep)] = b[keep], v[keep], st[keep]
    return Obstacles(jnp.asarray(bb, jnp.float32), jnp.asarray(vv), jnp.asarray(t, jnp.float32), jnp.asarray(ss))


def run_recorded(directory, limit, batch, cfg=NORMAL):
    """Recorded scenes planned ``batch`` at a time (the synthetic batch's shapes: no new compile).

    Returns (table, (times, example), files skipped, scenes skipped)."""
    import sys

    from jaxplan.scenarios.files import load_folder
    from jaxplan.scenarios.scenario import lane_reference

    folder = load_folder(directory, horizon=cfg.horizon, limit=limit)
    scenes, unusable = [], 0
    for f, sc in zip(folder.files, folder.scenarios):
        try:
            ref = ReferenceLine.from_polyline(uniform_resample(np.asarray(lane_reference(sc).xy), N_REF))
        except ValueError as e:
            print(f"jaxplan: lattice: no reference line in {f}: {e}", file=sys.stderr)
            unusable += 1
            continue
        obs = recorded_obstacles(sc, cfg)
        st = PlanState.make(sc.ego.x, sc.ego.y, sc.ego.heading, sc.ego.v, a=sc.ego.a)
        scenes.append((st, ref, obs, sc.id))
    if not scenes:
        return {}, None, len(folder.skipped), unusable
    rows, times, example = [], [], None
    for i in range(0, len(scenes), batch):
        chunk = scenes[i : i + batch]
        pad = chunk + [chunk[-1]] * (batch - len(chunk))
        S, R, O = (_stack([c[j] for c in pad]) for j in range(3))
        t0 = time.perf_counter()
        res = jax.block_until_ready(plan_batch(S, R, O, cfg, CostWeights()))
        times.append((time.perf_counter() - t0) / batch)
        o = _outcome(res, cfg)
        for j in range(len(chunk)):
            rows.append({k: v[j] for k, v in o.items()})
            if example is None or (not rows[-1]["level0_free"] and rows[-1]["any_free"]):
                example = (jax.tree_util.tree_map(lambda a: a[j], res), cfg, chunk[j][0], chunk[j][2], chunk[j][3])
    table = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    return table, (times, example), len(folder.skipped), unusable


def _figures(table, prefix=""):
    n = len(table["chosen_free"])
    return {
        f"{prefix}scenes": n,
        f"{prefix}share_chosen_collision_free": float(np.mean(table["chosen_free"])),
        f"{prefix}share_speed_variation_found_free": float(np.mean(table["any_free"] & ~table["fixed_free"])),
        f"{prefix}share_escalated": float(np.mean(table["mode"] == 1)),
        f"{prefix}share_all_collide": float(np.mean(table["mode"] == 2)),
        f"{prefix}share_emergency": float(np.mean(table["mode"] == 3)),
        f"{prefix}share_constrained": float(np.mean(table["mode"] == 4)),
        f"{prefix}share_not_ok": float(np.mean(~table["ok"])),
    }


@register("lattice")
def lattice_suite(args: SuiteArgs) -> dict:
    if args.weights:  # a bad weights file fails before the planning, not after it
        from jaxplan.tuning.run import load_cost

        load_cost(args.weights)
    n = args.n or (4 if args.quick else 40)
    table, results, timing = _run_synthetic(n, args.seed)
    m = _figures(table)
    m["synthetic_" + "scenes"] = m.pop("scenes")
    for kind in KINDS:
        sel = table["kind"] == kind
        m[f"{kind}_share_chosen_collision_free"] = float(np.mean(table["chosen_free"][sel]))
        m[f"{kind}_share_speed_variation_found_free"] = float(np.mean((table["any_free"] & ~table["fixed_free"])[sel]))
    m["candidates_per_scene"] = NORMAL.n_candidates
    m["candidates_per_scene_lane_change"] = LANE_CHANGE.n_candidates
    m["time_per_plan_ms_batched"] = 1e3 * timing[NORMAL][1]
    m["time_per_plan_ms_batched_lane_change"] = 1e3 * timing[LANE_CHANGE][1]
    m["compile_s_first_batch"] = float(timing[NORMAL][0])
    if not args.quick:  # single (unbatched) plan latency: one more compile
        res, cfg, states, obs = results["cut_in"]
        ref = _road()
        # one plan compiled as the planner compiles it (the host checks of ``plan`` skipped under jit)
        single = jit(plan, options=NO_YNN, static_argnames=("config", "keep_candidates"))
        jax.block_until_ready(single(states[0], ref, obs[0], cfg, CostWeights()))
        ts = []
        for st, o in zip(states, obs):
            t0 = time.perf_counter()
            jax.block_until_ready(single(st, ref, o, cfg, CostWeights()))
            ts.append(time.perf_counter() - t0)
        m["time_per_plan_ms_single"] = 1e3 * float(np.median(ts))
    _plot_fan(results, args.out)
    if args.scenarios:
        rec, extra, skipped, unusable = run_recorded(args.scenarios, 8 if args.quick else None, timing[NORMAL][2])
        m["skipped_files"] = skipped
        m["recorded_skipped_scenes"] = unusable
        if rec:
            m.update(_figures(rec, "recorded_"))
            m["recorded_time_per_plan_ms_batched"] = 1e3 * float(np.median(extra[0]))
            _plot_recorded(extra[1], args.out)
    if args.weights:
        m.update(imitation_figures(args))
    return m


def imitation_figures(args: SuiteArgs) -> dict:
    """Imitation figures of the cost in ``--weights`` on the held-out demonstrations of
    ``--scenarios`` (vehicles disjoint from the training ones; synthetic demonstrations
    without it), beside the default weights, constant velocity, constant acceleration, the
    IDM driven by the recorded leader and the best candidate, each with a 95 % bootstrap
    interval over scenarios: ``imitation.{method}.{ade3, fde3, ade5, fde5, collision_share}``
    and ``..._ci_lo`` / ``..._ci_hi``, per location too (``imitation.us101.weights.ade3``)."""
    from jaxplan.eval.tune_suite import LOCATION_GROUPS, plot_heldout
    from jaxplan.tuning.run import demonstrations, evaluate_cost, load_cost

    if args.weights is None:
        raise ValueError("imitation figures: need --weights")
    cost = load_cost(args.weights)
    train, val, source = demonstrations(
        args.scenarios,
        n_synthetic=args.n or 24,
        seed=args.seed,
        pattern="USA_US101-1[0-2]*" if args.quick and args.scenarios else None,
    )
    m = evaluate_cost(train, val, cost, n_boot=200 if args.quick else 1000, seed=args.seed)
    plot_heldout(
        m,
        os.path.join(args.out, "lattice_imitation.png"),
        LOCATION_GROUPS,
        methods=("constant_velocity", "constant_acceleration", "idm", "default", "weights", "oracle"),
        title=f"imitation of held-out vehicles ({os.path.basename(args.weights)}): ADE at 3 s",
    )
    out = {f"imitation.{k}": v for k, v in m.items()}
    out["imitation.recorded"] = int(source == "recorded")
    return out


def _draw(ax, res, i, cfg, obs_boxes, obs_valid, title):
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon as MplPolygon

    from jaxplan.geometry import box_corners

    pick = lambda x: np.asarray(x)[i] if i is not None else np.asarray(x)
    x, y = pick(res.candidates.traj.x), pick(res.candidates.traj.y)
    cost = pick(res.cost)
    col = pick(res.collided)
    chosen = int(pick(res.chosen))
    lvl = pick(res.candidates.level)
    lines = np.stack([x, y], -1)
    c = np.log10(np.maximum(cost - cost.min(), 1e-3) + 1e-3)
    lc = LineCollection(lines[~col], array=c[~col], cmap="viridis", linewidths=0.8)
    ax.add_collection(lc)
    ax.add_collection(LineCollection(lines[col], colors="0.75", linewidths=0.5, linestyles=":"))
    plt.colorbar(lc, ax=ax, fraction=0.03, label="log10 cost above the best")
    T = x.shape[-1]
    steps = range(0, T, 10)
    for k in range(obs_boxes.shape[0]):
        for j, s in enumerate(steps):
            if not obs_valid[k, s]:
                continue
            alpha = 0.15 + 0.6 * j / max(1, len(steps) - 1)
            ax.add_patch(
                MplPolygon(
                    np.asarray(box_corners(jnp.asarray(obs_boxes[k, s]))),
                    closed=True,
                    facecolor="C3",
                    alpha=alpha,
                    edgecolor="C3",
                )
            )
    ax.plot(
        x[chosen],
        y[chosen],
        "k-",
        lw=2.5,
        label=f"chosen (level {lvl[chosen]}, {'collides' if col[chosen] else 'free'})",
    )
    ax.plot(x[chosen, ::10], y[chosen, ::10], "ko", ms=4)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=7)
    ax.autoscale_view()


def _plot_fan(results, out):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(KINDS), 1, figsize=(11, 2.6 * len(KINDS)))
    for ax, kind in zip(axes, KINDS):
        res, cfg, states, obs = results[kind]
        # the first scene of the kind (scenes are drawn at random: a representative, not the worst one);
        # the title gives the share over every scene of the kind
        modes = np.asarray(res.mode)
        chosen_free = ~np.take_along_axis(np.asarray(res.collided), np.asarray(res.chosen)[:, None], -1)[:, 0]
        i = 0
        _draw(
            ax,
            res,
            i,
            cfg,
            np.asarray(res.obstacles.boxes[i]),
            np.asarray(res.obstacles.valid[i]),
            f"{kind}: {cfg.n_candidates} candidates, mode {MODE_NAMES[modes[i]]}; chosen plan collision-free "
            f"in {chosen_free.mean():.0%} of {len(modes)} scenes; obstacles every 1 s (darker = later), "
            f"collided candidates dotted",
        )
        ax.set_xlim(-10, 110)
        ax.set_ylim(-8, 10)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(os.path.join(out, "lattice_fan.png"), dpi=80)
    plt.close(fig)


def _plot_recorded(example, out):
    if example is None:
        return
    import matplotlib.pyplot as plt

    res, cfg, st, obs, sid = example
    fig, ax = plt.subplots(figsize=(10, 5))
    _draw(ax, res, None, cfg, np.asarray(res.obstacles.boxes), np.asarray(res.obstacles.valid), f"recorded scene {sid}")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    x, y = np.asarray(res.candidates.traj.x), np.asarray(res.candidates.traj.y)
    ax.set_xlim(x.min() - 30, x.max() + 30)
    ax.set_ylim(y.min() - 25, y.max() + 25)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "lattice_recorded.png"), dpi=80)
    plt.close(fig)
