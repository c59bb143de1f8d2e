"""The ST graph of one speed plan (``SpeedScene``): the path sampled on the DP's station
grid, the obstacles projected onto it and classified (blocking, non-blocking), a wall before
the road's stop, keep-clear regions, and the speed limit along the path made an envelope the
DP's knots cannot step over."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.plan_context import curvature_speed
from jaxplan.speed.nonblocking import classify, keep_clear_intervals
from jaxplan.speed.path_profile import PathProfile, path_profile, resample_obstacles
from jaxplan.speed.problem import SpeedConfig, SpeedRoad, SpeedScene
from jaxplan.speed.st_boundary import BIG, STBoundary, car_extent, project_obstacles
from jaxplan.types import Obstacles, VehicleParams


def speed_envelope(v_lim, ds, decel, accel):
    """The speed limit ``v_lim (N,)`` on stations ``i ds`` lowered to what a car that meets it
    everywhere can drive: ``v(s) <= sqrt(v_lim(s')^2 + 2 decel (s' - s))`` for every ``s' > s``
    (braking into a slow stretch) and ``sqrt(v_lim(s')^2 + 2 accel (s - s'))`` for ``s' < s``
    (accelerating out of it); min-plus scans on ``v^2``."""
    w = jnp.square(v_lim)
    i = jnp.arange(w.shape[-1], dtype=w.dtype)
    cb, ca = 2.0 * decel * ds, 2.0 * accel * ds
    w = jnp.minimum(w, jax.lax.cummin(w + cb * i, reverse=True) - cb * i)
    w = jnp.minimum(w, jax.lax.cummin(w - ca * i) + ca * i)
    return jnp.sqrt(jnp.maximum(w, 0.0))


def time_margin(b: STBoundary, m: int, which=None) -> STBoundary:
    """Each boundary ``(K, F)`` at check time ``f`` widened to its union over ``f .. f + m``:
    passing ahead of an obstacle must clear where it will be ``m`` check times later (a
    crossing car is passed with a time margin, not by a hair); following behind one that
    drives on is unchanged. ``which (K,)``: the obstacles widened (default all)."""
    if m <= 0:
        return b
    big = jnp.asarray(BIG, b.lower.dtype)
    lo, hi, hit = jnp.where(b.hit, b.lower, big), jnp.where(b.hit, b.upper, -big), b.hit
    # one windowed min / max over f .. f + m (the identity as padding past the last check time)
    win = lambda a, init, op: jax.lax.reduce_window(
        a, init, op, (1,) * (a.ndim - 1) + (m + 1,), (1,) * a.ndim, [(0, 0)] * (a.ndim - 1) + [(0, m)]
    )
    inf = jnp.asarray(jnp.inf, lo.dtype)
    L, H = win(lo, inf, jax.lax.min), win(hi, -inf, jax.lax.max)
    X = win(hit.astype(jnp.int32), jnp.asarray(np.iinfo(np.int32).min, jnp.int32), jax.lax.max) > 0
    if which is not None:
        X = jnp.where(which[..., None], X, hit)
        L, H = jnp.where(which[..., None], L, b.lower), jnp.where(which[..., None], H, b.upper)
    return STBoundary(jnp.where(X, L, b.lower), jnp.where(X, H, b.upper), X)


def build_speed_scene(
    profile: PathProfile,
    obstacles: Obstacles,
    vehicle: VehicleParams,
    config: SpeedConfig,
    keep_clear=None,
    v0=0.0,
    road: SpeedRoad | None = None,
    buffer=None,
    merging=None,
    margin=None,
) -> SpeedScene:
    """Resample obstacles to the check times, project them to the path once per time,
    classify them, project keep-clear regions, sample the speed limit.

    Args:
        profile: the path on ``config.n_s`` stations ``s0 + i ds`` (its ``ref`` is the path).
        obstacles: boxes ``(K, T, 5)`` with their own times (from 0 = now).
        keep_clear: optional ``(vertices (R, P, 2), valid (R, P), active (R,))``.
        v0: the car's speed (the ``behind`` rule).
        road: ``SpeedRoad`` or None (no limit but curvature and ``v_max``, no stop, no goal).
        buffer: ``()`` the clearance around obstacles and before a stop (m), traced; None:
            ``config.buffer``.
        merging: ``(K,)`` bool, the obstacles moving over into the car's lane
            (``jaxplan.speed.paths.merging_in``); None: none.
        margin: ``()`` bool, traced: blocking boundaries keep ``config.pass_margin`` (None: True;
            False: the plain overlap, for a plan without the comfort clearances).
    """
    if merging is not None and jnp.shape(merging) != obstacles.valid.shape[:1]:
        raise ValueError(
            f"build_speed_scene: merging has shape {jnp.shape(merging)}; one flag per obstacle, "
            f"{obstacles.valid.shape[:1]}, expected"
        )
    if margin is not None and jnp.ndim(margin) != 0:
        raise ValueError(f"build_speed_scene: margin has shape {jnp.shape(margin)}; one flag, (), expected")
    dtype = profile.s.dtype
    road = SpeedRoad.free(dtype) if road is None else road
    buffer = config.buffer if buffer is None else buffer
    tf = jnp.asarray(config.fine_times(), dtype)
    obs = resample_obstacles(obstacles, tf)
    s0 = profile.s[0]
    osl = project_obstacles(profile.ref, obs, s0)  # stations relative to the car now
    c = classify(
        osl,
        obs,
        vehicle,
        tf,
        v0,
        config.a_min,
        lane_s=road.lane_s,
        side_width=config.side_width,
        buffer=buffer,
        no_overtake_side=config.no_overtake_side,
        v_moving=config.v_moving,
    )
    held = int(round(config.pass_margin * config.n_sub / config.dt))  # check times in pass_margin
    # a vehicle driving the car's way that moves over into the car's lane is passed when the car is
    # ahead of it (it follows, then); the margin is for crossing and oncoming traffic, and for a
    # vehicle whose lane the car moves over to (it may not brake for the car)
    which = None if merging is None else ~(c.same_way & jnp.asarray(merging, bool))
    if margin is not None:  # a plan without the comfort clearances: the plain overlap
        keep = jnp.broadcast_to(jnp.asarray(margin, bool), c.same_way.shape)
        which = keep if which is None else keep & which
    c = dataclasses.replace(c, blocking=time_margin(c.blocking, held, which))
    front, rear = car_extent(vehicle, dtype)
    stop = jnp.asarray(road.stop_s, dtype)
    has = jnp.isfinite(stop)
    F = tf.shape[0]
    wall = STBoundary(
        jnp.full((1, F), jnp.where(has, stop - front - buffer, BIG), dtype),
        jnp.full((1, F), BIG, dtype),
        jnp.full((1, F), has),
    )
    if keep_clear is None:
        lo = hi = jnp.zeros((1,), dtype)
        hit = jnp.zeros((1,), bool)
    else:
        lo, hi, hit = keep_clear_intervals(profile, vehicle, *keep_clear)
        lo, hi = lo - s0, hi - s0
    lane = jnp.interp(
        profile.s - s0, jnp.asarray(road.limit_s, dtype), jnp.minimum(jnp.asarray(road.limit_v, dtype), 1e3)
    )
    curve = curvature_speed(profile.kappa, config.a_lat_max)
    v_limit = speed_envelope(
        jnp.minimum(jnp.minimum(lane, curve), config.v_max), config.ds, config.b_comfort, config.a_max
    )
    return SpeedScene(
        c,
        wall,
        lo,
        hi,
        hit,
        v_limit,
        jnp.asarray(road.goal_s, dtype),
        jnp.asarray(road.goal_t, dtype),
        jnp.asarray(road.goal_v, dtype),
        front,
        rear,
    )


def make_scene(
    path: ReferenceLine,
    obstacles: Obstacles,
    config: SpeedConfig,
    vehicle=None,
    s0=0.0,
    keep_clear=None,
    v0=0.0,
    road=None,
    buffer=None,
    merging=None,
    margin=None,
) -> tuple[PathProfile, SpeedScene]:
    """Path profile on the DP station grid and the scene boundaries (``buffer``, ``merging``,
    ``margin``: as ``build_speed_scene``'s)."""
    vehicle = VehicleParams() if vehicle is None else vehicle
    profile = path_profile(path, s0, config.n_s, config.ds)
    return profile, build_speed_scene(
        profile, obstacles, vehicle, config, keep_clear, v0, road, buffer, merging, margin
    )
