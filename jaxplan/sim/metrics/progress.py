"""``progress``: metres driven along the route (arc length of the box centre's projection
at the drive's end minus at its start), and the share of the way to the goal region's
near end covered."""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import to_frenet
from jaxplan.sim.metrics.registry import register_metric


@register_metric("progress")
def progress(log, scene, vehicle):
    last = jnp.max(jnp.where(log.valid, jnp.arange(log.x.shape[0]), 0))
    xy = jnp.stack([log.x[jnp.array([0, 0])], log.y[jnp.array([0, 0])]], -1)
    xy = xy.at[1].set(jnp.stack([log.x[last], log.y[last]]))
    s, l = to_frenet(scene.route, xy)
    need = scene.goal.s_range[0] - s[0]
    share = jnp.where(jnp.isfinite(need) & (need > 1.0), (s[1] - s[0]) / jnp.maximum(need, 1.0), 1.0)
    return {"route_m": s[1] - s[0], "goal_share": jnp.clip(share, 0.0, 1.0), "final_l": l[1]}
