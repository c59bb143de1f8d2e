"""Turning radii, the three reference circles O1/O2/O3 and the reference curves.

A reference curve is a chain of three segments (arc, arc, straight extension),
each ``[x0, y0, heading0, curvature]`` with a length, parametrised in the
direction of travel: for the backward curve the travel heading is the car's
heading + pi. Beyond its end a curve continues straight (the pure-pursuit
look-ahead needs points past the end).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry import wrap_angle

TWO_PI = 2 * jnp.pi


def turning_radius(vehicle):
    """Smallest radius of the rear-axle centre: ``wheelbase / tan(max_steer)``."""
    return vehicle.wheelbase / jnp.tan(vehicle.max_steer)


def front_corner_radius(vehicle, margin=0.0):
    """Radius swept by the outer front corner at the smallest turning radius.

    ``sqrt((R + width/2 + margin)^2 + (wheelbase + front_overhang + margin)^2)``.
    """
    R = turning_radius(vehicle)
    a = vehicle.wheelbase + vehicle.front_overhang + margin
    return jnp.sqrt((R + 0.5 * vehicle.width + margin) ** 2 + a**2)


def stop_line(vehicle, c=1.0):
    """``d = width + c``: the car is out once its rear axle is beyond ``y = d``."""
    return vehicle.width + c


def min_front_gap(vehicle, margin=0.0, corner_y=None):
    """Smallest gap from the front bumper to an obstacle ahead for one forward move.

    The outer front corner turns on a circle of ``front_corner_radius`` about
    O3 = (0, R); the obstacle's nearest corner at ``(x_f, corner_y)`` must stay
    outside it: ``x_f >= sqrt(rho^2 - (R - corner_y)^2)``. ``corner_y`` defaults to
    ``width / 2`` (a car of the same width ahead, aligned), which gives
    ``sqrt((a + m)^2 + (w + m)(2R + m)) - a`` with ``a = wheelbase + front overhang``.
    """
    R = turning_radius(vehicle)
    rho = front_corner_radius(vehicle, margin)
    cy = 0.5 * vehicle.width if corner_y is None else corner_y
    xf = jnp.sqrt(jnp.maximum(rho**2 - (R - cy) ** 2, 0.0))
    return xf - (vehicle.wheelbase + vehicle.front_overhang)


def min_slot_length(vehicle, margin=0.0, corner_y=None):
    """Analytic shortest slot (bumper to bumper) the car leaves in one forward move.

    Car length + ``margin`` behind (the start pose must be clear) + ``min_front_gap``.
    """
    return vehicle.length + margin + min_front_gap(vehicle, margin, corner_y)


def reference_circles(pose, R, d):
    """Centres of O1, O2, O3 for a pose and the O3-O1 tangent point.

    Args:
        pose: ``(..., 3)`` = [x, y, heading]; R: turning radius; d: stop line.

    Returns:
        (centres ``(..., 3, 2)`` in the order O1, O2, O3, tangent point ``(..., 2)``).
        O3 is on the car's left through the pose, O2 on its right, O1 has its
        centre on ``y = d - R`` (tangent to the stop line) ahead of O3 and touches O3.
    """
    x, y, th = pose[..., 0], pose[..., 1], pose[..., 2]
    s, c = jnp.sin(th), jnp.cos(th)
    o3 = jnp.stack([x - R * s, y + R * c], -1)
    o2 = jnp.stack([x + R * s, y - R * c], -1)
    dy = (d - R) - o3[..., 1]
    dx = jnp.sqrt(jnp.maximum(4 * R * R - dy * dy, 0.0))
    o1 = jnp.stack([o3[..., 0] + dx, jnp.broadcast_to(d - R, dx.shape)], -1)
    return jnp.stack([o1, o2, o3], -2), 0.5 * (o1 + o3)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Curve:
    """A reference curve: three segments in the direction of travel.

    Attributes:
        start: ``(..., 3, 3)`` [x, y, travel heading] at each segment's start.
        kappa: ``(..., 3)`` signed curvature (left positive, w.r.t. travel).
        length: ``(..., 3)`` segment lengths (>= 0).
        end: ``(...)`` arc length at which the move is complete.
        gear: ``(...)`` +1 forward, -1 backward.
    """

    start: Any
    kappa: Any
    length: Any
    end: Any
    gear: Any


def _advance(p, k, s):
    """Pose ``(..., 3)`` after arc length ``s`` on curvature ``k`` (exact arc)."""
    th0 = p[..., 2]
    th = th0 + k * s
    small = jnp.abs(k) < 1e-6
    ks = jnp.where(small, 1.0, k)
    dx = jnp.where(small, s * jnp.cos(th0 + 0.5 * k * s), (jnp.sin(th) - jnp.sin(th0)) / ks)
    dy = jnp.where(small, s * jnp.sin(th0 + 0.5 * k * s), -(jnp.cos(th) - jnp.cos(th0)) / ks)
    return jnp.stack([p[..., 0] + dx, p[..., 1] + dy, th], -1)


def make_curve(p0, kappa, length, end, gear):
    """Curve from a start pose ``(..., 3)`` (travel heading) and per-segment curvature and
    length ``(..., 3)``; the third segment is the straight extension (its curvature is ignored)."""
    starts = [p0]
    for i in range(2):
        starts.append(_advance(starts[-1], kappa[..., i], length[..., i]))
    return Curve(jnp.stack(starts, -2), kappa, length, end, gear)


def curve_point(curve: Curve, s):
    """Pose on one curve at arc length ``s``; straight beyond both ends.

    Args:
        curve: a single curve (``vmap`` for batches); s: ``(...)`` arc lengths.

    Returns:
        ``(..., 3)`` [x, y, travel heading].
    """
    s = jnp.asarray(s)
    s1 = curve.length[0]
    s2 = s1 + curve.length[1]
    seg1, seg2 = s >= s1, s >= s2
    before = s < 0
    # selects rather than indexing by segment (no gathers: this runs at every pursuit step)
    pick = lambda a: jnp.where(seg2[..., None], a[2], jnp.where(seg1[..., None], a[1], a[0]))  # noqa: E731
    st = pick(curve.start)
    k = jnp.where(before | seg2, 0.0, jnp.where(seg1, curve.kappa[1], curve.kappa[0]))
    local = s - jnp.where(seg2, s2, jnp.where(seg1, s1, 0.0))
    return _advance(st, k, local)


def forward_curve(pose, R, d, extension=3.0):
    """Forward reference: arc of O3 to the O3-O1 tangent point, then O1 up to ``y = d``.

    If the car already points past the tangent point (O3 would have to go
    round), the curve is the right-turn circle through the pose until the
    heading is 0 (the limit of the same construction).

    Args:
        pose: ``(3,)``; R: turning radius; d: target line (the stop line).
    """
    centres, tp = reference_circles(pose, R, d)
    o1, o3 = centres[..., 0, :], centres[..., 2, :]
    ang = lambda v: jnp.arctan2(v[..., 1], v[..., 0])  # noqa: E731
    a3 = jnp.mod(ang(tp - o3) - ang(pose[..., :2] - o3), 2 * jnp.pi)
    a1 = jnp.mod(ang(tp - o1) - 0.5 * jnp.pi, 2 * jnp.pi)
    past = a3 > jnp.pi
    a3 = jnp.where(past, 0.0, a3)
    a1 = jnp.where(past, jnp.maximum(wrap_angle(pose[..., 2]), 0.0), a1)
    kappa = jnp.stack([1.0 / R, -1.0 / R, 0.0 * R], -1)
    length = jnp.stack([R * a3, R * a1, extension + 0.0 * R], -1)
    return make_curve(pose, kappa, length, R * (a3 + a1), jnp.ones_like(R))


def backward_curve(pose, R, theta1, theta2, cap, extension=3.0):
    """Backward reference: the line ``y = 0`` (capped) or the circle O2.

    Below ``|heading| < theta1`` the car reverses along ``y = 0`` from the foot of
    its rear axle, for at most ``cap``; otherwise it reverses on O2 (the circle
    on its right through the pose), which turns the nose further out, until the
    heading reaches ``theta2``.
    """
    th = wrap_angle(pose[..., 2])
    line = jnp.abs(th) < theta1
    start = jnp.where(
        line[..., None],
        jnp.stack([pose[..., 0], 0.0 * th, jnp.pi + 0.0 * th], -1),
        jnp.stack([pose[..., 0], pose[..., 1], th + jnp.pi], -1),
    )
    arc = R * jnp.maximum(theta2 - th, 0.0)
    l0 = jnp.where(line, cap + 0.0 * R, arc)
    k0 = jnp.where(line, 0.0, 1.0 / R)
    kappa = jnp.stack([k0, 0.0 * R, 0.0 * R], -1)
    length = jnp.stack([l0, 0.0 * R, extension + 0.0 * R], -1)
    return make_curve(start, kappa, length, l0, -jnp.ones_like(R))
