"""Trajectories along the route: the baselines' path (keep the current lateral offset,
after a short quintic that aligns the car's heading with the lane)."""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import frenet_to_cartesian_state, ref_state
from jaxplan.geometry.quintic import cartesian_to_frenet_state, quintic_coeffs, quintic_eval
from jaxplan.types import Trajectory

ALIGN_TIME = 2.0  # s of driving over which the heading is aligned with the lane
ALIGN_MIN = 8.0  # m, at least


def follow_route(route, ego, ds, v, a, t) -> Trajectory:
    """A trajectory that keeps the car's current lateral offset from the route.

    The lateral path is the quintic from the car's Frenet state ``(l0, l0', l0'')`` to
    ``(l0, 0, 0)`` over ``max(ALIGN_MIN, ALIGN_TIME v)`` metres, then constant, so the first
    point is the car's pose (heading and curvature included) and the path is smooth.

    Args:
        route: ``ReferenceLine``.
        ego: ``EgoState`` (the car's reference point).
        ds, v, a, t: ``(H,)`` distance along the route from the car, speed, acceleration,
            time from now.

    Returns:
        ``Trajectory`` ``(H,)`` of the car's reference point (``s`` = distance driven).
    """
    f = route.xy.dtype
    s0, l0, dl0, ddl0 = cartesian_to_frenet_state(route, jnp.stack([ego.x, ego.y]).astype(f), ego.heading, ego.kappa)
    S = jnp.maximum(ALIGN_MIN, ALIGN_TIME * ego.v)
    c = quintic_coeffs(l0, jnp.clip(dl0, -1.0, 1.0), jnp.clip(ddl0, -0.5, 0.5), l0, S)
    l, dl, ddl = quintic_eval(c, S, ds)
    s = s0 + ds
    xy, _, kappa = frenet_to_cartesian_state(route, s, l, dl, ddl)
    _, th_r, kr, _ = ref_state(route, s)
    theta = th_r + jnp.arctan2(dl, 1.0 - kr * l)  # unwrapped
    seg = jnp.linalg.norm(jnp.diff(xy, axis=0), axis=-1)
    dist = jnp.concatenate([jnp.zeros((1,), f), jnp.cumsum(seg)])
    z = jnp.zeros_like(ds)
    return Trajectory(xy[:, 0], xy[:, 1], theta, kappa, v, a, t, dist, z + 1.0)
