"""``overlap``: collisions of the car's box with any obstacle at the same step, and fault.

The car's box (centre, heading, the vehicle's length and width) against every obstacle
box valid at that step (static obstacles at every step), by the geometry core's SAT
separation (negative = overlap, touching is not a collision). At fault: at the first
colliding step, some obstacle in contact is static, or its centre lies ahead of the car
along the car's heading (the car drove into it); otherwise another road user drove into
the car (recorded traffic does not react).
"""
from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.boxes import box_separation
from jaxplan.sim.metrics.registry import register_metric


def car_boxes(log, vehicle):
    """The car's boxes ``(N, 5)`` along the log."""
    f = log.x.dtype
    n = log.x.shape
    return jnp.stack([log.x, log.y, jnp.full(n, vehicle.length, f), jnp.full(n, vehicle.width, f), log.heading], -1)


def separations(log, scene, vehicle):
    """Signed separation ``(N, K)`` of the car from every obstacle at each logged step (``FAR`` where the
    obstacle is not there or the step is past the drive's end)."""
    N = log.x.shape[0]
    obs = scene.obstacles.window(0, N)
    sep = box_separation(car_boxes(log, vehicle)[:, None, :], jnp.swapaxes(obs.boxes, 0, 1))  # (N, K)
    there = jnp.swapaxes(obs.valid, 0, 1) & log.valid[:, None]
    return jnp.where(there, sep, 1e6), obs


@register_metric("overlap")
def overlap(log, scene, vehicle):
    sep, obs = separations(log, scene, vehicle)
    hit = sep < 0  # (N, K)
    any_hit = jnp.any(hit, axis=-1)
    collided = jnp.any(any_hit)
    k = jnp.argmax(any_hit)
    contact = hit[k]  # (K,)
    u = jnp.stack([jnp.cos(log.heading[k]), jnp.sin(log.heading[k])])
    rel = obs.boxes[:, k, :2] - jnp.stack([log.x[k], log.y[k]])
    ahead = rel @ u > 0
    fault = jnp.any(contact & (obs.static | ahead))
    first_obstacle = jnp.argmax(contact)
    return {"collided": collided, "at_fault": collided & fault, "first_step": jnp.where(collided, k, -1),
            "obstacle": jnp.where(collided, first_obstacle, -1), "min_separation": jnp.min(sep)}
