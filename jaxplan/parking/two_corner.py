"""Baseline obstacle model: each obstacle reduced to its two corners nearest the car."""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry import box_corners, points_in_polygon
from jaxplan.parking.grid import footprint_boxes


def two_corner_points(polygons, valid, ref_xy):
    """The two vertices of each obstacle outline nearest to ``ref_xy``.

    Args:
        polygons: ``(..., K, N, 2)`` outlines (e.g. ``box_corners`` of boxes); valid:
            ``(..., K)``; ref_xy: ``(..., 2)`` (the car's box centre at its start).

    Returns:
        (points ``(..., 2K, 2)``, valid ``(..., 2K)``).
    """
    c = jnp.asarray(polygons)
    d = jnp.sum((c - ref_xy[..., None, None, :]) ** 2, -1)
    idx = jnp.argsort(d, axis=-1)[..., :2]
    pts = jnp.take_along_axis(c, idx[..., None], axis=-2)
    ok = jnp.broadcast_to(valid[..., None], pts.shape[:-1])
    return pts.reshape(pts.shape[:-3] + (-1, 2)), ok.reshape(ok.shape[:-2] + (-1,))


def footprint_hits_points(points, valid, poses, vehicle, margin=0.0):
    """Whether any valid point lies in the footprint inflated by ``margin``.

    Args:
        points: ``(P, 2)``; valid: ``(P,)``; poses: ``(..., 3)``.

    Returns:
        ``(...)`` bool.
    """
    poly = box_corners(footprint_boxes(poses, vehicle, margin))  # (..., 4, 2)
    inside = points_in_polygon(jnp.broadcast_to(points, poly.shape[:-2] + points.shape), poly)
    return jnp.any(inside & valid, axis=-1)
