"""Path profile: the path sampled on the planner's station grid, and the first trajectory.

The path is a ``ReferenceLine`` (geometry core); the car's reference point
moves along it. Station ``s`` is measured along the line; the plan starts at
station ``s0``.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry.frenet import ReferenceLine, ref_state, reference_line, wrap_angle
from jaxplan.types import Obstacles, Trajectory


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PathProfile:
    """The path on a station grid ``s = s0 + i * ds`` (i < N).

    Attributes:
        ref: the reference line the car follows.
        s: ``(..., N)`` stations (absolute, along ``ref``).
        xy: ``(..., N, 2)`` positions; theta, kappa: ``(..., N)``.
    """

    ref: Any
    s: Any
    xy: Any
    theta: Any
    kappa: Any


def path_profile(ref: ReferenceLine, s0, n: int, ds: float) -> PathProfile:
    """Sample ``ref`` at ``n`` stations ``s0 + i * ds``. Jittable; ``s0`` scalar."""
    s = jnp.asarray(s0, ref.xy.dtype) + ds * jnp.arange(n, dtype=ref.xy.dtype)
    xy, theta, kappa, _ = ref_state(ref, s)
    return PathProfile(ref, s, xy, theta, kappa)


def path_from_polyline(xy) -> ReferenceLine:
    """Jittable reference line from ``(N, 2)`` distinct points (use
    ``ReferenceLine.from_polyline`` on the host to check and clean input)."""
    return reference_line(jnp.asarray(xy))


def path_from_trajectory(traj: Trajectory) -> ReferenceLine:
    """Reference line through a trajectory's points (``(T,)`` fields, distinct points)."""
    return ReferenceLine.from_polyline(jnp.stack([traj.x, traj.y], -1))


def first_trajectory(profile: PathProfile, v, t) -> Trajectory:
    """The first trajectory: the path driven at constant speed ``v`` over times ``t`` ``(T,)``."""
    t = jnp.asarray(t, profile.xy.dtype)
    s = profile.s[0] + v * (t - t[0])
    xy, theta, kappa, _ = ref_state(profile.ref, s)
    z = jnp.zeros_like(t)
    return Trajectory(xy[..., 0], xy[..., 1], wrap_angle(theta), kappa, z + v, z, t, s - s[0], z + 1.0)


def resample_obstacles(obstacles: Obstacles, t) -> Obstacles:
    """Obstacle predictions linearly interpolated at times ``t`` ``(T2,)``.

    Poses and sizes interpolate between the two neighbouring stamps (heading by
    the shortest turn); a time is valid where both neighbours are, and times
    outside the prediction are invalid, except for static obstacles (held).
    """
    t = jnp.asarray(t, obstacles.boxes.dtype)
    tt = obstacles.t
    n = tt.shape[-1]
    if n == 1:
        ok = jnp.abs(t - tt[..., :1]) < 1e-6
        b = jnp.broadcast_to(obstacles.boxes, obstacles.boxes.shape[:-2] + (t.shape[-1], 5))
        return Obstacles(b, (obstacles.valid & ok) | obstacles.static[..., None], t, obstacles.static)
    i = jnp.clip(jnp.searchsorted(tt, t, side="right") - 1, 0, n - 2)
    f = jnp.clip((t - tt[i]) / (tt[i + 1] - tt[i]), 0.0, 1.0)
    b0, b1 = obstacles.boxes[..., i, :], obstacles.boxes[..., i + 1, :]
    dh = wrap_angle(b1[..., 4] - b0[..., 4])
    b = b0 + f[:, None] * (b1 - b0)
    b = b.at[..., 4].set(b0[..., 4] + f * dh)
    inside = (t >= tt[0] - 1e-6) & (t <= tt[-1] + 1e-6)
    v0, v1 = obstacles.valid[..., i], obstacles.valid[..., i + 1]
    ok = jnp.where(f <= 1e-6, v0, jnp.where(f >= 1 - 1e-6, v1, v0 & v1)) & inside
    st = obstacles.static
    ok = ok | st[..., None]  # static obstacles are there at every time
    b = jnp.where(st[..., None, None], obstacles.boxes[..., :1, :], b)
    return Obstacles(b, ok, t, st)
