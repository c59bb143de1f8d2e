"""The re-planning supervisor: one safety layer shared by the lazy strategy and its baselines.

Strategies (int codes, traced, so one compiled loop serves all three) differ only in
*when* they ask the planner (``replan_decision``):

* ``LAZY``: re-plan only at an *intermediate destination* with the car (near)
  stopped: at a gear-shift point when the freshly observed goal moved or turned
  more than a threshold (``GOAL``); at a brake-stop point, because the obstacle
  is real (``OBSTACLE``, at most once per ``retry_s`` while blocked). Never while moving.
* ``PERIODIC``: re-plan every ``1 / periodic_hz`` seconds, moving or not.
* ``IMMEDIATE``: re-plan as soon as a new collision point is detected (``OBSTACLE``)
  or the observed goal moved more than the threshold (``GOAL``), debounced: at most
  once per ``debounce_s``.

All strategies re-plan when the tracking point has been lost for ``lost_time``
and the car has stopped (``LOST``), and when the car stands at the end of a plan
that the planner flagged as not reaching the goal (``OBSTACLE``, once per
``retry_s``); none re-plans once the run is done or while a plan is being made.

Everything else is the same for every strategy (``supervise``, ``submit``):

* **Collision points** at ``collision_hz`` on the current sub-trajectory from the
  tracking point, time-aware (each plan point, the car box grown by ``clearance``, is checked against where every
  perceived obstacle is predicted to be when the car gets there,
  :mod:`jaxplan.replan.prediction`), into the time-stamped queue; the brake-stop
  point ``brake_safety`` before the nearest entry.
* **The queue and the brake-stop point survive re-plans**: entries are re-anchored on
  the new plan where their remembered obstacle meets it.
* **A re-plan while moving starts ahead**: the request starts where the car will be
  on the old plan after the planning latency ``latency_s`` (predicted with the car's
  own longitudinal law), at the speed it will have there, or at the end of the current
  sub-trajectory when that is nearer than ``keep_s``; the new plan arrives
  ``latency_s`` later, the car drives on the old plan meanwhile.
* **A new plan is checked before it is installed**: it is stitched behind the stretch
  of the old plan the car drove meanwhile, then rejected (the old plan is kept) when
  its first sub-trajectory collides with the obstacles perceived now (time-aware), or a
  later one with a static obstacle, when its first gear change lies nearer than the
  car's braking distance, or when the car is no longer on the stitched stretch.
* **Signed speed and gear**: the car's speed is signed by the gear of its
  sub-trajectory; a gear changes only with the car stopped (at a gear-shift point, or
  by installing a plan with the car stopped).

``supervise`` is one jittable function of small pytrees, so any simulator (or a
real stack) can call it every tick and call its planner when it says so.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import poses_to_boxes
from jaxplan.replan.longitudinal import MotionLimits, advance, arrival_times
from jaxplan.replan.planner import Plan, PlanRequest, finish_plan
from jaxplan.replan.prediction import first_contact, plan_separation
from jaxplan.replan.queue import (
    BrakeStop,
    CollisionQueue,
    ObstacleMemory,
    brake_init,
    memory_init,
    memory_update,
    queue_expire,
    queue_init,
    queue_push,
    queue_reanchor,
    update_brake_stop,
)
from jaxplan.replan.tracking import find_tracking_point_directional
from jaxplan.replan.trajectory import interpolate_pose, last_valid_index, sub_trajectories
from jaxplan.types import VehicleParams

LAZY, PERIODIC, IMMEDIATE = 0, 1, 2
STRATEGY_NAMES = ("lazy", "periodic", "immediate")
NO_REPLAN, GOAL, OBSTACLE, LOST, PERIOD = 0, 1, 2, 3, 4
REASON_NAMES = ("none", "goal", "obstacle", "lost", "periodic")
# Why a new plan was not installed.
REJECT_COLLISION, REJECT_GEAR, REJECT_STALE = 0, 1, 2
REJECT_NAMES = ("collision", "gear", "stale")


@dataclasses.dataclass(frozen=True)
class SupervisorConfig:
    """Supervisor settings (static, hashable). Times in s, distances in m, angles in rad.

    ``latency_s``: time from a re-plan request to its plan (rounded to whole ticks, at
    least one); ``debounce_s``: least time between two immediate re-plans;
    ``before`` / ``after``: the prediction window of the time-aware collision test;
    ``stitch_tol``: how far the car may be past the start of a new plan when it arrives;
    ``clearance``: the car boxes of the collision test are grown by this much on each side
    (the tracking error); the planner must keep at least this much from the obstacles, else
    every new plan fails the check before it is installed (``ManeuverSimConfig`` compares it
    with a planner's ``clearance``);
    ``keep_s``: a re-plan whose start would lie this close to the end of the current
    sub-trajectory starts at that end instead (the old plan is kept up to there);
    ``prefix_points``: points of the kept stretch of the old plan.
    """

    dt: float = 0.1
    collision_hz: float = 10.0
    window_s: float = 2.0
    brake_safety: float = 0.5
    queue_size: int = 32
    v_stopped: float = 0.05
    at_point_tol: float = 0.3
    goal_pos_thresh: float = 0.2
    goal_yaw_thresh: float = 0.1
    lost_time: float = 1.0
    track_window: int = 32
    track_max_dist: float = 1.0
    periodic_hz: float = 1.0
    retry_s: float = 1.0
    max_sub: int = 8
    latency_s: float = 0.2
    debounce_s: float = 0.5
    before: float = 0.5
    after: float = 2.0
    stitch_tol: float = 0.3
    clearance: float = 0.15
    keep_s: float = 3.0
    prefix_points: int = 16
    limits: MotionLimits = MotionLimits()

    def __post_init__(self):
        for f in ("dt", "collision_hz", "periodic_hz", "v_stopped", "at_point_tol", "track_max_dist", "stitch_tol"):
            if not float(getattr(self, f)) > 0:
                raise ValueError(f"SupervisorConfig.{f} must be positive, got {getattr(self, f)}")
        for f in (
            "window_s",
            "brake_safety",
            "goal_pos_thresh",
            "goal_yaw_thresh",
            "lost_time",
            "retry_s",
            "latency_s",
            "debounce_s",
            "before",
            "after",
            "keep_s",
            "clearance",
        ):
            if not float(getattr(self, f)) >= 0:
                raise ValueError(f"SupervisorConfig.{f} must be >= 0, got {getattr(self, f)}")
        for f in ("queue_size", "track_window", "max_sub", "prefix_points"):
            if int(getattr(self, f)) < 1:
                raise ValueError(f"SupervisorConfig.{f} must be >= 1, got {getattr(self, f)}")

    @property
    def collision_every(self) -> int:
        """Collision check every this many ticks."""
        return max(1, int(round(1.0 / (self.collision_hz * self.dt))))

    @property
    def latency_steps(self) -> int:
        """Ticks from a request to its plan (>= 1)."""
        return max(1, int(round(self.latency_s / self.dt)))


def goal_moved(goal_est, plan_goal, cfg: SupervisorConfig):
    """Whether the believed goal ``(..., 3)`` moved or turned more than the thresholds from the plan's."""
    d = jnp.linalg.norm(goal_est[..., :2] - plan_goal[..., :2], axis=-1)
    dh = goal_est[..., 2] - plan_goal[..., 2]
    dy = jnp.abs(jnp.arctan2(jnp.sin(dh), jnp.cos(dh)))
    return (d > cfg.goal_pos_thresh) | (dy > cfg.goal_yaw_thresh)


def replan_decision(
    strategy,
    cfg: SupervisorConfig,
    *,
    stopped,
    at_gear_shift,
    at_brake_stop,
    goal_moved,
    new_collision,
    lost_stopped,
    since_replan,
    done,
    at_blocked_end=False,
    busy=False,
):
    """Whether to re-plan now and why.

    Args (all ``(...)`` arrays): strategy (int code); stopped (speed below
    ``v_stopped``); at_gear_shift / at_brake_stop (the car is at that point);
    goal_moved (fresh goal differs from the plan's); new_collision (a collision
    point was detected this tick); lost_stopped (tracking lost long enough and
    stopped); since_replan (s since the last re-plan); done (run over);
    at_blocked_end (at the end of a plan that does not reach the goal);
    busy (a plan is being made).

    Returns:
        (replan ``(...)`` bool, reason ``(...)`` int).
    """
    eps = 1e-6
    lazy_obstacle = stopped & at_brake_stop & (since_replan >= cfg.retry_s - eps)
    lazy_goal = stopped & at_gear_shift & goal_moved
    lazy_reason = jnp.where(lazy_obstacle, OBSTACLE, jnp.where(lazy_goal, GOAL, NO_REPLAN))
    periodic_reason = jnp.where(since_replan >= 1.0 / cfg.periodic_hz - eps, PERIOD, NO_REPLAN)
    settled = since_replan >= cfg.debounce_s - eps
    immediate_reason = jnp.where(new_collision & settled, OBSTACLE, jnp.where(goal_moved & settled, GOAL, NO_REPLAN))
    reason = jnp.where(
        strategy == LAZY, lazy_reason, jnp.where(strategy == PERIODIC, periodic_reason, immediate_reason)
    )
    blocked_end = stopped & at_blocked_end & (since_replan >= cfg.retry_s - eps)
    reason = jnp.where(blocked_end & (reason == NO_REPLAN), OBSTACLE, reason)
    reason = jnp.where(lost_stopped, LOST, reason)
    reason = jnp.where(done | busy, NO_REPLAN, reason)
    return reason != NO_REPLAN, reason.astype(jnp.int32)


class Perception(NamedTuple):
    """What the car perceives now: boxes ``(K, 5)``, velocities ``(K, 2)`` (m/s), valid ``(K,)``.
    Slot ``k`` is one object across ticks (a track id)."""

    boxes: jnp.ndarray
    vel: jnp.ndarray
    valid: jnp.ndarray


class CarState(NamedTuple):
    """The car: pose ``(3,)``, signed speed ``()`` (> 0 forward), arc length ``s ()`` along the
    current plan (the tracking controller's progress)."""

    pose: jnp.ndarray
    v: jnp.ndarray
    s: jnp.ndarray


class SupervisorState(NamedTuple):
    """Everything the supervisor keeps between ticks (one instance; add a leading axis to batch)."""

    plan: Plan
    boxes: jnp.ndarray
    lo: jnp.ndarray
    hi: jnp.ndarray
    dirs: jnp.ndarray
    nsub: jnp.ndarray
    k: jnp.ndarray
    track_idx: jnp.ndarray
    lost_t: jnp.ndarray
    queue: CollisionQueue
    memory: ObstacleMemory
    brake: BrakeStop
    plan_goal: jnp.ndarray
    last_replan_t: jnp.ndarray
    tick: jnp.ndarray
    pending: jnp.ndarray
    pending_plan: Plan
    ready_t: jnp.ndarray
    req_s: jnp.ndarray
    req_v: jnp.ndarray
    stitch_s: jnp.ndarray
    pending_goal: jnp.ndarray
    first: jnp.ndarray
    done: jnp.ndarray
    n_replan: jnp.ndarray
    n_replan_moving: jnp.ndarray
    n_reason: jnp.ndarray
    n_rejected: jnp.ndarray
    n_jumps: jnp.ndarray


class Decision(NamedTuple):
    """What one tick decided (all jnp arrays).

    replan / reason: ask the planner now (with ``request``), and why. installed: a new
    plan was installed this tick; the car's arc length on it is ``car.s - s_offset``.
    rejected ``(3,)``: a new plan arrived and was refused (collision, gear, stale).
    stop_s: arc length on the (current) plan where the car must stand (brake-stop
    point or the end of its sub-trajectory); s_end: the end of its sub-trajectory;
    direction: +1 / -1 the gear of the sub-trajectory the car drives; vmax: its top
    speed; new_collision: a collision point was found this tick; arrived: the car
    stands at the end of a plan that reaches the goal; lost: tracking lost for
    ``lost_time`` (the car brakes).
    """

    replan: jnp.ndarray
    reason: jnp.ndarray
    request: PlanRequest
    installed: jnp.ndarray
    s_offset: jnp.ndarray
    rejected: jnp.ndarray
    stop_s: jnp.ndarray
    s_end: jnp.ndarray
    direction: jnp.ndarray
    vmax: jnp.ndarray
    new_collision: jnp.ndarray
    arrived: jnp.ndarray
    lost: jnp.ndarray


def placeholder_plan(like: Plan, pose, extra: int = 0) -> Plan:
    """A one-point plan at ``pose (3,)`` with the shapes of ``like`` and ``extra`` more points
    (the car holds it until the first plan arrives)."""
    plan = jax.tree.map(lambda a: jnp.zeros(a.shape[:-1] + (a.shape[-1] + extra,) if a.ndim else (), a.dtype), like)
    tr = plan.traj
    tr = dataclasses.replace(
        tr, x=tr.x + pose[0], y=tr.y + pose[1], theta=tr.theta + pose[2], gear=jnp.ones_like(tr.gear)
    )
    return plan._replace(traj=tr, valid=plan.valid.at[0].set(True), ok=jnp.zeros((), bool))


def init(
    plan_like: Plan, pose, goal, n_obstacles: int, cfg: SupervisorConfig, vehicle: VehicleParams
) -> SupervisorState:
    """State before the first tick: a placeholder plan at ``pose``; the first tick asks for a plan.

    ``plan_like``: a plan of the planner's shape ``(N,)``; the installed plans have
    ``cfg.prefix_points + N`` points (the kept stretch of the old plan, then the new one)."""
    pose = jnp.asarray(pose, plan_like.traj.x.dtype)
    plan = placeholder_plan(plan_like, pose, cfg.prefix_points)
    lo, hi, dirs, nsub = sub_trajectories(plan.traj.gear, plan.valid, cfg.max_sub)
    z, zi, f = jnp.zeros(()), jnp.zeros((), jnp.int32), jnp.zeros((), bool)
    return SupervisorState(
        plan=plan,
        boxes=_car_boxes(plan, vehicle, cfg),
        lo=lo,
        hi=hi,
        dirs=dirs,
        nsub=nsub,
        k=zi,
        track_idx=zi,
        lost_t=z,
        queue=queue_init(cfg.queue_size),
        memory=memory_init(n_obstacles),
        brake=brake_init(),
        plan_goal=jnp.asarray(goal, jnp.float32),
        last_replan_t=z,
        tick=zi,
        pending=f,
        pending_plan=placeholder_plan(plan_like, pose),
        ready_t=z,
        req_s=z,
        req_v=z,
        stitch_s=z,
        pending_goal=jnp.asarray(goal, jnp.float32),
        first=jnp.ones((), bool),
        done=f,
        n_replan=zi,
        n_replan_moving=zi,
        n_reason=jnp.zeros((5,), jnp.int32),
        n_rejected=jnp.zeros((3,), jnp.int32),
        n_jumps=zi,
    )


def _car_boxes(plan: Plan, vehicle: VehicleParams, cfg: SupervisorConfig):
    """Car boxes ``(N, 5)`` along a plan, grown by ``cfg.clearance`` on each side."""
    return poses_to_boxes(plan.traj.xy, plan.traj.theta, vehicle).at[:, 2:4].add(2 * cfg.clearance)


def _contacts(plan: Plan, boxes, check, tau, obs, vel, age, valid, cfg: SupervisorConfig):
    """Per-obstacle first contact on ``plan``: (index ``(K,)``, arc length ``(K,)``, found ``(K,)``),
    and the overall first (index, arc length, found, slot)."""
    sep = plan_separation(boxes, tau, check, obs, vel, age, valid, cfg.before, cfg.after)  # (N, K)
    idx, s, found = jax.vmap(lambda c: first_contact(c, plan.s_abs, 0), in_axes=1)(sep)
    slot = jnp.argmin(jnp.where(found, s, jnp.inf))
    return idx, s, found, slot


def _leg_times(plan: Plan, lo, hi, dirs, k, s0, v0, cfg: SupervisorConfig):
    """Arrival times ``(N,)`` on sub-trajectory ``k`` from arc length ``s0`` at speed ``v0 >= 0``."""
    return arrival_times(plan.s_abs, s0, v0, plan.s_abs[hi[k]], cfg.limits.vmax(dirs[k]), cfg.limits)


def check_new_plan(plan: Plan, boxes, s0, v0, per: Perception, cfg: SupervisorConfig):
    """Whether a plan collides with the obstacles perceived now, seen from a car at arc length
    ``s0`` with speed ``v0 >= 0`` on its first sub-trajectory: that sub-trajectory time-aware
    (from ``s0`` on), later ones with static obstacles.

    Returns (collides ``()``, sub-trajectory bounds ``(lo, hi, dirs, nsub)``)."""
    lo, hi, dirs, nsub = sub_trajectories(plan.traj.gear, plan.valid, cfg.max_sub)
    i = jnp.arange(plan.valid.shape[0])
    tau = _leg_times(plan, lo, hi, dirs, 0, s0, v0, cfg)
    first_leg = (i <= hi[0]) & plan.valid
    later = (i > hi[0]) & plan.valid
    z = jnp.zeros(per.valid.shape, per.boxes.dtype)
    static = jnp.linalg.norm(per.vel, axis=-1) < 1e-6
    sep1 = plan_separation(boxes, tau, first_leg, per.boxes, per.vel, z, per.valid, cfg.before, cfg.after)
    sep2 = plan_separation(boxes, jnp.zeros_like(tau), later, per.boxes, per.vel, z, per.valid & static, 0.0, 0.0)
    return jnp.any(sep1 < 0) | jnp.any(sep2 < 0), (lo, hi, dirs, nsub)


def stitch(old: Plan, s_from, s_to, gear, new: Plan, v0, cfg: SupervisorConfig) -> Plan:
    """The plan to install: the old plan from arc length ``s_from`` (where the car was when it
    asked) to ``s_to`` (the new plan's start) in ``cfg.prefix_points`` points driven in
    ``gear``, then the new plan; speed profile and time stamps again from speed ``v0``.

    Returns a plan of ``prefix_points + N`` points (``N`` the new plan's)."""
    n_p = cfg.prefix_points
    u = jnp.linspace(0.0, 1.0, n_p)
    sp = s_from + u * (s_to - s_from)
    p, h, _ = jax.vmap(lambda q: interpolate_pose(old.traj.xy, old.traj.theta, old.s_abs, q))(sp)
    h = h + 2 * jnp.pi * jnp.round((new.traj.theta[0] - h[-1]) / (2 * jnp.pi))  # same branch as the new plan
    xy = jnp.concatenate([p, new.traj.xy])
    theta = jnp.concatenate([h, new.traj.theta])
    g = jnp.concatenate([jnp.full((n_p,), gear, new.traj.gear.dtype), new.traj.gear])
    # The new plan's first point repeats the junction; it belongs to the prefix's gear.
    g = g.at[n_p].set(gear)
    valid = jnp.concatenate([jnp.ones((n_p,), bool), new.valid])
    return finish_plan(xy, theta, g, valid, v0, cfg.limits, new.ok)


def submit(state: SupervisorState, plan: Plan, decision: Decision) -> SupervisorState:
    """Hand the planner's answer to a request of this tick's ``decision`` (no-op when it asked none)."""
    pend = jax.tree.map(lambda a, b: jnp.where(decision.replan, a, b), plan, state.pending_plan)
    return state._replace(pending_plan=pend)


def supervise(
    state: SupervisorState,
    car: CarState,
    per: Perception,
    goal_est,
    t,
    strategy,
    park,
    cfg: SupervisorConfig,
    vehicle: VehicleParams,
):
    """One tick at time ``t``: install an arrived plan (after checking it), track, find
    collision points, update queue and brake-stop point, decide whether to re-plan.

    Args:
        state: from the last tick (or ``init``).
        car: the car now (its ``s`` on ``state.plan``).
        per: perception now.
        goal_est: ``(3,)`` believed goal.
        t: ``()`` time (s).
        strategy: ``()`` int code; park: ``()`` bool, a parking approach (for the request's phase).

    Returns:
        (state, ``Decision``). When ``decision.replan``, call the planner on
        ``decision.request`` and pass its plan to ``submit`` (it is installed
        ``latency_s`` later, if it passes the check).
    """
    dt = jnp.asarray(cfg.dt, jnp.float32)
    speed = jnp.abs(car.v)
    moving = speed >= cfg.v_stopped

    # 1. A plan that has arrived: stitch it behind the stretch the car drove meanwhile, check it,
    #    then install it or keep the old one.
    arrive = state.pending & (t >= state.ready_t - 1e-4)
    old = state.plan
    new = stitch(old, state.req_s, state.stitch_s, state.dirs[state.k], state.pending_plan, state.req_v, cfg)
    new_boxes = _car_boxes(new, vehicle, cfg)
    s_rel = car.s - state.req_s
    stale = (s_rel < -cfg.stitch_tol) | (car.s > state.stitch_s + cfg.stitch_tol)
    collides, (lo_n, hi_n, dirs_n, nsub_n) = check_new_plan(new, new_boxes, jnp.maximum(s_rel, 0.0), speed, per, cfg)
    # A gear change needs the car stopped: the first sub-trajectory must not end (in a gear shift)
    # nearer than the car's braking distance.
    to_shift = new.s_abs[hi_n[0]] - jnp.maximum(s_rel, 0.0)
    gear_bad = moving & (nsub_n > 1) & (to_shift < speed**2 / (2 * cfg.limits.decel) - 0.05)
    bad = jnp.stack([collides & ~stale, gear_bad & ~stale & ~collides, stale])
    accept = arrive & ~jnp.any(bad)
    rejected = arrive & bad
    # Re-anchor the queue: where each remembered obstacle meets the new plan's first sub-trajectory.
    mem = state.memory
    i = jnp.arange(new.valid.shape[0])
    tau_n = _leg_times(new, lo_n, hi_n, dirs_n, 0, jnp.maximum(s_rel, 0.0), speed, cfg)
    idx_m, s_m, found_m, _ = _contacts(
        new, new_boxes, (i <= hi_n[0]) & new.valid, tau_n, mem.box, mem.vel, t - mem.t, mem.valid, cfg
    )
    q_new = queue_reanchor(state.queue, jnp.where(found_m, s_m, jnp.inf), new.traj.xy[idx_m])
    brake_new = update_brake_stop(brake_init(), q_new, cfg.brake_safety)
    new_last = last_valid_index(new.valid)
    jump = jnp.linalg.norm(new.traj.xy[new_last] - old.traj.xy[last_valid_index(old.valid)]) > 0.1
    installed = state._replace(
        plan=new,
        boxes=new_boxes,
        lo=lo_n,
        hi=hi_n,
        dirs=dirs_n,
        nsub=nsub_n,
        k=jnp.zeros((), jnp.int32),
        track_idx=jnp.zeros((), jnp.int32),
        queue=q_new,
        brake=brake_new,
        plan_goal=state.pending_goal,
        n_jumps=state.n_jumps + (jump & ~state.first),
        first=jnp.zeros((), bool),
    )
    st = jax.tree.map(lambda a, b: jnp.where(accept, a, b), installed, state)
    st = st._replace(pending=state.pending & ~arrive, n_rejected=state.n_rejected + rejected)
    s = jnp.where(accept, jnp.maximum(s_rel, 0.0), car.s)
    s_offset = jnp.where(accept, car.s - s, 0.0)

    # 2. Tracking point on the current sub-trajectory.
    plan, k = st.plan, st.k
    old_last = last_valid_index(plan.valid)
    xy = plan.traj.xy
    lo_k, hi_k, dir_k = st.lo[k], st.hi[k], st.dirs[k]
    start = jnp.maximum(st.track_idx, lo_k)
    tp = find_tracking_point_directional(
        xy, plan.traj.gear, car.pose[:2], car.pose[2], dir_k, start, hi_k, cfg.track_window, cfg.track_max_dist
    )
    at_point = jnp.linalg.norm(xy[start] - car.pose[:2]) <= cfg.at_point_tol
    track_idx = jnp.where(tp.found, tp.index, start)
    lost_t = jnp.where(tp.found | at_point | st.first, 0.0, st.lost_t + dt)

    # 3. Collision points (time-aware) from the tracking point to the end of the sub-trajectory.
    check = (st.tick % cfg.collision_every) == 0
    tau = _leg_times(plan, st.lo, st.hi, st.dirs, k, s, speed, cfg)
    rng = (i >= track_idx) & (i <= hi_k) & plan.valid
    z = jnp.zeros(per.valid.shape, per.boxes.dtype)
    idx_c, s_c, found_c, slot = _contacts(plan, st.boxes, rng, tau, per.boxes, per.vel, z, per.valid, cfg)
    new_collision = check & found_c[slot] & ~st.done & ~st.first
    q = queue_push(st.queue, t, s_c[slot], xy[idx_c[slot]], new_collision, slot)
    memory = memory_update(st.memory, slot, per.boxes[slot], per.vel[slot], t, new_collision)
    q = queue_expire(q, t, cfg.window_s)
    memory = memory._replace(valid=memory.valid & (t - memory.t <= cfg.window_s))
    brake = update_brake_stop(st.brake, q, cfg.brake_safety)

    # 4. Where the car is, and the decision.
    stopped = ~moving
    s_hi = plan.s_abs[hi_k]
    at_end = s_hi - s < cfg.at_point_tol
    at_gear_shift = (k < st.nsub - 1) & at_end
    at_final = (k == st.nsub - 1) & at_end
    at_brake = brake.active & (brake.s - s < cfg.at_point_tol)
    # The goal moved: the believed goal is off where the plan ends (not off the goal it was made for:
    # a plan may end anywhere in the planner's goal region).
    plan_end = jnp.stack([plan.traj.x[old_last], plan.traj.y[old_last], plan.traj.theta[old_last]])
    moved = goal_moved(goal_est, plan_end, cfg)
    lost = lost_t >= cfg.lost_time
    arrived = ~st.first & at_final & stopped & ~at_brake & plan.ok & ~st.pending
    done = st.done | arrived
    since = t - st.last_replan_t
    replan, reason = replan_decision(
        strategy,
        cfg,
        stopped=stopped,
        at_gear_shift=at_gear_shift,
        at_brake_stop=at_brake,
        goal_moved=moved,
        new_collision=new_collision,
        lost_stopped=lost & stopped,
        since_replan=since,
        done=done,
        at_blocked_end=at_final & ~plan.ok & ~st.first,
        busy=st.pending,
    )
    replan = (replan | st.first) & ~st.pending
    counted = replan & ~st.first

    # 5. The request: from where the car will be when the plan arrives, or from the end of the
    #    sub-trajectory when that is nearer than keep_s (the old plan is kept up to there).
    brake_stop = jnp.where(brake.active, jnp.minimum(brake.s, s_hi), s_hi)
    vmax = cfg.limits.vmax(dir_k)
    s_st, v_st = advance(s, speed, brake_stop, s_hi, vmax, cfg.limits, dt, cfg.latency_steps)
    hold = lost | st.first
    to_end = ~hold & (s_hi - s_st < cfg.keep_s) & (brake_stop >= s_hi - 1e-6)
    s_st = jnp.where(hold, s, jnp.where(to_end, s_hi, s_st))
    v_st = jnp.where(hold | to_end, 0.0, v_st)
    p_st, h_st, _ = interpolate_pose(xy, plan.traj.theta, plan.s_abs, s_st)
    pose_st = jnp.where(st.first, car.pose, jnp.concatenate([p_st, h_st[None]]))
    at_shift_then = (k < st.nsub - 1) & (s_hi - s_st < cfg.at_point_tol) & (v_st < cfg.v_stopped)
    k_req = jnp.where(at_shift_then, k + 1, k)
    gear_req = jnp.where(st.first, 1, st.dirs[k_req]).astype(jnp.int32)
    final_leg = park & ~st.first & (k_req == st.nsub - 1) & (st.dirs[k_req] < 0)
    lat = cfg.latency_steps * dt
    request = PlanRequest(
        start=pose_st,
        speed=gear_req * v_st,
        gear=gear_req,
        phase=jnp.where(final_leg, -1, 1).astype(jnp.int32),
        goal=goal_est,
        obstacles=per.boxes.at[:, :2].add(per.vel * lat),
        obstacles_vel=per.vel,
        obstacles_valid=per.valid,
        park=jnp.asarray(park),
        prev_end=jnp.stack([plan.traj.x[old_last], plan.traj.y[old_last], plan.traj.theta[old_last]]),
        prev_via=jnp.stack([plan.traj.x[hi_k], plan.traj.y[hi_k], plan.traj.theta[hi_k]]),
    )

    # 6. Gear shift at the end of a sub-trajectory (stopped, no plan in the making).
    shift = at_gear_shift & stopped & ~replan & ~st.pending
    k_next = jnp.where(shift, k + 1, k)
    track_next = jnp.where(shift, st.lo[jnp.minimum(k_next, st.lo.shape[0] - 1)], track_idx)

    st = st._replace(
        k=k_next,
        track_idx=track_next,
        lost_t=lost_t,
        queue=q,
        memory=memory,
        brake=brake,
        tick=st.tick + 1,
        done=done,
        pending=st.pending | replan,
        ready_t=jnp.where(replan, t + lat, st.ready_t),
        stitch_s=jnp.where(replan, s_st, st.stitch_s),
        req_s=jnp.where(replan, s, st.req_s),
        req_v=jnp.where(replan, speed, st.req_v),
        pending_goal=jnp.where(replan, goal_est, st.pending_goal),
        last_replan_t=jnp.where(replan, t, st.last_replan_t),
        n_replan=st.n_replan + counted,
        n_replan_moving=st.n_replan_moving + (counted & moving),
        n_reason=st.n_reason + (counted & (jnp.arange(5) == reason)),
    )
    hi_now = st.hi[k_next]
    s_end = plan.s_abs[hi_now]
    stop_s = jnp.where(brake.active, jnp.minimum(brake.s, s_end), s_end)
    dec = Decision(
        replan=replan,
        reason=jnp.where(counted, reason, NO_REPLAN),
        request=request,
        installed=accept,
        s_offset=s_offset,
        rejected=rejected,
        stop_s=stop_s,
        s_end=s_end,
        direction=st.dirs[k_next],
        vmax=cfg.limits.vmax(st.dirs[k_next]),
        new_collision=new_collision,
        arrived=arrived,
        lost=lost,
    )
    return st, dec
