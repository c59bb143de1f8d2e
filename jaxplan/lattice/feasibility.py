"""Feasibility filter: kinematic limits checked on every candidate before the collision check.

As Apollo's constraint checker and the reactive planner's kinematic check: a candidate is
infeasible when, at some sample,

- ``curvature``: ``|kappa| > config.curvature_limit`` (the steering limit
  ``tan(max_steer) / wheelbase`` unless ``kappa_max`` is given);
- ``lat_acc``: ``|v^2 kappa|`` exceeds the lateral acceleration limit;
- ``lon_acc``: the acceleration, or the speed change over a step, leaves
  ``lon_acc_limits`` (emergency levels: down to ``emergency_a_min``, up to ``emergency_a_max``);
- ``jerk``: ``|da/dt|`` (finite differences of the samples) exceeds the jerk limit;
- ``reverse``: the speed drops below zero (a quintic profile that would reverse).

The comfortable levels use the comfortable limits; the emergency and fallback levels
(``level >= len(config.escalation)``) the emergency limits. The selection never takes an
infeasible candidate while a feasible one exists; ``LatticeResult.rejected`` counts the
reasons.
"""

from __future__ import annotations

import jax.numpy as jnp

REASONS = ("curvature", "lat_acc", "lon_acc", "jerk", "reverse")
TOL = 1e-3


def feasibility(traj, level, config):
    """Per-candidate feasibility.

    Args:
        traj: ``Trajectory`` with fields ``(..., N, T)``.
        level: ``(..., N)`` int selection level.
        config: ``LatticeConfig``.

    Returns:
        (feasible ``(..., N)`` bool, reasons ``(..., N, len(REASONS))`` bool).
    """
    f = traj.v.dtype
    emerg = level >= len(config.escalation)
    lo, hi = config.lon_acc_limits
    a_lo = jnp.where(emerg, min(config.emergency_a_min, lo), lo) - TOL
    a_hi = jnp.where(emerg, max(config.emergency_a_max, hi), hi) + TOL
    lat_max = jnp.where(emerg, config.emergency_lat_acc_max, config.lat_acc_max) + TOL
    j_max = jnp.where(emerg, config.emergency_jerk_max, config.lon_jerk_max) + TOL
    kap = jnp.max(jnp.abs(traj.kappa), axis=-1)
    lat = jnp.max(jnp.abs(traj.v**2 * traj.kappa), axis=-1)
    a_min, a_max = jnp.min(traj.a, axis=-1), jnp.max(traj.a, axis=-1)
    if traj.v.shape[-1] > 1:  # and the speed change over each step (what a drive's metric measures)
        fd = jnp.diff(traj.v, axis=-1) / jnp.asarray(config.dt, f)
        a_min, a_max = jnp.minimum(a_min, jnp.min(fd, axis=-1)), jnp.maximum(a_max, jnp.max(fd, axis=-1))
    jerk = (
        jnp.max(jnp.abs(jnp.diff(traj.a, axis=-1)), axis=-1) / jnp.asarray(config.dt, f)
        if traj.a.shape[-1] > 1
        else jnp.zeros_like(a_min)
    )
    reasons = jnp.stack(
        [
            kap > config.curvature_limit * (1 + TOL) + 1e-4,
            lat > lat_max,
            (a_min < a_lo) | (a_max > a_hi),
            jerk > j_max,
            jnp.min(traj.v, axis=-1) < -TOL,
        ],
        axis=-1,
    )
    if not config.feasibility:
        reasons = jnp.zeros_like(reasons)
    return ~jnp.any(reasons, axis=-1), reasons


def violation(traj, level, config):
    """``(..., N)`` how far beyond its lateral limits a candidate goes: the larger of its peak
    curvature over the curvature limit and its peak lateral acceleration over its level's limit
    (<= 1: within both)."""
    emerg = level >= len(config.escalation)
    lat_max = jnp.where(emerg, config.emergency_lat_acc_max, config.lat_acc_max)
    kap = jnp.max(jnp.abs(traj.kappa), axis=-1)
    lat = jnp.max(jnp.abs(traj.v**2 * traj.kappa), axis=-1)
    return jnp.maximum(kap / config.curvature_limit, lat / lat_max)


def usable(feasible, reasons, viol, available):
    """``(..., N)`` the candidates the selection may take.

    The feasible ones when any is available. Otherwise (typically a start state already
    beyond the curvature or lateral limits, which every lateral path inherits) the
    candidates within the longitudinal limits (acceleration, jerk, no reversing; the
    fallback level is built to be) whose curvature / lateral-acceleration excess ``viol``
    (``violation``) is within 10 % of the least one: the least infeasible plans, never one
    that teleports the car by an impossible speed profile. Only when none is within the
    longitudinal limits: all.
    """
    avail_f = available & feasible
    lon_ok = ~jnp.any(reasons[..., 2:], axis=-1)
    cand = available & lon_ok
    best = jnp.min(jnp.where(cand, viol, jnp.inf), axis=-1, keepdims=True)
    least = cand & (viol <= 1.1 * best + 1e-6)
    has_f = jnp.any(avail_f, axis=-1, keepdims=True)
    has_l = jnp.any(cand, axis=-1, keepdims=True)
    return jnp.where(has_f, feasible, jnp.where(has_l, least, True))
