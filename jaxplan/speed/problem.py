"""The speed DP's problem, as data: its grid and hard limits (``SpeedConfig``, with the
rectangle of reachable stations and speeds, ``band_widths`` / ``band_offsets``), its cost
weights (``CostWeights``), what the road asks of the speed (``SpeedRoad``), the ST graph of
one plan (``SpeedScene``, built by ``jaxplan.speed.st_graph``) and a plan (``SpeedPlan``,
read at any time by ``profile_at``). The search is ``jaxplan.speed.dp``, its costs
``jaxplan.speed.costs``."""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.planner import EMERGENCY_DECEL
from jaxplan.types import check_weights, pytree_dataclass


@dataclasses.dataclass(frozen=True)
class SpeedConfig:
    """Grid sizes and hard limits (static under jit).

    Attributes:
        dt, n_t: knot step (s) and number of segments (horizon ``n_t dt``).
        ds: station step (m); knot speeds every ``dv = 2 ds / dt``, accelerations (after the
            first segment) every ``da = dv / dt``.
        v_max, a_min, a_max: hard limits of the DP (m/s, m/s^2).
        n_sub: obstacle checks per segment (the boundaries are built at ``dt / n_sub``).
        a_lat_max: lateral acceleration of the curvature speed limit (m/s^2).
        buffer: clearance around blocking obstacles, lateral and longitudinal (m).
        side_width: width of the left / right non-blocking strips (m).
        no_overtake_side: +1: neighbours on the left must not be passed; -1 right; 0 none.
        v_moving: slower neighbours get no decision (m/s).
        blind_back, blind_front: a neighbour's blind zone, from its rear minus / plus (m).
        keep_clear_v: slower than this inside a keep-clear region is stopping there (m/s).
        b_comfort: end of horizon: must be able to stop behind blocking obstacles at this
            deceleration (m/s^2).
        pass_margin: s; a blocking boundary at time t also covers where the obstacle is up to
            this later (``time_margin``): the car passes ahead of a crossing car with that much
            time to spare or yields. Not for a vehicle driving the car's way that moves over into
            its lane (``build_speed_scene``'s ``merging``): that one is passed when the car is ahead.
        big: cost of a collision.
        qp_dt, a_brake, jerk_max: the smoothing QP (``smooth.py``): its step (s, must divide
            ``dt / n_sub``), its hardest braking (m/s^2, <= a_min) and jerk bound (m/s^3).
    """

    dt: float = 1.0
    n_t: int = 7
    ds: float = 1.0
    v_max: float = 30.0
    a_min: float = -5.0
    a_max: float = 4.0
    n_sub: int = 5
    a_lat_max: float = 3.0
    buffer: float = 0.3
    side_width: float = 3.5
    no_overtake_side: int = 1
    v_moving: float = 1.0
    blind_back: float = 4.0
    blind_front: float = 1.0
    keep_clear_v: float = 1.0
    b_comfort: float = 2.0
    pass_margin: float = 0.6
    big: float = 1e6
    qp_dt: float = 0.1
    a_brake: float = -EMERGENCY_DECEL
    jerk_max: float = 20.0

    @property
    def first_accel_range(self) -> tuple:
        """``(lo, hi)`` m/s^2: the accelerations of the DP's first segment, ``[a_min, a_max]``
        widened by half an acceleration step ``da``, so that the first knot's speed can be the
        grid speed nearest to what ``a_min`` / ``a_max`` reach from the car's speed, not only
        the ones inside (from 13.5 m/s with ``a_max`` 4 and speeds every 2 m/s, 16 m/s, 2.5
        m/s^2, would be the hardest acceleration of the first second). The smoothing QP keeps
        the executed profile within ``[a_brake, a_max]``."""
        return self.a_min - 0.5 * self.da, self.a_max + 0.5 * self.da

    @property
    def dv(self):
        return 2.0 * self.ds / self.dt

    @property
    def da(self):
        return self.dv / self.dt

    @property
    def n_v(self):
        return int(math.floor(self.v_max / self.dv + 1e-9)) + 1

    @property
    def n_s(self):
        """Station indices ``i`` of the grid (``c0 + i ds``, i < n_s)."""
        return int(math.floor(self.v_max * self.horizon / self.ds + 1e-9)) + 2

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

    def validate(self) -> SpeedConfig:
        if self.dt <= 0 or self.ds <= 0 or self.n_t < 1 or self.n_sub < 1:
            raise ValueError("SpeedConfig: dt, ds, n_t and n_sub must be positive")
        if self.v_max < self.dv:
            raise ValueError(f"SpeedConfig: v_max {self.v_max} below one speed step {self.dv}")
        if not (self.a_min <= 0 <= self.a_max) or 0 not in self.accel_offsets:
            raise ValueError("SpeedConfig: need a_min <= 0 <= a_max")
        if self.a_min > -self.da + 1e-9:
            raise ValueError(
                f"SpeedConfig: a_min {self.a_min} allows no braking step (da = {self.da}); lower a_min or ds"
            )
        r = self.dt / self.n_sub / self.qp_dt
        if self.qp_dt <= 0 or abs(r - round(r)) > 1e-6:
            raise ValueError(f"SpeedConfig: qp_dt {self.qp_dt} must divide the check step dt / n_sub")
        if self.a_brake > self.a_min or self.jerk_max <= 0:
            raise ValueError("SpeedConfig: need a_brake <= a_min and jerk_max > 0")
        if not (self.pass_margin >= 0) or not (self.b_comfort > 0):
            raise ValueError(
                f"SpeedConfig.pass_margin ({self.pass_margin}) must be >= 0 and b_comfort ({self.b_comfort}) > 0"
            )
        return self


@functools.cache
def band_widths(config: SpeedConfig) -> tuple:
    """Static band sizes ``((S_1, V_1), ..., (S_n, V_n))``: stations and speeds of the
    reachable states at each knot, the widest over every start speed in ``[0, v_max]``."""
    c = config
    v0 = np.linspace(0.0, c.v_max, 1201)
    out = []
    for k in range(1, c.n_t + 1):
        t = k * c.dt
        lo, hi = _station_range(v0, t, c, np)
        c0 = v0 * c.dt / 2
        ilo = np.floor((lo - c0) / c.ds) - 1
        ihi = np.ceil((hi - c0) / c.ds) + 1
        S = int(min(c.n_s, np.max(ihi - ilo) + 1))
        a_lo, a_hi = c.first_accel_range
        V = int(min(c.n_v, math.floor((a_hi - a_lo) * t / c.dv + 1e-9) + 3))
        out.append((S, V))
    return tuple(out)


def _station_range(v0, t, c: SpeedConfig, xp):
    """Least and most distance ``(...)`` reachable in ``t`` from speed ``v0`` (at the first
    segment's limits throughout: a band that holds every profile)."""
    a_lo, a_hi = c.first_accel_range
    tb = xp.minimum(t, v0 / -a_lo)
    lo = v0 * tb + 0.5 * a_lo * tb * tb
    ta = xp.clip((c.v_max - v0) / a_hi, 0.0, t)
    hi = v0 * ta + 0.5 * a_hi * ta * ta + (t - ta) * xp.maximum(v0 + a_hi * ta, 0.0)
    return lo, hi


def band_offsets(v0, config: SpeedConfig):
    """Dynamic band offsets ``(ilo (n_t,), jlo (n_t,))`` int32 for start speed ``v0``."""
    c = config
    dtype = jnp.result_type(v0, jnp.float32)
    v0 = jnp.asarray(v0, dtype)
    S = np.array([b[0] for b in band_widths(c)])
    V = np.array([b[1] for b in band_widths(c)])
    t = jnp.arange(1, c.n_t + 1, dtype=dtype) * c.dt
    lo, _ = _station_range(v0, t, c, jnp)
    c0 = v0 * c.dt / 2
    ilo = jnp.clip(jnp.floor((lo - c0) / c.ds) - 1, 0, c.n_s - S).astype(jnp.int32)
    jlo = jnp.clip(jnp.floor((v0 + c.first_accel_range[0] * t) / c.dv) - 1, 0, c.n_v - V).astype(jnp.int32)
    return ilo, jlo


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CostWeights:
    """Differentiable cost weights (scalars or arrays; tune with jax.grad / optax): the DP's terms
    (the module docstring) and ``w_lane_change``, the path-speed planner's cost of changing lanes
    (``jaxplan.speed.planner.PathSpeedPlanner.lane_change``)."""

    v_cruise: Any = 12.0
    w_speed: Any = 1.0
    w_accel: Any = 1.0
    a_comfort: Any = 2.0
    w_hard_accel: Any = 100.0
    w_jerk: Any = 0.5
    w_block: Any = 20.0
    follow_dist: Any = 4.0
    overtake_dist: Any = 4.0
    w_no_bypass: Any = 10.0
    w_blind: Any = 40.0
    size_exp: Any = 0.5
    w_keep_clear: Any = 500.0
    follow_headway: Any = 1.0
    w_limit: Any = 20.0
    w_goal: Any = 50.0
    w_goal_v: Any = 5.0
    w_rear: Any = 20.0
    rear_gap: Any = 2.0
    w_lane_change: Any = 300.0

    def validate(self) -> CostWeights:
        """Host-side: every weight finite and >= 0 (a ``ValueError`` names the field)."""
        check_weights(self)
        return self

    @classmethod
    def default(cls, dtype=jnp.float32) -> CostWeights:
        return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), cls())


SpeedCostWeights = CostWeights


@pytree_dataclass(data_fields=("limit_s", "limit_v", "stop_s", "goal_s", "goal_t", "goal_v", "lane_s"))
class SpeedRoad:
    """What the road asks of the speed (one scene; stations on the path, relative to the car).

    Attributes:
        limit_s, limit_v: ``(P,)`` the lane speed limit (m/s) sampled at increasing
            stations (constant beyond the ends).
        stop_s: ``()`` stop before this station (the path's blockage, the end of the map;
            ``inf``: none).
        goal_s: ``(2,)`` stations between which the car's box centre meets the goal;
            goal_t: ``(2,)`` its time window from now (s); goal_v: ``(2,)`` its speed range.
        lane_s: ``()`` the station where the path leaves the car's lane (it moves sideways
            by more than ``LANE_SHIFT`` from the car; ``inf``: it stays). An obstacle that
            reaches the car's band from behind beyond it is one the car merges in front
            of: blocking, not excused as ``behind`` (``nonblocking.classify``).
    """

    limit_s: Any
    limit_v: Any
    stop_s: Any
    goal_s: Any
    goal_t: Any
    goal_v: Any
    lane_s: Any = float("inf")

    @classmethod
    def free(cls, dtype=jnp.float32) -> SpeedRoad:
        """No speed limit, nothing to stop for, no goal."""
        inf = jnp.asarray(jnp.inf, dtype)
        two = jnp.array([-jnp.inf, jnp.inf], dtype)
        return cls(
            jnp.zeros((1,), dtype),
            jnp.full((1,), jnp.inf, dtype),
            inf,
            two,
            jnp.array([jnp.inf, jnp.inf], dtype),
            two,
            inf,
        )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedScene:
    """Everything the DP needs about one scene, at the check times ``config.fine_times()``
    (stations relative to the car's reference point now).

    Attributes:
        classified: ``Classified`` with boundaries ``(K, F)``.
        wall: ``STBoundary`` ``(1, F)`` the stop station (``road.stop_s``) as a boundary.
        kc_lower, kc_upper, kc_hit: ``(R,)`` keep-clear ranges.
        v_limit: ``(N,)`` speed limit at stations ``i ds`` (lane limit, curvature, v_max;
            the ``speed_envelope`` of their minimum).
        goal_s, goal_t, goal_v: ``(2,)`` the goal (``SpeedRoad``).
        front, rear: car front / rear ahead of its reference point (m).
    """

    classified: Any
    wall: Any
    kc_lower: Any
    kc_upper: Any
    kc_hit: Any
    v_limit: Any
    goal_s: Any
    goal_t: Any
    goal_v: Any
    front: Any
    rear: Any

    def blocking(self) -> tuple:
        """(lower, upper, hit, v_along) ``(K + 1, F)``: the blocking obstacles and the wall."""
        b, w = self.classified.blocking, self.wall
        cat = lambda a, c: jnp.concatenate([a, c], 0)
        return (
            cat(b.lower, w.lower),
            cat(b.upper, w.upper),
            cat(b.hit, w.hit),
            cat(self.classified.v_along, jnp.zeros_like(w.lower)),
        )


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedPlan:
    """DP result of one scene (add leading dims for batches).

    Attributes:
        t, s, v: ``(..., n_t + 1)`` knot times, stations (relative to s0) and speeds
            (``v[0] = v0``); a: ``(..., n_t)`` the constant acceleration of each segment.
        cost, feasible: ``(...)`` total cost, and no collision / impossible stop.
        scene: the ``SpeedScene`` planned against (ST boundaries, decisions), or None.
    """

    t: Any
    s: Any
    v: Any
    a: Any
    cost: Any
    feasible: Any
    scene: Any = None

    def at(self, t):
        """Exact (s, v, a) ``(T,)`` of the piecewise-constant-acceleration profile at ``t (T,)``."""
        return profile_at(self, t)


def profile_at(plan: SpeedPlan, t):
    """Station, speed and acceleration ``(T,)`` of a plan's profile at times ``t (T,)``
    (constant acceleration within each segment; held at the last knot's speed after it)."""
    t = jnp.asarray(t, plan.s.dtype)
    n = plan.a.shape[-1]
    dt = plan.t[1] - plan.t[0]
    k = jnp.clip(jnp.floor(t / dt).astype(jnp.int32), 0, n - 1)
    tau = jnp.clip(t - plan.t[k], 0.0, dt)
    a = plan.a[k]
    s = plan.s[k] + plan.v[k] * tau + 0.5 * a * tau * tau
    v = plan.v[k] + a * tau
    after = t > plan.t[-1]
    s = jnp.where(after, plan.s[-1] + plan.v[-1] * (t - plan.t[-1]), s)
    return s, jnp.where(after, plan.v[-1], v), jnp.where(after, 0.0, a)
