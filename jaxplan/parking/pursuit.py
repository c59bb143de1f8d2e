"""Pure-pursuit rollout of a kinematic bicycle along a reference curve (``lax.scan``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.parking.circles import Curve, _advance, curve_point
from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.grid import to_frame


class Rollout(NamedTuple):
    """One maneuver: ``T = config.steps`` points, valid ones first.

    Attributes:
        poses: ``(..., T, 3)`` rear-axle [x, y, heading] in the initial frame;
            point 0 is the start pose. Points after the last valid one repeat it.
        gear: ``(..., T)`` +1 forward, -1 backward.
        steer: ``(..., T)`` front steering angle applied when leaving each point.
        s: ``(..., T)`` signed arc length driven from point 0.
        valid: ``(..., T)`` bool; the trajectory up to its end, cut before the
            first pose whose footprint collides.
        length: ``(...)`` unsigned length of the valid part.
        complete: ``(...)`` the valid part reaches the curve's goal.
        cut: ``(...)`` the trajectory was cut at a collision.
    """

    poses: jnp.ndarray
    gear: jnp.ndarray
    steer: jnp.ndarray
    s: jnp.ndarray
    valid: jnp.ndarray
    length: jnp.ndarray
    complete: jnp.ndarray
    cut: jnp.ndarray

    def to_trajectory(self, vehicle, speed=1.0):
        """As a ``jaxplan.types.Trajectory`` at constant ``speed`` (invalid points keep the end pose).

        ``kappa = tan(steer) / wheelbase``, ``v = gear * speed``, ``t = |s| / speed``.
        """
        from jaxplan.types import Trajectory

        p = jnp.where(self.valid[..., None], self.poses, self.end_pose[..., None, :])
        kappa = jnp.tan(self.steer) / vehicle.wheelbase
        z = jnp.zeros_like(self.s)
        return Trajectory(
            x=p[..., 0],
            y=p[..., 1],
            theta=p[..., 2],
            kappa=kappa,
            v=self.gear * speed,
            a=z,
            t=jnp.abs(self.s) / speed,
            s=self.s,
            gear=self.gear,
        )

    @property
    def end_pose(self):
        """``(..., 3)``: the last valid pose (the start pose if none is valid)."""
        n = jnp.sum(self.valid, -1)
        i = jnp.maximum(n - 1, 0)
        return jnp.take_along_axis(self.poses, i[..., None, None], axis=-2)[..., 0, :]


def pursuit_steer(pose, target, vehicle):
    """Steering angle whose circle runs through the rear axle (tangent to the body) and ``target``.

    The circle's curvature is ``2 v / (u^2 + v^2)`` for the target at ``(u, v)``
    in the car frame, forward or backward alike; Ackermann gives
    ``atan(wheelbase * curvature)``, clipped to the steering limit.
    """
    uv = to_frame(pose, target)
    d2 = jnp.maximum(jnp.sum(uv * uv, -1), 1e-9)
    k = 2.0 * uv[..., 1] / d2
    return jnp.clip(jnp.arctan(vehicle.wheelbase * k), -vehicle.max_steer, vehicle.max_steer)


def bicycle_step(pose, steer, ds, vehicle):
    """Rear-axle pose ``(..., 3)`` after signed distance ``ds`` at a fixed steering angle."""
    return _advance(pose, jnp.tan(steer) / vehicle.wheelbase, ds)


def project(tr: Track, p, s_min):
    """Arc length of the point of a track's curve nearest to ``p (2,)`` among those at or after ``s_min``.

    Closed form on each piece: the line before the curve, its two arcs and the
    straight extension (onto a circle the nearest point is along the radius;
    a piece's clamped end by the law of cosines). The pursuit passes
    ``s_min`` = the furthest projection so far less ``BACKTRACK``, so the
    projection cannot jump back along the curve.
    """
    g = tr.geometry
    best_s, best_d = jnp.zeros((), p.dtype), jnp.asarray(jnp.inf, p.dtype)

    def line(o, t, lo, hi, s_off):
        lo = jnp.maximum(lo, s_min - s_off)
        u = jnp.clip(jnp.dot(p - o, t), lo, jnp.maximum(hi, lo))
        return s_off + u, jnp.where(lo <= hi, jnp.sum((p - o - u * t) ** 2), jnp.inf)

    pieces = [line(g.origin[0], g.direction[0], -jnp.inf, 0.0, 0.0)]
    for i in range(2):
        k, length, s_off = tr.curve.kappa[i], tr.curve.length[i], g.s_start[i]
        r0, r = g.radius[i], p - g.centre[i]
        rad = jnp.abs(g.inv_k[i])
        phi = jnp.arctan2(r0[0] * r[1] - r0[1] * r[0], jnp.dot(r0, r))
        lo = jnp.maximum(0.0, s_min - s_off)
        u = jnp.clip(phi * g.inv_k[i], lo, jnp.maximum(length, lo))
        nr = jnp.sqrt(jnp.sum(r * r))
        d = nr * nr + rad * rad - 2.0 * nr * rad * jnp.cos(phi - k * u)
        d = jnp.where(lo <= length, d, jnp.inf)
        sl, dl_ = line(g.origin[i], g.direction[i], 0.0, length, s_off)
        straight = g.straight[i]
        pieces.append((jnp.where(straight, sl, s_off + u), jnp.where(straight, dl_, d)))
    pieces.append(line(g.origin[2], g.direction[2], 0.0, jnp.inf, g.s_start[2]))
    for sp, dp in pieces:
        better = dp < best_d
        best_s, best_d = jnp.where(better, sp, best_s), jnp.where(better, dp, best_d)
    return best_s


BACKTRACK = 0.1  # m the projection may move back along the curve between steps


def rollout(
    pose,
    curve: Curve,
    hits: Callable,
    vehicle,
    config: ParkoutConfig,
    stop_y=None,
    stop_heading=0.0,
    steps: int | None = None,
) -> Rollout:
    """Drive one curve by pure pursuit and cut it at the first collision.

    Each step projects the rear axle onto the curve, aims at the point
    ``look_ahead`` further along it, moves the steering towards that by at
    most ``steer_rate`` (the first step may steer in place), and advances
    ``dl`` in the curve's gear. The move is done once the projection passes
    ``curve.end``; with ``stop_y`` (the forward move to the stop line) it is done
    once ``y >= stop_y`` and either the projection has passed the end or the
    heading is within ``config.out_tol / 2`` of ``stop_heading``. After that the
    pose stays.

    Args:
        pose: ``(3,)`` start pose (one instance; ``vmap`` for batches).
        curve: one reference curve.
        hits: ``poses (T, 3) -> (T,) bool`` footprint collision check.
        stop_y: if given and finite, the goal is this ``y`` (see above);
            stop_heading: its heading.
        steps: points ``T`` (default ``config.steps``).

    Returns:
        ``Rollout`` with ``T`` points.
    """
    T = config.steps if steps is None else steps
    tr = track(curve, config, stop_y, stop_heading)
    _, (poses, exists, goal, steer) = pursuit_steps(pursuit_start(pose), tr, vehicle, config, T)
    collide = hits(poses)
    clear = jnp.cumprod(~collide) > 0
    return finish_rollout(poses, exists, goal, steer, clear, curve.gear.astype(pose.dtype), config)


def finish_rollout(poses, exists, goal, steer, clear, gear, config: ParkoutConfig) -> Rollout:
    """``Rollout`` from the pursuit's points ``(T, ...)`` and which of them are clear of collisions
    up to the first one (``clear``, a prefix)."""
    T = poses.shape[0]
    dtype = poses.dtype
    valid = exists & clear
    nv = jnp.sum(valid)
    k = jnp.arange(T)
    s = gear * config.dl * jnp.minimum(k, jnp.maximum(nv - 1, 0)).astype(dtype)
    return Rollout(
        poses=poses,
        gear=jnp.broadcast_to(gear, (T,)),
        steer=steer,
        s=s,
        valid=valid,
        length=config.dl * jnp.maximum(nv - 1, 0).astype(dtype),
        complete=jnp.any(goal & valid),
        cut=jnp.any(exists & ~clear),
    )


class CurveGeometry(NamedTuple):
    """Per-piece constants of a curve for ``project`` (computed once per move, not per step).

    ``origin (3, 2)`` and ``direction (3, 2)``: start point and unit heading of each
    segment; ``centre (2, 2)``, ``radius (2, 2)`` (start point minus centre),
    ``inv_k (2,)`` (signed radius) and ``straight (2,)`` of the two arcs;
    ``s_start (3,)``: arc length at each segment's start.
    """

    origin: jnp.ndarray
    direction: jnp.ndarray
    centre: jnp.ndarray
    radius: jnp.ndarray
    inv_k: jnp.ndarray
    straight: jnp.ndarray
    s_start: jnp.ndarray


def curve_geometry(curve: Curve) -> CurveGeometry:
    st = curve.start  # (3, 3)
    direction = jnp.stack([jnp.cos(st[:, 2]), jnp.sin(st[:, 2])], -1)
    k = curve.kappa[:2]
    straight = jnp.abs(k) < 1e-6
    inv_k = 1.0 / jnp.where(straight, 1.0, k)
    normal = jnp.stack([-direction[:2, 1], direction[:2, 0]], -1)
    centre = st[:2, :2] + normal * inv_k[:, None]
    s_start = jnp.concatenate([jnp.zeros((1,), st.dtype), jnp.cumsum(curve.length[:2])])
    return CurveGeometry(st[:, :2], direction, centre, st[:2, :2] - centre, inv_k, straight, s_start)


class Track(NamedTuple):
    """What a pursuit rollout follows: the curve, its ``CurveGeometry`` and the goal line
    (``stop_y = inf``: the curve's end)."""

    curve: Curve
    geometry: CurveGeometry
    stop_y: jnp.ndarray
    stop_heading: jnp.ndarray


class Pursuit(NamedTuple):
    """A pursuit rollout's state between steps: pose, steering, furthest projection, finished, step count."""

    pose: jnp.ndarray
    steer: jnp.ndarray
    s_prev: jnp.ndarray
    finished: jnp.ndarray
    step: jnp.ndarray


def track(curve: Curve, config: ParkoutConfig, stop_y=None, stop_heading=0.0) -> Track:
    """``Track`` of one curve."""
    dtype = curve.start.dtype
    stop = jnp.asarray(jnp.inf if stop_y is None else stop_y, dtype)
    return Track(curve, curve_geometry(curve), stop, jnp.asarray(stop_heading, dtype))


def pursuit_start(pose) -> Pursuit:
    z = jnp.zeros((), jnp.int32)
    return Pursuit(pose, jnp.zeros((), pose.dtype), jnp.asarray(-1e6, pose.dtype), jnp.zeros((), bool), z)


def pursuit_steps(state: Pursuit, tr: Track, vehicle, config: ParkoutConfig, n: int):
    """``n`` pursuit steps (``lax.scan``): returns (state, (poses, exists, goal, steer), each ``(n, ...)``).

    ``exists``: the point is part of the move (the goal was not reached before
    it); ``goal``: the move reaches its goal at this point.
    """
    curve = tr.curve
    gear = curve.gear.astype(state.pose.dtype)
    line = jnp.isfinite(tr.stop_y)

    def step(st: Pursuit, _):
        p, steer, s_prev, finished, i = st
        s_p = project(tr, p[:2], s_prev - BACKTRACK)
        level = jnp.cos(p[2] - tr.stop_heading) > np.cos(0.5 * config.out_tol)
        done = jnp.where(line, (p[1] >= tr.stop_y) & (level | (s_p >= curve.end)), s_p >= curve.end)
        target = curve_point(curve, s_p + config.look_ahead)[:2]
        want = pursuit_steer(p, target, vehicle)
        free = (i == 0) & config.steer_in_place
        new_steer = jnp.where(free, want, steer + jnp.clip(want - steer, -config.steer_rate, config.steer_rate))
        stop = finished | done
        nxt = jnp.where(stop, p, bicycle_step(p, new_steer, gear * config.dl, vehicle))
        out = (p, ~finished, done & ~finished, new_steer)
        return Pursuit(nxt, jnp.where(stop, steer, new_steer), jnp.maximum(s_prev, s_p), stop, i + 1), out

    return lax.scan(step, state, None, length=n)
