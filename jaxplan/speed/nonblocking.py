"""Blocking vs non-blocking obstacles, their decisions, and keep-clear road regions.

Regions of a configurable width are projected outward from the left and right
of the first trajectory (the car's footprint driven along the path). An obstacle
whose prediction overlaps the footprint at some time is *blocking*; one that
overlaps only a side region is *non-blocking*, and gets a decision:

* ``no_bypass``: stay behind it (do not pass it), for moving neighbours on the
  configured no-overtake side (the left, where overtaking on the right is illegal);
* ``blind_zone``: do not stay alongside its blind zone (beside its rear), for
  every moving neighbour.

Keep-clear regions (a junction box, a crosswalk: convex polygons) project onto
the path as a station range where the car must not stop.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_corners
from jaxplan.geometry.polygons import has_overlap
from jaxplan.speed.path_profile import PathProfile
from jaxplan.speed.st_boundary import STBoundary, blocking_boundaries, car_probes, station_intervals
from jaxplan.types import Obstacles, VehicleParams

LEFT, RIGHT, NONE = 1, -1, 0


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Classified:
    """Obstacles sorted into blocking / non-blocking, with decisions.

    Attributes:
        blocking: ``STBoundary`` ``(K, T)`` in the car's reference station.
        side: ``STBoundary`` ``(K, T)`` road stations the obstacle covers in the
            side region it was assigned to (union of left and right).
        is_blocking, is_nonblocking: ``(K,)`` bool.
        side_of: ``(K,)`` int, +1 left, -1 right, 0 neither (or blocking).
        no_bypass, blind_zone: ``(K,)`` bool decisions.
        size: ``(K,)`` footprint area (m^2) of each obstacle.
    """

    blocking: Any
    side: Any
    is_blocking: Any
    is_nonblocking: Any
    side_of: Any
    no_bypass: Any
    blind_zone: Any
    size: Any


def side_probes(profile: PathProfile, vehicle: VehicleParams, width, side: int):
    """Strips ``(N, 5)`` of ``width`` beside the car's footprint, one per station.

    A strip is centred on the station (the car's reference point moved sideways),
    one station step long and ``width`` wide; ``side`` +1 left, -1 right.
    """
    ds = profile.s[1] - profile.s[0]
    off = side * (0.5 * vehicle.width + 0.5 * width)
    nx, ny = -jnp.sin(profile.theta), jnp.cos(profile.theta)
    cx = profile.xy[..., 0] + off * nx
    cy = profile.xy[..., 1] + off * ny
    one = jnp.ones_like(cx)
    return jnp.stack([cx, cy, one * ds * 1.001, one * width, profile.theta], -1)


def obstacle_speed(obstacles: Obstacles):
    """Mean speed ``(K,)`` of each obstacle over its valid consecutive stamps (0 if none)."""
    b, m, t = obstacles.boxes, obstacles.valid, obstacles.t
    d = jnp.linalg.norm(b[..., 1:, :2] - b[..., :-1, :2], axis=-1)
    ok = m[..., 1:] & m[..., :-1]
    dt = jnp.maximum(t[1:] - t[:-1], 1e-6)
    n = jnp.sum(ok * dt, -1)
    return jnp.where(n > 0, jnp.sum(jnp.where(ok, d, 0.0), -1) / jnp.maximum(n, 1e-6), 0.0)


def classify(profile: PathProfile, obstacles: Obstacles, vehicle: VehicleParams, *,
             side_width=3.5, buffer=0.0, no_overtake_side: int = LEFT, v_moving=1.0) -> Classified:
    """Blocking / non-blocking classification with decisions. Obstacles ``(K, T, 5)``."""
    blk = blocking_boundaries(profile, obstacles, vehicle, buffer)
    left = station_intervals(side_probes(profile, vehicle, side_width, LEFT), profile.s, obstacles)
    right = station_intervals(side_probes(profile, vehicle, side_width, RIGHT), profile.s, obstacles)
    is_blk = jnp.any(blk.hit, -1)
    nl, nr = jnp.sum(left.hit, -1), jnp.sum(right.hit, -1)
    is_nb = ~is_blk & ((nl + nr) > 0)
    side_of = jnp.where(is_nb, jnp.where(nl >= nr, LEFT, RIGHT), NONE)
    hit = left.hit | right.hit
    big = jnp.asarray(1e9, profile.s.dtype)
    lo = jnp.minimum(jnp.where(left.hit, left.lower, big), jnp.where(right.hit, right.lower, big))
    hi = jnp.maximum(jnp.where(left.hit, left.upper, -big), jnp.where(right.hit, right.upper, -big))
    side = STBoundary(lo, hi, hit & is_nb[..., None])
    moving = obstacle_speed(obstacles) > v_moving
    no_bypass = is_nb & moving & (side_of == no_overtake_side)
    blind = is_nb & moving
    b0 = jnp.max(jnp.where(obstacles.valid[..., None], obstacles.boxes, 0.0), axis=-2)
    size = b0[..., 2] * b0[..., 3]
    return Classified(blk, side, is_blk, is_nb, side_of, no_bypass, blind, size)


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
    big = jnp.asarray(1e9, profile.s.dtype)
    lower = jnp.min(jnp.where(hits, profile.s, big), -1)
    upper = jnp.max(jnp.where(hits, profile.s, -big), -1)
    return lower, upper, jnp.any(hits, -1)
