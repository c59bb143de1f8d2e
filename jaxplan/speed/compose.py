"""Second trajectory: the path profile and a speed profile composed into a Trajectory."""
from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import ReferenceLine, ref_state, wrap_angle
from jaxplan.types import Trajectory


def _slopes(t, s, v0):
    """Knot speeds of a monotone cubic through ``(t, s)`` ``(K+1,)``: harmonic mean of the
    neighbouring secants inside (0 where either is 0), ``v0`` at the start (limited to 3
    secants), the last secant at the end."""
    sec = jnp.diff(s) / jnp.diff(t)  # (K,)
    a, b = sec[:-1], sec[1:]
    inner = jnp.where((a > 0) & (b > 0), 2 * a * b / jnp.maximum(a + b, 1e-9), 0.0)
    first = jnp.clip(v0, 0.0, 3.0 * sec[0])
    return jnp.concatenate([first[None], inner, sec[-1:]])


def speed_profile_at(t_knots, s_knots, v0, t):
    """Monotone cubic Hermite speed profile through the DP knots, sampled at ``t``.

    Args:
        t_knots, s_knots: ``(K+1,)`` times and stations of the plan; v0: scalar.
        t: ``(T,)`` output times within ``[t_knots[0], t_knots[-1]]``.

    Returns:
        (s, v, a) each ``(T,)``; s passes through every knot.
    """
    d = _slopes(t_knots, s_knots, jnp.asarray(v0, s_knots.dtype))
    k = jnp.clip(jnp.searchsorted(t_knots, t, side="right") - 1, 0, t_knots.shape[0] - 2)
    h = t_knots[k + 1] - t_knots[k]
    u = (t - t_knots[k]) / h
    p0, p1, m0, m1 = s_knots[k], s_knots[k + 1], d[k] * h, d[k + 1] * h
    h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
    s = h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1
    ds = (6 * u**2 - 6 * u) * p0 + (3 * u**2 - 4 * u + 1) * m0 + (-6 * u**2 + 6 * u) * p1 + (3 * u**2 - 2 * u) * m1
    dds = (12 * u - 6) * p0 + (6 * u - 4) * m0 + (-12 * u + 6) * p1 + (6 * u - 2) * m1
    return s, ds / h, dds / h**2


def compose(ref: ReferenceLine, s0, s, v, a, t) -> Trajectory:
    """Trajectory of a speed profile along the path.

    Args:
        ref: the path; s0: station of the car at t[0].
        s, v, a, t: ``(T,)`` station travelled (from 0), speed, acceleration, time.

    Returns:
        ``Trajectory`` ``(T,)`` with x, y, heading and curvature from the path.
    """
    xy, theta, kappa, _ = ref_state(ref, s0 + s)
    return Trajectory(xy[..., 0], xy[..., 1], wrap_angle(theta), kappa, v, a, t, s, jnp.ones_like(s))


def compose_plan(ref: ReferenceLine, s0, plan, v0, dt_out: float, n: int) -> Trajectory:
    """Trajectory of ``n`` samples every ``dt_out`` from a ``SpeedPlan`` of one scene.

    The station profile is a monotone cubic through the plan's knots, so ``v`` is its
    exact derivative and ``a`` its second derivative.
    """
    t = jnp.arange(n, dtype=plan.s.dtype) * dt_out
    s, v, a = speed_profile_at(plan.t, plan.s, v0, t)
    return compose(ref, s0, s, v, a, t)
