"""Virtual stop target before a crossroad.

When the distance to the crossroad ``D_toC`` is below ``d_threshold``, a stopped
virtual obstacle (a ``stop_length x stop_width`` box across the lanes) is placed
with its near edge at ``D_toC + d_margin`` ahead of the car along the reference
line; candidates that would drive into it collide, so the plan stops before it.
Under jit the box is always present and its ``valid`` mask says whether it counts.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.types import Obstacles


def stop_box(ref: ReferenceLine, s_car, d_crossroad, config):
    """The virtual box ``(5,)`` and whether it is active ``()``.

    Args:
        s_car: ``()`` the car's arc length on ``ref``.
        d_crossroad: ``()`` distance to the crossroad (inf = none).
    """
    dtype = ref.xy.dtype
    d = jnp.asarray(d_crossroad, dtype)
    active = d < config.d_threshold
    s_c = s_car + jnp.where(active, d, 0.0) + config.d_margin + 0.5 * config.stop_length
    lane_mid = 0.5 * (min(config.lanes) + max(config.lanes)) * config.lane_width
    xy, theta, _, _ = ref_state(ref, s_c)
    nrm = jnp.stack([-jnp.sin(theta), jnp.cos(theta)])
    c = xy + lane_mid * nrm
    width = config.stop_width + (max(config.lanes) - min(config.lanes)) * config.lane_width
    box = jnp.stack([c[0], c[1], jnp.asarray(config.stop_length, dtype), jnp.asarray(width, dtype), theta])
    return box, active


def with_stop_target(obstacles: Obstacles, ref: ReferenceLine, s_car, d_crossroad, config) -> Obstacles:
    """``obstacles (K, T)`` plus the virtual stop box as obstacle ``K`` (valid only when active).

    ``s_car`` is the car's arc length on ``ref`` (``to_frenet``)."""
    box, active = stop_box(ref, s_car, d_crossroad, config)
    T = obstacles.boxes.shape[-2]
    b = jnp.concatenate([obstacles.boxes, jnp.broadcast_to(box, (1, T, 5)).astype(obstacles.boxes.dtype)], axis=-3)
    v = jnp.concatenate([obstacles.valid, jnp.broadcast_to(active, (1, T))], axis=-2)
    st = jnp.concatenate([obstacles.static, jnp.ones((1,), bool)], axis=-1)
    return Obstacles(b, v, obstacles.t, st)
