"""Planner callback interface: what a planner is asked and what it returns.

A planner callback is ``plan(request: PlanRequest) -> Plan``; the supervisor and
the simulator only see this interface, so any planner (the drivable approach
planner of :mod:`jaxplan.replan.path_planner`, the park-out planner through
:mod:`jaxplan.replan.parkout_adapter`, a user's own) can drive them. Inside
``lax.scan`` it must be jittable; the host-loop simulator accepts any Python callable.
A planner may say what it plans with (``vehicle``, ``limits``) and how close its plans may
pass the obstacles (``clearance``, m); the simulator checks these against the supervisor's.
``finish_plan`` turns a geometric path into a plan with the speed profile and
time stamps of the shared longitudinal model (:mod:`jaxplan.replan.longitudinal`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.replan.longitudinal import MotionLimits, profile_speed, profile_times
from jaxplan.replan.trajectory import arc_length
from jaxplan.types import Trajectory


class PlanRequest(NamedTuple):
    """What a planner is asked (one instance; all jnp arrays).

    start: ``(3,)`` pose [x, y, heading] the plan must start from (the car's pose, or a
    point ahead of it on the old plan when it is moving); speed: ``()`` signed speed there
    (> 0 forward, < 0 reverse); gear: ``()`` +1 / -1, the gear the car is in there (a plan
    may change it only when ``|speed|`` is below the supervisor's ``v_stopped``);
    phase: ``()`` +1 plan the whole approach, -1 the car is in its final reverse leg;
    goal: ``(3,)`` believed goal pose; obstacles: ``(K, 5)`` perceived boxes at the time
    of the request; obstacles_vel: ``(K, 2)`` their velocities (m/s); obstacles_valid: ``(K,)``;
    park: ``()`` bool, parking approach (forward, gear shift, reverse) or a short forward drive;
    prev_end: ``(3,)`` the end pose of the plan the car follows now (its start pose before the
    first plan): a planner may keep it as its end while it lies within its goal tolerance;
    prev_via: ``(3,)`` the end of the sub-trajectory the car drives now (its next intermediate
    destination, e.g. the pre-pose of a parking approach): a planner may keep it.
    """

    start: jnp.ndarray
    speed: jnp.ndarray
    gear: jnp.ndarray
    phase: jnp.ndarray
    goal: jnp.ndarray
    obstacles: jnp.ndarray
    obstacles_vel: jnp.ndarray
    obstacles_valid: jnp.ndarray
    park: jnp.ndarray
    prev_end: jnp.ndarray
    prev_via: jnp.ndarray


class Plan(NamedTuple):
    """A planned trajectory ``(N,)`` with its prefix mask ``valid (N,)``, unsigned arc
    length ``s_abs (N,)`` and ``ok ()``: False when the plan does not reach the goal
    collision-free (the car then stops at its end, or at a brake-stop point, and re-plans)."""

    traj: Trajectory
    valid: jnp.ndarray
    s_abs: jnp.ndarray
    ok: jnp.ndarray


def finish_plan(xy, theta, gear, valid, v0, limits: MotionLimits, ok, kappa=None) -> Plan:
    """Fill speed, acceleration, curvature, time and arc length of a geometric plan.

    Args:
        xy: ``(N, 2)``; theta: ``(N,)`` car heading; gear: ``(N,)`` the gear used to reach
        each point; valid: ``(N,)`` prefix mask; v0: ``()`` speed (>= 0) at the start;
        limits: the longitudinal model; ok: ``()``; kappa: ``(N,)`` curvature (default: the
            heading's rate ``d theta / ds`` between consecutive points).

    Speed on each single-direction leg: ``min(vmax, sqrt(v_in^2 + 2 a s), sqrt(2 d (s_leg - s)))``
    (``jaxplan.replan.longitudinal.profile_speed``), ``v_in = v0`` on the first leg and 0
    after a gear shift; time stamps by ``jaxplan.replan.longitudinal.profile_times``.
    """
    n = xy.shape[0]
    s_abs = arc_length(xy, valid)
    last = jnp.sum(valid) - 1
    shift = jnp.concatenate([gear[:-1] != gear[1:], jnp.zeros((1,), bool)]) & valid & (jnp.arange(n) < last)
    leg = jnp.concatenate([jnp.zeros((1,), jnp.int32), jnp.cumsum(shift[:-1]).astype(jnp.int32)])
    first = jnp.concatenate([jnp.ones((1,), bool), shift[:-1]])  # first point of each leg
    leg_start = jax.lax.cummax(jnp.where(first, s_abs, -jnp.inf))
    leg_end = jax.lax.cummin(jnp.where(shift | (jnp.arange(n) == last), s_abs, jnp.inf), reverse=True)
    leg_end = jnp.where(jnp.isinf(leg_end), s_abs[-1], leg_end)
    v_in = jnp.where(leg == 0, jnp.abs(v0), 0.0)
    leg_gear = jnp.concatenate([gear[1:2], gear[1:]])  # point 0 drives in the gear of its leg
    speed = profile_speed(s_abs, leg_start, leg_end, v_in, limits.vmax(leg_gear), limits.accel, limits.decel)
    speed = jnp.where(valid, speed, 0.0)
    t = profile_times(s_abs, speed, valid)
    ds = jnp.diff(s_abs)
    dt = jnp.diff(t)
    acc = jnp.concatenate([jnp.where(dt > 0, jnp.diff(speed) / jnp.where(dt > 0, dt, 1.0), 0.0), jnp.zeros(1)])
    if kappa is None:
        dth = jnp.arctan2(jnp.sin(jnp.diff(theta)), jnp.cos(jnp.diff(theta)))
        kappa = jnp.concatenate([jnp.where(ds > 1e-6, dth / jnp.where(ds > 1e-6, ds, 1.0), 0.0), jnp.zeros(1)])
    sgn = leg_gear.astype(xy.dtype)
    s_signed = jnp.concatenate([jnp.zeros(1), jnp.cumsum(ds * sgn[1:])])
    traj = Trajectory(
        x=xy[:, 0],
        y=xy[:, 1],
        theta=theta,
        kappa=jnp.where(valid, kappa, 0.0),
        v=sgn * speed,
        a=acc,
        t=t,
        s=s_signed,
        gear=gear,
    )
    return Plan(traj, valid, s_abs, jnp.asarray(ok))
