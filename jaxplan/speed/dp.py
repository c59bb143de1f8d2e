"""Dynamic programming over the ST grid: exact (min) and smooth (soft-min) forms.

Grid: DP times ``t_k = k * dt`` (k <= n_t), stations ``s_i = s0 + i * ds``.
A state at t_k is ``(i, j, m)``: station index i, speed ``v = j * dv`` of the
segment that ended at t_k (``dv = ds / dt``, so a segment moves ``j`` stations)
and the index m of the acceleration that produced it (``a = off[m] * da``,
``da = dv / dt``). So a transition ``(i, j, m) -> (i + j', j', m')`` with
``j' = j + off[m']`` has exact speed, acceleration and jerk
``(off[m'] - off[m]) * da / dt``; the DP is exact for its cost and the hard
limits (speed in [0, v_max], acceleration in [a_min, a_max], lateral
acceleration on curves) are the state space itself.

Cost of a transition (all per-second terms times their duration):
  speed ``w_speed (v' - v_cruise)^2``, accel ``w_accel a'^2``, jerk ``w_jerk j^2``;
  obstacles on ``n_sub`` sub-steps along the segment (constant speed):
  blocking -- ``big`` inside the boundary, ``w_block * relu(d - gap)^2`` closer
  than the follow / overtake distance; non-blocking (times a size factor
  ``(area / 8 m^2) ** size_exp``) -- ``no_bypass``: ``w_no_bypass * relu(front - rear_of_neighbour)^2``,
  ``blind_zone``: ``w_blind`` while the footprint is alongside the zone
  ``[rear - blind_back, rear + blind_front]``; keep-clear: ``w_keep_clear``
  while inside the region slower than ``keep_clear_v``, and at the end of the horizon
  when it is in (or would stop at ``b_comfort`` in) one it cannot leave (a blocking obstacle makes it stop before the end).
  End of horizon: stopping at ``b_comfort`` must keep the follow distance to
  blocking obstacles (``big`` if even ``a_min`` cannot stop in time).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.speed.nonblocking import classify, keep_clear_intervals
from jaxplan.speed.path_profile import PathProfile, path_profile, resample_obstacles
from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.types import Obstacles, VehicleParams, check_weights, is_concrete


@dataclasses.dataclass(frozen=True)
class SpeedConfig:
    """Grid sizes and hard limits (static under jit)."""

    dt: float = 1.0            # DP time step (s); Apollo uses 1 s
    n_t: int = 7               # DP steps; horizon = n_t * dt
    ds: float = 1.0            # station step (m); sets dv = ds/dt and da = ds/dt^2
    v_max: float = 20.0        # hard speed limit (m/s)
    a_min: float = -5.0        # hard acceleration limits (m/s^2)
    a_max: float = 2.0
    a_lat_max: float = 3.0     # lateral acceleration limit on curves (m/s^2)
    n_sub: int = 5             # obstacle checks per DP step
    buffer: float = 0.3        # clearance around blocking obstacles (m)
    side_width: float = 3.5    # width of the left/right non-blocking regions (m)
    no_overtake_side: int = 1  # +1: neighbours on the left must not be passed; 0: none
    v_moving: float = 1.0      # slower neighbours get no decision (m/s)
    blind_back: float = 4.0    # blind zone: from the neighbour's rear minus this ...
    blind_front: float = 1.0   # ... to its rear plus this (m, along the path)
    keep_clear_v: float = 1.0  # slower than this inside a keep-clear region is stopping there
    b_comfort: float = 2.0     # end of horizon: must be able to stop behind blocking obstacles at this decel
    big: float = 1e6           # cost of a collision / impossible state

    @property
    def dv(self):
        return self.ds / self.dt

    @property
    def da(self):
        return self.dv / self.dt

    @property
    def n_v(self):
        return int(math.floor(self.v_max / self.dv + 1e-9)) + 1

    @property
    def n_s(self):
        return self.n_t * (self.n_v - 1) + 1

    @property
    def accel_offsets(self):
        lo = int(math.ceil(self.a_min / self.da - 1e-9))
        hi = int(math.floor(self.a_max / self.da + 1e-9))
        return tuple(range(lo, hi + 1))

    @property
    def horizon(self):
        return self.n_t * self.dt

    def fine_times(self):
        """``(n_t * n_sub + 1,)`` times of the obstacle checks."""
        return np.arange(self.n_t * self.n_sub + 1) * (self.dt / self.n_sub)

    def validate(self) -> "SpeedConfig":
        if self.dt <= 0 or self.ds <= 0 or self.n_t < 1 or self.n_sub < 1:
            raise ValueError("SpeedConfig: dt, ds, n_t and n_sub must be positive")
        if self.v_max < self.dv:
            raise ValueError(f"SpeedConfig: v_max {self.v_max} below one speed step {self.dv}")
        if not (self.a_min <= 0 <= self.a_max) or 0 not in self.accel_offsets:
            raise ValueError("SpeedConfig: need a_min <= 0 <= a_max")
        return self


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CostWeights:
    """Differentiable cost weights (scalars or arrays; tune with jax.grad / optax)."""

    v_cruise: Any = 12.0
    w_speed: Any = 1.0
    w_accel: Any = 1.0
    w_jerk: Any = 0.5
    w_block: Any = 20.0
    follow_dist: Any = 6.0
    overtake_dist: Any = 4.0
    w_no_bypass: Any = 10.0
    w_blind: Any = 40.0
    size_exp: Any = 0.5
    w_keep_clear: Any = 500.0

    def validate(self) -> "CostWeights":
        """Host-side: every weight finite and >= 0 (a ``ValueError`` names the field)."""
        check_weights(self)
        return self

    @classmethod
    def default(cls, dtype=jnp.float32) -> "CostWeights":
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), cls())


SpeedCostWeights = CostWeights


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedScene:
    """Everything the DP needs about one scene, on the plan's grids (relative stations).

    Attributes:
        classified: ``Classified`` with boundaries ``(K, F)`` at the fine times.
        kc_lower, kc_upper, kc_hit: ``(R,)`` keep-clear ranges.
        v_limit: ``(N,)`` speed limit per station from curvature.
        front, rear: car front / rear ahead of its reference point (m).
    """

    classified: Any
    kc_lower: Any
    kc_upper: Any
    kc_hit: Any
    v_limit: Any
    front: Any
    rear: Any


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedPlan:
    """DP result: ``t``, ``s`` (relative to s0) ``(..., n_t + 1)``; segment speed ``v``
    and acceleration ``a`` ``(..., n_t)``; total ``cost`` and ``feasible`` ``(...)``;
    ``scene``: the ``SpeedScene`` planned against (ST boundaries, decisions), or None."""

    t: Any
    s: Any
    v: Any
    a: Any
    cost: Any
    feasible: Any
    scene: Any = None


def build_scene(profile: PathProfile, obstacles: Obstacles, vehicle: VehicleParams, config: SpeedConfig,
                keep_clear=None) -> SpeedScene:
    """Resample obstacles to the fine times, classify them, project keep-clear regions.

    Args:
        profile: path on ``config.n_s`` stations from s0.
        obstacles: boxes ``(K, T, 5)`` with their own times (from 0 = now).
        keep_clear: optional ``(vertices (R, P, 2), valid (R, P), active (R,))``.
    """
    obs = resample_obstacles(obstacles, jnp.asarray(config.fine_times(), obstacles.boxes.dtype))
    c = classify(profile, obs, vehicle, side_width=config.side_width, buffer=config.buffer,
                 no_overtake_side=config.no_overtake_side, v_moving=config.v_moving)
    s0 = profile.s[0]
    rel = lambda b: dataclasses.replace(b, lower=b.lower - s0, upper=b.upper - s0)
    c = dataclasses.replace(c, blocking=rel(c.blocking), side=rel(c.side))
    if keep_clear is None:
        lo = hi = jnp.zeros((1,), profile.s.dtype)
        hit = jnp.zeros((1,), bool)
    else:
        lo, hi, hit = keep_clear_intervals(profile, vehicle, *keep_clear)
        lo, hi = lo - s0, hi - s0
    v_limit = jnp.sqrt(config.a_lat_max / jnp.maximum(jnp.abs(profile.kappa), 1e-6))
    off = jnp.asarray(vehicle.center_offset, profile.s.dtype)
    return SpeedScene(c, lo, hi, hit, v_limit, off + 0.5 * vehicle.length, off - 0.5 * vehicle.length)


def _obstacle_terms(x, f, scene: SpeedScene, config: SpeedConfig, w: CostWeights):
    """(rate without keep-clear ``(...)``, collision ``(...)``, inside a keep-clear region ``(...)``)."""
    c = scene.classified
    ds = config.ds
    x = x[..., None]
    b = c.blocking
    lo, hi, hit = b.lower[:, f], b.upper[:, f], b.hit[:, f]
    inside = hit & (x > lo - ds) & (x < hi + ds)
    follow = jnp.where(hit & (x <= lo - ds), jnp.maximum(w.follow_dist - (lo - x), 0.0) ** 2, 0.0)
    ahead = jnp.where(hit & (x >= hi + ds), jnp.maximum(w.overtake_dist - (x - hi), 0.0) ** 2, 0.0)
    rate = w.w_block * jnp.sum(follow + ahead, -1)
    collision = jnp.any(inside, -1)
    sd = c.side
    lo, hi, hit = sd.lower[:, f], sd.upper[:, f], sd.hit[:, f]
    mult = (c.size / 8.0) ** w.size_exp
    front, rear = x + scene.front, x + scene.rear
    nb = jnp.where(hit & c.no_bypass, jnp.maximum(front - lo, 0.0) ** 2, 0.0)
    zone = hit & c.blind_zone & (front > lo - config.blind_back) & (rear < lo + config.blind_front)
    rate = rate + jnp.sum(mult * (w.w_no_bypass * nb + w.w_blind * zone), -1)
    kc = jnp.any(scene.kc_hit & (x > scene.kc_lower - ds) & (x < scene.kc_upper + ds), -1)
    return rate, collision, kc


def obstacle_cost(x, v, f, scene: SpeedScene, config: SpeedConfig, w: CostWeights):
    """Per-second obstacle cost rate of the car at relative station ``x`` with speed ``v``
    at fine time index ``f`` (``big`` for a collision, not scaled by time).

    Args:
        x, v: ``(...)`` broadcastable; f: int scalar.

    Returns:
        (rate ``(...)``, collision ``(...)`` bool).
    """
    rate, collision, kc = _obstacle_terms(x, f, scene, config, w)
    return rate + w.w_keep_clear * (kc & (v < config.keep_clear_v)), collision


def stage_costs(scene: SpeedScene, config: SpeedConfig, w: CostWeights, v0, a0):
    """Cost tensors of the DP.

    Returns:
        node ``(n_t, N, V)``: cost of the segment of step k ending at station i' with
        speed index j' (obstacles, speed, curvature limit); accel ``(M,)``: cost of
        each acceleration level for one step; jerk ``(M, M)`` [m', m]; terminal
        ``(N, V)`` cost of the final state; initial indices ``(j0, m0)``.
    """
    dt, ns = config.dt, config.n_sub
    N, V = config.n_s, config.n_v
    dtype = scene.v_limit.dtype
    offs = jnp.asarray(config.accel_offsets, dtype)
    i = jnp.arange(N)[:, None]
    j = jnp.arange(V)[None, :]
    v = (j * config.dv).astype(dtype)
    speed = w.w_speed * (v - w.v_cruise) ** 2 * dt  # (1, V)
    curve = jnp.where(v > scene.v_limit[:, None] + 1e-6, config.big, 0.0)  # (N, V)

    # Obstacle terms on a table of fine times x fine stations (step ds / n_sub): the car
    # moves at constant speed within a step, so every sub-step lands on that grid.
    F, X = config.n_t * ns + 1, (N - 1) * ns + 1
    xs = jnp.arange(X, dtype=dtype) * (config.ds / ns)
    rate, col, kc = jax.vmap(lambda f: _obstacle_terms(xs, f, scene, config, w))(jnp.arange(F))  # (F, X)
    moving = rate * (dt / ns) + jnp.where(col, config.big, 0.0)
    table = jnp.stack([moving, moving + w.w_keep_clear * kc * (dt / ns)])  # (2, F, X): [moving, slow]
    slow = (v < config.keep_clear_v).astype(jnp.int32)  # (1, V)
    u = jnp.clip((i - j) * ns, 0, X - 1)  # (N, V) fine station at the segment start

    def one_step(k):
        def sub(q):
            return table[slow, k * ns + q, jnp.clip(u + q * j, 0, X - 1)]

        return jnp.sum(jax.vmap(sub)(jnp.arange(1, ns + 1)), 0)

    obst = jax.vmap(one_step)(jnp.arange(config.n_t))  # (n_t, N, V)
    node = obst + speed + curve
    accel = w.w_accel * (offs * config.da) ** 2 * dt
    jerk = w.w_jerk * ((offs[:, None] - offs[None, :]) * config.da / dt) ** 2 * dt
    # End of horizon: stopping at b_comfort must keep the follow distance to blocking
    # obstacles present at the last time (hard if even a_min cannot stop in time).
    b = scene.classified.blocking
    lo = jnp.where(b.hit[:, -1], b.lower[:, -1], jnp.inf)  # (K,)
    x = i.astype(dtype) * config.ds
    behind = x[..., None] <= lo - config.ds
    stop = x + v ** 2 / (2.0 * config.b_comfort)
    hard = x + v ** 2 / (2.0 * abs(config.a_min))
    gap = jnp.where(behind, lo - stop[..., None], jnp.inf)
    terminal = w.w_block * jnp.sum(jnp.where(behind, jnp.maximum(w.follow_dist - gap, 0.0) ** 2, 0.0), -1)
    terminal = terminal + jnp.where(jnp.any(behind & (hard[..., None] > lo - config.ds), -1), config.big, 0.0)
    # Keep-clear: do not end inside a region that the car cannot leave because it must stop
    # (follow distance) behind a blocking obstacle before the region's end.
    stop_at = jnp.min(jnp.where(behind, lo - w.follow_dist, jnp.inf), -1)  # (N, V)
    inside = scene.kc_hit & (stop[..., None] > scene.kc_lower - config.ds) & (x[..., None] < scene.kc_upper + config.ds)
    trapped = inside & (stop_at[..., None] < scene.kc_upper + config.ds)
    terminal = terminal + w.w_keep_clear * dt * jnp.sum(trapped, -1)
    j0 = jnp.clip(jnp.round(v0 / config.dv), 0, V - 1).astype(jnp.int32)
    m0 = jnp.argmin(jnp.abs(offs * config.da - a0)).astype(jnp.int32)
    return node, accel, jerk, terminal, j0, m0


def _predecessors(V, config: SpeedConfig):
    """Gather indices: for target (i', j', m') the predecessor (i' - j', j' - off[m'])."""
    N = config.n_s
    offs = np.asarray(config.accel_offsets)
    ip = np.arange(N)[:, None] - np.arange(V)[None, :]  # (N, V)
    jp = np.arange(V)[:, None] - offs[None, :]  # (V, M)
    ok = (ip[:, :, None] >= 0) & (jp[None] >= 0) & (jp[None] < V)
    return np.clip(ip, 0, N - 1), np.clip(jp, 0, V - 1), ok


def _dp(node, accel, jerk, terminal, j0, m0, config: SpeedConfig, temperature=None):
    """Forward pass. Returns (final values ``(N, V, M)``, argmins ``(n_t, N, V, M)``)."""
    N, V, M = config.n_s, config.n_v, len(config.accel_offsets)
    # Unreachable states cost far more than any sum of collisions (``big`` per sub-step), so
    # the argmin never backtracks through an impossible predecessor, even in hopeless scenes.
    unreach = 1e3 * config.big
    ip, jp, ok = _predecessors(V, config)
    init = jnp.full((N, V, M), unreach, node.dtype).at[0, j0, m0].set(0.0)

    def step(val, nk):
        pred = val[ip[:, :, None], jp[None, :, :]]  # (N, V, M', M)
        pred = jnp.where(ok[..., None], pred, unreach) + jerk
        if temperature is None:
            best = jnp.min(pred, -1)
            arg = jnp.argmin(pred, -1).astype(jnp.int8)
        else:
            best = -temperature * jax.nn.logsumexp(-pred / temperature, -1)
            arg = jnp.zeros(pred.shape[:-1], jnp.int8)
        new = jnp.minimum(best + nk[:, :, None] + accel, unreach)
        return new, arg

    final, args = lax.scan(step, init, node)
    return final + terminal[:, :, None], args


def _backtrack(final, args, config: SpeedConfig):
    V, M = config.n_v, len(config.accel_offsets)
    offs = jnp.asarray(config.accel_offsets)
    flat = jnp.argmin(final)
    cost = final.reshape(-1)[flat]
    i, j, m = flat // (V * M), (flat // M) % V, flat % M

    def back(state, arg):
        i, j, m = state
        mp = arg[i, j, m].astype(jnp.int32)
        return (i - j, j - offs[m], mp), (i, j, m)

    _, (ii, jj, mm) = lax.scan(back, (i, j, m), args, reverse=True)
    return ii, jj, offs[mm], cost


def dp_from_costs(node, accel, jerk, terminal, j0, m0, config: SpeedConfig):
    """Exact DP on given cost tensors. Returns (station idx ``(n_t,)`` at t_1..t_n,
    speed idx ``(n_t,)``, accel offsets ``(n_t,)``, total cost)."""
    final, args = _dp(node, accel, jerk, terminal, j0, m0, config)
    return _backtrack(final, args, config)


def soft_value(node, accel, jerk, terminal, j0, m0, config: SpeedConfig, temperature):
    """Soft-min DP value (a smooth lower bound of the DP optimum; equal as temperature -> 0)."""
    final, _ = _dp(node, accel, jerk, terminal, j0, m0, config, temperature)
    return -temperature * jax.nn.logsumexp(-final / temperature)


def make_scene(path: ReferenceLine, obstacles: Obstacles, config: SpeedConfig, vehicle=None, s0=0.0,
               keep_clear=None) -> tuple[PathProfile, SpeedScene]:
    """Path profile on the DP station grid and the scene boundaries."""
    vehicle = VehicleParams() if vehicle is None else vehicle
    profile = path_profile(path, s0, config.n_s, config.ds)
    return profile, build_scene(profile, obstacles, vehicle, config, keep_clear)


def _plan_one(path, obstacles, v0, a0, s0, keep_clear, vehicle, config, weights):
    _, scene = make_scene(path, obstacles, config, vehicle, s0, keep_clear)
    costs = stage_costs(scene, config, weights, v0, a0)
    ii, jj, aa, cost = dp_from_costs(*costs, config)
    node = costs[0]
    dtype = node.dtype
    s = jnp.concatenate([jnp.zeros((1,), dtype), ii.astype(dtype) * config.ds])
    t = jnp.arange(config.n_t + 1, dtype=dtype) * config.dt
    return SpeedPlan(t, s, jj.astype(dtype) * config.dv, aa.astype(dtype) * config.da, cost,
                     cost < 0.5 * config.big, scene)


def _expected_one(path, obstacles, v0, a0, s0, keep_clear, vehicle, config, weights, temperature):
    _, scene = make_scene(path, obstacles, config, vehicle, s0, keep_clear)
    node, *rest = stage_costs(scene, config, weights, v0, a0)
    probe = jnp.zeros_like(node)
    value, p = jax.value_and_grad(lambda pr: soft_value(node + pr, *rest, config, temperature))(probe)
    dtype = node.dtype
    i = jnp.arange(config.n_s, dtype=dtype)[:, None] * config.ds
    j = jnp.arange(config.n_v, dtype=dtype)[None, :] * config.dv
    es = jnp.sum(p * i, (-2, -1))
    ev = jnp.sum(p * j, (-2, -1))
    t = jnp.arange(config.n_t + 1, dtype=dtype) * config.dt
    s = jnp.concatenate([jnp.zeros((1,), dtype), es])
    a = jnp.diff(jnp.concatenate([jnp.reshape(v0, (1,)).astype(dtype), ev])) / config.dt
    return SpeedPlan(t, s, ev, a, value, value < 0.5 * config.big, scene)


def _batched(fn, batch_ndim, args, static):
    f = lambda *a: fn(*a, *static)
    for _ in range(batch_ndim):
        f = jax.vmap(f)
    return f(*args)


def _check_inputs(path, obstacles, config, v0, weights):
    config.validate()
    if is_concrete(path, obstacles, v0):
        path.validate()
        obstacles.validate()
        if np.any(np.asarray(v0) < 0):
            raise ValueError("plan_speed: v0 must be >= 0")
    if weights is not None and is_concrete(weights):
        weights.validate()


def plan_speed(path: ReferenceLine, obstacles: Obstacles, config: SpeedConfig = SpeedConfig(),
               weights: CostWeights | None = None, *, v0=0.0, a0=0.0, s0=0.0, keep_clear=None,
               vehicle: VehicleParams | None = None) -> SpeedPlan:
    """Exact DP speed plan along ``path``.

    Args:
        path: ``ReferenceLine`` with leading batch dims ``(..., P, 2)`` on its fields.
        obstacles: boxes ``(..., K, T, 5)``, valid ``(..., K, T)``, times ``(..., T)`` from now.
        config: grid and limits (static); weights: ``CostWeights``, each leaf a scalar
            (shared by the batch) or ``(...)`` (one per scene).
        v0, a0, s0: ``(...)`` current speed, acceleration and station on the path.
        keep_clear: optional ``(vertices (..., R, P, 2), valid (..., R, P), active (..., R))``.

    Returns:
        ``SpeedPlan`` with leading dims ``(...)``.
    """
    _check_inputs(path, obstacles, config, v0, weights)
    weights = CostWeights.default(path.xy.dtype) if weights is None else weights
    vehicle = VehicleParams() if vehicle is None else vehicle
    return _plan_jit(path, obstacles, v0, a0, s0, keep_clear, vehicle, weights, config)


def _plan_impl(path, obstacles, v0, a0, s0, keep_clear, vehicle, weights, config):
    dtype = path.xy.dtype
    nb = path.xy.ndim - 2
    shape = path.xy.shape[:nb]
    v0, a0, s0 = (jnp.broadcast_to(jnp.asarray(x, dtype), shape) for x in (v0, a0, s0))
    weights = jax.tree_util.tree_map(lambda w: jnp.broadcast_to(jnp.asarray(w, dtype), shape), weights)
    return _batched(lambda *a: _plan_one(*a[:6], vehicle, config, a[6]), nb,
                    (path, obstacles, v0, a0, s0, keep_clear, weights), ())


_plan_jit = jax.jit(_plan_impl, static_argnames=("config",))


def _expected_impl(path, obstacles, v0, a0, s0, keep_clear, vehicle, weights, temperature, config):
    dtype = path.xy.dtype
    nb = path.xy.ndim - 2
    shape = path.xy.shape[:nb]
    v0, a0, s0 = (jnp.broadcast_to(jnp.asarray(x, dtype), shape) for x in (v0, a0, s0))
    weights = jax.tree_util.tree_map(lambda w: jnp.broadcast_to(jnp.asarray(w, dtype), shape), weights)
    return _batched(lambda *a: _expected_one(*a[:6], vehicle, config, a[6], temperature), nb,
                    (path, obstacles, v0, a0, s0, keep_clear, weights), ())


_expected_jit = jax.jit(_expected_impl, static_argnames=("config",))


def expected_speed_profile(path: ReferenceLine, obstacles: Obstacles, config: SpeedConfig = SpeedConfig(),
                           weights: CostWeights | None = None, temperature=1.0, *, v0=0.0, a0=0.0,
                           s0=0.0, keep_clear=None, vehicle: VehicleParams | None = None) -> SpeedPlan:
    """Smooth (soft-min) DP: the expected station and segment speed under the Gibbs
    distribution of speed profiles ``p ~ exp(-cost / temperature)``.

    Differentiable in ``weights`` (for tuning against recorded profiles); as the
    temperature goes to 0 it becomes the exact DP's profile. Same arguments as
    ``plan_speed``; ``cost`` holds the soft value.
    """
    _check_inputs(path, obstacles, config, v0, weights)
    weights = CostWeights.default(path.xy.dtype) if weights is None else weights
    vehicle = VehicleParams() if vehicle is None else vehicle
    return _expected_jit(path, obstacles, v0, a0, s0, keep_clear, vehicle, weights,
                         jnp.asarray(temperature, path.xy.dtype), config)
