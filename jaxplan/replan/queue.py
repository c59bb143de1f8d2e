"""Collision points, the time-stamped collision-point queue and the brake-stop point.

Collision points are found on the plan from the tracking point forward to the
end of the current sub-trajectory, stopping at the first pose whose car box
overlaps a perceived obstacle (SAT separation of the geometry core,
``box_separation < 0``; with moving obstacles the time-aware test of
:mod:`jaxplan.replan.prediction`). Each goes into a fixed-size queue with its
time stamp and the perception slot of the obstacle that caused it; entries older
than ``window`` seconds are dropped. The nearest remaining entry (smallest arc
length) sets the brake-stop point ``safety`` metres before it; the brake-stop
point moves only when that nearest entry changes; with an empty queue there is none.

The queue survives re-plans: on a new plan every entry is re-anchored
(``queue_reanchor``) at the arc length where its obstacle, as remembered
(``ObstacleMemory``), meets the new plan, or at ``inf`` (kept, but not
binding) when the new plan passes clear of it.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_separation
from jaxplan.replan.prediction import first_contact


class CollisionQueue(NamedTuple):
    """Fixed-size queue. t, s: ``(Q,)`` time stamp and plan arc length (``inf``: not on the
    current plan); xy: ``(Q, 2)`` plan point; slot: ``(Q,)`` perception slot of the obstacle;
    valid: ``(Q,)``."""

    t: jnp.ndarray
    s: jnp.ndarray
    xy: jnp.ndarray
    slot: jnp.ndarray
    valid: jnp.ndarray


class ObstacleMemory(NamedTuple):
    """Per perception slot, the last sighting that made a collision point: box ``(K, 5)``,
    velocity ``(K, 2)``, time ``(K,)``, valid ``(K,)``."""

    box: jnp.ndarray
    vel: jnp.ndarray
    t: jnp.ndarray
    valid: jnp.ndarray


def memory_init(k: int, dtype=jnp.float32) -> ObstacleMemory:
    return ObstacleMemory(
        jnp.zeros((k, 5), dtype), jnp.zeros((k, 2), dtype), jnp.zeros((k,), dtype), jnp.zeros((k,), bool)
    )


def memory_update(m: ObstacleMemory, slot, box, vel, t, push) -> ObstacleMemory:
    """Remember slot ``slot``'s obstacle ``box (5,)``, ``vel (2,)`` seen at ``t`` when ``push``."""
    hit = (jnp.arange(m.t.shape[0]) == slot) & push
    return ObstacleMemory(
        jnp.where(hit[:, None], box, m.box), jnp.where(hit[:, None], vel, m.vel), jnp.where(hit, t, m.t), m.valid | hit
    )


class BrakeStop(NamedTuple):
    """Brake-stop point: arc length ``s``, the nearest collision arc length it was set from
    (``key``), and whether there is one (``active``); all ``()``."""

    s: jnp.ndarray
    key: jnp.ndarray
    active: jnp.ndarray


def queue_init(size: int = 32, dtype=jnp.float32) -> CollisionQueue:
    return CollisionQueue(
        jnp.zeros((size,), dtype),
        jnp.zeros((size,), dtype),
        jnp.zeros((size, 2), dtype),
        jnp.zeros((size,), jnp.int32),
        jnp.zeros((size,), bool),
    )


def queue_push(q: CollisionQueue, t, s, xy, push=True, slot=0) -> CollisionQueue:
    """Insert ``(t, s, xy, slot)`` when ``push``: into a free place, else over the oldest entry."""
    at = jnp.argmin(jnp.where(q.valid, q.t, -jnp.inf))
    hit = (jnp.arange(q.t.shape[0]) == at) & push
    return CollisionQueue(
        jnp.where(hit, t, q.t),
        jnp.where(hit, s, q.s),
        jnp.where(hit[:, None], xy, q.xy),
        jnp.where(hit, slot, q.slot).astype(jnp.int32),
        q.valid | hit,
    )


def queue_reanchor(q: CollisionQueue, slot_s, slot_xy) -> CollisionQueue:
    """Move every entry onto a new plan: arc length ``slot_s[slot]`` ``(K,)`` and point
    ``slot_xy[slot]`` ``(K, 2)`` where its obstacle meets the new plan (``inf``: clear of it)."""
    return q._replace(s=slot_s[q.slot].astype(q.s.dtype), xy=slot_xy[q.slot].astype(q.xy.dtype))


def queue_expire(q: CollisionQueue, now, window=2.0) -> CollisionQueue:
    """Drop entries older than ``window`` seconds (``now - t > window``)."""
    return q._replace(valid=q.valid & (now - q.t <= window))


def queue_clear(q: CollisionQueue) -> CollisionQueue:
    return q._replace(valid=jnp.zeros_like(q.valid))


def queue_size(q: CollisionQueue):
    return jnp.sum(q.valid).astype(jnp.int32)


def queue_nearest(q: CollisionQueue):
    """(arc length ``()``, xy ``(2,)``, found ``()``) of the nearest entry on the current plan."""
    on = q.valid & jnp.isfinite(q.s)
    k = jnp.argmin(jnp.where(on, q.s, jnp.inf))
    return q.s[k], q.xy[k], jnp.any(on)


def brake_init(dtype=jnp.float32) -> BrakeStop:
    return BrakeStop(jnp.zeros((), dtype), jnp.full((), jnp.inf, dtype), jnp.zeros((), bool))


def update_brake_stop(b: BrakeStop, q: CollisionQueue, safety=0.5) -> BrakeStop:
    """Brake-stop point from the queue: ``safety`` before the nearest entry, moved only when it changes."""
    s, _, found = queue_nearest(q)
    changed = found & ((~b.active) | (s != b.key))
    return BrakeStop(jnp.where(changed, s - safety, b.s), jnp.where(found, s, jnp.inf).astype(b.key.dtype), found)


def first_collision_point(car_boxes, start, end, obs_boxes, obs_valid):
    """First plan point in ``[start, end]`` whose car box overlaps a valid (static) obstacle.

    Args:
        car_boxes: ``(N, 5)`` car box at every plan point.
        start, end: ``()`` int index range (inclusive).
        obs_boxes: ``(K, 5)``; obs_valid: ``(K,)``.

    Returns:
        (index ``()``, found ``()``); index is ``end`` when nothing collides.
    """
    idx, _, found = collision_arc_length(
        car_boxes, jnp.zeros(car_boxes.shape[:1], car_boxes.dtype), start, end, obs_boxes, obs_valid
    )
    return idx, found


def collision_arc_length(car_boxes, s_path, start, end, obs_boxes, obs_valid):
    """First collision point with static obstacles and where along the plan contact begins.

    The contact arc length interpolates the signed separation linearly between
    the last free point and the first colliding one (``s_path[idx]`` when the
    first colliding point is ``start``), so the brake-stop point does not depend
    on the point spacing.

    Returns:
        (index ``()``, contact arc length ``()``, found ``()``); index ``end`` when nothing collides.
    """
    i = jnp.arange(car_boxes.shape[0])
    sep = box_separation(car_boxes[:, None, :], obs_boxes[None, :, :])
    sep = jnp.min(
        jnp.where(obs_valid[None, :] & ((i >= start) & (i <= end))[:, None], sep, jnp.inf), axis=-1, initial=jnp.inf
    )
    idx, s, found = first_contact(sep, s_path, start)
    return jnp.where(found, idx, end).astype(jnp.int32), s, found


first_collision_point_jit = jax.jit(first_collision_point)
