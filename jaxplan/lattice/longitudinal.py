"""Longitudinal modes of the lattice: the speed profiles ``s(t)`` every lateral path is combined with.

Each profile runs in ``ds/dt`` along the reference line from the car's ``(sdot0, sddot0)``.
The set, in this order (``LatticeConfig`` switches the parts on):

- **cruise** (the base profiles): constant-jerk (or constant-acceleration) ramps to end
  speeds ``v0 + scale * delta`` for each escalation level ``scale`` (levels ``0 .. E-1``),
  and, with ``target_speed``, one more on level 0 to the set speed capped by the curvature
  ahead (``target_speed``);
- **follow** a leader: a quintic ``s(t)`` that ends, at each end time ``T``, a time gap
  ``follow_gap + follow_time_gap * v_lead(T)`` behind the leader's predicted rear at the
  leader's speed and zero acceleration (Werling et al. 2010, "following");
- **stop** at a point (before a stopped obstacle, a virtual crossroad target or the end of
  the route): a quintic to ``(s_stop, 0, 0)`` at each end time, and at the natural time
  ``2.5 d / v0``; held at rest after;
- **goal**: a quintic that reaches the goal region's middle inside its time window (at three
  times spread over the window) at a speed inside its range;
- **emergency** (level ``E``): constant-jerk braking with the stronger limits
  (``emergency_a_min``, ``emergency_jerk``) to a stop and to half the speed, and the escape:
  speeding up at up to ``emergency_a_max`` by ``ESCAPE_DV`` (a vehicle closing in from behind
  faster than the comfortable levels can leave room for);
- **fallback** (level ``E + 1``): braking at the constant deceleration ``fallback_decel``
  (reached with the emergency jerk) to a stop; it is always generated.

Modes whose target does not exist (no leader, no stop point, no goal) are marked
unavailable (``available = False``), never silently turned into another mode.
A quintic ``s(t)`` from ``(0, v0, a0)`` to ``(s1, v1, 0)`` at ``T`` is the closed form of
``jaxplan.geometry.quintic`` (its ``quintic_coeffs`` with the end slope ``v1``); after ``T`` the
speed ``v1`` is held. Quintics may reverse or exceed the limits: the
feasibility filter rejects those, the profile is not clamped.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from jaxplan.geometry.quintic import quintic_coeffs, quintic_eval
from jaxplan.lattice.config import KMH
from jaxplan.lattice.profiles import accel_profile, jerk_profile
from jaxplan.plan_context import curvature_speed
from jaxplan.types import pytree_dataclass

# Mode ids of the longitudinal profiles.
CRUISE, FOLLOW, STOP, GOAL, EMERGENCY, FALLBACK = 0, 1, 2, 3, 4, 5
# the profiles run along the reference line; the car's own acceleration adds the line's
# geometry (an offset on a curve, a heading change): the emergency profiles brake at this
# share of ``emergency_a_min`` so that the car's stays within it (the feasibility filter checks)
EMERGENCY_SHARE = 0.96
MODE_NAMES = ("cruise", "follow", "stop", "goal", "emergency", "fallback")
MIN_END_TIME = 1.0  # s: the earliest end time of a quintic profile
ESCAPE_DV = 10.0  # m/s: the emergency escape's speed gain
TARGET_LAT_SHARE = 0.9  # of lat_acc_max: the curvature cap of the target speed leaves this much for curves


@pytree_dataclass(data_fields=("s", "v", "a", "v_end", "level", "kind", "available", "end_time"))
class Longitudinal:
    """``G`` speed profiles: ``s, v, a (..., G, T)`` (``s`` from the car), ``v_end (..., G)`` the
    targeted end speed, ``level``, ``kind`` (``CRUISE`` ... ``FALLBACK``) ``(G,)`` int,
    ``available (..., G)`` bool, ``end_time (..., G)`` (s; inf for the jerk profiles)."""

    s: Any
    v: Any
    a: Any
    v_end: Any
    level: Any
    kind: Any
    available: Any
    end_time: Any


def quintic_profile(v0, a0, s1, v1, T, t):
    """Quintic ``s(t)`` from ``(0, v0, a0)`` to ``(s1, v1, 0)`` at ``T``, ``v1`` held after.

    Args:
        v0, a0, s1, v1, T: ``(...)``, ``T > 0``.
        t: ``(T_samples,)`` times from now.

    Returns:
        (s, v, a) each ``(..., T_samples)``.
    """
    v0, a0, s1, v1, T = jnp.broadcast_arrays(*(jnp.asarray(x, t.dtype) for x in (v0, a0, s1, v1, T)))
    coeffs = quintic_coeffs(jnp.zeros_like(v0), v0, a0, s1, T, dl1=v1).astype(t.dtype)
    s, v, a = quintic_eval(coeffs, T, jnp.broadcast_to(t, v0.shape + t.shape))
    e = lambda x: x[..., None]
    past = t >= e(T)  # (quintic_eval ends a path with zero slope there; the profile keeps v1)
    s = jnp.where(past, e(s1) + e(v1) * (t - e(T)), s)
    return s, jnp.where(past, e(v1), v), jnp.where(past, 0.0, a)


def target_speed(kappa_ahead, v_set, lat_acc_max):
    """``()`` the target speed's end speed: ``v_set`` capped by the curvature limit
    (``plan_context.curvature_speed`` at ``TARGET_LAT_SHARE lat_acc_max``) of the reference line
    at the samples ``kappa_ahead (n,)`` ahead of the car."""
    cap = jnp.min(curvature_speed(kappa_ahead, TARGET_LAT_SHARE * lat_acc_max))
    return jnp.minimum(jnp.asarray(v_set, cap.dtype), cap)


def n_profiles(config) -> int:
    """``G``, the number of longitudinal profiles of ``config``."""
    n = len(config.escalation) * len(config.speed_deltas_kmh) + int(config.target_speed)
    nt = len(config.end_times)
    modes = set(config.modes)
    n += nt * ("follow" in modes) + (nt + 1) * ("stop" in modes) + 3 * ("goal" in modes)
    return n + 3 * bool(config.emergency) + bool(config.fallback)


def longitudinal_set(
    sdot0,
    a0,
    t,
    config,
    leader_s=None,
    leader_v=None,
    leader_ok=False,
    stop_s=jnp.inf,
    goal_s=jnp.inf,
    goal_t=(0.0, jnp.inf),
    goal_v=(-jnp.inf, jnp.inf),
    v_grid=None,
    v_target=None,
) -> Longitudinal:
    """Every longitudinal profile of ``config`` (see the module docstring), for one car.

    Args:
        sdot0, a0: ``()`` the car's speed and acceleration along the reference line.
        t: ``(T,)`` sample times.
        leader_s, leader_v: ``(T,)`` the leader's rear (m from the car's reference point, along
            the line, minus the car's front length) and speed at each sample; ``leader_ok ()``.
        stop_s: ``()`` distance (m) to the stop point of the car's reference point (inf: none).
        goal_s: ``()`` distance to the goal point of the reference point (inf: no goal region).
        goal_t: ``(2,)`` the goal's time window from now; goal_v: ``(2,)`` its speed range.
        v_grid: ``()`` the speed the cruise end speeds are offsets of (default ``sdot0``; the
            lattice passes the car's speed).
        v_target: ``()`` the end speed of the ``target_speed`` profile (needed with it).

    Returns:
        ``Longitudinal`` with ``G = n_profiles(config)``.
    """
    f = t.dtype
    E = len(config.escalation)
    v0 = jnp.asarray(sdot0, f)
    a0 = jnp.asarray(a0, f)
    scale = jnp.asarray(config.escalation, f)[:, None]
    deltas = jnp.asarray(config.speed_deltas_kmh, f)[None, :] * KMH
    vg = v0 if v_grid is None else jnp.asarray(v_grid, f)
    v_end = jnp.clip(vg + scale * deltas, 0.0, config.v_max).reshape(-1)  # (E V,)
    levels = jnp.repeat(jnp.arange(E), len(config.speed_deltas_kmh))
    if config.target_speed:
        if v_target is None:
            raise ValueError("longitudinal_set: config.target_speed needs v_target")
        v_t = jnp.clip(jnp.asarray(v_target, f), 0.0, config.v_max)
        v_end = jnp.concatenate([v_end, v_t[None]])  # (E V + 1,)
        levels = jnp.concatenate([levels, jnp.zeros((1,), levels.dtype)])
    if config.profile == "jerk":
        s, v, a = jerk_profile(v0, a0, v_end, t, config.jerk, config.a_min, config.a_max)
    else:
        s, v, a = accel_profile(v0, v_end, t, config.a_min, config.a_max)
    parts = [
        (
            s,
            v,
            a,
            v_end,
            levels,
            jnp.full(v_end.shape, CRUISE),
            jnp.ones(v_end.shape, bool),
            jnp.full(v_end.shape, jnp.inf, f),
        )
    ]
    modes = set(config.modes)
    ends = jnp.asarray(config.end_times, f)
    nt = len(config.end_times)
    horizon_t = t[-1]

    def quintic_part(s1, v1, T, kind, ok):
        s1, v1, T, ok = jnp.broadcast_arrays(s1, v1, T, ok)
        # at least MIN_END_TIME: a quintic ending within a step or two would jump between samples that
        # all look feasible (the feasibility filter sees only the samples); unavailable: a finite stand-in
        T = jnp.where(ok & jnp.isfinite(T), jnp.maximum(T, MIN_END_TIME), 1.0)
        v1 = jnp.where(ok, v1, 0.0)
        ss, vv, aa = quintic_profile(v0, a0, jnp.where(ok, s1, 0.0), jnp.where(ok, v1, 0.0), T, t)
        n = T.shape[0]
        return ss, vv, aa, v1, jnp.zeros((n,), int), jnp.full((n,), kind), ok, T

    if "follow" in modes and nt:
        if leader_s is None:
            leader_s, leader_v = jnp.zeros_like(t), jnp.zeros_like(t)
        # the leader's rear and speed at each end time (constant speed beyond the prediction)
        ls = jnp.interp(ends, t, leader_s) + leader_v[-1] * jnp.maximum(ends - horizon_t, 0.0)
        lv = jnp.maximum(jnp.interp(ends, t, leader_v), 0.0)
        target = ls - config.follow_gap - config.follow_time_gap * lv
        parts.append(quintic_part(target, lv, ends, FOLLOW, jnp.asarray(leader_ok) & (target > 0)))
    if "stop" in modes:
        d = jnp.asarray(stop_s, f)
        ok = jnp.isfinite(d) & (d >= 0)
        dd = jnp.where(ok, d, 0.0)
        natural = 2.5 * dd / jnp.maximum(v0, 0.5)
        T = jnp.concatenate([ends, natural[None]])
        T = jnp.clip(T, 0.5, 30.0)
        parts.append(
            quintic_part(jnp.broadcast_to(dd, T.shape), jnp.zeros_like(T), T, STOP, jnp.broadcast_to(ok, T.shape))
        )
    if "goal" in modes:
        gs = jnp.asarray(goal_s, f)
        lo, hi = jnp.asarray(goal_t[0], f), jnp.asarray(goal_t[1], f)
        vlo, vhi = jnp.asarray(goal_v[0], f), jnp.asarray(goal_v[1], f)
        ok = jnp.isfinite(gs) & (gs > 0) & (hi > 0)
        # without an end of the window, arrive at about the current speed
        natural = jnp.where(ok, gs, 0.0) / jnp.maximum(v0, 1.0)
        lo_c = jnp.maximum(lo, 0.0)
        hi_c = jnp.where(jnp.isfinite(hi), hi, jnp.maximum(lo_c, natural) * 2.0 + 1.0)
        T = lo_c + jnp.asarray([0.2, 0.5, 0.8], f) * (hi_c - lo_c)
        T = jnp.where(jnp.isfinite(hi), T, jnp.maximum(T, natural))
        v_fin = jnp.clip(
            jnp.clip(2.0 * jnp.where(ok, gs, 0.0) / jnp.maximum(T, 0.5) - v0, 0.0, config.v_max),
            jnp.maximum(vlo, 0.0),
            jnp.minimum(vhi, config.v_max),
        )
        parts.append(quintic_part(jnp.broadcast_to(gs, T.shape), v_fin, T, GOAL, jnp.broadcast_to(ok, T.shape)))
    if config.emergency:
        ve = jnp.stack([jnp.zeros_like(v0), 0.5 * v0])
        s, v, a = jerk_profile(
            v0, a0, ve, t, config.emergency_jerk, EMERGENCY_SHARE * config.emergency_a_min, config.a_max
        )
        up = jnp.minimum(v0 + ESCAPE_DV, config.v_max)[None]
        su, vu, au = jerk_profile(
            v0, a0, up, t, config.emergency_jerk, config.a_min, EMERGENCY_SHARE * config.emergency_a_max
        )
        parts.append(
            (
                jnp.concatenate([s, su]),
                jnp.concatenate([v, vu]),
                jnp.concatenate([a, au]),
                jnp.concatenate([ve, up]),
                jnp.full((3,), E),
                jnp.full((3,), EMERGENCY),
                jnp.ones((3,), bool),
                jnp.full((3,), jnp.inf, f),
            )
        )
    if config.fallback:
        s, v, a = jerk_profile(
            v0, a0, jnp.zeros((1,), f), t, config.emergency_jerk, -config.fallback_decel, config.a_max
        )
        parts.append(
            (
                s,
                v,
                a,
                jnp.zeros((1,), f),
                jnp.full((1,), E + 1),
                jnp.full((1,), FALLBACK),
                jnp.ones((1,), bool),
                jnp.full((1,), jnp.inf, f),
            )
        )
    cat = [jnp.concatenate([p[i] for p in parts]) for i in range(8)]
    return Longitudinal(cat[0], cat[1], cat[2], cat[3], cat[4], cat[5], cat[6], cat[7])
