"""Trajectories that follow the route at a fixed lateral offset (the baselines' path)."""
from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import frenet_to_cartesian_state, ref_state
from jaxplan.types import Trajectory


def follow_route(route, s, l, v, a, t) -> Trajectory:
    """A trajectory at constant offset ``l ()`` from the route along stations ``s (H,)``.

    Args:
        route: ``ReferenceLine``.
        s, v, a, t: ``(H,)`` arc length on the route, speed, acceleration, time from now.
        l: ``()`` lateral offset (m).

    Returns:
        ``Trajectory`` ``(H,)`` of the car's reference point (heading and curvature of the
        offset curve; ``s`` is the distance driven from the first point).
    """
    z = jnp.zeros_like(s)
    xy, theta, kappa = frenet_to_cartesian_state(route, s, z + l, z, z)
    _, th_r, kr, _ = ref_state(route, s)
    theta = th_r  # unwrapped (frenet_to_cartesian_state wraps it; dl = 0 gives the route heading)
    seg = jnp.linalg.norm(jnp.diff(xy, axis=0), axis=-1)
    dist = jnp.concatenate([z[:1], jnp.cumsum(seg)])
    return Trajectory(xy[:, 0], xy[:, 1], theta, kappa, v, a, t, dist, z + 1.0)


def braking_profile(v0, a_brake, t):
    """Distance, speed and acceleration ``(H,)`` of braking at ``a_brake < 0`` from ``v0`` to a stop."""
    t_stop = v0 / jnp.maximum(-a_brake, 1e-6)
    tc = jnp.minimum(t, t_stop)
    s = v0 * tc + 0.5 * a_brake * tc ** 2
    v = jnp.maximum(v0 + a_brake * t, 0.0)
    a = jnp.where(t < t_stop, a_brake, 0.0)
    return s, v, a
