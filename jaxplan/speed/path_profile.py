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
    """Obstacle predictions at times ``t`` ``(T2,)``: ``Obstacles.at_times`` (linear
    interpolation between stamps, heading along the shorter turn; dynamic obstacles are
    invalid outside their stamps, static ones held)."""
    return obstacles.at_times(t)
