"""Time-aware obstacle prediction and the one collision test every part of the loop uses.

An obstacle is a box ``[x, y, length, width, heading]`` seen ``age`` seconds ago with a
velocity ``(vx, vy)``; it is predicted to move on at that velocity (a static one has
velocity 0 and stays put). A plan point that the car reaches in ``tau`` seconds collides
with it when the car box there overlaps the obstacle's box *swept over the window*
``[tau - before, tau + after]`` around that time: the car may be a little early or late,
and it must not pass just in front of a walking pedestrian. A crossing pedestrian is thus
a moving box, not its whole future path held as a wall.

The planner (its candidates, with a margin), the supervisor's collision points, its
check of a new plan before installing it, and the re-anchoring of remembered collision
points on a new plan all call ``plan_separation``.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.boxes import box_separation


def swept_boxes(boxes, vel, t0, t1):
    """Oriented box covering a box moving at constant velocity over ``[t0, t1]``.

    The swept box is aligned with the velocity: its length is the box's extent along
    the velocity plus the distance travelled, its width the extent across. Exact (the
    convex hull of the moving box) when the box heading is along its velocity; a box
    containing it otherwise. A box with zero velocity is returned as it is.

    Args:
        boxes: ``(..., 5)`` box at time 0; vel: ``(..., 2)``; t0, t1: ``(...)`` with ``t0 <= t1``.

    Returns:
        ``(..., 5)``.
    """
    speed = jnp.linalg.norm(vel, axis=-1)
    moving = speed > 1e-6
    heading = boxes[..., 4]
    psi = jnp.where(moving, jnp.arctan2(vel[..., 1], vel[..., 0]), heading)
    c, s = jnp.abs(jnp.cos(heading - psi)), jnp.abs(jnp.sin(heading - psi))
    length, width = boxes[..., 2], boxes[..., 3]
    along = length * c + width * s + speed * (t1 - t0)
    across = length * s + width * c
    centre = boxes[..., :2] + vel * (0.5 * (t0 + t1))[..., None]
    shape = centre.shape[:-1]
    rest = [jnp.broadcast_to(a, shape)[..., None] for a in (along, across, psi)]
    return jnp.concatenate([centre] + rest, axis=-1)


def plan_separation(car_boxes, tau, check, obs, vel, age, valid, before, after):
    """Signed separation of the car at every plan point from every predicted obstacle.

    Args:
        car_boxes: ``(N, 5)`` car box at each plan point.
        tau: ``(N,)`` time until the car gets there (s, may be inf).
        check: ``(N,)`` bool, the points to test.
        obs: ``(K, 5)``; vel: ``(K, 2)``; age: ``(K,)`` s since each box was seen; valid: ``(K,)``.
        before, after: the time window (s) around ``tau``.

    Returns:
        ``(N, K)`` SAT separation (``< 0``: overlap), ``+inf`` where not tested.
    """
    ok = check[:, None] & valid[None, :] & jnp.isfinite(tau)[:, None]
    tt = jnp.where(jnp.isfinite(tau), tau, 0.0)[:, None] + age[None, :]
    sw = swept_boxes(obs[None, :, :], vel[None, :, :], tt - before, tt + after)  # (N, K, 5)
    sep = box_separation(car_boxes[:, None, :], sw)
    return jnp.where(ok, sep, jnp.inf)


def first_contact(sep, s_path, start):
    """First colliding point of a separation profile and where contact begins.

    Args:
        sep: ``(N,)`` separation along the plan (``+inf`` where not tested).
        s_path: ``(N,)`` arc length; start: ``()`` first index tested.

    Returns:
        (index ``()``, contact arc length ``()``, found ``()``). The contact arc length
        interpolates the separation linearly between the last free point and the first
        colliding one (``s_path[index]`` when that is ``start``); index and arc length are
        those of the last point and ``inf`` when nothing collides.
    """
    n = sep.shape[0]
    hit = sep < 0
    found = jnp.any(hit)
    idx = jnp.where(found, jnp.argmax(hit), n - 1).astype(jnp.int32)
    prev = jnp.maximum(idx - 1, 0)
    a, b = sep[prev], sep[idx]
    u = jnp.clip(a / jnp.where((a - b > 0) & jnp.isfinite(a), a - b, 1.0), 0.0, 1.0)
    s = jnp.where((idx > start) & jnp.isfinite(a), s_path[prev] + u * (s_path[idx] - s_path[prev]), s_path[idx])
    return idx, jnp.where(found, s, jnp.inf), found
