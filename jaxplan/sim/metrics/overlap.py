"""``overlap``: collisions of the car's box with any obstacle at the same step, and fault.

The car's box (centre, heading, the vehicle's length and width) against every obstacle
box valid at that step (static obstacles at every step), by the geometry core's SAT
separation (negative = overlap, touching is not a collision).

Fault is decided for every obstacle at its own first contact with the car (a drive may
touch several): the car is **not** at fault only when a moving obstacle hits it squarely
from behind, i.e. at that step

- the obstacle moves (faster than ``MOVING`` m/s, from its boxes one step apart: its next
  step's, or, where the contact is its last step or the drive's, its step before),
- its centre lies behind the car's rear bumper (more than half the car's length behind the
  car's centre, along the car's heading) and within the car's width across it,
- it drives the car's way (headings within ``SAME_WAY`` rad).

Every other first contact is the car's fault: it drove into something, turned or slid into a
neighbour (a car whose centre is beside or only partly behind it), or cut in so close that it
was hit from the side. The same rule judges every planner, the peers' drives included
(``jaxplan.sim.verdict``).
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


MOVING = 0.5  # m/s: slower obstacles count as standing
SAME_WAY = 0.5  # rad (about 29 degrees)


def hit_from_behind(car, obstacle, obstacle_next, dt):
    """Whether ``obstacle`` hits ``car`` squarely from behind (see the module docstring).

    Args:
        car, obstacle: boxes ``(..., 5)`` at the contact step; obstacle_next: the obstacle's box one
            step later (its motion; the same box when it is gone or static).
        dt: the step (s).

    Returns:
        ``(...)`` bool.
    """
    c, s = jnp.cos(car[..., 4]), jnp.sin(car[..., 4])
    rx, ry = obstacle[..., 0] - car[..., 0], obstacle[..., 1] - car[..., 1]
    along = rx * c + ry * s
    across = -rx * s + ry * c
    speed = jnp.hypot(obstacle_next[..., 0] - obstacle[..., 0], obstacle_next[..., 1] - obstacle[..., 1]) / dt
    dh = jnp.abs(jnp.arctan2(jnp.sin(obstacle[..., 4] - car[..., 4]), jnp.cos(obstacle[..., 4] - car[..., 4])))
    return (speed > MOVING) & (along < -0.5 * car[..., 2]) & (jnp.abs(across) <= 0.5 * car[..., 3]) & (dh < SAME_WAY)


@register_metric("overlap")
def overlap(log, scene, vehicle):
    sep, obs = separations(log, scene, vehicle)
    N, K = sep.shape
    hit = sep < 0  # (N, K)
    touched = jnp.any(hit, axis=0)  # (K,)
    first = jnp.argmax(hit, axis=0)  # (K,) each obstacle's first contact step
    car = car_boxes(log, vehicle)[first]  # (K, 5)
    idx = jnp.arange(K)
    box = obs.boxes[idx, first]  # (K, 5)
    nxt_step, prv_step = jnp.minimum(first + 1, N - 1), jnp.maximum(first - 1, 0)
    nxt_ok = obs.valid[idx, nxt_step] & (first + 1 < N) & ~obs.static
    # where the contact is the obstacle's last recorded step or the drive's last, its motion is the
    # step before's carried on (a vehicle that rear-ends the car as its recording ends still moves)
    prv_ok = obs.valid[idx, prv_step] & (first > 0) & ~obs.static
    carried = box.at[:, :2].set(2.0 * box[:, :2] - obs.boxes[idx, prv_step, :2])
    nxt = jnp.where(nxt_ok[:, None], obs.boxes[idx, nxt_step], jnp.where(prv_ok[:, None], carried, box))
    excused = hit_from_behind(car, box, nxt, jnp.asarray(scene.dt, box.dtype)) & ~obs.static
    fault = touched & ~excused  # (K,)
    collided = jnp.any(touched)
    any_hit = jnp.any(hit, axis=-1)
    k = jnp.argmax(any_hit)  # the drive's first contact
    first_obstacle = jnp.argmax(hit[k])
    fault_step = jnp.min(jnp.where(fault, first, N))
    return {
        "collided": collided,
        "at_fault": jnp.any(fault),
        "first_step": jnp.where(collided, k, -1),
        "obstacle": jnp.where(collided, first_obstacle, -1),
        "obstacles_hit": jnp.sum(touched),
        "obstacles_at_fault": jnp.sum(fault),
        "fault_step": jnp.where(jnp.any(fault), fault_step, -1),
        "fault_obstacle": jnp.where(jnp.any(fault), jnp.argmin(jnp.where(fault, first, N)), -1),
        "min_separation": jnp.min(sep),
    }
