"""Planner callback interface and a simple jittable planner for parking approaches.

A planner callback is ``plan(request: PlanRequest) -> Plan``; the supervisor and
the simulator only see this interface, so any planner (park-out, lattice, the
simple one here) can drive them. Inside ``lax.scan`` it must be jittable; the
host-loop simulator accepts any Python callable.

``SimplePlanner`` builds, for one request, a small set of candidates and keeps
the cheapest collision-free one:

* optionally a straight back-up (reverse) leg first, to get room after a stop;
* a forward leg: a cubic Bezier curve from the start pose to the target pose
  (for a parking approach the *pre-pose* beside the slot, else the goal), bent
  sideways by ``offset * sin(pi u)^2`` to pass obstacles;
* for a parking approach, a gear shift and a reverse Bezier leg into the slot.

With ``phase = -1`` (the car is already in its reverse leg) only the reverse
leg from the start pose to the goal is planned. Collision: the car box at every
point against the perceived obstacle boxes (the geometry core).
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.boxes import box_has_overlap, headings_from_path, poses_to_boxes
from jaxplan.replan.trajectory import arc_length
from jaxplan.types import Trajectory, VehicleParams


class PlanRequest(NamedTuple):
    """What a planner is asked (one instance; all jnp arrays).

    start: ``(3,)`` pose [x, y, heading] of the stopped (or moving) car;
    speed: ``()`` current speed; phase: ``()`` +1 plan the whole approach, -1 the
    car is in its final reverse leg; goal: ``(3,)`` believed goal pose;
    obstacles: ``(K, 5)`` perceived boxes; obstacles_valid: ``(K,)``;
    park: ``()`` bool, parking approach (forward, gear shift, reverse) or a short forward drive.
    """

    start: jnp.ndarray
    speed: jnp.ndarray
    phase: jnp.ndarray
    goal: jnp.ndarray
    obstacles: jnp.ndarray
    obstacles_valid: jnp.ndarray
    park: jnp.ndarray


class Plan(NamedTuple):
    """A planned trajectory ``(N,)`` with its prefix mask ``valid (N,)``, unsigned arc
    length ``s_abs (N,)`` and ``ok ()``: False when the plan does not reach the goal
    collision-free (the car then stops at its end, or at a brake-stop point, and re-plans)."""

    traj: Trajectory
    valid: jnp.ndarray
    s_abs: jnp.ndarray
    ok: jnp.ndarray


def _unit(h):
    return jnp.stack([jnp.cos(h), jnp.sin(h)], -1)


def _bezier(p0, m0, p3, m3, n, offset, max_handle, xp=jnp):
    """``n`` points ``(n, 2)`` of a cubic Bezier from ``p0`` (leaving along ``m0``) to ``p3``
    (arriving along ``m3``), bent by ``offset * sin(pi u)^2`` to the left of the chord.
    ``xp`` is ``jax.numpy`` or ``numpy``."""
    dist = xp.linalg.norm(p3 - p0)
    h = xp.minimum(0.4 * dist, max_handle)
    p1, p2 = p0 + h * m0, p3 - h * m3
    u = xp.linspace(0.0, 1.0, n)[:, None]
    pts = ((1 - u) ** 3) * p0 + 3 * ((1 - u) ** 2) * u * p1 + 3 * (1 - u) * u ** 2 * p2 + u ** 3 * p3
    chord = (p3 - p0) / xp.maximum(dist, 1e-6)
    normal = xp.stack([-chord[1], chord[0]])
    return pts + offset * xp.sin(xp.pi * u) ** 2 * normal


@dataclasses.dataclass(frozen=True)
class SimplePlanner:
    """Candidate-set planner for parking approaches and short drives (static config, hashable).

    The pre-pose of a parking approach is the goal moved by ``pre_pose`` =
    (along the goal heading, to its left) and turned by ``pre_turn``. Candidates
    must keep ``margin`` metres from every perceived obstacle.
    """

    vehicle: VehicleParams = VehicleParams()
    n_back: int = 8
    n_fwd: int = 80
    n_rev: int = 24
    back_up: float = 3.0
    offsets: tuple = (0.0, 1.2, -1.2, 2.4, -2.4, 3.6, -3.6)
    pre_pose: tuple = (8.5, -4.0)
    pre_turn: float = -0.7853981633974483
    max_handle: float = 3.0
    v_fwd: float = 3.0
    v_rev: float = 1.5
    accel: float = 1.0
    back_up_cost: float = 4.0
    margin: float = 0.2

    @property
    def n_points(self) -> int:
        return self.n_back + self.n_fwd + self.n_rev

    def pre(self, goal):
        """Pre-pose ``(3,)`` of a parking approach to ``goal (3,)``."""
        c, s = jnp.cos(goal[2]), jnp.sin(goal[2])
        a, l = self.pre_pose
        return jnp.stack([goal[0] + a * c - l * s, goal[1] + a * s + l * c, goal[2] + self.pre_turn])

    def nominal_forward_path(self, start, goal, park: bool):
        """Host-side (numpy) forward leg ``(n_fwd, 2)`` of the obstacle-free plan, for placing test obstacles."""
        start, goal = np.asarray(start, float), np.asarray(goal, float)
        target = np.asarray(self.pre(jnp.asarray(goal))) if park else goal
        unit = lambda h: np.array([np.cos(h), np.sin(h)])  # noqa: E731
        return _bezier(start[:2], unit(start[2]), target[:2], unit(target[2]), self.n_fwd, 0.0, self.max_handle, np)

    def _candidate(self, r: PlanRequest, offset, backup):
        fwd_phase = r.phase > 0
        start_xy, h0 = r.start[:2], r.start[2]
        back_len = jnp.where(backup & fwd_phase, self.back_up, 0.0)
        u = jnp.linspace(0.0, 1.0, self.n_back)[:, None]
        back = start_xy - u * back_len * _unit(h0)
        q = back[-1]
        target = jnp.where(r.park, self.pre(r.goal), r.goal)
        fwd = _bezier(q, _unit(h0), target[:2], _unit(target[2]), self.n_fwd, offset, self.max_handle)
        # Reverse leg: from the pre-pose (whole approach) or from the car (final leg only).
        r0 = jnp.where(fwd_phase, target, r.start)
        rev = _bezier(r0[:2], -_unit(r0[2]), r.goal[:2], -_unit(r.goal[2]), self.n_rev,
                      jnp.where(fwd_phase, 0.0, offset), self.max_handle)
        xy = jnp.concatenate([back, fwd, rev])
        hb = jnp.full((self.n_back,), h0)
        hf = headings_from_path(fwd)
        hr = headings_from_path(rev) + jnp.pi
        theta = jnp.concatenate([hb, hf, hr])
        gear = jnp.concatenate([-jnp.ones(self.n_back), jnp.ones(self.n_fwd), -jnp.ones(self.n_rev)]).astype(jnp.int32)
        valid = jnp.concatenate([jnp.full((self.n_back,), back_len > 0), jnp.full((self.n_fwd,), fwd_phase),
                                 jnp.full((self.n_rev,), r.park | ~fwd_phase)])
        # Move the valid legs to the front (index arithmetic, no sort); pad with the last valid point.
        nb = jnp.where(back_len > 0, self.n_back, 0)
        nf = jnp.where(fwd_phase, self.n_fwd, 0)
        i = jnp.arange(self.n_points)
        src = jnp.where(i < nb, i, jnp.where(i < nb + nf, self.n_back + i - nb, self.n_back + self.n_fwd + i - nb - nf))
        valid = valid[jnp.clip(src, 0, self.n_points - 1)] & (src < self.n_points)
        last = jnp.maximum(jnp.sum(valid) - 1, 0)
        src = jnp.where(valid, src, jnp.clip(src, 0, self.n_points - 1)[last])
        xy, theta, gear = xy[src], theta[src], gear[src]
        # Unwrap headings so interpolation between points is smooth.
        theta = theta[0] + jnp.concatenate([jnp.zeros(1), jnp.cumsum(jnp.arctan2(jnp.sin(jnp.diff(theta)),
                                                                                  jnp.cos(jnp.diff(theta))))])
        boxes = poses_to_boxes(xy, theta, self.vehicle)
        boxes = boxes.at[:, 2:4].add(2 * self.margin)  # keep ``margin`` clear (tracking noise, point spacing)
        hit = box_has_overlap(boxes[:, None, :], r.obstacles[None, :, :]) & r.obstacles_valid[None, :] & valid[:, None]
        collides = jnp.any(hit)
        cost = jnp.abs(offset) + self.back_up_cost * (back_len > 0) + 1e3 * collides
        return xy, theta, gear, valid, cost, collides

    def __call__(self, r: PlanRequest) -> Plan:
        offs = jnp.asarray(self.offsets, jnp.float32)
        o = jnp.concatenate([offs, offs])
        b = jnp.concatenate([jnp.zeros(offs.shape, bool), jnp.ones(offs.shape, bool)])
        xy, theta, gear, valid, cost, collides = jax.vmap(lambda oo, bb: self._candidate(r, oo, bb))(o, b)
        k = jnp.argmin(cost)
        xy, theta, gear, valid = xy[k], theta[k], gear[k], valid[k]
        return finish_plan(xy, theta, gear, valid, r.speed, self.v_fwd, self.v_rev, self.accel, ~collides[k])


def finish_plan(xy, theta, gear, valid, v0, v_fwd, v_rev, accel, ok) -> Plan:
    """Fill speed, acceleration, curvature, time and arc length of a geometric plan.

    Speed on each single-direction leg: ``min(vmax, sqrt(v_in^2 + 2 a s), sqrt(2 a (s_leg - s)))``,
    ``v_in = v0`` on the first leg and 0 after a gear shift.
    """
    s_abs = arc_length(xy, valid)
    shift = jnp.concatenate([gear[:-1] != gear[1:], jnp.zeros((1,), bool)]) & valid
    leg = jnp.concatenate([jnp.zeros((1,), jnp.int32), jnp.cumsum(shift[:-1]).astype(jnp.int32)])
    first = jnp.concatenate([jnp.ones((1,), bool), shift[:-1]])  # first point of each leg
    leg_start = jax.lax.cummax(jnp.where(first, s_abs, -jnp.inf))
    leg_end = jax.lax.cummin(jnp.where(shift | (jnp.arange(xy.shape[0]) == jnp.sum(valid) - 1), s_abs, jnp.inf),
                             reverse=True)
    leg_end = jnp.where(jnp.isinf(leg_end), s_abs[-1], leg_end)
    v_in = jnp.where(leg == 0, v0, 0.0)
    vmax = jnp.where(gear > 0, v_fwd, v_rev)
    speed = jnp.minimum(vmax, jnp.minimum(jnp.sqrt(v_in ** 2 + 2 * accel * (s_abs - leg_start)),
                                          jnp.sqrt(2 * accel * jnp.maximum(leg_end - s_abs, 0.0))))
    speed = jnp.where(valid, speed, 0.0)
    ds = jnp.diff(s_abs)
    vm = jnp.maximum(0.5 * (speed[1:] + speed[:-1]), 0.1)
    dt = jnp.where(ds > 0, ds / vm, 0.0)
    t = jnp.concatenate([jnp.zeros(1), jnp.cumsum(dt)])
    acc = jnp.concatenate([jnp.where(dt > 0, jnp.diff(speed) / jnp.where(dt > 0, dt, 1.0), 0.0), jnp.zeros(1)])
    kap = jnp.concatenate([jnp.where(ds > 1e-6, jnp.diff(theta) / jnp.where(ds > 1e-6, ds, 1.0), 0.0), jnp.zeros(1)])
    sgn = gear.astype(xy.dtype)
    s_signed = jnp.concatenate([jnp.zeros(1), jnp.cumsum(ds * sgn[1:])])
    traj = Trajectory(x=xy[:, 0], y=xy[:, 1], theta=theta, kappa=kap, v=sgn * speed, a=acc, t=t, s=s_signed,
                      gear=gear)
    return Plan(traj, valid, s_abs, jnp.asarray(ok))
