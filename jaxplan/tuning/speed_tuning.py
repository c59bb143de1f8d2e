"""Learning the ST speed planner's weights from recorded speed profiles, against baselines.

Each demonstration gives the path the human drove (its recorded positions,
resampled by arc length and extended straight past the end) and the stations it
reached at the DP times (every ``config.dt``). The smooth (soft-min) DP's expected
station profile is differentiable in the weights; the loss is its Huber error to
the human's (masked where the recording ended).

Everything is measured on the same metric, station errors along the human's own
path (ADE / FDE at 3 s and 5 s): the exact DP with the tuned weights, with the
default ones, with a grid over two of them and with a random search; constant
velocity, constant acceleration, and the IDM following the recorded leader along
the same path. (The DP grid's own limit, an ``oracle`` tracking the human's stations, was
built on the station-grid DP; it is gone with the knot-speed DP and not yet rebuilt.)
"""

from __future__ import annotations

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.geometry.frenet import reference_line
from jaxplan.scenarios.polylines import resample_polyline
from jaxplan.speed import CostWeights, SpeedConfig, expected_speed_profile, plan_speed
from jaxplan.tuning.demos import Demo
from jaxplan.tuning.traffic import IDMParams, frenet_traffic, idm_rollout
from jaxplan.tuning.train import fit, from_log, to_log
from jaxplan.types import Obstacles, VehicleParams

# 5 s at 1 s steps and 1 m stations (knot speeds every 2 m/s, accelerations every 2 m/s^2), speeds up to
# 30 m/s (US-101 traffic).
SPEED_TUNING_CONFIG = SpeedConfig(n_t=5, dt=1.0, ds=1.0, v_max=30.0, a_min=-4.0, no_overtake_side=0)
# Weights learned from the recordings (the others keep their defaults). The cruise
# speed is learned relative to each driver's start speed: v_cruise = cruise_ratio * v0.
SPEED_LEARNED = ("cruise_ratio", "w_speed", "w_accel", "w_jerk", "w_block", "follow_dist")
VEHICLE = VehicleParams(reference="center")
SPEED_METHODS = ("constant_velocity", "constant_acceleration", "idm", "default", "grid", "random_search", "weights")


def default_speed_weights() -> dict:
    """The speed planner's default weights, with ``cruise_ratio`` 1 (keep the start speed)."""
    w = CostWeights()
    d = {f.name: float(getattr(w, f.name)) for f in dataclasses.fields(CostWeights)}
    d.pop("v_cruise")
    return {**d, "cruise_ratio": 1.0}


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedData:
    """Batched speed-tuning examples (leading axis ``B``).

    Attributes:
        path_xy: ``(B, P, 2)`` the human's path, uniformly resampled.
        obstacles: the other vehicles, boxes ``(B, K, T, 5)``.
        v0, a0: ``(B,)`` start speed and acceleration.
        s_human: ``(B, n_t + 1)`` stations the human reached at the DP times.
        valid: ``(B, n_t + 1)`` the recording reaches that time.
    """

    path_xy: jax.Array
    obstacles: Obstacles
    v0: jax.Array
    a0: jax.Array
    s_human: jax.Array
    valid: jax.Array


def speed_data(
    demos: Demo, config: SpeedConfig = SPEED_TUNING_CONFIG, points: int = 64, extend: float = 200.0
) -> tuple[SpeedData, np.ndarray]:
    """Examples from demonstrations whose human moved at least 2 m along a path that does not
    turn back on itself (recorded positions of a nearly stopped car jitter back and forth;
    the speed planner refuses such a path, ``ReferenceLine.validate``).

    Returns:
        (data, kept) where ``kept`` indexes the demonstrations used.
    """
    from jaxplan.geometry.frenet import check_turns

    hxy = np.asarray(demos.human_xy, np.float64)
    hv = np.asarray(demos.human_valid, bool)
    seg = np.linalg.norm(np.diff(hxy, axis=1), axis=-1) * hv[:, 1:]  # (B, T-1), 0 past the recording
    s = np.concatenate([np.zeros((len(hxy), 1)), np.cumsum(seg, 1)], 1)  # (B, T)
    steps = int(round(config.dt / 0.1))
    idx = np.arange(config.n_t + 1) * steps
    if idx[-1] >= s.shape[1]:
        raise ValueError(f"speed_data: demonstrations of {s.shape[1]} samples are shorter than the DP horizon")
    paths, kept_b = [], []
    for b in np.nonzero(s[:, -1] > 2.0)[0]:
        keep = np.concatenate([[True], seg[b] > 1e-3])
        sb = s[b][keep]
        path = resample_polyline(hxy[b][keep], sb, np.linspace(0.0, sb[-1] + extend, points))
        try:
            check_turns(path)
        except ValueError:
            continue
        paths.append(path)
        kept_b.append(b)
    kept = np.asarray(kept_b, int)
    pick = lambda x: jnp.asarray(np.asarray(x)[kept])
    obs = Obstacles(pick(demos.obstacles), pick(demos.obstacle_valid), pick(demos.t), pick(demos.obstacle_static))
    data = SpeedData(
        jnp.asarray(np.array(paths).reshape(len(kept), points, 2), jnp.float32),
        obs,
        pick(demos.ego[:, 3]),
        jnp.clip(pick(demos.ego[:, 4]), config.a_min, config.a_max),
        jnp.asarray(s[kept][:, idx], jnp.float32),
        jnp.asarray(hv[kept][:, idx]),
    )
    return data, kept


def _weights(w: dict, v0) -> CostWeights:
    """Per-example ``CostWeights`` ``(B,)``: ``v_cruise = cruise_ratio * v0``."""
    w = dict(w)
    ratio = w.pop("cruise_ratio")
    ones = jnp.ones_like(v0)
    return CostWeights(v_cruise=ratio * v0, **{k: jnp.asarray(v, jnp.float32) * ones for k, v in w.items()})


def speed_loss(params: dict, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG, temperature: float = 1.0):
    """Mean Huber loss (1 m) of the soft DP's expected stations against the human's (recorded times)."""
    w = _weights({**default_speed_weights(), **from_log(params)}, data.v0)
    refs = jax.vmap(reference_line)(data.path_xy)
    plan = expected_speed_profile(refs, data.obstacles, config, w, temperature, v0=data.v0, a0=data.a0, vehicle=VEHICLE)
    err = optax.huber_loss(plan.s, data.s_human, delta=1.0)
    return jnp.sum(jnp.where(data.valid, err, 0.0)) / jnp.maximum(jnp.sum(data.valid), 1)


def _exact(weights: dict, data: SpeedData, config: SpeedConfig):
    refs = jax.vmap(reference_line)(data.path_xy)
    return plan_speed(
        refs,
        data.obstacles,
        config,
        _weights({**default_speed_weights(), **weights}, data.v0),
        v0=data.v0,
        a0=data.a0,
        vehicle=VEHICLE,
    )


def station_profiles(weights: dict, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG) -> np.ndarray:
    """``(B, n_t + 1)`` stations of the exact DP plans with ``weights``."""
    return np.asarray(_exact(weights, data, config).s)


def _baseline_stations(data: SpeedData, idm: IDMParams, steps: int):
    t = jnp.arange(data.s_human.shape[1], dtype=data.v0.dtype) * (steps * 0.1)
    v0, a0 = data.v0[:, None], data.a0[:, None]
    cv = v0 * t
    t_stop = jnp.where(a0 < 0, -v0 / jnp.where(a0 < 0, a0, -1.0), jnp.inf)
    tt = jnp.minimum(t, t_stop)
    ca = v0 * tt + 0.5 * a0 * tt * tt

    def one(path_xy, obs, v0):
        ref = reference_line(path_xy)
        tr = frenet_traffic(ref, obs, 0.1)
        s, _ = idm_rollout(tr, jnp.zeros((), ref.xy.dtype), jnp.zeros((), ref.xy.dtype), v0, 4.8, idm, 0.1)
        return s[::steps]

    return cv, ca, jax.vmap(one)(data.path_xy, data.obstacles, data.v0)


def station_errors(stations, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG) -> dict:
    """Per-example station errors ``(B,)`` (m) at 3 s and 5 s, in the form of ``metrics.displacement``."""
    err = np.abs(np.asarray(stations)[:, : data.s_human.shape[1]] - np.asarray(data.s_human))
    ok = np.asarray(data.valid)
    k3, k5 = int(round(3.0 / config.dt)), int(round(5.0 / config.dt))
    return {
        "ade3": err[:, 1 : k3 + 1].mean(1),
        "fde3": err[:, k3],
        "valid3": ok[:, k3],
        "ade5": err[:, 1 : k5 + 1].mean(1),
        "fde5": err[:, k5],
        "valid5": ok[:, k5],
    }


def speed_metrics(weights: dict, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG) -> dict:
    """Station errors (m) of the exact DP plan at 3 s and 5 s (recorded times only), and the feasible share."""
    plan = _exact(weights, data, config)
    e = station_errors(plan.s, data, config)
    mean = lambda k, v: float(e[k][e[v]].mean()) if e[v].any() else float("nan")
    return {
        "station_ade3": mean("ade3", "valid3"),
        "station_fde3": mean("fde3", "valid3"),
        "station_ade5": mean("ade5", "valid5"),
        "station_fde5": mean("fde5", "valid5"),
        "feasible_share": float(np.asarray(plan.feasible).mean()),
    }


SPEED_GRID = {"cruise_ratio": (0.95, 1.0, 1.05, 1.1), "w_accel": (0.1, 1.0, 10.0)}


def grid_speed(
    data: SpeedData, grid: dict = SPEED_GRID, config: SpeedConfig = SPEED_TUNING_CONFIG
) -> tuple[dict, float]:
    """The combination of ``grid`` (others default) with the least station ADE3 of the exact DP on ``data``."""
    best, best_ade = default_speed_weights(), np.inf
    for combo in itertools.product(*grid.values()):
        w = {**default_speed_weights(), **dict(zip(grid, combo))}
        e = station_errors(station_profiles(w, data, config), data, config)
        ade = float(e["ade3"][e["valid3"]].mean())
        if ade < best_ade:
            best, best_ade = w, ade
    return best, best_ade


def random_search_speed(
    data: SpeedData, evals: int, scale: float = 1.0, seed: int = 0, config: SpeedConfig = SPEED_TUNING_CONFIG
) -> tuple[dict, float]:
    """The best of ``evals`` random weights (``SPEED_LEARNED`` times ``exp(uniform(+-scale))``
    around the defaults, the first the defaults themselves) by the exact DP's station ADE3
    on ``data``: the gradient-free baseline, judged on the metric itself."""
    rng = np.random.default_rng(seed)
    best, best_ade = default_speed_weights(), np.inf
    for i in range(max(1, evals)):
        w = dict(default_speed_weights())
        if i:
            w.update({k: w[k] * float(np.exp(rng.uniform(-scale, scale))) for k in SPEED_LEARNED})
        e = station_errors(station_profiles(w, data, config), data, config)
        ade = float(e["ade3"][e["valid3"]].mean())
        if ade < best_ade:
            best, best_ade = w, ade
    return best, best_ade


@dataclasses.dataclass
class SpeedRun:
    """What ``compare_speed`` produced: tuned ``weights``, ``history``, flat ``metrics``
    (``{method}.{ade3, ...}`` with intervals), per-example ``errors``, held-out ``val_data``."""

    weights: dict
    history: dict
    metrics: dict
    errors: dict
    val_data: SpeedData
    grid: dict


def compare_speed(
    train,
    val,
    steps: int = 40,
    lr: float = 0.1,
    seed: int = 0,
    batch_size: int = 32,
    idm_params: IDMParams | None = None,
    n_boot: int = 1000,
    grid: dict = SPEED_GRID,
    config: SpeedConfig = SPEED_TUNING_CONFIG,
    grid_examples: int = 128,
) -> SpeedRun:
    """Fit ``SPEED_LEARNED`` through the soft DP on ``train`` (``DemoSet``) and compare every
    method of ``SPEED_METHODS`` on ``val`` (station errors, bootstrap intervals over scenarios)."""
    from jaxplan.tuning.metrics import summary

    dtr, _ = speed_data(train.demos, config)
    dva, kept = speed_data(val.demos, config)
    if dtr.v0.shape[0] == 0 or dva.v0.shape[0] == 0:
        raise ValueError("compare_speed: no demonstration moved 2 m on one side of the split")
    idm_params = IDMParams() if idm_params is None else idm_params
    start = {k: v for k, v in to_log(default_speed_weights()).items() if k in SPEED_LEARNED}
    loss = lambda p, d: speed_loss(p, d, config)
    params, hist = fit(
        loss, start, dtr, steps=steps, lr=lr, batch_size=batch_size, seed=seed, log_every=max(1, steps // 20)
    )
    sub = jax.tree_util.tree_map(lambda x: x[:grid_examples], dtr)
    evals = max(2, steps * batch_size // max(1, sub.v0.shape[0]))  # the gradient's number of example evaluations
    rand, _ = random_search_speed(sub, evals, seed=seed, config=config)
    rule, _ = grid_speed(sub, grid, config)
    tuned = {**default_speed_weights(), **{k: float(v) for k, v in from_log(params).items()}}
    steps_per = int(round(config.dt / 0.1))
    cv, ca, im = _baseline_stations(dva, idm_params, steps_per)
    stations = {
        "constant_velocity": cv,
        "constant_acceleration": ca,
        "idm": im,
        "default": station_profiles(default_speed_weights(), dva, config),
        "grid": station_profiles(rule, dva, config),
        "random_search": station_profiles(rand, dva, config),
        "weights": station_profiles(tuned, dva, config),
    }
    errors = {k: station_errors(v, dva, config) for k, v in stations.items()}
    scen = val.index.scenario[kept]
    m = {
        "train_examples": int(dtr.v0.shape[0]),
        "val_examples": int(dva.v0.shape[0]),
        "steps": steps,
        "loss_start": hist["loss"][0],
        "loss_end": hist["loss"][-1],
        "feasible_share": float(np.asarray(_exact(tuned, dva, config).feasible).mean()),
    }
    for name, e in errors.items():
        m.update(summary(e, scen, f"{name}.", n_boot=n_boot, seed=seed))
    m.update({f"weight.{k}": tuned[k] for k in SPEED_LEARNED})
    return SpeedRun(tuned, hist, m, errors, dva, rule)
