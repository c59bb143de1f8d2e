"""Collision points, the time-stamped collision-point queue and the brake-stop point.

Collision points are found on the plan from the tracking point forward to the
end of the current sub-trajectory, stopping at the first pose whose car box
overlaps a perceived obstacle (SAT separation of the geometry core,
``box_separation < 0``, the same test as ``box_has_overlap``). Each goes
into a fixed-size queue with its time stamp; entries older than ``window``
seconds are dropped. The nearest remaining entry (smallest arc length) sets the
brake-stop point ``safety`` metres before it; the brake-stop point moves only
when that nearest entry changes; with an empty queue there is none.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_separation


class CollisionQueue(NamedTuple):
    """Fixed-size queue. t, s: ``(Q,)`` time stamp and plan arc length; xy: ``(Q, 2)``; valid: ``(Q,)``."""

    t: jnp.ndarray
    s: jnp.ndarray
    xy: jnp.ndarray
    valid: jnp.ndarray


class BrakeStop(NamedTuple):
    """Brake-stop point: arc length ``s``, the nearest collision arc length it was set from
    (``key``), and whether there is one (``active``); all ``()``."""

    s: jnp.ndarray
    key: jnp.ndarray
    active: jnp.ndarray


def queue_init(size: int = 32, dtype=jnp.float32) -> CollisionQueue:
    return CollisionQueue(jnp.zeros((size,), dtype), jnp.zeros((size,), dtype), jnp.zeros((size, 2), dtype),
                          jnp.zeros((size,), bool))


def queue_push(q: CollisionQueue, t, s, xy, push=True) -> CollisionQueue:
    """Insert ``(t, s, xy)`` when ``push``: into a free slot, else over the oldest entry."""
    slot = jnp.argmin(jnp.where(q.valid, q.t, -jnp.inf))
    hit = (jnp.arange(q.t.shape[0]) == slot) & push
    return CollisionQueue(jnp.where(hit, t, q.t), jnp.where(hit, s, q.s), jnp.where(hit[:, None], xy, q.xy),
                          q.valid | hit)


def queue_expire(q: CollisionQueue, now, window=2.0) -> CollisionQueue:
    """Drop entries older than ``window`` seconds (``now - t > window``)."""
    return q._replace(valid=q.valid & (now - q.t <= window))


def queue_clear(q: CollisionQueue) -> CollisionQueue:
    return q._replace(valid=jnp.zeros_like(q.valid))


def queue_size(q: CollisionQueue):
    return jnp.sum(q.valid).astype(jnp.int32)


def queue_nearest(q: CollisionQueue):
    """(arc length ``()``, xy ``(2,)``, found ``()``) of the nearest entry along the plan."""
    k = jnp.argmin(jnp.where(q.valid, q.s, jnp.inf))
    return q.s[k], q.xy[k], jnp.any(q.valid)


def brake_init(dtype=jnp.float32) -> BrakeStop:
    return BrakeStop(jnp.zeros((), dtype), jnp.full((), jnp.inf, dtype), jnp.zeros((), bool))


def update_brake_stop(b: BrakeStop, q: CollisionQueue, safety=0.5) -> BrakeStop:
    """Brake-stop point from the queue: ``safety`` before the nearest entry, moved only when it changes."""
    s, _, found = queue_nearest(q)
    changed = found & ((~b.active) | (s != b.key))
    return BrakeStop(jnp.where(changed, s - safety, b.s), jnp.where(found, s, jnp.inf).astype(b.key.dtype), found)


def first_collision_point(car_boxes, start, end, obs_boxes, obs_valid):
    """First plan point in ``[start, end]`` whose car box overlaps a valid obstacle.

    Args:
        car_boxes: ``(N, 5)`` car box at every plan point.
        start, end: ``()`` int index range (inclusive).
        obs_boxes: ``(K, 5)``; obs_valid: ``(K,)``.

    Returns:
        (index ``()``, found ``()``); index is ``end`` when nothing collides.
    """
    idx, found, _ = _first_collision(car_boxes, start, end, obs_boxes, obs_valid)
    return idx, found


def _first_collision(car_boxes, start, end, obs_boxes, obs_valid):
    i = jnp.arange(car_boxes.shape[0])
    sep = jnp.min(jnp.where(obs_valid[None, :], box_separation(car_boxes[:, None, :], obs_boxes[None, :, :]),
                            jnp.inf), axis=-1, initial=jnp.inf)  # (N,)
    hit = (sep < 0) & (i >= start) & (i <= end)
    found = jnp.any(hit)
    return jnp.where(found, jnp.argmax(hit), end).astype(jnp.int32), found, sep


def collision_arc_length(car_boxes, s_path, start, end, obs_boxes, obs_valid):
    """First collision point and where along the plan contact begins.

    The contact arc length interpolates the signed separation linearly between
    the last free point and the first colliding one (``s_path[idx]`` when the
    first colliding point is ``start``), so the brake-stop point does not depend
    on the point spacing.

    Returns:
        (index ``()``, contact arc length ``()``, found ``()``).
    """
    idx, found, sep = _first_collision(car_boxes, start, end, obs_boxes, obs_valid)
    prev = jnp.maximum(idx - 1, 0)
    a, b = sep[prev], sep[idx]
    u = jnp.clip(a / jnp.where(a - b > 0, a - b, 1.0), 0.0, 1.0)
    s = jnp.where(idx > start, s_path[prev] + u * (s_path[idx] - s_path[prev]), s_path[idx])
    return idx, s, found


first_collision_point_jit = jax.jit(first_collision_point)
