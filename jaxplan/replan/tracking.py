"""Tracking point search: where on the plan the car is now.

The car is projected onto the segments ``j -> j + 1`` of the plan, starting at
the last tracking point and looking at most ``window`` segments ahead (never
the whole plan each time). A segment qualifies when the projection ``p`` of
the car satisfies ``0 < p <= |segment|`` and the car is at most ``max_dist``
from it; the tracking point is the start ``j`` of the nearest qualifying
segment. The direction-aware variant keeps only segments driven in the car's
direction of motion (same gear, direction vector agreeing with the car's
motion), which picks the right branch where a reverse leg retraces a forward one.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.geometry.lines import cross2, dot2


class TrackingPoint(NamedTuple):
    """Result of a search (all ``()``).

    index: segment start ``j`` (the tracking point); proj: distance along the
    segment from point ``j``; dist: lateral distance of the car from the segment;
    found: whether any segment qualified (else index is the start index).
    """

    index: jnp.ndarray  # type: ignore[assignment]  # public field name; shadows tuple.index on purpose
    proj: jnp.ndarray
    dist: jnp.ndarray
    found: jnp.ndarray


def _search(path_xy, car_xy, start, end, window, max_dist, extra_ok=None, eps=1e-9):
    n = path_xy.shape[-2]
    j = start + jnp.arange(window, dtype=jnp.int32)  # (W,)
    jc = jnp.clip(j, 0, n - 2)
    a, b = path_xy[jc], path_xy[jc + 1]  # (W, 2)
    d = b - a
    length = jnp.linalg.norm(d, axis=-1)
    safe = jnp.where(length > eps, length, 1.0)
    w = car_xy - a
    proj = dot2(w, d) / safe
    dist = jnp.abs(cross2(d, w)) / safe
    ok = (j < end) & (j <= n - 2) & (length > eps) & (proj > 0) & (proj <= length) & (dist <= max_dist)
    if extra_ok is not None:
        ok = ok & extra_ok(jc, d)
    k = jnp.argmin(jnp.where(ok, dist, jnp.inf))
    found = jnp.any(ok)
    return TrackingPoint(
        jnp.where(found, j[k], start).astype(jnp.int32),
        jnp.where(found, proj[k], 0.0),
        jnp.where(found, dist[k], jnp.inf),
        found,
    )


def find_tracking_point(path_xy, car_xy, start, end, window: int = 32, max_dist=jnp.inf):
    """Nearest qualifying segment of ``path_xy`` among ``j`` in ``[start, min(start + window, end))``.

    Args:
        path_xy: ``(N, 2)`` plan points.
        car_xy: ``(2,)`` car reference point.
        start: ``()`` int, the last tracking point.
        end: ``()`` int, last point index usable (segments end at most there).
        window: static number of segments searched.
        max_dist: farthest lateral distance accepted.

    Returns:
        ``TrackingPoint``.
    """
    return _search(path_xy, car_xy, start, end, window, max_dist)


def find_tracking_point_directional(
    path_xy, gear, car_xy, car_heading, motion, start, end, window: int = 32, max_dist=jnp.inf
):
    """Direction-aware search: as ``find_tracking_point``, keeping only segments
    driven in the car's direction of motion.

    Args:
        gear: ``(N,)`` gear used to reach each point (segment ``j`` is driven in ``gear[j+1]``).
        car_heading: ``()`` heading of the car body.
        motion: ``()`` +1 moving forward, -1 reversing.
    """
    m = motion * jnp.stack([jnp.cos(car_heading), jnp.sin(car_heading)])

    def agree(jc, d):
        return (gear[jc + 1] == motion) & (dot2(d, m) > 0)

    return _search(path_xy, car_xy, start, end, window, max_dist, agree)


find_tracking_point_jit = jax.jit(find_tracking_point, static_argnames="window")
find_tracking_point_directional_jit = jax.jit(find_tracking_point_directional, static_argnames="window")
