"""ST boundaries: where (in station s) an obstacle occupies a band along the path, per time.

A *probe* is a box per station (the car's footprint for blocking obstacles, a
strip beside the path for non-blocking ones). An obstacle's boundary at time t
is the range ``[lower, upper]`` of probe stations whose box overlaps the
obstacle's box at t (geometry core, ``box_has_overlap``); ``hit`` says whether
there is any. Static obstacles repeat their box, so they span all t.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_has_overlap, poses_to_boxes
from jaxplan.speed.path_profile import PathProfile
from jaxplan.types import Obstacles, VehicleParams


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class STBoundary:
    """Per-obstacle station ranges over time.

    Attributes:
        lower, upper: ``(..., K, T)`` first and last station of the range
            (meaningless where ``hit`` is False).
        hit: ``(..., K, T)`` bool, the obstacle touches the band at time t.
    """

    lower: Any
    upper: Any
    hit: Any


def inflate(boxes, buffer):
    """Boxes ``(..., 5)`` grown by ``buffer`` metres on every side."""
    return boxes.at[..., 2:4].add(2.0 * buffer)


def station_intervals(probes, stations, obstacles: Obstacles, buffer=0.0) -> STBoundary:
    """Station range of the probes each obstacle overlaps, per time.

    Args:
        probes: ``(N, 5)`` one box per station.
        stations: ``(N,)`` increasing stations of the probes.
        obstacles: boxes ``(K, T, 5)``, valid ``(K, T)``.
        buffer: extra clearance (m) added around the obstacles.

    Returns:
        ``STBoundary`` with fields ``(K, T)``.
    """
    ob = inflate(obstacles.boxes, buffer)
    hits = box_has_overlap(probes, ob[..., None, :]) & obstacles.valid[..., None]  # (K, T, N)
    big = jnp.asarray(1e9, stations.dtype)
    lower = jnp.min(jnp.where(hits, stations, big), axis=-1)
    upper = jnp.max(jnp.where(hits, stations, -big), axis=-1)
    return STBoundary(lower, upper, jnp.any(hits, axis=-1))


def car_probes(profile: PathProfile, vehicle: VehicleParams):
    """The car's box ``(N, 5)`` with its reference point at each station of the path."""
    return poses_to_boxes(profile.xy, profile.theta, vehicle)


def blocking_boundaries(profile: PathProfile, obstacles: Obstacles, vehicle: VehicleParams,
                        buffer=0.0) -> STBoundary:
    """ST boundaries of obstacles against the car driving the path.

    ``lower <= s <= upper`` (station of the car's reference point) is where the
    car, placed on the path at station s, overlaps the obstacle at time t.

    Args:
        profile: path on N stations; obstacles: boxes ``(K, T, 5)`` at the plan's times.

    Returns:
        ``STBoundary`` ``(K, T)``.
    """
    return station_intervals(car_probes(profile, vehicle), profile.s, obstacles, buffer)
