"""Points on the road: the lanelet outlines (``Scene.drivable``) near a group of points, and the
points of the group that lie inside one of them (the off-road and goal metrics use it)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.geometry.polygons import points_in_simple_polygon

TOL = 0.05  # m: the referee's ROAD_TOL (map seams up to 10 cm wide are road)

NEAR_LANELETS = 16  # lanelets a group of points is tested against (the nearest by bounding box)


def lanelet_boxes(scene):
    """``(M, 2), (M, 2)``: the lower and upper corners of every lanelet outline's bounding box
    (empty outlines: an inverted box that no point is near)."""
    v, ok = scene.drivable, scene.drivable_valid
    big = 1e9
    return (jnp.min(jnp.where(ok[..., None], v, big), axis=-2), jnp.max(jnp.where(ok[..., None], v, -big), axis=-2))


def in_drivable(pts, scene):
    """``(G, P)`` bool, ``()`` int: whether points ``(G, P, 2)`` lie inside some lanelet of ``scene.drivable``
    (within ``TOL``), and how many lanelets went untested.

    Each group of ``P`` points (e.g. a box's outline at one step) is tested against the
    ``NEAR_LANELETS`` lanelets whose bounding boxes are nearest the group's centre; a lanelet that
    holds one of the points lies within the group's radius of its centre, so only when more than
    ``NEAR_LANELETS`` do is one left out (the count returned, 0 normally).
    """
    lo, hi = lanelet_boxes(scene)  # (M, 2)
    centre = jnp.mean(pts, axis=-2)  # (G, 2)
    radius = jnp.max(jnp.linalg.norm(pts - centre[:, None], axis=-1), axis=-1) + TOL  # (G,)
    gap = jnp.linalg.norm(
        jnp.maximum(jnp.maximum(lo[None] - centre[:, None], centre[:, None] - hi[None]), 0.0), axis=-1
    )  # (G, M) distance from the centre to each bounding box
    reach = gap <= radius[:, None]
    L = min(NEAR_LANELETS, lo.shape[0])
    neg, idx = jax.lax.top_k(-gap, L)  # (G, L) the nearest
    use = -neg <= radius[:, None]
    poly, ok = scene.drivable[idx], scene.drivable_valid[idx] & use[..., None]  # (G, L, V, 2), (G, L, V)
    inside = points_in_simple_polygon(pts[:, None], poly, ok, TOL)  # (G, L, P)
    return jnp.any(inside, axis=1), jnp.maximum(jnp.sum(reach) - jnp.sum(use), 0)
