"""The speed DP's cost tables of one scene (``DPCosts``, built by ``stage_costs``).

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
  seconds of the goal's time window (per second of that part; the stations moved in from the
  region's ends, ``goal_inside``; beyond the region nothing once the window is open);
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
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.plan_context import goal_inside
from jaxplan.speed.problem import CostWeights, SpeedConfig, SpeedScene, band_offsets
from jaxplan.speed.st_boundary import BIG


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


def table_origin(config: SpeedConfig) -> int:
    """``U0``: the cost tables' index of the station ``c0`` (room below it for the DP's band)."""
    return config.n_v + 1


def table_size(config: SpeedConfig) -> int:
    """``X``: stations of the cost tables (``c0 + (u - U0) ds``, ``u < X``)."""
    return config.n_s + table_origin(config) + 2


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
    """``(F, X)`` goal cost rate: the box centre's distance (Huber) to the part of the goal
    region planners aim for (``goal_inside``) at the check times ``f_goal (F,)`` of the
    window's last part, per second of that part (a short window asks as much as a long one).
    Beyond the region costs nothing where the window is already open: the car passed through
    the region inside the window (the goal is met on arrival; what lies past it is no matter)."""
    cx = xs + 0.5 * (scene.front + scene.rear)
    aim = goal_inside(scene.goal_s)
    passed = jnp.where(scene.goal_t[0] <= 0.0, 0.0, jnp.maximum(cx - aim[1], 0.0))
    gd = jnp.maximum(aim[0] - cx, 0.0) + passed
    gd = jnp.where(jnp.isfinite(gd), gd, 0.0)
    hub = jnp.where(gd < GOAL_HUBER, gd * gd, GOAL_HUBER * (2.0 * gd - GOAL_HUBER))
    tail = jnp.clip(scene.goal_t[1] - goal_tail_start(scene.goal_t), 0.1, GOAL_TAIL)
    tail = jnp.where(jnp.isfinite(tail), tail, GOAL_TAIL)
    return jnp.where(f_goal[:, None], (w.w_goal / tail) * hub[None, :], 0.0)


COLLISION_V = 10.0  # m/s: a collision's cost grows by big per this much impact speed
# per second in contact with a vehicle from behind, times big (far below a collision of the car's own)
REAR_CONTACT = 0.01
GOAL_TAIL = 1.0  # s: the goal is asked for in the last second of its time window
GOAL_HUBER = 2.0  # m: the goal's distance cost is quadratic up to this, then linear


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


def goal_tail_start(goal_t):
    """``()`` the start of the part of the goal's window ``goal_t (2,)`` the goal is asked for
    in: its last ``GOAL_TAIL`` seconds (the whole window when shorter)."""
    return jnp.maximum(goal_t[0], goal_t[1] - GOAL_TAIL)


def goal_times(goal_t, t):
    """``(T,)`` bool: times ``t`` in the last ``GOAL_TAIL`` seconds of the goal's window
    ``goal_t (2,)`` (the car must be in the goal region before the window closes)."""
    return (t >= goal_tail_start(goal_t) - 1e-6) & (t <= goal_t[1] + 1e-6)


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
    V, X, U0, ns = c.n_v, table_size(c), table_origin(c), c.n_sub
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
    # first segment: from (0, v0) to speed j with the exact acceleration (v_j - v0) / dt, within
    # the limits widened by half a step (the grid speed nearest to what the limits reach)
    a1 = (vj - v0) / c.dt
    tq = jnp.arange(0, ns + 1, dtype=dtype) * h
    xq = v0 * tq[None] + 0.5 * a1[:, None] * tq[None] ** 2  # (V, ns + 1)
    uq = jnp.clip(jnp.round((xq - x0) / c.ds).astype(jnp.int32), 0, X - 1)
    vq = v0 + a1[:, None] * tq[None]
    slow = (vq < c.keep_clear_v).astype(jnp.int32)
    obst1 = segment_cost(table[slow, jnp.arange(0, ns + 1)[None], uq], vq, c.big)
    first = accel_cost(a1, w) * c.dt + w.w_jerk * ((a1 - a0) / c.dt) ** 2 * c.dt + obst1
    a_lo, a_hi = c.first_accel_range
    ok1 = (a1 >= a_lo - 1e-4) & (a1 <= a_hi + 1e-4)
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
