"""Blocking vs non-blocking obstacles, their decisions, and keep-clear road regions.

The car's band along the path (its width plus a buffer) and two strips of a configurable
width left and right of it are the regions (``st_boundary``); every obstacle is projected
to the path frame once per time, so the strips reach beside and behind the car (negative
stations) as well as ahead. An obstacle whose prediction enters the car's band at some
time is *blocking*, unless it is **behind**: squarely behind the car, as the verdict's fault
rule has it (``jaxplan.sim.metrics.overlap``): at the first time its centre comes within
the car's width of the path, that centre lies behind the car's even if the car braked at
``a_min`` from now (it would drive into the car; recorded traffic does not react, and such
a contact is the other road user's fault). Beyond ``lane_s``, where the path leaves the
car's lane, the car is the one moving over: the centre must be behind the car's rear bumper
there, and one that only grazes the band there is blocking (a car beside the path that the
path moves over to, coming up from behind, is one the car would merge in front of). An
obstacle that is not blocking (or is behind) and enters a side strip is *non-blocking*, and
gets decisions if it drives the car's way (faster than ``v_moving`` and, over its prediction,
moving along the path at least ``SAME_WAY_SHARE`` of its speed: an oncoming or crossing
vehicle has no blind zone beside the car and is not overtaken):

* ``no_bypass``: stay behind it (do not pass it), for neighbours on the configured
  no-overtake side (the left, where overtaking on the right is illegal) that are **ahead**
  of the car when they first come beside the path (its rear ahead of the car's front at
  the car's current speed): a neighbour the car is already beside or ahead of is no
  reason to brake;
* ``blind_zone``: do not stay alongside its blind zone (beside its rear), for every such
  neighbour.

An obstacle behind keeps its band boundary as ``rear``: the speed plan leaves it room (a
vehicle closing in from behind that will not brake is not waited for).

Keep-clear regions (a junction box, a crosswalk: convex polygons) project onto the path
as a station range where the car must not stop.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_corners
from jaxplan.geometry.polygons import has_overlap
from jaxplan.models.braking import braking_profile
from jaxplan.speed.path_profile import PathProfile
from jaxplan.speed.st_boundary import BIG, ObstaclesSL, STBoundary, car_extent, car_probes, strip_boundaries
from jaxplan.types import Obstacles, VehicleParams

LEFT, RIGHT, NONE = 1, -1, 0
SAME_WAY_SHARE = 0.5  # a neighbour drives the car's way when it moves along the path this share of its speed


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Classified:
    """Obstacles sorted into blocking / non-blocking, with decisions.

    Attributes:
        blocking: ``STBoundary`` ``(K, T)`` in the car's reference station (``hit`` False
            for obstacles that are not blocking, e.g. behind).
        side: ``STBoundary`` ``(K, T)`` road stations the obstacle covers in the side strip
            it was assigned to (union of left and right), non-blocking obstacles only.
        is_blocking, is_nonblocking, behind: ``(K,)`` bool (``behind``: it enters the car's
            band but behind the car, so it is ignored as blocking).
        side_of: ``(K,)`` int, +1 left, -1 right, 0 neither (or blocking).
        no_bypass, blind_zone: ``(K,)`` bool decisions.
        size: ``(K,)`` footprint area (m^2) of each obstacle.
        v_along: ``(K, T)`` speed of each obstacle along the path (m/s, from its centre's
            station over time).
        rear: ``STBoundary`` ``(K, T)``: the band boundary of the obstacles behind (``hit``
            only for those).
        same_way: ``(K,)`` bool: it drives the car's way (moving faster than ``v_moving``, along
            the path at least ``SAME_WAY_SHARE`` of its speed).
    """

    blocking: Any
    side: Any
    is_blocking: Any
    is_nonblocking: Any
    behind: Any
    side_of: Any
    no_bypass: Any
    blind_zone: Any
    size: Any
    v_along: Any
    rear: Any
    same_way: Any


def obstacle_speed(obstacles: Obstacles):
    """Mean speed ``(K,)`` of each obstacle over its valid consecutive stamps (0 if none)."""
    b, m, t = obstacles.boxes, obstacles.valid, obstacles.t
    d = jnp.linalg.norm(b[..., 1:, :2] - b[..., :-1, :2], axis=-1)
    ok = m[..., 1:] & m[..., :-1]
    dt = jnp.maximum(t[1:] - t[:-1], 1e-6)
    n = jnp.sum(ok * dt, -1)
    return jnp.where(n > 0, jnp.sum(jnp.where(ok, d, 0.0), -1) / jnp.maximum(n, 1e-6), 0.0)


def along_speed(osl: ObstaclesSL, t):
    """``(K, T)`` rate of each obstacle's centre station (m/s; 0 where not known)."""
    s = osl.centre[..., 0]
    ok = osl.valid[..., 1:] & osl.valid[..., :-1]
    r = jnp.where(ok, jnp.diff(s, axis=-1) / jnp.maximum(jnp.diff(t), 1e-6), 0.0)
    return jnp.concatenate([r, r[..., -1:]], -1)


def _first(hit):
    """Index ``(K,)`` of the first True along the last axis (0 where none)."""
    return jnp.argmax(hit, -1)


def classify(
    osl: ObstaclesSL,
    obstacles: Obstacles,
    vehicle: VehicleParams,
    t,
    v0=0.0,
    a_min=-5.0,
    lane_s=jnp.inf,
    *,
    side_width=3.5,
    buffer=0.0,
    no_overtake_side: int = LEFT,
    v_moving=1.0,
) -> Classified:
    """Blocking / non-blocking classification with decisions.

    Args:
        osl: obstacles in the path frame ``(K, T)``, stations relative to the car's
            reference point now; obstacles: the same obstacles (boxes ``(K, T, 5)``) for
            their speed and size; t: ``(T,)`` times from now.
        v0, a_min: the car's speed now and hardest braking (for the ``behind`` rule).
        lane_s: the station where the path leaves the car's lane (``SpeedRoad.lane_s``).
    """
    dtype = osl.corners.dtype
    t = jnp.asarray(t, dtype)
    blk, left, right = strip_boundaries(osl, vehicle, side_width, buffer)
    enters = jnp.any(blk.hit, -1)
    # squarely behind (the verdict's rule): judged when its centre first comes within the car's
    # width of the path; one that only grazes the band, when it first touches it
    aligned = blk.hit & (jnp.abs(osl.centre[..., 1]) <= 0.5 * vehicle.width)
    squarely = jnp.any(aligned, -1)
    f = jnp.where(squarely, _first(aligned), _first(blk.hit))
    at = lambda x: jnp.take_along_axis(x, f[:, None], -1)[:, 0]
    centre = 0.5 * (at(blk.lower) + at(blk.upper))
    # where the path has left the car's lane the car is the one moving over: its rear bumper, not
    # its reference point, must be ahead of the obstacle's centre
    moved = at(blk.upper) >= lane_s
    limit = braking_profile(jnp.asarray(v0, dtype), a_min, t[f])[0] - jnp.where(moved, 0.5 * vehicle.length, 0.0)
    behind = enters & (centre < limit) & (squarely | ~moved)
    is_blk = enters & ~behind
    rear = STBoundary(blk.lower, blk.upper, blk.hit & behind[:, None])
    blk = STBoundary(blk.lower, blk.upper, blk.hit & is_blk[:, None])
    nl, nr = jnp.sum(left.hit, -1), jnp.sum(right.hit, -1)
    is_nb = ~is_blk & ((nl + nr) > 0)
    side_of = jnp.where(is_nb, jnp.where(nl >= nr, LEFT, RIGHT), NONE)
    hit = left.hit | right.hit
    big = jnp.asarray(BIG, dtype)
    lo = jnp.minimum(jnp.where(left.hit, left.lower, big), jnp.where(right.hit, right.lower, big))
    hi = jnp.maximum(jnp.where(left.hit, left.upper, -big), jnp.where(right.hit, right.upper, -big))
    side = STBoundary(lo, hi, hit & is_nb[..., None])
    # decisions are for neighbours driving the car's way (an oncoming or crossing vehicle has no
    # blind zone beside the car and is not overtaken): moving, mostly along the path
    speed = obstacle_speed(obstacles)
    along = along_speed(osl, t)
    n_ok = jnp.maximum(jnp.sum(osl.valid, -1), 1)
    same_way = jnp.sum(jnp.where(osl.valid, along, 0.0), -1) / n_ok > SAME_WAY_SHARE * speed
    moving = (speed > v_moving) & same_way
    front, _ = car_extent(vehicle, dtype)
    fs = _first(side.hit)
    rear_first = jnp.take_along_axis(side.lower, fs[:, None], -1)[:, 0]
    ahead = rear_first > jnp.asarray(v0, dtype) * t[fs] + front
    no_bypass = is_nb & moving & (side_of == no_overtake_side) & ahead
    blind = is_nb & moving
    b0 = jnp.max(jnp.where(obstacles.valid[..., None], obstacles.boxes, 0.0), axis=-2)
    size = b0[..., 2] * b0[..., 3]
    return Classified(blk, side, is_blk, is_nb, behind, side_of, no_bypass, blind, size, along, rear, moving)


def keep_clear_intervals(profile: PathProfile, vehicle: VehicleParams, vertices, valid=None, active=None):
    """Station range where the car on the path overlaps each keep-clear polygon.

    Args:
        vertices: ``(R, P, 2)`` convex CCW polygons; valid ``(R, P)``; active ``(R,)``.

    Returns:
        (lower ``(R,)``, upper ``(R,)``, hit ``(R,)``) in the car's reference station.
    """
    corners = box_corners(car_probes(profile, vehicle))  # (N, 4, 2)
    vertices = jnp.asarray(vertices, corners.dtype)
    if valid is None:
        valid = jnp.ones(vertices.shape[:-1], bool)
    hits = has_overlap(corners, vertices[:, None], None, valid[:, None])  # (R, N)
    if active is not None:
        hits = hits & jnp.asarray(active)[:, None]
    big = jnp.asarray(BIG, profile.s.dtype)
    lower = jnp.min(jnp.where(hits, profile.s, big), -1)
    upper = jnp.max(jnp.where(hits, profile.s, -big), -1)
    return lower, upper, jnp.any(hits, -1)
