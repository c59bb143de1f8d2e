"""``goal``: the drive reaches its goal as CommonRoad defines it: at one step the car's
position (its box centre) is inside the goal region (any of its polygons; anywhere when
the goal has none), the time is inside the goal's interval, and the speed and heading are
inside their ranges where the goal gives them (the heading interval taken on the circle).

``off_map``: the goal has a region and no part of it touches the road: none of its polygons'
vertices, nor their centroids, lies inside a lanelet (some recorded scenes put the goal past
the map's end; a car cannot reach it without leaving the road). Such drives are shown apart.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.polygons import points_in_simple_polygon
from jaxplan.sim.metrics.registry import register_metric
from jaxplan.sim.metrics.road import in_drivable

TIME_EPS = 1e-3  # s: a time step on the interval's end counts as inside


def heading_in(theta, lo, hi):
    """Whether ``theta`` lies in the arc from ``lo`` to ``hi`` (counter-clockwise), ``(...)``."""
    two_pi = 2 * jnp.pi
    width = hi - lo
    d = jnp.mod(theta - lo, two_pi)
    return (width >= two_pi) | (d <= width + 1e-6) | (jnp.mod(theta - hi, two_pi) >= two_pi - 1e-6)


def goal_reached(goal, xy, heading, v, t):
    """Whether states ``(...)`` meet the goal: position ``xy (..., 2)`` (box centre), heading,
    speed and time ``(...)``."""
    poly_ok = jnp.any(goal.region_valid, axis=-1)  # (G,)
    inside = points_in_simple_polygon(xy[..., None, None, :], goal.region, goal.region_valid)[..., 0]  # (..., G)
    pos = ~goal.has_region | jnp.any(inside & poly_ok, axis=-1)
    tim = (t >= goal.time[0] - TIME_EPS) & (t <= goal.time[1] + TIME_EPS)
    spd = (v >= goal.speed[0] - 1e-6) & (v <= goal.speed[1] + 1e-6)
    hdg = ~goal.has_heading | heading_in(heading, goal.heading[0], goal.heading[1])
    return pos & tim & spd & hdg


def region_on_road(goal, scene):
    """``()`` bool: some vertex or centroid of the goal's polygons ``(G, W, 2)`` (mask
    ``goal.region_valid``) lies inside a lanelet outline of ``scene.drivable`` (``road.in_drivable``:
    each polygon's points against the lanelets nearest it)."""
    ok = goal.region_valid
    w = ok.astype(goal.region.dtype)
    centroid = jnp.sum(goal.region * w[..., None], -2) / jnp.maximum(jnp.sum(w, -1, keepdims=True), 1.0)  # (G, 2)
    pts = jnp.concatenate([goal.region, centroid[:, None]], 1)  # (G, W + 1, 2)
    pok = jnp.concatenate([ok, jnp.any(ok, -1, keepdims=True)], 1)
    # each polygon's points about its centroid (padding vertices repeat a valid one)
    pts = jnp.where(pok[..., None], pts, centroid[:, None])
    inside, _ = in_drivable(pts, scene)
    return jnp.any(inside & pok)


@register_metric("goal")
def goal(log, scene, vehicle):
    ok = goal_reached(scene.goal, jnp.stack([log.x, log.y], -1), log.heading, log.v, log.t) & log.valid
    k = jnp.argmax(ok)
    reached = jnp.any(ok)
    off_map = scene.goal.has_region & ~region_on_road(scene.goal, scene)
    return {
        "reached": reached,
        "step": jnp.where(reached, k, -1),
        "time": jnp.where(reached, log.t[k], jnp.inf),
        "off_map": off_map,
    }
