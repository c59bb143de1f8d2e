"""A drivable planner for parking approaches and short drives, with time-aware obstacle prediction.

Every path is made of Dubins paths (:mod:`jaxplan.replan.dubins`) with a turning radius
``radius_factor`` times the car's minimum ``wheelbase / tan(max_steer)``, so its curvature
never exceeds what the car can steer. One request builds a fixed candidate set and keeps
the cheapest collision-free candidate:

* an optional straight back-up leg first (only when the car stands still);
* a forward leg from there to the *target* (the pre-pose beside the slot of a parking
  approach, else the goal), either direct or through a *via pose* beside a perceived
  obstacle (both sides) or beside the middle of the chord: two Dubins paths joined;
* for a parking approach a gear shift and a reverse leg from the pre-pose into the slot
  (the Dubins path of the flipped poses); several pre-poses are tried, and the current
  plan's intermediate destination (so a re-plan near the pre-pose need not loop);
* with ``phase = -1`` (the car is in its final reverse leg) only the reverse leg from the
  car to the goal, optionally after a short pull forward (only when standing still).

The final target is the goal or, at a small extra cost, a pose of the goal region
(``goal_tol`` = (distance, yaw), the supervisor's goal-moved thresholds): the current
plan's end while it lies in the region, else the region's pose nearest the car. So a
re-plan just before the goal, with the believed goal moved a few centimetres, keeps the
end it can reach instead of looping; a car standing at its target gets an empty plan.
Each candidate gets the speed profile and time stamps of the shared longitudinal
model, and its car boxes (grown by ``margin``) are checked against every obstacle
*where that obstacle is predicted to be when the car gets there* (constant velocity,
swept over ``[t - before, t + after]``, ``jaxplan.replan.prediction.plan_separation``).
Cost: length (reverse metres count ``reverse_weight`` times), penalties for back-up /
pull-forward / goal-region targets, and a large
penalty for a collision (the cheapest colliding candidate is returned with ``ok = False``
when none is free; the supervisor then keeps its old plan).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import poses_to_boxes
from jaxplan.replan import dubins
from jaxplan.replan.longitudinal import MotionLimits
from jaxplan.replan.planner import Plan, PlanRequest, finish_plan
from jaxplan.replan.prediction import plan_separation
from jaxplan.types import VehicleParams


def max_curvature(vehicle: VehicleParams) -> float:
    """The car's largest curvature ``tan(max_steer) / wheelbase`` (1/m)."""
    return math.tan(float(vehicle.max_steer)) / float(vehicle.wheelbase)


def _unit(h):
    return jnp.stack([jnp.cos(h), jnp.sin(h)], -1)


def _flip(pose):
    return pose.at[..., 2].add(jnp.pi)


def _unflip(pose):
    return pose.at[..., 2].add(-jnp.pi)


def _pose_err(a, b):
    """(distance, |heading difference|) between poses ``(3,)``."""
    return jnp.linalg.norm(a[:2] - b[:2]), jnp.abs(jnp.arctan2(jnp.sin(a[2] - b[2]), jnp.cos(a[2] - b[2])))


@dataclasses.dataclass(frozen=True)
class ApproachPlanner:
    """Candidate-set Dubins planner (static config, hashable); ``__call__(PlanRequest) -> Plan``.

    Pre-poses of a parking approach are ``(along, left, turn)`` from the goal: moved
    ``along`` its heading and ``left`` to its left, turned by ``turn``.
    """

    vehicle: VehicleParams = VehicleParams()
    limits: MotionLimits = MotionLimits()
    radius_factor: float = 1.05
    n_back: int = 12
    n_fwd: int = 192
    n_rev: int = 72
    back_up: float = 3.5
    pull_forward: float = 2.5
    pre_poses: tuple = ((8.0, -4.5, -0.7853981633974483), (9.5, -4.0, -0.7853981633974483), (7.0, -6.0, -1.2))
    chord_offsets: tuple = (2.5, -2.5)
    obstacle_clearance: float = 0.6
    goal_tol: tuple = (0.2, 0.1)
    end_tol: tuple = (0.05, 0.02)
    margin: float = 0.2
    before: float = 0.5
    after: float = 2.0
    back_up_cost: float = 6.0
    reverse_weight: float = 2.0
    region_cost: float = 0.5
    v_stopped: float = 0.05
    max_obstacles: int = 4

    def __post_init__(self):
        if self.radius_factor < 1.0:
            raise ValueError(f"ApproachPlanner.radius_factor must be >= 1 (drivable paths), got {self.radius_factor}")
        for f in ("n_back", "n_fwd", "n_rev"):
            if getattr(self, f) < 2:
                raise ValueError(f"ApproachPlanner.{f} must be >= 2, got {getattr(self, f)}")
        if len(self.pre_poses) < 1 or any(len(p) != 3 for p in self.pre_poses):
            raise ValueError("ApproachPlanner.pre_poses must be a non-empty tuple of (along, left, turn)")

    @property
    def clearance(self) -> float:
        """Least distance (m) a collision-free plan keeps from the obstacles it was given: its
        car boxes are grown by ``margin`` and tested against the exact boxes."""
        return float(self.margin)

    @property
    def radius(self) -> float:
        return self.radius_factor / max_curvature(self.vehicle)

    @property
    def n_points(self) -> int:
        return self.n_back + self.n_fwd + self.n_rev

    @property
    def n_targets(self) -> int:
        """Approach: the pre-poses and the current plan's intermediate destination; else goal and region."""
        return len(self.pre_poses) + 1

    def pre(self, goal, j):
        """Pre-pose ``(3,)`` number ``j`` of a parking approach to ``goal (3,)``."""
        a, l, t = (jnp.asarray([p[i] for p in self.pre_poses], goal.dtype)[j] for i in range(3))
        c, s = jnp.cos(goal[2]), jnp.sin(goal[2])
        return jnp.stack([goal[0] + a * c - l * s, goal[1] + a * s + l * c, goal[2] + t])

    # ------------------------------------------------------------------ candidates

    def in_region(self, pose, goal):
        """Whether ``pose (3,)`` lies within ``goal_tol`` = (distance, yaw) of ``goal (3,)``."""
        dyaw = jnp.arctan2(jnp.sin(pose[2] - goal[2]), jnp.cos(pose[2] - goal[2]))
        return (jnp.linalg.norm(pose[:2] - goal[:2]) <= self.goal_tol[0]) & (jnp.abs(dyaw) <= self.goal_tol[1])

    def _region_target(self, r: PlanRequest, q):
        """The goal-region target: the current plan's end while it lies in the region (so a re-plan
        just before the goal keeps the end it can reach), else the region's pose nearest ``q``."""
        goal = r.goal
        d = q[:2] - goal[:2]
        dist = jnp.linalg.norm(d)
        shift = d * jnp.minimum(1.0, self.goal_tol[0] / jnp.maximum(dist, 1e-9))
        dh = jnp.clip(
            jnp.arctan2(jnp.sin(q[2] - goal[2]), jnp.cos(q[2] - goal[2])), -self.goal_tol[1], self.goal_tol[1]
        )
        near = jnp.concatenate([goal[:2] + shift, (goal[2] + dh)[None]])
        return jnp.where(self.in_region(r.prev_end, goal), r.prev_end, near)

    def _vias(self, r: PlanRequest, q, target):
        """Via poses ``(V, 3)`` and whether each is used ``(V,)``: direct (the target itself),
        both sides of the chord's middle, both sides of every perceived obstacle."""
        chord = target[:2] - q[:2]
        L = jnp.maximum(jnp.linalg.norm(chord), 1e-6)
        u = chord / L
        nrm = jnp.stack([-u[1], u[0]])
        h = jnp.arctan2(u[1], u[0])
        mid = q[:2] + 0.5 * chord
        pts = [target[:2]] + [mid + o * nrm for o in self.chord_offsets]
        use = [jnp.ones((), bool)] + [L > 4.0 for _ in self.chord_offsets]
        k = min(self.max_obstacles, r.obstacles.shape[0])
        for i in range(k):
            c = r.obstacles[i, :2]
            along = jnp.dot(c - q[:2], u)
            half = 0.5 * jnp.linalg.norm(r.obstacles[i, 2:4])
            clear = half + 0.5 * self.vehicle.width + self.margin + self.obstacle_clearance
            side = jnp.dot(c - q[:2], nrm)
            for sgn in (1.0, -1.0):
                pts.append(q[:2] + along * u + (side + sgn * clear) * nrm)
                use.append(r.obstacles_valid[i] & (along > 2.0) & (along < L - 2.0))
        xy = jnp.stack(pts)
        heads = jnp.concatenate([target[2:3], jnp.full((xy.shape[0] - 1,), h)])
        return jnp.concatenate([xy, heads[:, None]], -1), jnp.stack(use)

    def _leg(self, pieces, n):
        """``n`` poses ``(n, 3)`` evenly spaced along consecutive Dubins paths, their curvature and length."""
        total = sum(p.length for p in pieces)
        u = jnp.linspace(0.0, 1.0, n) * total
        poses, kap = dubins.sample(pieces[0], u)
        off = pieces[0].length
        for p in pieces[1:]:
            pp, kk = dubins.sample(p, u - off)
            later = u > off
            poses = jnp.where(later[:, None], pp, poses)
            kap = jnp.where(later, kk, kap)
            off = off + p.length
        return poses, kap, total, jnp.all(jnp.stack([p.ok for p in pieces]))

    def _candidate(self, r: PlanRequest, backup, via, via_used, j):
        """One candidate: back-up length ``backup``, via pose ``via (3,)``, target index ``j``."""
        R = self.radius
        moving = jnp.abs(r.speed) >= self.v_stopped
        final_leg = r.phase < 0
        park = r.park
        start = r.start
        # Back-up (approach) or pull-forward (final leg) straight, only from standstill.
        b = jnp.where(moving, 0.0, backup)
        back_len = jnp.where(final_leg, 0.0, b)
        pull_len = jnp.where(final_leg, jnp.where(backup > 0, self.pull_forward, 0.0) * (~moving), 0.0)
        ub = jnp.linspace(0.0, 1.0, self.n_back)[:, None]
        back_xy = start[:2] - ub * back_len * _unit(start[2])
        back = jnp.concatenate([back_xy, jnp.full((self.n_back, 1), start[2])], -1)
        q = back[-1]
        # Targets: pre-pose j (approach), else goal / goal region.
        goal_j = jnp.where(j == 1, self._region_target(r, q), r.goal)
        npre = len(self.pre_poses)
        pre_j = jnp.where(j < npre, self.pre(r.goal, jnp.minimum(j, npre - 1)), r.prev_via)
        tgt_fwd = jnp.where(park, pre_j, goal_j)
        pulled = q.at[:2].add(pull_len * _unit(q[2]))
        fwd_end = jnp.where(final_leg, pulled, tgt_fwd)
        via = jnp.where(final_leg | ~via_used, fwd_end, via)
        # Each piece starts where the previous one really ends (continuous path); the end is checked.
        p1 = dubins.shortest(q, via, R)
        p2 = dubins.shortest(dubins.end_pose(p1), fwd_end, R)
        fwd, kf, len_f, ok_f = self._leg([p1, p2], self.n_fwd)
        fwd_real = dubins.end_pose(p2)
        # Reverse leg into the slot: from the pre-pose (approach) or from the car / pulled pose (final leg).
        rev_goal = jnp.where(final_leg, goal_j, r.goal)
        rp = dubins.shortest(_flip(fwd_real), _flip(rev_goal), R)
        rev, kr, len_r, ok_r = self._leg([rp], self.n_rev)
        rev = _unflip(rev)
        has_rev = park | final_leg
        valid_b = back_len > 1e-3
        valid_f = len_f > 1e-3
        valid_r = has_rev & (len_r > 1e-3)
        xy = jnp.concatenate([back[:, :2], fwd[:, :2], rev[:, :2]])
        theta = jnp.concatenate([back[:, 2], fwd[:, 2], rev[:, 2]])
        kap = jnp.concatenate([jnp.zeros(self.n_back), kf, kr])  # d heading / d (unsigned) s
        gear = jnp.concatenate([-jnp.ones(self.n_back), jnp.ones(self.n_fwd), -jnp.ones(self.n_rev)]).astype(jnp.int32)
        leg_valid = jnp.concatenate(
            [jnp.full((self.n_back,), valid_b), jnp.full((self.n_fwd,), valid_f), jnp.full((self.n_rev,), valid_r)]
        )
        # Valid legs to the front (index arithmetic); pad with the last valid point.
        nb = jnp.where(valid_b, self.n_back, 0)
        nf = jnp.where(valid_f, self.n_fwd, 0)
        n = self.n_points
        i = jnp.arange(n)
        src = jnp.where(i < nb, i, jnp.where(i < nb + nf, self.n_back + i - nb, self.n_back + self.n_fwd + i - nb - nf))
        valid = leg_valid[jnp.clip(src, 0, n - 1)] & (src < n)
        any_valid = jnp.any(valid)
        valid = valid.at[0].set(True)
        last = jnp.maximum(jnp.sum(valid) - 1, 0)
        src = jnp.where(valid, jnp.clip(src, 0, n - 1), jnp.clip(src, 0, n - 1)[last])
        xy = jnp.where(any_valid, xy[src], jnp.broadcast_to(start[:2], xy.shape))
        theta, kap, gear = theta[src], kap[src], gear[src]
        theta = jnp.where(any_valid, theta, start[2])
        # Unwrap headings so interpolation between points is smooth.
        theta = theta[0] + jnp.concatenate(
            [jnp.zeros(1), jnp.cumsum(jnp.arctan2(jnp.sin(jnp.diff(theta)), jnp.cos(jnp.diff(theta))))]
        )
        # Nothing to drive is a plan only when the car already stands at its (region) target.
        final_target = jnp.where(has_rev, rev_goal, fwd_end)
        at_target = (jnp.linalg.norm(final_target[:2] - start[:2]) < 1e-3) & (
            jnp.abs(jnp.sin(0.5 * (final_target[2] - start[2]))) < 1e-3
        )
        first_gear = jnp.where(valid_b, -1, jnp.where(valid_f, 1, jnp.where(valid_r, -1, jnp.sign(r.speed))))
        gear_ok = ~moving | (first_gear == jnp.sign(r.speed))
        length = self.reverse_weight * (back_len + jnp.where(valid_r, len_r, 0.0)) + jnp.where(valid_f, len_f, 0.0)
        real_end = jnp.where(has_rev, _unflip(dubins.end_pose(rp)), fwd_real)
        e_pos, e_yaw = _pose_err(real_end, final_target)
        close = (e_pos <= self.end_tol[0]) & (e_yaw <= self.end_tol[1])
        reaches = ok_f & (ok_r | ~has_rev) & (any_valid | at_target) & gear_ok & close
        approach = park & ~final_leg  # j indexes the pre-poses; else 0: goal, 1: goal region, 2+: unused
        extra = (
            self.back_up_cost * (valid_b | (pull_len > 0))
            + self.region_cost * (~approach & (j == 1))
            + 1e6 * ~reaches
            + 1e6 * (~approach & (j > 1))
        )
        return xy, theta, kap, gear, valid, length + extra, reaches

    def candidates(self, r: PlanRequest):
        """Every candidate of the request, stacked: xy ``(C, N, 2)``, theta, kappa, gear, valid ``(C, N)``,
        cost ``(C,)`` (before the collision check), reaches ``(C,)``."""
        q = r.start
        tgt = jnp.where(r.park, self.pre(r.goal, 0), r.goal)
        vias, used = self._vias(r, q, tgt)
        backs = jnp.asarray([0.0, self.back_up], r.start.dtype)
        B, V, T = 2, vias.shape[0], self.n_targets
        bi, vi, ti = jnp.meshgrid(jnp.arange(B), jnp.arange(V), jnp.arange(T), indexing="ij")
        bi, vi, ti = bi.ravel(), vi.ravel(), ti.ravel()
        fn = jax.vmap(lambda b, v, u, j: self._candidate(r, b, v, u, j))
        return fn(backs[bi], vias[vi], used[vi], ti)

    def __call__(self, r: PlanRequest) -> Plan:
        xy, theta, kap, gear, valid, cost, reaches = self.candidates(r)

        def finish(xy, theta, kap, gear, valid):
            return finish_plan(xy, theta, gear, valid, jnp.abs(r.speed), self.limits, True, kap)

        plans = jax.vmap(finish)(xy, theta, kap, gear, valid)
        boxes = poses_to_boxes(xy, theta, self.vehicle)
        boxes = boxes.at[..., 2:4].add(2 * self.margin)
        z = jnp.zeros(r.obstacles.shape[:1], r.obstacles.dtype)

        def collides(bx, t, v):
            sep = plan_separation(bx, t, v, r.obstacles, r.obstacles_vel, z, r.obstacles_valid, self.before, self.after)
            return jnp.any(sep < 0)

        hit = jax.vmap(collides)(boxes, plans.traj.t, valid)
        total = cost + 1e3 * hit
        k = jnp.argmin(total)
        best = jax.tree.map(lambda a: a[k], plans)
        return best._replace(ok=reaches[k] & ~hit[k])


def nominal_forward_path(planner: ApproachPlanner, start, goal, park: bool, n: int = 96):
    """Host-side: the forward leg ``(n, 2)`` of the planner's obstacle-free plan from ``start`` to
    ``goal`` (direct, through the pre-pose whose two legs are shortest; for placing scenario obstacles)."""
    import numpy as np

    return np.asarray(
        _nominal_jit(planner, n)(jnp.asarray(start, jnp.float32), jnp.asarray(goal, jnp.float32), jnp.asarray(park))
    )


_NOMINAL: dict = {}


def _nominal_jit(planner, n):
    if (planner, n) not in _NOMINAL:

        def fwd(start, goal, park):
            pres = jnp.stack([planner.pre(goal, j) for j in range(len(planner.pre_poses))])
            R = planner.radius
            to_pre = dubins.shortest(jnp.broadcast_to(start, pres.shape), pres, R)
            rev = dubins.shortest(_flip(pres), _flip(jnp.broadcast_to(goal, pres.shape)), R)
            j = jnp.argmin(to_pre.length + rev.length)
            path = jax.tree.map(lambda a: a[j], to_pre)
            direct = dubins.shortest(start, goal, R)
            path = jax.tree.map(lambda a, b: jnp.where(park, a, b), path, direct)
            poses, _ = dubins.sample(path, jnp.linspace(0.0, 1.0, n) * path.length)
            return poses[:, :2]

        _NOMINAL[(planner, n)] = jax.jit(fwd)
    return _NOMINAL[(planner, n)]
