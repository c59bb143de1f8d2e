"""Oriented boxes, path headings and the car's contour corners."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, ArrayLike, Bool, Float

from jaxplan.types import VehicleParams, check_boxes, check_trailing, is_concrete

# Corner offsets in units of (length/2, width/2): front-left, rear-left,
# rear-right, front-right -- counter-clockwise.
_CORNER_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))


def box_corners(boxes: Float[ArrayLike, "... 5"]) -> Float[Array, "... 4 2"]:
    """Corners of oriented boxes.

    Args:
        boxes: ``(..., 5)`` = [x, y, length, width, heading].

    Returns:
        ``(..., 4, 2)`` corners, counter-clockwise from the front-left corner.
    """
    if is_concrete(boxes):
        check_boxes(boxes)
    return _box_corners(jnp.asarray(boxes))


@jax.jit
def _box_corners(boxes):
    """``box_corners`` without the input check; jitted, so that an eager call is one compiled
    program per shape, not one per operation."""
    x, y, length, width, heading = (boxes[..., i] for i in range(5))
    c, s = jnp.cos(heading), jnp.sin(heading)
    signs = jnp.asarray(_CORNER_SIGNS, dtype=boxes.dtype)
    dx = 0.5 * length[..., None] * signs[:, 0]  # (..., 4) along the body
    dy = 0.5 * width[..., None] * signs[:, 1]  # (..., 4) to the left
    cx = x[..., None] + c[..., None] * dx - s[..., None] * dy
    cy = y[..., None] + s[..., None] * dx + c[..., None] * dy
    return jnp.stack([cx, cy], axis=-1)


def box_half_extents(boxes: Float[ArrayLike, "... 5"], heading: Float[ArrayLike, " ..."]) -> Float[Array, "... 2"]:
    """Half extents ``(..., 2)`` of boxes ``(..., 5)`` along and across the direction ``heading``
    ``(...)``: half the lengths of their projections onto that axis and its normal."""
    boxes = jnp.asarray(boxes)
    d = boxes[..., 4] - heading
    c, s = jnp.abs(jnp.cos(d)), jnp.abs(jnp.sin(d))
    return 0.5 * jnp.stack([boxes[..., 2] * c + boxes[..., 3] * s, boxes[..., 2] * s + boxes[..., 3] * c], -1)


def headings_from_path(xy: Float[ArrayLike, "... T 2"], eps: float = 1e-9) -> Float[Array, "... T"]:
    """Heading of every path point from consecutive points.

    ``theta[i] = atan2(xy[i] - xy[i-1])`` and the first point takes the next
    difference. Zero-length steps (repeated points) keep the heading of the
    nearest earlier step, or of the first non-zero step at the start. A path
    of one point, or one with no non-zero step, has heading 0.

    Args:
        xy: ``(..., T, 2)``.

    Returns:
        ``(..., T)`` headings in radians.
    """
    if is_concrete(xy):
        check_trailing("path xy", xy, (2,), coords=2)
        if jnp.ndim(xy) < 2:
            raise ValueError(f"path xy: expected shape (..., T, 2), got {jnp.shape(xy)}")
    xy = jnp.asarray(xy)
    T = xy.shape[-2]
    if T < 2:
        return jnp.zeros(xy.shape[:-1], xy.dtype)
    d = xy[..., 1:, :] - xy[..., :-1, :]  # (..., T-1, 2)
    ok = jnp.sum(d * d, axis=-1) > eps * eps
    idx = jnp.arange(T - 1)
    last_ok = lax.cummax(jnp.where(ok, idx, -1), axis=ok.ndim - 1)
    first_ok = jnp.argmax(ok, axis=-1)[..., None]
    pick = jnp.where(last_ok < 0, first_ok, last_ok)
    d = jnp.take_along_axis(d, pick[..., None], axis=-2)
    h = jnp.arctan2(d[..., 1], d[..., 0])
    return jnp.concatenate([h[..., :1], h], axis=-1)


def poses_to_boxes(
    xy: Float[ArrayLike, "... 2"], heading: Float[ArrayLike, " ..."], vehicle: VehicleParams
) -> Float[Array, "... 5"]:
    """Car boxes ``(..., 5)`` from reference-point positions ``(..., 2)`` and headings ``(...)``."""
    xy = jnp.asarray(xy)
    heading = jnp.asarray(heading, xy.dtype)
    off = jnp.asarray(vehicle.center_offset, xy.dtype)
    cx = xy[..., 0] + off * jnp.cos(heading)
    cy = xy[..., 1] + off * jnp.sin(heading)
    length = jnp.broadcast_to(jnp.asarray(vehicle.length, xy.dtype), cx.shape)
    width = jnp.broadcast_to(jnp.asarray(vehicle.width, xy.dtype), cx.shape)
    return jnp.stack([cx, cy, length, width, heading], axis=-1)


def vehicle_corners(
    path_xy: Float[ArrayLike, "... T 2"], vehicle: VehicleParams, heading: Float[ArrayLike, "... T"] | None = None
) -> Float[Array, "... T 4 2"]:
    """The car's four contour corners at every trajectory point.

    Args:
        path_xy: ``(..., T, 2)`` positions of the car's reference point.
        vehicle: car size and reference point.
        heading: optional ``(..., T)``; by default ``headings_from_path(path_xy)``.

    Returns:
        ``(..., T, 4, 2)`` corners, counter-clockwise from the front-left corner.
    """
    if is_concrete(vehicle):
        vehicle.validate()
    if heading is None:
        heading = headings_from_path(path_xy)
    return box_corners(poses_to_boxes(path_xy, heading, vehicle))


def box_separation(boxes_a: Float[ArrayLike, "... 5"], boxes_b: Float[ArrayLike, "... 5"]) -> Float[Array, " ..."]:
    """Signed SAT separation of oriented boxes, straight from their parameters.

    The same quantity as ``separation(box_corners(a), box_corners(b))`` (the
    four box axes), without building corners: the fast path for box-vs-box.

    Args:
        boxes_a, boxes_b: ``(..., 5)`` = [x, y, length, width, heading]; broadcast.

    Returns:
        ``(...)``, positive apart, negative = minus the penetration depth.
    """
    a, b = jnp.asarray(boxes_a), jnp.asarray(boxes_b)
    unit = lambda h: jnp.stack([jnp.cos(h), jnp.sin(h)], axis=-1)
    return box_separation_axes(
        a[..., :2], unit(a[..., 4]), 0.5 * a[..., 2:4], b[..., :2], unit(b[..., 4]), 0.5 * b[..., 2:4]
    )


def box_has_overlap(boxes_a: Float[ArrayLike, "... 5"], boxes_b: Float[ArrayLike, "... 5"]) -> Bool[Array, " ..."]:
    """Whether oriented boxes ``(..., 5)`` overlap (touching is not). Returns ``(...)`` bool."""
    return box_separation(boxes_a, boxes_b) < 0


def box_separation_axes(center_a, axis_a, half_a, center_b, axis_b, half_b):
    """``box_separation`` for boxes given by centre, unit heading and half sizes.

    The same signed SAT separation, for callers that already hold each box's
    heading as a unit vector (no trigonometry per pair: the fast path when many
    boxes are checked against many).

    Args:
        center_a, center_b: ``(..., 2)`` box centres.
        axis_a, axis_b: ``(..., 2)`` unit heading vectors ``(cos, sin)``.
        half_a, half_b: ``(..., 2)`` half length and half width.
        All broadcast against each other.

    Returns:
        ``(...)``, positive apart, negative = minus the penetration depth.
    """
    dx = center_b[..., 0] - center_a[..., 0]
    dy = center_b[..., 1] - center_a[..., 1]
    ca, sa = axis_a[..., 0], axis_a[..., 1]
    cb, sb = axis_b[..., 0], axis_b[..., 1]
    c = jnp.abs(ca * cb + sa * sb)
    s = jnp.abs(sa * cb - ca * sb)
    la, wa, lb, wb = half_a[..., 0], half_a[..., 1], half_b[..., 0], half_b[..., 1]
    g0 = jnp.abs(dx * ca + dy * sa) - (la + lb * c + wb * s)
    g1 = jnp.abs(dy * ca - dx * sa) - (wa + lb * s + wb * c)
    g2 = jnp.abs(dx * cb + dy * sb) - (lb + la * c + wa * s)
    g3 = jnp.abs(dy * cb - dx * sb) - (wb + la * s + wa * c)
    return jnp.maximum(jnp.maximum(g0, g1), jnp.maximum(g2, g3))


def car_reach(vehicle, dtheta):
    """Lateral reach of the car's body left / right of its reference point at relative
    heading ``dtheta (...)``: ``(left, right)`` both ``>= 0``-ish, ``(...)`` each."""
    front = vehicle.front_offset
    rear = vehicle.rear_offset
    hw = 0.5 * vehicle.width
    sn, cs = jnp.sin(dtheta), jnp.cos(dtheta)
    offs = jnp.stack([x * sn + y * cs for x in (front, rear) for y in (hw, -hw)], -1)
    return jnp.max(offs, -1), -jnp.min(offs, -1)
