"""One longitudinal model for plans, arrival-time estimates and the simulated car.

The car accelerates at ``accel`` up to the gear's top speed and brakes at ``decel``
so that it stands still at the next stop point (the end of a single-direction
sub-trajectory, or a brake-stop point). The same law gives

* a plan's speed profile and time stamps (``profile_speed``, ``profile_times``),
* the supervisor's estimate of when the car reaches each plan point from where it is
  now (the same two functions, started at the car's arc length and speed), used for
  the time-aware collision check, and
* the simulated car's speed, one step at a time (``speed_step``), and the
  supervisor's prediction of where the car will be after the planning latency
  (``advance``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class MotionLimits:
    """Longitudinal limits (static, hashable): top speed forward / reverse in m/s,
    acceleration and comfortable braking in m/s^2, emergency braking in m/s^2."""

    v_fwd: float = 3.0
    v_rev: float = 1.5
    accel: float = 1.0
    decel: float = 2.0
    emergency: float = 6.0

    def __post_init__(self):
        for f in ("v_fwd", "v_rev", "accel", "decel", "emergency"):
            if not float(getattr(self, f)) > 0:
                raise ValueError(f"MotionLimits.{f} must be positive, got {getattr(self, f)}")
        if self.emergency < self.decel:
            raise ValueError("MotionLimits.emergency must be >= decel")

    def vmax(self, gear):
        """Top speed ``(...)`` for gear ``(...)`` (+1 forward, -1 reverse)."""
        return jnp.where(gear > 0, self.v_fwd, self.v_rev)


def profile_speed(s_abs, leg_start, leg_end, v_in, vmax, accel, decel):
    """Speed at every plan point ``(N,)``: ``min(vmax, sqrt(v_in^2 + 2 a (s - leg_start)),
    sqrt(2 d (leg_end - s)))``, 0 outside ``[leg_start, leg_end]``.

    Args:
        s_abs: ``(N,)`` unsigned arc length.
        leg_start, leg_end: ``(N,)`` arc length where each point's leg starts / ends (its stop point).
        v_in: ``(N,)`` speed at the leg start; vmax: ``(N,)`` top speed.
    """
    up = jnp.sqrt(v_in**2 + 2 * accel * jnp.maximum(s_abs - leg_start, 0.0))
    down = jnp.sqrt(2 * decel * jnp.maximum(leg_end - s_abs, 0.0))
    v = jnp.minimum(vmax, jnp.minimum(up, down))
    return jnp.where((s_abs >= leg_start - 1e-6) & (s_abs <= leg_end + 1e-6), v, 0.0)


def profile_times(s_abs, speed, active, v_floor: float = 0.05):
    """Time to reach every point ``(N,)`` from the first active one: trapezoid rule
    ``ds / mean(v)`` (exact for constant acceleration from rest), the mean speed floored
    at ``v_floor``. Inactive points get the time of the last active point before them
    (0 before the first).

    Args:
        s_abs: ``(N,)``; speed: ``(N,)`` >= 0; active: ``(N,)`` bool, a contiguous run.
    """
    ds = jnp.diff(s_abs)
    vm = jnp.maximum(0.5 * (speed[1:] + speed[:-1]), v_floor)
    dt = jnp.where(active[1:] & active[:-1], ds / vm, 0.0)
    return jnp.concatenate([jnp.zeros((1,), s_abs.dtype), jnp.cumsum(dt)])


def arrival_times(s_abs, s0, v0, s_stop, vmax, limits: MotionLimits):
    """Estimated time ``(N,)`` until the car, at arc length ``s0`` with speed ``v0 >= 0``,
    reaches each plan point up to its stop point ``s_stop`` (inf beyond it or behind the car).
    """
    n = s_abs.shape[-1]
    leg_start = jnp.full((n,), s0, s_abs.dtype)
    leg_end = jnp.full((n,), s_stop, s_abs.dtype)
    ahead = (s_abs >= s0 - 1e-6) & (s_abs <= s_stop + 1e-6)
    # Point 0 of the estimate is the car itself: shift arc lengths so the car sits at s0.
    s = jnp.maximum(s_abs, s0)
    v = profile_speed(
        s,
        leg_start,
        leg_end,
        jnp.full((n,), v0, s_abs.dtype),
        jnp.full((n,), vmax, s_abs.dtype),
        limits.accel,
        limits.decel,
    )
    # Time from s0 to the first point ahead: (s_1 - s0) at the mean of v0 and v_1.
    j0 = jnp.argmax(ahead)
    t0 = (s[j0] - s0) / jnp.maximum(0.5 * (v0 + v[j0]), 0.05)
    t = profile_times(s, v, ahead) + t0
    return jnp.where(ahead, t, jnp.inf)


def speed_step(v, dist_stop, vmax, limits: MotionLimits, dt):
    """The car's next speed ``()`` >= 0 from speed ``v >= 0`` with ``dist_stop`` metres to the
    next stop point: ``min(v + a dt, vmax, sqrt(2 d dist), dist / dt)``, never braking
    harder than the emergency limit."""
    d = jnp.maximum(dist_stop, 0.0)
    nxt = jnp.minimum(jnp.minimum(v + limits.accel * dt, vmax), jnp.minimum(jnp.sqrt(2 * limits.decel * d), d / dt))
    return jnp.maximum(jnp.maximum(nxt, v - limits.emergency * dt), 0.0)


def advance(s, v, s_stop, s_end, vmax, limits: MotionLimits, dt, steps: int):
    """Where the car will be after ``steps`` steps of ``speed_step``: arc length and speed
    (both ``()``). It brakes for ``s_stop`` and cannot pass ``s_end`` (its sub-trajectory's end);
    the simulated car moves the same way."""

    def body(_, c):
        s, v = c
        v = speed_step(v, s_stop - s, vmax, limits, dt)
        return move(s, v, s_end, dt)

    return jax.lax.fori_loop(0, steps, body, (s, v))


def move(s, v, s_end, dt):
    """One step along the plan: ``(s + v dt, v)``, stopping exactly at ``s_end``."""
    over = s + v * dt > s_end + 1e-6
    return jnp.minimum(s + v * dt, jnp.maximum(s_end, s)), jnp.where(over, jnp.maximum(s_end - s, 0.0) / dt, v)
