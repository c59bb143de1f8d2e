"""Learning the ST speed planner's weights from recorded speed profiles.

Each demonstration gives the path the human drove (its recorded positions,
resampled by arc length and extended straight past the end) and the stations it
reached at the DP times. The smooth (soft-min) DP's expected station profile is
differentiable in the weights; the loss is its squared error to the human's.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.geometry.frenet import reference_line
from jaxplan.speed import CostWeights, SpeedConfig, expected_speed_profile, plan_speed
from jaxplan.scenarios.polylines import resample_polyline
from jaxplan.tuning.demos import Demo
from jaxplan.tuning.train import from_log
from jaxplan.types import Obstacles, VehicleParams

# 5 s at 1 s steps and 1 m stations (knot speeds every 2 m/s, accelerations every 2 m/s^2), speeds up to
# 30 m/s (US-101 traffic).
SPEED_TUNING_CONFIG = SpeedConfig(n_t=5, dt=1.0, ds=1.0, v_max=30.0, a_min=-4.0, no_overtake_side=0)
# Weights learned from the recordings (the others keep their defaults). The cruise
# speed is learned relative to each driver's start speed: v_cruise = cruise_ratio * v0.
SPEED_LEARNED = ("cruise_ratio", "w_speed", "w_accel", "w_jerk", "w_block", "follow_dist")
VEHICLE = VehicleParams(reference="center")


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
    """

    path_xy: jax.Array
    obstacles: Obstacles
    v0: jax.Array
    a0: jax.Array
    s_human: jax.Array


def speed_data(demos: Demo, config: SpeedConfig = SPEED_TUNING_CONFIG, points: int = 64,
               extend: float = 200.0) -> tuple[SpeedData, np.ndarray]:
    """Examples from demonstrations whose human moved at least 2 m.

    Returns:
        (data, kept) where ``kept`` indexes the demonstrations used.
    """
    hxy = np.asarray(demos.human_xy, np.float64)
    seg = np.linalg.norm(np.diff(hxy, axis=1), axis=-1)                    # (B, T-1)
    s = np.concatenate([np.zeros((len(hxy), 1)), np.cumsum(seg, 1)], 1)   # (B, T)
    steps = int(round(config.dt / 0.1))
    idx = np.arange(config.n_t + 1) * steps
    kept = np.nonzero((s[:, -1] > 2.0) & (idx[-1] < s.shape[1]))[0]
    paths = []
    for b in kept:
        keep = np.concatenate([[True], seg[b] > 1e-3])
        sb = s[b][keep]
        paths.append(resample_polyline(hxy[b][keep], sb, np.linspace(0.0, sb[-1] + extend, points)))
    pick = lambda x: jnp.asarray(np.asarray(x)[kept])
    static = None if demos.obstacle_static is None else pick(demos.obstacle_static)
    obs = Obstacles(pick(demos.obstacles), pick(demos.obstacle_valid), pick(demos.t), static)
    data = SpeedData(jnp.asarray(np.array(paths), jnp.float32), obs, pick(demos.ego[:, 3]),
                     jnp.clip(pick(demos.ego[:, 4]), config.a_min, config.a_max),
                     jnp.asarray(s[kept][:, idx], jnp.float32))
    return data, kept


def _weights(w: dict, v0) -> CostWeights:
    """Per-example ``CostWeights`` ``(B,)``: ``v_cruise = cruise_ratio * v0``."""
    w = dict(w)
    ratio = w.pop("cruise_ratio")
    ones = jnp.ones_like(v0)
    return CostWeights(v_cruise=ratio * v0, **{k: jnp.asarray(v, jnp.float32) * ones for k, v in w.items()})


def speed_loss(params: dict, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG,
               temperature: float = 1.0):
    """Mean Huber loss (1 m) of the soft DP's expected stations against the human's."""
    w = _weights({**default_speed_weights(), **from_log(params)}, data.v0)
    refs = jax.vmap(reference_line)(data.path_xy)
    plan = expected_speed_profile(refs, data.obstacles, config, w, temperature, v0=data.v0, a0=data.a0,
                                  vehicle=VEHICLE)
    return jnp.mean(optax.huber_loss(plan.s, data.s_human, delta=1.0))


def _exact(weights: dict, data: SpeedData, config: SpeedConfig):
    refs = jax.vmap(reference_line)(data.path_xy)
    return plan_speed(refs, data.obstacles, config, _weights({**default_speed_weights(), **weights}, data.v0),
                      v0=data.v0, a0=data.a0, vehicle=VEHICLE)


def station_profiles(weights: dict, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG) -> np.ndarray:
    """``(B, n_t + 1)`` stations of the exact DP plans with ``weights``."""
    return np.asarray(_exact(weights, data, config).s)


def speed_metrics(weights: dict, data: SpeedData, config: SpeedConfig = SPEED_TUNING_CONFIG) -> dict:
    """Station errors (m) of the exact DP plan at 3 s and 5 s, and the feasible share."""
    plan = _exact(weights, data, config)
    err = np.abs(np.asarray(plan.s) - np.asarray(data.s_human))
    k3 = int(round(3.0 / config.dt))
    return {"station_ade3": float(err[:, 1:k3 + 1].mean()), "station_fde3": float(err[:, k3].mean()),
            "station_ade5": float(err[:, 1:].mean()), "station_fde5": float(err[:, -1].mean()),
            "feasible_share": float(np.asarray(plan.feasible).mean())}
