"""Second trajectory: the path and a speed profile composed into a Trajectory."""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.speed.problem import profile_at
from jaxplan.types import Trajectory


def compose(ref: ReferenceLine, s0, s, v, a, t) -> Trajectory:
    """Trajectory of a speed profile along the path.

    Args:
        ref: the path; s0: station of the car at t[0].
        s, v, a, t: ``(T,)`` station travelled (from 0), speed, acceleration, time.

    Returns:
        ``Trajectory`` ``(T,)`` with x, y, heading (unwrapped, continuous along the path)
        and curvature from the path.
    """
    xy, theta, kappa, _ = ref_state(ref, s0 + s)
    return Trajectory(xy[..., 0], xy[..., 1], theta, kappa, v, a, t, s, jnp.ones_like(s))


def compose_profile(ref: ReferenceLine, s0, profile) -> Trajectory:
    """Trajectory of a ``SpeedProfile`` (``smooth.py``) or any object with ``t, s, v, a``."""
    return compose(ref, s0, profile.s, profile.v, profile.a, profile.t)


def compose_plan(ref: ReferenceLine, s0, plan, dt_out: float, n: int) -> Trajectory:
    """Trajectory of ``n`` samples every ``dt_out`` of a DP ``SpeedPlan``'s exact
    piecewise-constant-acceleration profile (no smoothing)."""
    t = jnp.arange(n, dtype=plan.s.dtype) * dt_out
    s, v, a = profile_at(plan, t)
    return compose(ref, s0, s, v, a, t)
