"""``offroad``: the car's box leaves the drivable area (the union of the lanelets).

Points along the box's outline (its corners and at most every ``SPACING`` metres of its
sides) must each lie inside some lanelet outline, or within ``TOL`` of one (seams between
lanelets whose shared bound is not vertex-identical).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_corners
from jaxplan.geometry.polygons import points_in_simple_polygon
from jaxplan.sim.metrics.overlap import car_boxes
from jaxplan.sim.metrics.registry import register_metric

SPACING = 0.5
TOL = 0.01


def outline_points(boxes, spacing: float = SPACING, length=4.5, width=1.8):
    """Points ``(..., P, 2)`` along the outlines of boxes ``(..., 5)`` (corners included)."""
    c = box_corners(boxes)  # (..., 4, 2)
    pts = []
    for i in range(4):
        a, b = c[..., i, :], c[..., (i + 1) % 4, :]
        side = length if i % 2 == 0 else width  # corners run FL, RL, RR, FR: edges 0 and 2 are the long sides
        n = max(1, int(-(-side // spacing)))
        u = jnp.arange(n, dtype=boxes.dtype) / n
        pts.append(a[..., None, :] + u[:, None] * (b - a)[..., None, :])
    return jnp.concatenate(pts, axis=-2)


def offroad_steps(log, scene, vehicle):
    """``(N,)`` bool: some outline point is off the drivable area at that step (within the drive)."""
    pts = outline_points(car_boxes(log, vehicle), SPACING, vehicle.length, vehicle.width)  # (N, P, 2)
    lo, hi = jnp.min(pts, axis=(0, 1)), jnp.max(pts, axis=(0, 1))

    def add(inside, poly):  # one lanelet at a time: memory (N, P, V), not (N, M, P, V)
        v, ok = poly
        big = 1e9
        plo = jnp.min(jnp.where(ok[:, None], v, big), axis=0)
        phi = jnp.max(jnp.where(ok[:, None], v, -big), axis=0)
        near = jnp.any(ok) & jnp.all(plo <= hi + TOL) & jnp.all(phi >= lo - TOL)
        here = jax.lax.cond(near, lambda: points_in_simple_polygon(pts, v, ok, TOL),
                            lambda: jnp.zeros(pts.shape[:-1], bool))
        return inside | here, None

    inside, _ = jax.lax.scan(add, jnp.zeros(pts.shape[:-1], bool), (scene.drivable, scene.drivable_valid))
    return ~jnp.all(inside, axis=-1) & log.valid


@register_metric("offroad")
def offroad(log, scene, vehicle):
    off = offroad_steps(log, scene, vehicle)
    k = jnp.argmax(off)
    return {"offroad": jnp.any(off), "first_step": jnp.where(jnp.any(off), k, -1), "steps": jnp.sum(off)}
