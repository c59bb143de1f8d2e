"""Braking at a constant deceleration to a stop: the one profile the brake baseline, the
simulator's fallback, the speed planner's classification and the evaluation suites share."""

from __future__ import annotations

import jax.numpy as jnp


def braking_profile(v0, a_brake, t):
    """Distance, speed and acceleration (each broadcast of ``v0 (...)`` and ``t (...)``) at times
    ``t`` of braking at ``a_brake < 0`` from speed ``v0``, held at rest once stopped."""
    t_stop = v0 / jnp.maximum(-a_brake, 1e-6)
    tc = jnp.minimum(t, t_stop)
    s = v0 * tc + 0.5 * a_brake * tc**2
    v = jnp.maximum(v0 + a_brake * t, 0.0)
    a = jnp.where(t < t_stop, a_brake, 0.0)
    return s, v, a
