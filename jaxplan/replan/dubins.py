"""Dubins paths: shortest forward paths between two poses with a bounded curvature.

A Dubins path is three segments, each a left arc (L), a straight (S) or a right arc (R)
of radius ``radius``; the shortest path between two poses is one of the six words LSL,
RSR, LSR, RSL, RLR, LRL (Dubins 1957; closed forms as in Shkel & Lumelsky 2001). Its
curvature is ``1 / radius`` on the arcs and 0 on the straights, so a path with
``radius >= wheelbase / tan(max_steer)`` is drivable by the car. A reverse leg is the
Dubins path of the flipped poses (heading + pi) driven backwards.

All functions are elementwise over leading batch dimensions.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

WORDS = ("LSL", "RSR", "LSR", "RSL", "RLR", "LRL")
# Curvature sign of each segment (+1 left, 0 straight, -1 right), per word.
WORD_SIGNS = ((1, 0, 1), (-1, 0, -1), (1, 0, -1), (-1, 0, 1), (-1, 1, -1), (1, -1, 1))
_TWO_PI = 2 * jnp.pi


class DubinsPath(NamedTuple):
    """start ``(..., 3)``; lengths ``(..., 3)`` of the three segments in m; signs ``(..., 3)``
    curvature signs; radius ``(...)``; length ``(...)`` total; ok ``(...)`` a path was found."""

    start: jnp.ndarray
    lengths: jnp.ndarray
    signs: jnp.ndarray
    radius: jnp.ndarray
    length: jnp.ndarray
    ok: jnp.ndarray


def _mod2pi(x):
    return x - _TWO_PI * jnp.floor(x / _TWO_PI)


SNAP = 1e-2


def _snap(x):
    """An arc within ``SNAP`` rad of a full turn is no turn: float32 rounding of a zero-length
    arc (from a start a hair off an earlier path) must not become a loop. The path then ends
    up to ``radius * SNAP`` off its target; callers check the end pose (see ``end_pose``)."""
    return jnp.where(x > _TWO_PI - SNAP, 0.0, x)


def word_lengths(start, end, radius):
    """Segment lengths of all six words.

    Args:
        start, end: ``(..., 3)`` poses ``[x, y, heading]``; radius: ``(...)`` or scalar.

    Returns:
        (lengths ``(..., 6, 3)`` in m, feasible ``(..., 6)``).
    """
    radius = jnp.asarray(radius, start.dtype)
    dx, dy = end[..., 0] - start[..., 0], end[..., 1] - start[..., 1]
    d = jnp.sqrt(dx * dx + dy * dy) / radius
    phi = jnp.where(d > 1e-9, jnp.arctan2(dy, dx), 0.0)
    a, b = _mod2pi(start[..., 2] - phi), _mod2pi(end[..., 2] - phi)
    sa, sb, ca, cb = jnp.sin(a), jnp.sin(b), jnp.cos(a), jnp.cos(b)
    cab = jnp.cos(a - b)
    rows, feas = [], []

    # LSL
    p2 = 2 + d * d - 2 * cab + 2 * d * (sa - sb)
    t1 = jnp.arctan2(cb - ca, d + sa - sb)
    rows.append((_mod2pi(t1 - a), jnp.sqrt(jnp.maximum(p2, 0.0)), _mod2pi(b - t1)))
    feas.append(p2 >= 0)
    # RSR
    p2 = 2 + d * d - 2 * cab + 2 * d * (sb - sa)
    t1 = jnp.arctan2(ca - cb, d - sa + sb)
    rows.append((_mod2pi(a - t1), jnp.sqrt(jnp.maximum(p2, 0.0)), _mod2pi(t1 - b)))
    feas.append(p2 >= 0)
    # LSR
    p2 = -2 + d * d + 2 * cab + 2 * d * (sa + sb)
    p = jnp.sqrt(jnp.maximum(p2, 0.0))
    t0 = jnp.arctan2(-ca - cb, d + sa + sb) - jnp.arctan2(-2.0, p)
    rows.append((_mod2pi(t0 - a), p, _mod2pi(t0 - b)))
    feas.append(p2 >= 0)
    # RSL
    p2 = -2 + d * d + 2 * cab - 2 * d * (sa + sb)
    p = jnp.sqrt(jnp.maximum(p2, 0.0))
    t0 = jnp.arctan2(ca + cb, d - sa - sb) - jnp.arctan2(2.0, p)
    rows.append((_mod2pi(a - t0), p, _mod2pi(b - t0)))
    feas.append(p2 >= 0)
    # RLR
    c = (6 - d * d + 2 * cab + 2 * d * (sa - sb)) / 8
    ph = jnp.arctan2(ca - cb, d - sa + sb)
    p = _mod2pi(_TWO_PI - jnp.arccos(jnp.clip(c, -1.0, 1.0)))
    t = _mod2pi(a - ph + p / 2)
    rows.append((t, p, _mod2pi(a - b - t + p)))
    feas.append(jnp.abs(c) <= 1)
    # LRL
    c = (6 - d * d + 2 * cab + 2 * d * (sb - sa)) / 8
    ph = jnp.arctan2(ca - cb, d + sa - sb)
    p = _mod2pi(_TWO_PI - jnp.arccos(jnp.clip(c, -1.0, 1.0)))
    t = _mod2pi(-a - ph + p / 2)
    rows.append((t, p, _mod2pi(b - a - t + p)))
    feas.append(jnp.abs(c) <= 1)

    lengths = jnp.stack([jnp.stack([_snap(t), p, _snap(q)], -1) for t, p, q in rows], -2)
    # Straights are lengths already (normalised by the radius); arcs are angles. Both scale by the radius.
    lengths = lengths * radius[..., None, None]
    feasible = jnp.stack(feas, -1)
    same = (d < 1e-6) & (jnp.abs(jnp.sin(0.5 * (end[..., 2] - start[..., 2]))) < 1e-6)
    # Identical poses: the empty path (the words would give a full turn).
    lengths = jnp.where(same[..., None, None], 0.0, lengths)
    return lengths, feasible | same[..., None]


def shortest(start, end, radius) -> DubinsPath:
    """Shortest Dubins path from ``start`` to ``end`` ``(..., 3)`` with turning radius ``radius``."""
    start = jnp.asarray(start)
    end = jnp.asarray(end, start.dtype)
    radius = jnp.broadcast_to(jnp.asarray(radius, start.dtype), start.shape[:-1])
    lengths, feasible = word_lengths(start, end, radius)
    total = jnp.where(feasible, jnp.sum(lengths, -1), jnp.inf)
    k = jnp.argmin(total, axis=-1)
    signs = jnp.asarray(WORD_SIGNS, start.dtype)[k]
    lk = jnp.take_along_axis(lengths, k[..., None, None], axis=-2)[..., 0, :]
    return DubinsPath(start, lk, signs, radius, jnp.sum(lk, -1), jnp.any(feasible, -1))


def _advance(pose, sign, length, radius):
    """Pose after driving ``length`` on a segment of curvature ``sign / radius``."""
    x, y, h = pose[..., 0], pose[..., 1], pose[..., 2]
    h2 = h + sign * length / radius
    arc_x = x + sign * radius * (jnp.sin(h2) - jnp.sin(h))
    arc_y = y - sign * radius * (jnp.cos(h2) - jnp.cos(h))
    straight = sign == 0
    return jnp.stack(
        [jnp.where(straight, x + length * jnp.cos(h), arc_x), jnp.where(straight, y + length * jnp.sin(h), arc_y), h2],
        -1,
    )


def end_pose(path: DubinsPath):
    """Where ``path`` ends ``(..., 3)``."""
    p1 = _advance(path.start, path.signs[..., 0], path.lengths[..., 0], path.radius)
    p2 = _advance(p1, path.signs[..., 1], path.lengths[..., 1], path.radius)
    return _advance(p2, path.signs[..., 2], path.lengths[..., 2], path.radius)


def sample(path: DubinsPath, u):
    """Poses at arc lengths ``u`` ``(..., M)`` (clipped to ``[0, length]``) along ``path`` (batch ``(...)``).

    Returns:
        (poses ``(..., M, 3)``, curvature ``(..., M)`` of the segment each pose lies on).
    """
    l1, l2 = path.lengths[..., 0:1], path.lengths[..., 1:2]
    p0 = path.start
    r = path.radius[..., None]
    p1 = _advance(p0, path.signs[..., 0], path.lengths[..., 0], path.radius)
    p2 = _advance(p1, path.signs[..., 1], path.lengths[..., 1], path.radius)
    u = jnp.clip(u, 0.0, path.length[..., None])
    seg = jnp.where(u <= l1, 0, jnp.where(u <= l1 + l2, 1, 2))  # (..., M)
    base = jnp.stack([p0, p1, p2], -2)  # (..., 3, 3)
    off = jnp.concatenate([jnp.zeros_like(l1), l1, l1 + l2], -1)  # (..., 3)
    pick = lambda a: jnp.take_along_axis(a, seg, axis=-1)  # noqa: E731
    b = jnp.take_along_axis(base, seg[..., None], axis=-2)  # (..., M, 3)
    sign = pick(path.signs)
    return _advance(b, sign, u - pick(off), r), sign / r
