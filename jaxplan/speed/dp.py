"""Dynamic programming over the ST graph: exact (min) and smooth (soft-min) forms.

**Formulation.** Knot times ``t_k = k dt`` (k <= n_t). A state at ``t_k`` is the car's
station and its speed *at the knot*: ``s = c0 + i ds``, ``v = j dv`` with
``dv = 2 ds / dt`` and ``c0 = v0 dt / 2``; between knots the acceleration is constant, so
consecutive stations fix the speed: ``s_{k+1} - s_k = (v_k + v_{k+1}) dt / 2``, i.e. a
transition ``(i, j) -> (i + j + j', j')`` moves ``j + j'`` stations with acceleration
``(j' - j) dv / dt``. The first segment starts exactly at the car's speed ``v0`` (the
station offset ``c0`` makes every later station a grid point) with the exact
acceleration ``(v_1 - v0) / dt``, and its jerk is taken from the car's acceleration ``a0``.
So the profile the DP returns *is* a kinematically exact piecewise-constant-acceleration
profile: its accelerations (not differences of segment averages) lie in
``[a_min, a_max]`` and its speeds in ``[0, v_max]``. The executed trajectory is the
smoothing QP's (``smooth.py``), which runs after the DP.

**Reachable band.** At ``t_k`` only the stations and speeds reachable from ``(0, v0)``
with accelerations in ``[a_min, a_max]`` are states. Station and speed have the same
parity (``i_1 = j_1`` and every step adds ``j + j'``), so the DP indexes a state by
``h = (i - j) / 2 = j_1 + ... + j_{k-1}`` and ``j``: every speed, and a run of ``h`` of
static width (``dp_band``, the widest over every ``v0``) from an offset fixed by the
least first-knot speed (``dp_offsets``). ``band_widths`` / ``band_offsets`` give the
rectangle of reachable stations and speeds (``DPCosts.ilo``, ``jlo``).

**Costs** (per-second terms times their duration), on tables built once per plan:

* per sub-step (``n_sub`` per segment, the car at its exact position, rounded to the
  station grid), from a table over (check time, station) built once from the ST
  boundaries (a scan over the obstacles of elementwise table updates): ``big (1 + v / 10
  m/s)`` for every sub-step that enters a blocking boundary (``ds / 2`` margin; entering,
  not staying inside: a collision the car cannot avoid is met at the lowest speed); ``w_block relu(d_follow - gap)^2`` behind the
  tightest one ahead, with the time-headway follow distance
  ``d_follow = follow_dist + follow_headway * v_obstacle``; ``w_block relu(overtake_dist
  - lead)^2`` ahead of one passed; ``w_rear relu(upper + rear_gap - s)^2`` ahead of the
  nearest one behind (the room left to a vehicle closing in from behind) and ``REAR_CONTACT
  big`` per second not ahead of its boundary (contact the other's fault: far below one the
  car's own; it lasts until the car is ahead again, so letting a recorded vehicle drive
  through the car does not end it); non-blocking (times a size factor ``(area / 8 m^2) **
  size_exp``): ``w_no_bypass relu(front - rear_of_neighbour)^2``, ``w_blind`` while the
  footprint is alongside the zone ``[rear - blind_back, rear + blind_front]``; keep-clear
  ``w_keep_clear`` while inside a region slower than ``keep_clear_v``; the goal
  ``w_goal huber(dist(centre, goal stations))`` at check times in the last ``GOAL_TAIL``
  seconds of the goal's time window;
* per knot: speed ``w_speed (v - v_target(s))^2`` with ``v_target = min(v_cruise,
  v_limit(s))``, and ``w_limit relu(v - v_limit(s))^2`` above the limit (the lane's speed
  limit and the continuous curvature limit ``sqrt(a_lat_max / |kappa(s)|)``, interpolated
  in s, made an envelope that the knots every ``dt`` cannot step over (``speed_envelope``:
  no faster before a slow stretch than braking at ``b_comfort`` reaches, nor after it than
  accelerating at ``a_max`` reaches)); ``w_goal_v dist(v, goal speeds)^2`` at knots in that
  part of the window;
* per segment: ``w_accel a^2`` and ``w_hard_accel relu(a - a_comfort)^2`` (``accel_cost``:
  harder than comfortable only to get away from a vehicle closing in from behind); the first
  segment also ``w_jerk ((a_1 - a0) / dt)^2``;
* end of horizon: stopping at ``b_comfort`` (the obstacle ahead braking the same) must
  keep ``follow_dist``; ``big`` if even ``a_min`` cannot stop in time; keep-clear: do not
  end in a region the car cannot leave.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.speed.nonblocking import classify, keep_clear_intervals
from jaxplan.speed.path_profile import PathProfile, path_profile, resample_obstacles
from jaxplan.speed.st_boundary import BIG, STBoundary, car_extent, project_obstacles
from jaxplan.types import Obstacles, VehicleParams, check_weights, is_concrete, pytree_dataclass


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
            time to spare or yields.
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
    a_brake: float = -7.0
    jerk_max: float = 20.0

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
        V = int(min(c.n_v, math.floor((c.a_max - c.a_min) * t / c.dv + 1e-9) + 3))
        out.append((S, V))
    return tuple(out)


def _station_range(v0, t, c: SpeedConfig, xp):
    """Least and most distance ``(...)`` reachable in ``t`` from speed ``v0``."""
    tb = xp.minimum(t, v0 / -c.a_min)
    lo = v0 * tb + 0.5 * c.a_min * tb * tb
    ta = xp.clip((c.v_max - v0) / c.a_max, 0.0, t)
    hi = v0 * ta + 0.5 * c.a_max * ta * ta + (t - ta) * xp.maximum(v0 + c.a_max * ta, 0.0)
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
    jlo = jnp.clip(jnp.floor((v0 + c.a_min * t) / c.dv) - 1, 0, c.n_v - V).astype(jnp.int32)
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
    w_goal: Any = 5.0
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


# ----------------------------------------------------------------------------- scene


def speed_envelope(v_lim, ds, decel, accel):
    """The speed limit ``v_lim (N,)`` on stations ``i ds`` lowered to what a car that meets it
    everywhere can drive: ``v(s) <= sqrt(v_lim(s')^2 + 2 decel (s' - s))`` for every ``s' > s``
    (braking into a slow stretch) and ``sqrt(v_lim(s')^2 + 2 accel (s - s'))`` for ``s' < s``
    (accelerating out of it); min-plus scans on ``v^2``."""
    w = jnp.square(v_lim)
    i = jnp.arange(w.shape[-1], dtype=w.dtype)
    cb, ca = 2.0 * decel * ds, 2.0 * accel * ds
    w = jnp.minimum(w, jax.lax.cummin(w + cb * i, reverse=True) - cb * i)
    w = jnp.minimum(w, jax.lax.cummin(w - ca * i) + ca * i)
    return jnp.sqrt(jnp.maximum(w, 0.0))


def time_margin(b: STBoundary, m: int) -> STBoundary:
    """Each boundary ``(K, F)`` at check time ``f`` widened to its union over ``f .. f + m``:
    passing ahead of an obstacle must clear where it will be ``m`` check times later (a
    crossing car is passed with a time margin, not by a hair); following behind one that
    drives on is unchanged."""
    if m <= 0:
        return b
    big = jnp.asarray(BIG, b.lower.dtype)
    lo, hi, hit = jnp.where(b.hit, b.lower, big), jnp.where(b.hit, b.upper, -big), b.hit
    # one windowed min / max over f .. f + m (the identity as padding past the last check time)
    win = lambda a, init, op: jax.lax.reduce_window(
        a, init, op, (1,) * (a.ndim - 1) + (m + 1,), (1,) * a.ndim, [(0, 0)] * (a.ndim - 1) + [(0, m)]
    )
    inf = jnp.asarray(jnp.inf, lo.dtype)
    L, H = win(lo, inf, jax.lax.min), win(hi, -inf, jax.lax.max)
    X = win(hit.astype(jnp.int32), jnp.asarray(np.iinfo(np.int32).min, jnp.int32), jax.lax.max) > 0
    return STBoundary(jnp.where(X, L, b.lower), jnp.where(X, H, b.upper), X)


def build_scene(
    profile: PathProfile,
    obstacles: Obstacles,
    vehicle: VehicleParams,
    config: SpeedConfig,
    keep_clear=None,
    v0=0.0,
    road: SpeedRoad | None = None,
) -> SpeedScene:
    """Resample obstacles to the check times, project them to the path once per time,
    classify them, project keep-clear regions, sample the speed limit.

    Args:
        profile: the path on ``config.n_s`` stations ``s0 + i ds`` (its ``ref`` is the path).
        obstacles: boxes ``(K, T, 5)`` with their own times (from 0 = now).
        keep_clear: optional ``(vertices (R, P, 2), valid (R, P), active (R,))``.
        v0: the car's speed (the ``behind`` rule).
        road: ``SpeedRoad`` or None (no limit but curvature and ``v_max``, no stop, no goal).
    """
    dtype = profile.s.dtype
    road = SpeedRoad.free(dtype) if road is None else road
    tf = jnp.asarray(config.fine_times(), dtype)
    obs = resample_obstacles(obstacles, tf)
    s0 = profile.s[0]
    osl = project_obstacles(profile.ref, obs, s0)  # stations relative to the car now
    c = classify(
        osl,
        obs,
        vehicle,
        tf,
        v0,
        config.a_min,
        lane_s=road.lane_s,
        side_width=config.side_width,
        buffer=config.buffer,
        no_overtake_side=config.no_overtake_side,
        v_moving=config.v_moving,
    )
    held = int(round(config.pass_margin * config.n_sub / config.dt))  # check times in pass_margin
    c = dataclasses.replace(c, blocking=time_margin(c.blocking, held))
    front, rear = car_extent(vehicle, dtype)
    stop = jnp.asarray(road.stop_s, dtype)
    has = jnp.isfinite(stop)
    F = tf.shape[0]
    wall = STBoundary(
        jnp.full((1, F), jnp.where(has, stop - front - config.buffer, BIG), dtype),
        jnp.full((1, F), BIG, dtype),
        jnp.full((1, F), has),
    )
    if keep_clear is None:
        lo = hi = jnp.zeros((1,), dtype)
        hit = jnp.zeros((1,), bool)
    else:
        lo, hi, hit = keep_clear_intervals(profile, vehicle, *keep_clear)
        lo, hi = lo - s0, hi - s0
    lane = jnp.interp(
        profile.s - s0, jnp.asarray(road.limit_s, dtype), jnp.minimum(jnp.asarray(road.limit_v, dtype), 1e3)
    )
    curve = jnp.sqrt(config.a_lat_max / jnp.maximum(jnp.abs(profile.kappa), 1e-6))
    v_limit = speed_envelope(
        jnp.minimum(jnp.minimum(lane, curve), config.v_max), config.ds, config.b_comfort, config.a_max
    )
    return SpeedScene(
        c,
        wall,
        lo,
        hi,
        hit,
        v_limit,
        jnp.asarray(road.goal_s, dtype),
        jnp.asarray(road.goal_t, dtype),
        jnp.asarray(road.goal_v, dtype),
        front,
        rear,
    )


# ----------------------------------------------------------------------------- cost tables


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class DPCosts:
    """The DP's cost tensors of one scene (``X`` table stations ``c0 + (u - U0) ds``).

    Attributes:
        table: ``(2, F, X)`` cost of one sub-step at check time f and station u, for a
            moving car [0] and one slower than ``keep_clear_v`` [1] (``big`` in collision).
        node: ``(X, V)`` per-knot cost of speed index j at station u (speed, limits).
        goal_v: ``(V,)`` extra knot cost inside the goal window; goal_k: ``(n_t,)`` bool,
            knot k+1 inside it.
        accel: ``(M,)`` cost of each acceleration offset for one segment (segments >= 2).
        first: ``(V,)`` cost of the first segment ending at speed j (accel, jerk from a0,
            obstacles on its sub-steps; ``UNREACH`` where its acceleration is out of range).
        terminal: ``(X, V)``.
        ilo, jlo: ``(n_t,)`` int32 offsets of the reachable stations and speeds
            (``band_offsets``; the DP's own band follows from ``first``, ``dp_offsets``).
        c0: ``()`` station of index 0.
    """

    table: Any
    node: Any
    goal_v: Any
    goal_k: Any
    accel: Any
    first: Any
    terminal: Any
    ilo: Any
    jlo: Any
    c0: Any


def _u0(config: SpeedConfig) -> int:
    return config.n_v + 1


def _n_table(config: SpeedConfig) -> int:
    return config.n_s + _u0(config) + 2


def unreach(config: SpeedConfig) -> float:
    """Cost of an unreachable state: above any sum of collisions, so the argmin never
    backtracks through an impossible predecessor (hopeless scenes keep a valid profile)."""
    return 1e3 * config.big


def _scatter(n, idx, val, init, op):
    """``(n, ...)`` array: ``init`` with ``val (N, ...)`` combined (op: add/min/max) at
    ``idx (N,)`` (indices ``>= n`` are dropped)."""
    a = jnp.full((n + 1,) + val.shape[1:], init, val.dtype)
    a = getattr(a.at[jnp.clip(idx, 0, n)], op)(val)
    return a[:n]


def _obstacle_tables(xs, x0, ds, scene: SpeedScene, config: SpeedConfig, w: CostWeights, mult):
    """Per-second obstacle cost ``(F, X)`` and collision ``(F, X)`` at every check time and
    table station: a scan over the obstacles (elementwise updates of the tables, which XLA
    fuses; no reduction over the small obstacle axis).

    Station ``u`` (index of ``xs``) collides with a blocking boundary when
    ``lower - ds / 2 <= xs_u <= upper + ds / 2`` (sub-steps are rounded to the nearest
    station); it is behind it below that range (follow line ``lower - d_follow``, the
    tightest counts) and ahead of it above (lead line ``upper + overtake_dist``, the
    farthest counts). Obstacles behind (``Classified.rear``) ask for ``rear_gap`` ahead of
    their boundary's upper end (the nearest counts).
    """
    X = xs.shape[0]
    F = config.n_t * config.n_sub + 1
    dtype = xs.dtype
    big = jnp.asarray(BIG, dtype)
    uf = jnp.arange(X, dtype=dtype)
    lo, hi, hit, vob = scene.blocking()  # (K + 1, F)

    def block(carry, k):
        col, e, g = carry
        lo_k, hi_k, hit_k = lo[k][:, None], hi[k][:, None], hit[k][:, None]
        y = (lo_k - x0) / ds - 0.5
        z = (hi_k - x0) / ds + 0.5
        col = col | (hit_k & (uf >= y) & (uf <= z))
        d_f = w.follow_dist + w.follow_headway * jnp.maximum(vob[k][:, None], 0.0)
        e = jnp.minimum(e, jnp.where(hit_k & (uf < y), lo_k - d_f, big))
        g = jnp.maximum(g, jnp.where(hit_k & (uf > z), hi_k + w.overtake_dist, -big))
        return (col, e, g), None

    # the first boundary from scalar initial values (no table-sized fills), the rest scanned
    init, _ = block((jnp.zeros((), bool), big, -big), 0)
    (collide, e, g), _ = jax.lax.scan(block, init, jnp.arange(1, lo.shape[0]))
    cl = scene.classified
    slo, shit = cl.side.lower, cl.side.hit  # (K, F)

    def side(carry, k):
        zone, nbp = carry
        s_k = slo[k][:, None]
        on_b = shit[k][:, None] & cl.blind_zone[k]
        yb = (s_k - config.blind_back - scene.front - x0) / ds
        zb = (s_k + config.blind_front - scene.rear - x0) / ds
        zone = zone + jnp.where(on_b & (uf >= yb) & (uf <= zb), mult[k], 0.0)
        on_n = shit[k][:, None] & cl.no_bypass[k]
        cpos = s_k - scene.front
        nbp = nbp + jnp.where(on_n, mult[k] * jnp.maximum(xs - cpos, 0.0) ** 2, 0.0)
        return (zone, nbp), None

    zero = jnp.zeros((), dtype)
    init, _ = side((zero, zero), 0) if slo.shape[0] else ((jnp.zeros((F, X), dtype),) * 2, None)
    (zone, nbp), _ = jax.lax.scan(side, init, jnp.arange(1, slo.shape[0]))
    rate = w.w_block * (jnp.maximum(xs - e, 0.0) ** 2 + jnp.maximum(g - xs, 0.0) ** 2)
    # behind: the room left ahead of the nearest one, and a contact (its fault, but a contact)
    rb = cl.rear
    r = jnp.max(jnp.where(rb.hit, rb.upper, -big), axis=0, initial=-big)[:, None]  # (F, 1)
    # a contact lasts while the car is not ahead of the nearest one: one that drives through the
    # car (a recording does not brake) is not left behind by letting it pass
    struck = xs <= r + 0.5 * ds  # (F, X); r = -big where none is behind
    rate = (
        rate + w.w_rear * jnp.maximum(r + w.rear_gap - xs, 0.0) ** 2 + jnp.where(struck, REAR_CONTACT * config.big, 0.0)
    )
    return rate + w.w_no_bypass * nbp + w.w_blind * zone, collide


def _goal_table(xs, f_goal, scene: SpeedScene, w: CostWeights):
    """``(F, X)`` goal cost rate: the box centre's distance to the goal's stations (Huber) at
    the check times ``f_goal (F,)`` of the window's last part."""
    cx = xs + 0.5 * (scene.front + scene.rear)
    gd = jnp.maximum(scene.goal_s[0] - cx, 0.0) + jnp.maximum(cx - scene.goal_s[1], 0.0)
    gd = jnp.where(jnp.isfinite(gd), gd, 0.0)
    hub = jnp.where(gd < GOAL_HUBER, gd * gd, GOAL_HUBER * (2.0 * gd - GOAL_HUBER))
    return jnp.where(f_goal[:, None], w.w_goal * hub[None, :], 0.0)


COLLISION_V = 10.0  # m/s: a collision's cost grows by big per this much impact speed
# per second in contact with a vehicle from behind, times big (far below a collision of the car's own)
REAR_CONTACT = 0.01
GOAL_TAIL = 1.0  # s: the goal is asked for in the last second of its time window
GOAL_HUBER = 2.0  # m: the goal's distance cost is quadratic up to this, then linear


def goal_times(goal_t, t):
    """``(T,)`` bool: times ``t`` in the last ``GOAL_TAIL`` seconds of the goal's window
    ``goal_t (2,)`` (the car must be in the goal region before the window closes)."""
    return (t >= jnp.maximum(goal_t[0], goal_t[1] - GOAL_TAIL) - 1e-6) & (t <= goal_t[1] + 1e-6)


def accel_cost(a, w: CostWeights):
    """Acceleration cost rate ``(...)`` of accelerations ``a (...)``: ``w_accel a^2`` and, above
    the comfortable ``a_comfort``, ``w_hard_accel relu(a - a_comfort)^2`` (the DP may speed up
    harder, up to ``SpeedConfig.a_max``, only for much: to get away from a vehicle closing in
    from behind)."""
    return w.w_accel * a**2 + w.w_hard_accel * jnp.maximum(a - w.a_comfort, 0.0) ** 2


def stage_costs(scene: SpeedScene, config: SpeedConfig, w: CostWeights, v0, a0) -> DPCosts:
    """Cost tensors of the DP for one scene (``DPCosts``)."""
    c = config
    dtype = scene.v_limit.dtype
    v0 = jnp.clip(jnp.asarray(v0, dtype), 0.0, c.v_max)
    a0 = jnp.asarray(a0, dtype)
    V, X, U0, ns = c.n_v, _n_table(c), _u0(c), c.n_sub
    h = c.dt / ns
    c0 = v0 * c.dt / 2
    xs = c0 + (jnp.arange(X, dtype=dtype) - U0) * c.ds
    x0 = xs[0]
    tf = jnp.asarray(c.fine_times(), dtype)
    f_goal = goal_times(scene.goal_t, tf)
    lo, hi, hit, vob = scene.blocking()
    cl = scene.classified
    mult = (cl.size / 8.0) ** w.size_exp
    rate, collide = _obstacle_tables(xs, x0, c.ds, scene, c, w, mult)
    rate = rate + _goal_table(xs, f_goal, scene, w)
    moving = rate * h + jnp.where(collide, c.big, 0.0)  # (F, X)
    kc = jnp.any(scene.kc_hit & (xs[:, None] > scene.kc_lower - c.ds) & (xs[:, None] < scene.kc_upper + c.ds), -1)
    layer = jnp.arange(2)[:, None, None]  # one elementwise pass (a stack of two tables is two)
    table = jnp.where(layer == 1, moving + w.w_keep_clear * h * kc, moving)
    # per-knot speed cost against the target speed and the limit at each station
    n_lim = scene.v_limit.shape[0]
    q = jnp.clip(xs / c.ds, 0.0, n_lim - 1.0)
    k = jnp.clip(jnp.floor(q).astype(jnp.int32), 0, n_lim - 2)
    lim = scene.v_limit[k] + (q - k) * (scene.v_limit[k + 1] - scene.v_limit[k])  # (X,)
    vj = jnp.arange(V, dtype=dtype) * c.dv
    target = jnp.minimum(w.v_cruise, lim)
    node = c.dt * (
        w.w_speed * (vj[None] - target[:, None]) ** 2 + w.w_limit * jnp.maximum(vj[None] - lim[:, None], 0.0) ** 2
    )
    gv = scene.goal_v
    gdist = jnp.maximum(gv[0] - vj, 0.0) + jnp.maximum(vj - gv[1], 0.0)
    goal_v = c.dt * w.w_goal_v * jnp.where(jnp.isfinite(gdist), gdist, 0.0) ** 2
    goal_k = goal_times(scene.goal_t, jnp.arange(1, c.n_t + 1, dtype=dtype) * c.dt)
    offs = jnp.asarray(c.accel_offsets, dtype)
    accel = accel_cost(offs * c.da, w) * c.dt
    # first segment: from (0, v0) to speed j with the exact acceleration (v_j - v0) / dt
    a1 = (vj - v0) / c.dt
    tq = jnp.arange(0, ns + 1, dtype=dtype) * h
    xq = v0 * tq[None] + 0.5 * a1[:, None] * tq[None] ** 2  # (V, ns + 1)
    uq = jnp.clip(jnp.round((xq - x0) / c.ds).astype(jnp.int32), 0, X - 1)
    vq = v0 + a1[:, None] * tq[None]
    slow = (vq < c.keep_clear_v).astype(jnp.int32)
    obst1 = segment_cost(table[slow, jnp.arange(0, ns + 1)[None], uq], vq, c.big)
    first = accel_cost(a1, w) * c.dt + w.w_jerk * ((a1 - a0) / c.dt) ** 2 * c.dt + obst1
    ok1 = (a1 >= c.a_min - 1e-4) & (a1 <= c.a_max + 1e-4)
    first = jnp.where(ok1, first, unreach(c))
    terminal = _terminal(xs, x0, vj, lo[:, -1], hit[:, -1], vob[:, -1], kc, scene, c, w)
    ilo, jlo = band_offsets(v0, c)
    return DPCosts(table, node, goal_v, goal_k, accel, first, terminal, ilo, jlo, c0)


def _terminal(xs, x0, vj, lo, hit, vob, kc, scene, c: SpeedConfig, w: CostWeights):
    """End-of-horizon cost ``(X, V)`` (see the module docstring)."""
    X = xs.shape[0]
    dtype = xs.dtype
    big = jnp.asarray(BIG, dtype)
    i_b = jnp.minimum(jnp.ceil((lo - x0) / c.ds - 0.5).astype(jnp.int32) - 1, X - 1)
    where = jnp.where(hit & (i_b >= 0), i_b, X)
    v2 = jnp.maximum(vob, 0.0) ** 2
    # min over the obstacles ahead of: their stop lines braking at b_comfort and at a_min,
    # and their follow lines
    lines = jnp.stack([lo + v2 / (2.0 * c.b_comfort), lo + v2 / (2.0 * abs(c.a_min)), lo - w.follow_dist], -1)
    lines = jax.lax.cummin(_scatter(X, where, lines, big, "min"), axis=0, reverse=True)
    l_comfort, l_hard, l_follow = lines[:, 0], lines[:, 1], lines[:, 2]
    stop = xs[:, None] + vj[None] ** 2 / (2.0 * c.b_comfort)
    hard = xs[:, None] + vj[None] ** 2 / (2.0 * abs(c.a_min))
    term = w.w_block * jnp.maximum(w.follow_dist - (l_comfort[:, None] - stop), 0.0) ** 2
    term = term + jnp.where(hard > l_hard[:, None] - c.ds, c.big, 0.0)
    inside = scene.kc_hit & (stop[..., None] > scene.kc_lower - c.ds) & (xs[:, None, None] < scene.kc_upper + c.ds)
    trapped = inside & (l_follow[:, None, None] < scene.kc_upper + c.ds)
    return term + w.w_keep_clear * c.dt * jnp.sum(trapped, -1)


# ----------------------------------------------------------------------------- the DP


@functools.cache
def _substep_tables(config: SpeedConfig):
    """Static ``(V, M, n_sub + 1)`` tables for the sub-steps ``q = 0..n_sub`` of a segment
    starting at speed j with acceleration offset m: station offset (rounded, in ds),
    whether it is slower than ``keep_clear_v``, and its speed (m/s)."""
    c = config
    offs = np.asarray(c.accel_offsets)
    j = np.arange(c.n_v)[:, None, None]
    m = offs[None, :, None]
    q = np.arange(0, c.n_sub + 1)[None, None, :] / c.n_sub
    r = np.round(2 * j * q + m * q * q).astype(np.int32)
    v = (j + m * q) * c.dv
    return r, (v < c.keep_clear_v).astype(np.int32), v


def segment_cost(g, v, big):
    """Obstacle cost of a segment from its table values at the sub-steps ``q = 0..n_sub``
    (``g (..., n_sub + 1)``; the knot it starts from first), the speeds there ``v`` and the
    collision cost ``big`` (``SpeedConfig.big``, added to the tables inside boundaries): the
    per-second costs of sub-steps 1..n, and for every sub-step that *enters* a blocking
    boundary (inside it, not inside at the sub-step before) ``big * (1 + v / COLLISION_V)``.
    So among profiles that cannot avoid a collision the DP picks the one that hits at the
    lowest speed (braking), not the one that spends the least time inside the boundary."""
    inside = g >= 0.5 * big
    rate = jnp.where(inside, g - big, g)[..., 1:]
    enter = inside[..., 1:] & ~inside[..., :-1]
    return jnp.sum(rate + jnp.where(enter, big * (1.0 + v[..., 1:] / COLLISION_V), 0.0), -1)


def _h_range(jlo1, jhi1, k: int, c: SpeedConfig, xp=np):
    """Least and most ``h = j_1 + ... + j_{k-1}`` at knot ``k`` (1-based) over the speed
    sequences from a first knot speed in ``[jlo1, jhi1]`` (steps ``accel_offsets``, speeds
    in ``[0, n_v)``; each sum of the pointwise extreme sequences)."""
    offs = c.accel_offsets
    lo = hi = 0
    for l in range(1, k):
        lo = lo + xp.maximum(0, jlo1 + offs[0] * (l - 1))
        hi = hi + xp.minimum(c.n_v - 1, jhi1 + offs[-1] * (l - 1))
    return lo, hi


@functools.cache
def dp_band(config: SpeedConfig) -> tuple:
    """The DP's static band: ``(H, D, cap)``. At knot ``k`` the states are ``(h, j)``, ``h`` in
    ``[hlo_k, hlo_k + H[k-1])`` (``dp_offsets``), every speed ``j < n_v``; ``D``: the most
    first-knot speeds above the least; ``cap[k-1]``: the largest offset (the band never
    reaches past the largest reachable ``h``)."""
    c = config
    D = int(math.floor((c.a_max - c.a_min + 2e-4) * c.dt / c.dv + 1e-9))
    jlo = np.arange(c.n_v)
    H, cap, lo_prev = [], [], None
    for k in range(1, c.n_t + 1):
        lo, hi = _h_range(jlo, np.minimum(c.n_v - 1, jlo + D), k, c)
        Hk = int(np.max(hi - lo)) + 1
        H.append(Hk)
        cap.append(int(_h_range(0, c.n_v - 1, k, c)[1]) - Hk + 1)
        off = np.minimum(lo, cap[-1])
        # the step's table block (stations up to 2 (cap + H) + n_v) lies inside the table
        assert _u0(c) + 2 * (cap[-1] + Hk) + c.n_v <= _n_table(c), (k, cap[-1], Hk)
        if lo_prev is not None:  # the offsets grow by at most n_v - 1 a knot (the windows below)
            assert np.all(off >= lo_prev) and np.all(off - lo_prev < c.n_v), (k, off, lo_prev)
        lo_prev = off
    return tuple(H), D, tuple(cap)


def dp_offsets(first, config: SpeedConfig):
    """``(n_t,)`` int32 offsets ``hlo_k`` of the band from the reachable first-knot speeds
    (``first < unreach``)."""
    c = config
    H, D, cap = dp_band(c)
    jlo1 = jnp.argmax(first < unreach(c)).astype(jnp.int32)
    return jnp.stack(
        [jnp.minimum(_h_range(jlo1, jlo1 + D, k, c, jnp)[0], cap[k - 1]) for k in range(1, c.n_t + 1)]
    ).astype(jnp.int32)


@functools.cache
def _step_tables(config: SpeedConfig, k: int):
    """Static tables of the DP step into knot ``k`` (per target speed ``j'``, rows):
    ``(V, M (n_sub + 1) + M)`` int32 flat starts of the sub-step windows in the step's table
    block (``m``-major, then ``q``) and of the predecessor windows in the padded value block,
    and ``(V, M (n_sub + 1))`` the collision cost ``big (1 + v / COLLISION_V)`` of each sub-step."""
    c = config
    H, _, _ = dp_band(c)
    Hk, V, ns, offs = H[k - 1], c.n_v, c.n_sub, c.accel_offsets
    M = len(offs)
    R, SLOW, VQ = _substep_tables(c)
    half = Hk + V - 1  # table block columns of one parity
    top = max(0, max(offs))
    starts = np.zeros((V, M * (ns + 1) + M), np.int32)
    K = np.zeros((V, M * (ns + 1)))
    for mi, om in enumerate(offs):
        for jp in range(V):
            j = jp - om  # speed at the segment's start (a padding row of big_u when out of range)
            starts[jp, M * (ns + 1) + mi] = (j + top) * half + min(max(V - 1 - j, 0), V - 1)
            jc = min(max(j, 0), V - 1)
            for q in range(ns + 1):
                y = int(R[jc, mi, q]) - jc + V - 1  # block column of the sub-step at h' = hlo
                starts[jp, mi * (ns + 1) + q] = ((y % 2 * 2 + int(SLOW[jc, mi, q])) * (ns + 1) + q) * half + y // 2
                K[jp, mi * (ns + 1) + q] = c.big * (1.0 + float(VQ[jc, mi, q]) / COLLISION_V)
    return starts, K


def _forward(d: DPCosts, config: SpeedConfig, temperature=None, probes=None):
    """Forward pass. Returns (final values ``(V, H_n)`` incl. terminal, argmins per step
    ``[(V, H_k)]`` int8 for k >= 2, band offsets ``(n_t,)``).

    **States.** ``h = j_1 + ... + j_{k-1}`` (the knot speeds before, in ``dv``): station
    ``i = 2 h + j`` (every reachable station has the parity of its speed), and a transition
    ``(h, j) -> (h + j, j')``. Values are rows per speed ``j``, each over the band's ``h``.

    **Reads.** For a target row ``j'`` and acceleration ``m`` the predecessors and every
    sub-step's table cells are contiguous runs (``i = 2 h' + const`` splits the table by
    parity) at offsets that depend on ``(j', m, q)`` only: per step the table block and
    the previous values are cut out once per plan (the band's dynamic offsets), then a
    ``scan`` over ``j'`` reads them with ``dynamic_slice`` at offsets shared by the whole
    batch (vectorised loops, no gathers), with every ``m`` and sub-step unrolled.
    """
    c = config
    H, _, _ = dp_band(c)
    offs = c.accel_offsets
    M, V, ns = len(offs), c.n_v, c.n_sub
    U0 = _u0(c)
    big_u = unreach(c)
    dtype = d.table.dtype
    hlo = dp_offsets(d.first, c)
    z = jnp.zeros((), hlo.dtype)  # every start index int32 (also under x64)
    top, bot = max(0, max(offs)), max(0, -min(offs))

    def rows(src, k):  # (V, X) -> (V, H_k): src[j, U0 + 2 (hlo_k + a) + j]
        Hk = H[k - 1]
        blk = jax.lax.dynamic_slice(src, (z, U0 + 2 * hlo[k - 1]), (V, 2 * Hk + V))
        idx = np.arange(V)[:, None] * (2 * Hk + V + 1) + 2 * np.arange(Hk)[None, :]
        return blk.reshape(-1)[idx]

    def knot_cost(k):  # (V, H_k)
        nc = rows(d.node.T, k) + jnp.where(d.goal_k[k - 1], d.goal_v, 0.0)[:, None]
        return nc if probes is None else nc + probes[k - 1]

    val = jnp.minimum(d.first[:, None] + knot_cost(1), big_u)  # knot 1: h = 0
    accel = d.accel.astype(dtype)
    args = []
    for k in range(2, c.n_t + 1):
        Hk = H[k - 1]
        half = Hk + V - 1
        # previous values at h = hlo_k + a - j - (V - 1) + x, rows j = -top .. V - 1 + bot
        vp = jnp.pad(val, ((top, bot), (V - 1, Hk + V)), constant_values=big_u)
        pblk = jax.lax.dynamic_slice(vp, (z, hlo[k - 1] - hlo[k - 2]), (V + top + bot, half)).reshape(-1)
        # table block: check times (k-1) n_sub .. k n_sub, stations from 2 hlo_k - (V - 1), by parity
        tb = jax.lax.dynamic_slice(d.table, (z, z + (k - 1) * ns, U0 + 2 * hlo[k - 1] - (V - 1)), (2, ns + 1, 2 * half))
        tb = jnp.stack([tb[..., 0::2], tb[..., 1::2]]).reshape(-1)  # (parity, layer, q, half)
        inside = tb >= 0.5 * c.big
        rate = jnp.where(inside, tb - c.big, tb)
        starts, K = _step_tables(c, k)

        def body(_, xs, Hk=Hk, pblk=pblk, inside=inside, rate=rate):
            st, kq, nc = xs  # this target row's window starts, collision costs and knot costs
            tots = []
            for mi in range(M):
                obst, prev = None, None
                for q in range(ns + 1):
                    s = st[mi * (ns + 1) + q]
                    ins = jax.lax.dynamic_slice(inside, (s,), (Hk,))
                    if q > 0:  # segment_cost: the sub-step's rate, big on entering a boundary
                        enter = jnp.where(ins & ~prev, kq[mi * (ns + 1) + q], 0.0)
                        term = jax.lax.dynamic_slice(rate, (s,), (Hk,)) + enter
                        obst = term if obst is None else obst + term
                    prev = ins
                pred = jax.lax.dynamic_slice(pblk, (st[M * (ns + 1) + mi],), (Hk,))
                tots.append(pred + obst + accel[mi])
            if temperature is None:  # min over m, the first on ties (argmin)
                best, arg = tots[0], jnp.zeros((Hk,), jnp.int8)
                for mi in range(1, M):
                    better = tots[mi] < best
                    best, arg = jnp.where(better, tots[mi], best), jnp.where(better, jnp.int8(mi), arg)
            else:
                best = -temperature * jax.nn.logsumexp(-jnp.stack(tots) / temperature, 0)
                arg = jnp.zeros((Hk,), jnp.int8)
            return None, (jnp.minimum(best + nc, big_u), arg)

        # a scan over the target rows (the rows come out stacked; no carry to update in place)
        _, (val, arg) = jax.lax.scan(body, None, (jnp.asarray(starts), jnp.asarray(K, dtype), knot_cost(k)))
        args.append(arg)
    return val + rows(d.terminal.T, c.n_t), args, hlo


def _backtrack(final, args, hlo, config: SpeedConfig):
    """Station and speed indices ``(n_t,)`` at t_1..t_n and the total cost."""
    c = config
    Hn = dp_band(c)[0][-1]
    offs = jnp.asarray(c.accel_offsets)
    flat = jnp.argmin(final)
    cost = final.reshape(-1)[flat]
    j = (flat // Hn).astype(jnp.int32)
    h = hlo[-1] + (flat % Hn).astype(jnp.int32)
    hh, jj = [h], [j]
    for k in range(c.n_t, 1, -1):
        m = args[k - 2][j, h - hlo[k - 1]].astype(jnp.int32)
        jp = j - offs[m]
        h, j = h - jp, jp
        hh.append(h)
        jj.append(j)
    hs, js = jnp.stack(hh[::-1]), jnp.stack(jj[::-1])
    return 2 * hs + js, js, cost


def dp_from_costs(d: DPCosts, config: SpeedConfig):
    """Exact DP on given cost tensors. Returns (station idx ``(n_t,)`` at t_1..t_n, speed
    idx ``(n_t,)``, total cost)."""
    final, args, hlo = _forward(d, config)
    return _backtrack(final, args, hlo, config)


def soft_value(d: DPCosts, config: SpeedConfig, temperature, probes=None):
    """Soft-min DP value (a smooth lower bound of the DP optimum; equal as temperature -> 0).
    ``probes``: optional ``[(n_v, H_k)]`` added to the knot costs (``dp_band``)."""
    final, _, _ = _forward(d, config, temperature, probes)
    return -temperature * jax.nn.logsumexp(-final / temperature)


def profile_cost(d: DPCosts, config: SpeedConfig, j_seq):
    """Cost of one knot-speed sequence ``j_seq (n_t,)`` (host numpy loops, independent of the
    DP's band and windows: the brute-force reference). ``inf`` when not a valid profile."""
    c = config
    table, node, terminal = (np.asarray(a, np.float64) for a in (d.table, d.node, d.terminal))
    first, accel, gv, gk = (np.asarray(a, np.float64) for a in (d.first, d.accel, d.goal_v, d.goal_k))
    offs = list(c.accel_offsets)
    U0, X, ns = _u0(c), table.shape[-1], c.n_sub
    j_seq = [int(j) for j in j_seq]
    if not 0 <= j_seq[0] < c.n_v or first[j_seq[0]] >= unreach(c):
        return np.inf
    i, cost = j_seq[0], first[j_seq[0]] + node[U0 + j_seq[0], j_seq[0]] + (gv[j_seq[0]] if gk[0] else 0.0)
    for k in range(1, c.n_t):
        j, j2 = j_seq[k - 1], j_seq[k]
        if j2 - j not in offs or not 0 <= j2 < c.n_v:
            return np.inf
        m = j2 - j
        inside_prev = None
        for q in range(0, ns + 1):
            u = min(max(U0 + i + int(np.round(2 * j * q / ns + m * (q / ns) ** 2)), 0), X - 1)
            v = (j + m * q / ns) * c.dv
            g = table[int(v < c.keep_clear_v), k * ns + q, u]
            inside = g >= 0.5 * c.big
            if q > 0:
                cost += g - c.big if inside else g
                if inside and not inside_prev:
                    cost += c.big * (1.0 + v / COLLISION_V)
            inside_prev = inside
        cost += accel[offs.index(m)]
        i = i + j + j2
        cost += node[min(U0 + i, X - 1), j2] + (gv[j2] if gk[k] else 0.0)
    return cost + terminal[min(U0 + i, X - 1), j_seq[-1]]


# ----------------------------------------------------------------------------- plans


def make_scene(
    path: ReferenceLine,
    obstacles: Obstacles,
    config: SpeedConfig,
    vehicle=None,
    s0=0.0,
    keep_clear=None,
    v0=0.0,
    road=None,
) -> tuple[PathProfile, SpeedScene]:
    """Path profile on the DP station grid and the scene boundaries."""
    vehicle = VehicleParams() if vehicle is None else vehicle
    profile = path_profile(path, s0, config.n_s, config.ds)
    return profile, build_scene(profile, obstacles, vehicle, config, keep_clear, v0, road)


def _plan_one(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, config, weights):
    _, scene = make_scene(path, obstacles, config, vehicle, s0, keep_clear, v0, road)
    d = stage_costs(scene, config, weights, v0, a0)
    ii, jj, cost = dp_from_costs(d, config)
    return _plan_from_indices(ii, jj, cost, d, v0, config, scene)


def _plan_from_indices(ii, jj, cost, d, v0, config, scene):
    dtype = d.table.dtype
    v0 = jnp.clip(jnp.asarray(v0, dtype), 0.0, config.v_max)
    s = jnp.concatenate([jnp.zeros((1,), dtype), d.c0 + ii.astype(dtype) * config.ds])
    v = jnp.concatenate([v0[None], jj.astype(dtype) * config.dv])
    t = jnp.arange(config.n_t + 1, dtype=dtype) * config.dt
    return SpeedPlan(t, s, v, jnp.diff(v) / config.dt, cost, cost < 0.5 * config.big, scene)


def _expected_one(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, config, weights, temperature):
    _, scene = make_scene(path, obstacles, config, vehicle, s0, keep_clear, v0, road)
    d = stage_costs(scene, config, weights, v0, a0)
    dtype = d.table.dtype
    H = dp_band(config)[0]
    probes = [jnp.zeros((config.n_v, Hk), dtype) for Hk in H]
    value, p = jax.value_and_grad(lambda pr: soft_value(d, config, temperature, pr))(probes)
    hlo = dp_offsets(d.first, config)
    j = jnp.arange(config.n_v, dtype=dtype)[:, None]
    es, ev = [], []
    for k, (pk, Hk) in enumerate(zip(p, H)):
        i = 2.0 * (hlo[k] + jnp.arange(Hk)).astype(dtype)[None, :] + j  # station index 2 h + j
        es.append(d.c0 + config.ds * jnp.sum(pk * i))
        ev.append(config.dv * jnp.sum(pk * j))
    v0c = jnp.clip(jnp.asarray(v0, dtype), 0.0, config.v_max)
    t = jnp.arange(config.n_t + 1, dtype=dtype) * config.dt
    s = jnp.concatenate([jnp.zeros((1,), dtype), jnp.stack(es)])
    v = jnp.concatenate([v0c[None], jnp.stack(ev)])
    return SpeedPlan(t, s, v, jnp.diff(v) / config.dt, value, value < 0.5 * config.big, scene)


BATCH_CHUNK = 100  # plans per vectorised chunk of a large leading batch


def _batched(fn, batch_ndim, args):
    """``fn`` mapped over ``batch_ndim`` leading dims of ``args``: ``vmap``, except that a
    leading batch of more than ``BATCH_CHUNK`` plans runs as a loop over vmapped chunks of
    that many (``lax.map``): a plan's tables stay in the CPU's caches between the passes
    over them (``experiments/bench_speed.py``'s scenes, batch 1000, one process, load average
    3: 1,095 and 1,081 plans/s in one vmap, 1,438 and 1,244 in chunks of 100)."""
    if batch_ndim == 0:
        return fn(*args)
    f = fn
    for _ in range(batch_ndim - 1):
        f = jax.vmap(f)
    n = jax.tree_util.tree_leaves(args)[0].shape[0]
    if n > BATCH_CHUNK:
        return jax.lax.map(lambda a: f(*a), tuple(args), batch_size=BATCH_CHUNK)
    return jax.vmap(f)(*args)


def _check_inputs(path, obstacles, config, v0, weights):
    config.validate()
    if is_concrete(path, obstacles, v0):
        path.validate()
        obstacles.validate()
        if np.any(np.asarray(v0) < 0):
            raise ValueError("plan_speed: v0 must be >= 0")
    if weights is not None and is_concrete(weights):
        weights.validate()


def _prepare(path, obstacles, v0, a0, s0, road, weights):
    dtype = path.xy.dtype
    nb = path.xy.ndim - 2
    shape = path.xy.shape[:nb]
    v0, a0, s0 = (jnp.broadcast_to(jnp.asarray(x, dtype), shape) for x in (v0, a0, s0))
    weights = jax.tree_util.tree_map(lambda w: jnp.broadcast_to(jnp.asarray(w, dtype), shape), weights)
    if road is None:
        road = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, shape + x.shape), SpeedRoad.free(dtype))
    return nb, v0, a0, s0, road, weights


def _plan_impl(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, config):
    nb, v0, a0, s0, road, weights = _prepare(path, obstacles, v0, a0, s0, road, weights)
    fn = lambda p, o, v, a, s, kc, r, w: _plan_one(p, o, v, a, s, kc, r, vehicle, config, w)
    return _batched(fn, nb, (path, obstacles, v0, a0, s0, keep_clear, road, weights))


_plan_jit = jax.jit(_plan_impl, static_argnames=("config",))


def plan_speed(
    path: ReferenceLine,
    obstacles: Obstacles,
    config: SpeedConfig = SpeedConfig(),
    weights: CostWeights | None = None,
    *,
    v0=0.0,
    a0=0.0,
    s0=0.0,
    keep_clear=None,
    vehicle: VehicleParams | None = None,
    road: SpeedRoad | None = None,
) -> SpeedPlan:
    """Exact DP speed plan along ``path``.

    Args:
        path: ``ReferenceLine`` with leading batch dims ``(..., P, 2)`` on its fields.
        obstacles: boxes ``(..., K, T, 5)``, valid ``(..., K, T)``, times ``(..., T)`` from now.
        config: grid and limits (static); weights: ``CostWeights``, each leaf a scalar
            (shared by the batch) or ``(...)`` (one per scene).
        v0, a0, s0: ``(...)`` current speed, acceleration and station on the path.
        keep_clear: optional ``(vertices (..., R, P, 2), valid (..., R, P), active (..., R))``.
        road: optional ``SpeedRoad`` with leading dims ``(...)`` (speed limit, stop, goal).

    Returns:
        ``SpeedPlan`` with leading dims ``(...)``.
    """
    _check_inputs(path, obstacles, config, v0, weights)
    weights = CostWeights.default(path.xy.dtype) if weights is None else weights
    vehicle = VehicleParams() if vehicle is None else vehicle
    return _plan_jit(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, config)


def _expected_impl(path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, temperature, config):
    nb, v0, a0, s0, road, weights = _prepare(path, obstacles, v0, a0, s0, road, weights)
    fn = lambda p, o, v, a, s, kc, r, w: _expected_one(p, o, v, a, s, kc, r, vehicle, config, w, temperature)
    return _batched(fn, nb, (path, obstacles, v0, a0, s0, keep_clear, road, weights))


_expected_jit = jax.jit(_expected_impl, static_argnames=("config",))


def expected_speed_profile(
    path: ReferenceLine,
    obstacles: Obstacles,
    config: SpeedConfig = SpeedConfig(),
    weights: CostWeights | None = None,
    temperature=1.0,
    *,
    v0=0.0,
    a0=0.0,
    s0=0.0,
    keep_clear=None,
    vehicle: VehicleParams | None = None,
    road: SpeedRoad | None = None,
) -> SpeedPlan:
    """Smooth (soft-min) DP: the expected knot station and speed under the Gibbs
    distribution of speed profiles ``p ~ exp(-cost / temperature)``.

    Differentiable in ``weights`` (for tuning against recorded profiles); as the
    temperature goes to 0 it becomes the exact DP's profile. Same arguments as
    ``plan_speed``; ``cost`` holds the soft value.
    """
    _check_inputs(path, obstacles, config, v0, weights)
    weights = CostWeights.default(path.xy.dtype) if weights is None else weights
    vehicle = VehicleParams() if vehicle is None else vehicle
    return _expected_jit(
        path, obstacles, v0, a0, s0, keep_clear, road, vehicle, weights, jnp.asarray(temperature, path.xy.dtype), config
    )
