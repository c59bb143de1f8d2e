"""ST boundaries: where (in station s) an obstacle occupies a band along the path, per time.

Every obstacle is projected to the path's Frenet frame **once per time** (its centre with
the geometry core's ``frenet_points``, its corners about the centre at its heading relative to
the path, onto the arc of the path's curvature there: ``arc_frame``), not once per station. A band is a strip ``l_lo <= l <= l_hi`` of the
path frame; the station range of the obstacle inside the band is the exact extent of the
convex quadrilateral clipped to the strip (its corners inside the strip and its edges'
crossings of the strip's sides), so on a straight path it equals the range of car positions
whose footprint overlaps the obstacle (the brute-force ``station_intervals`` with one car box
per station, kept here as the reference). On a curved path the corners' offset from the
tangent (``kappa u^2 / 2`` at ``u`` metres from the reference point) widens the car's band
on the outside of the curve (``curvature_margin``).

Conventions: a *blocking* boundary ``[lower, upper]`` is in the station of the car's
reference point (the car at station x overlaps the obstacle iff ``lower <= x <= upper``);
a *side* boundary is in road stations (the neighbour's rear and front inside the strip).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_has_overlap, poses_to_boxes
from jaxplan.geometry.frenet import ReferenceLine, frenet_points, wrap_angle
from jaxplan.speed.path_profile import PathProfile
from jaxplan.types import Obstacles, VehicleParams

BIG = 1e9


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


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ObstaclesSL:
    """Obstacles in the path's Frenet frame.

    Attributes:
        corners: ``(..., K, T, 4, 2)`` corner ``(s, l)`` (s from the path's start).
        centre: ``(..., K, T, 2)`` centre ``(s, l)``.
        kappa: ``(..., K, T)`` path curvature at the centre's station.
        valid: ``(..., K, T)``.
    """

    corners: Any
    centre: Any
    kappa: Any
    valid: Any


def arc_frame(a, y, kappa):
    """Frenet coordinates ``(ds, l)`` (each ``(...)``) of points at ``(a, y)`` in the tangent frame
    of a path point (``a`` along the tangent from that point, ``y`` to its left) when the path is
    the arc of curvature ``kappa`` through it: ``ds = atan2(|k| a, 1 - k y) / |k|`` along the arc,
    ``l = (2 y - k (y^2 + a^2)) / (1 + |k| rho)`` (``rho`` the distance to the arc's centre), the
    point's exact offset from the arc in a cancellation-free form; ``(a, y)`` on a straight path."""
    k = jnp.asarray(kappa, a.dtype)
    ak = jnp.abs(k)
    one = 1.0 - k * y
    rho_k = jnp.sqrt((ak * a) ** 2 + one**2)
    l = (2.0 * y - k * (y * y + a * a)) / (1.0 + rho_k)
    x = ak * a
    small = jnp.abs(x) < 1e-4
    # (a point beyond the arc's centre, one <= 0, has no Frenet coordinates; kept finite)
    ds = jnp.where(
        small, a / jnp.maximum(one, 1e-6), jnp.arctan2(jnp.where(small, 1.0, x), one) / jnp.where(small, 1.0, ak)
    )
    return ds, l


def project_obstacles(ref: ReferenceLine, obstacles: Obstacles, s_offset=None) -> ObstaclesSL:
    """Project obstacle boxes ``(K, T, 5)`` to the path frame (one projection per box,
    ``frenet_points``).

    Beyond the path's ends the frame continues straight (``to_frenet``), so obstacles
    behind the car get negative stations. ``s_offset``: optional station subtracted from
    every station (stations relative to it, e.g. the car's).
    """
    b = obstacles.boxes
    s, l, th, kap = frenet_points(ref, b[..., 0], b[..., 1])
    d = wrap_angle(b[..., 4] - th)
    c, sn = jnp.cos(d), jnp.sin(d)
    signs = jnp.asarray(((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)), b.dtype)
    du = 0.5 * b[..., 2:3] * signs[:, 0]  # (K, T, 4) along the obstacle
    dw = 0.5 * b[..., 3:4] * signs[:, 1]
    # the corners in the tangent frame at the centre's foot point, then onto the arc of the path's
    # curvature there (``arc_frame``): a long box beside a curve bends towards the path on its inside
    ca, cl = arc_frame(
        c[..., None] * du - sn[..., None] * dw, l[..., None] + sn[..., None] * du + c[..., None] * dw, kap[..., None]
    )
    cs = s[..., None] + ca
    if s_offset is not None:  # before stacking: no elementwise pass over the stacked corners
        cs, s = cs - s_offset, s - s_offset
    return ObstaclesSL(jnp.stack([cs, cl], -1), jnp.stack([s, l], -1), kap, obstacles.valid)


def strip_extent(corners, l_lo, l_hi):
    """Station extent of convex quadrilaterals clipped to the strip ``l_lo <= l <= l_hi``.

    Args:
        corners: ``(..., 4, 2)`` ``(s, l)`` vertices in order (either orientation).
        l_lo, l_hi: ``(...)`` the strip (broadcast).

    Returns:
        (s_min ``(...)``, s_max ``(...)``, hit ``(...)``); s_min / s_max are
        ``+BIG`` / ``-BIG`` without a hit.
    """
    return _strip_extent([corners[..., c, 0] for c in range(4)], [corners[..., c, 1] for c in range(4)], l_lo, l_hi)


def _strip_extent(s, l, l_lo, l_hi):
    """``strip_extent`` of corners given as 4 station and 4 offset arrays ``(...)``."""
    lo, hi = jnp.asarray(l_lo), jnp.asarray(l_hi)
    big = jnp.asarray(BIG, s[0].dtype)
    s_min = s_max = hit = None

    def add(cand, ok):  # the candidates one by one: no reduction over a small trailing axis
        nonlocal s_min, s_max, hit
        a, b = jnp.where(ok, cand, big), jnp.where(ok, cand, -big)
        s_min, s_max, hit = (a, b, ok) if hit is None else (jnp.minimum(s_min, a), jnp.maximum(s_max, b), hit | ok)

    for c in range(4):  # corners inside the strip
        add(s[c], (l[c] >= lo) & (l[c] <= hi))
    for line in (lo, hi):  # edges c -> c + 1 crossing the strip's sides
        for c in range(4):
            n = (c + 1) % 4
            den = l[n] - l[c]
            big_den = jnp.abs(den) > 1e-12
            u = (line - l[c]) / jnp.where(big_den, den, 1.0)
            add(s[c] + u * (s[n] - s[c]), big_den & (u >= 0.0) & (u <= 1.0))
    return s_min, s_max, hit


def car_extent(vehicle: VehicleParams, dtype=jnp.float32):
    """(front, rear): the car's front and rear ahead of its reference point (m; rear < 0)."""
    return jnp.asarray(vehicle.front_offset, dtype), jnp.asarray(vehicle.rear_offset, dtype)


def curvature_margin(kappa, vehicle: VehicleParams):
    """Lateral widening ``(...)`` of the car's band on a path of curvature ``kappa``: the
    farthest body point from the reference point leaves the tangent by ``|kappa| u^2 / 2``,
    on the outside of the curve (the tangent lies outside the arc on both sides of the
    reference point)."""
    front, rear = car_extent(vehicle, kappa.dtype)
    u = jnp.maximum(front, -rear)
    return 0.5 * jnp.abs(kappa) * u * u


def _band(osl: ObstaclesSL, vehicle: VehicleParams, buffer) -> tuple:
    """Offsets ``(l_lo, l_hi)`` ``(K, T)`` of the car's band along the path: ``width / 2 +
    buffer`` on either side, and on the outside of the curve (the right side in a left turn,
    ``kappa > 0``) ``curvature_margin`` and the bow of the obstacle's straight edges towards the
    path there (``|kappa| (d / 2)^2 / 2`` for an edge spanning ``d`` stations; its corners are on
    the arc's frame, ``arc_frame``, its edges are straight)."""
    half = 0.5 * jnp.asarray(vehicle.width, osl.corners.dtype) + buffer
    span = jnp.max(osl.corners[..., 0], -1) - jnp.min(osl.corners[..., 0], -1)
    m = curvature_margin(osl.kappa, vehicle) + 0.125 * jnp.abs(osl.kappa) * span * span
    return -half - jnp.where(osl.kappa > 0, m, 0.0), half + jnp.where(osl.kappa < 0, m, 0.0)


def _side_strip(band: tuple, width, side: int) -> tuple:
    """Offsets ``(l_lo, l_hi)`` of the strip of ``width`` beside the car's ``band`` (``side`` +1
    left, -1 right), from the band's edge outwards."""
    lo, hi = band
    return (hi, hi + width) if side > 0 else (lo - width, lo)


def _blocking(osl: ObstaclesSL, vehicle: VehicleParams, buffer, lo, hi, hit) -> STBoundary:
    """The obstacles' range ``(K, T)`` in the car's band as a blocking boundary: extended by the
    car's front / rear (on a curve as far as its corners on the inside reach along the path,
    ``1 / (1 - |kappa| half_width)`` times further) and ``buffer`` (reference stations), valid
    steps only."""
    f = osl.corners.dtype
    front, rear = car_extent(vehicle, f)
    half = 0.5 * jnp.asarray(vehicle.width, f) + buffer
    stretch = 1.0 / jnp.maximum(1.0 - jnp.abs(osl.kappa) * half, 0.5)
    return STBoundary(lo - front * stretch - buffer, hi - rear * stretch + buffer, hit & osl.valid)


def strip_boundaries(osl: ObstaclesSL, vehicle: VehicleParams, side_width, buffer=0.0) -> tuple:
    """``blocking_boundaries`` and the left and right ``side_boundaries`` (strips of
    ``side_width``), ``STBoundary (K, T)`` each, as one ``scan`` over the three strips: the
    corners are split into components once and read by every strip (inlined, XLA would
    recompute the projection's trigonometry in each strip's elementwise fusions).

    Returns:
        (blocking, left, right).
    """
    band = _band(osl, vehicle, buffer)
    bands = (band, _side_strip(band, side_width, 1), _side_strip(band, side_width, -1))
    strips = tuple(jnp.stack(b) for b in zip(*bands))  # (l_lo, l_hi), each (3, T): blocking, left, right
    comps = jnp.stack([osl.corners[..., c, i] for i in range(2) for c in range(4)])  # (8, K, T) contiguous
    _, (lo, hi, hit) = jax.lax.scan(lambda _, b: (None, _strip_extent(comps[:4], comps[4:], b[0], b[1])), None, strips)
    return (
        _blocking(osl, vehicle, buffer, lo[0], hi[0], hit[0]),
        STBoundary(lo[1], hi[1], hit[1] & osl.valid),
        STBoundary(lo[2], hi[2], hit[2] & osl.valid),
    )


def blocking_boundaries(osl: ObstaclesSL, vehicle: VehicleParams, buffer=0.0) -> STBoundary:
    """ST boundaries ``(K, T)`` of obstacles against the car driving the path (reference stations).

    The car's band is ``|l| <= width / 2 + buffer`` (plus ``curvature_margin`` on the outside of
    the curve, ``_band``); the obstacle's range in it is extended by the car's front / rear and
    ``buffer``.
    """
    return _blocking(osl, vehicle, buffer, *strip_extent(osl.corners, *_band(osl, vehicle, buffer)))


def side_boundaries(osl: ObstaclesSL, vehicle: VehicleParams, width, side: int, buffer=0.0) -> STBoundary:
    """Road-station range ``(K, T)`` of each obstacle inside the strip of ``width`` beside the
    car's band (``side`` +1 left, -1 right), from the band's edge outwards."""
    lo, hi, hit = strip_extent(osl.corners, *_side_strip(_band(osl, vehicle, buffer), width, side))
    return STBoundary(lo, hi, hit & osl.valid)


# ---------------------------------------------------------------- brute-force reference


def station_intervals(probes, stations, obstacles: Obstacles, buffer=0.0) -> STBoundary:
    """Station range of the probes each obstacle overlaps, per time (one box test per
    station and time: the brute-force reference of the projected boundaries).

    Args:
        probes: ``(N, 5)`` one box per station.
        stations: ``(N,)`` increasing stations of the probes.
        obstacles: boxes ``(K, T, 5)``, valid ``(K, T)``.
        buffer: extra clearance (m) added around the obstacles.

    Returns:
        ``STBoundary`` with fields ``(K, T)``.
    """
    ob = obstacles.boxes.at[..., 2:4].add(2.0 * buffer)
    hits = box_has_overlap(probes, ob[..., None, :]) & obstacles.valid[..., None]  # (K, T, N)
    big = jnp.asarray(BIG, stations.dtype)
    lower = jnp.min(jnp.where(hits, stations, big), axis=-1)
    upper = jnp.max(jnp.where(hits, stations, -big), axis=-1)
    return STBoundary(lower, upper, jnp.any(hits, axis=-1))


def car_probes(profile: PathProfile, vehicle: VehicleParams):
    """The car's box ``(N, 5)`` with its reference point at each station of the path."""
    return poses_to_boxes(profile.xy, profile.theta, vehicle)
