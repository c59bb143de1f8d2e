"""Closed-loop simulator: a car, noisy perception, a planner callback and the supervisor.

One simulation step (``dt``, default 0.1 s) is:

1. **Perception.** The goal slot is observed with a bias that shrinks with the
   square of the distance to it plus white noise; the believed goal is an
   exponential average of the observations. Obstacles within ``sensor_range``:
   real static boxes (always there), phantoms (false positives that show for a
   short time when the car first comes near, then vanish), and dynamic
   obstacles that cross the path and leave (reported as the box swept over the
   next ``sweep_s`` seconds).
2. **Supervisor.** Direction-aware tracking point search from the last
   tracking point; collision points at ``collision_hz`` into the time-stamped
   queue; expiry; brake-stop point; re-plan decision (:mod:`supervisor`).
3. **Planner callback** when the decision says so, from the car's current pose.
4. **Car.** Exact tracking with noise: the car advances along the plan by its
   speed and carries a small random lateral offset; the speed follows
   ``min(v + a dt, vmax, sqrt(2 a_brake d), d / dt)`` towards the next stop
   point (sub-trajectory end or brake-stop point, distance ``d``), never braking
   harder than ``a_emergency``.
5. **Truth.** Collisions of the car box with real and dynamic obstacles; success
   when the car stops at the end of its plan within tolerance of the *true* goal.

Everything from step 1 to 5 is jittable: :func:`simulate` runs the loop as one
``lax.scan`` and ``vmap``s it over seeds (the planner must then be jittable; under
``vmap`` the planner call becomes a select, so it is evaluated every step).
:func:`simulate_host` runs the same jitted halves of a step in a Python loop and
calls the planner only on re-plans: for planners that are not jittable.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.boxes import box_has_overlap, poses_to_boxes
from jaxplan.replan.planner import Plan, PlanRequest, SimplePlanner
from jaxplan.replan.queue import (BrakeStop, CollisionQueue, brake_init, collision_arc_length, queue_clear,
                                  queue_expire, queue_init, queue_push, queue_size, update_brake_stop)
from jaxplan.replan.supervisor import SupervisorConfig, goal_moved, replan_decision
from jaxplan.replan.tracking import find_tracking_point_directional
from jaxplan.replan.trajectory import interpolate_pose, last_valid_index, sub_trajectories
from jaxplan.types import is_concrete


class Scenario(NamedTuple):
    """One closed-loop run (add a leading axis to batch).

    start, goal: ``(3,)`` car start and *true* goal pose; park: ``()`` bool;
    goal_bias: ``(3,)`` observation bias far from the goal (decays as
    ``min(1, dist / bias_range)^2``); goal_sigma, yaw_sigma: ``()`` noise;
    real: ``(R, 5)`` static boxes, real_valid ``(R,)``;
    phantom: ``(P, 5)``, phantom_valid, phantom_range (shows when the car is this
    near), phantom_dur (for this long) ``(P,)``;
    dyn_point ``(D, 2)`` crossing point, dyn_dir ``(D, 2)`` unit walking direction,
    dyn_speed ``(D,)``, dyn_size ``(D, 2)``, dyn_range ``(D,)`` (starts walking,
    ``dyn_lead`` metres before the crossing point, when the car is this near), dyn_valid ``(D,)``;
    key: ``(2,)`` uint32 noise key.
    """

    start: Any
    goal: Any
    park: Any
    goal_bias: Any
    goal_sigma: Any
    yaw_sigma: Any
    real: Any
    real_valid: Any
    phantom: Any
    phantom_valid: Any
    phantom_range: Any
    phantom_dur: Any
    dyn_point: Any
    dyn_dir: Any
    dyn_speed: Any
    dyn_size: Any
    dyn_range: Any
    dyn_valid: Any
    key: Any


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Simulator settings (static, hashable)."""

    supervisor: SupervisorConfig = SupervisorConfig()
    planner: Callable = SimplePlanner()
    steps: int = 400
    sensor_range: float = 10.0
    bias_range: float = 20.0
    goal_ema: float = 0.2
    accel: float = 1.0
    a_brake: float = 2.0
    a_emergency: float = 6.0
    lat_sigma: float = 0.02
    lat_max: float = 0.1
    sweep_s: float = 2.0
    dyn_lead: float = 4.0
    success_pos: float = 0.35
    success_yaw: float = 0.12
    jump_thresh: float = 0.1


class SimState(NamedTuple):
    t: Any
    step: Any
    key: Any
    plan: Plan
    plan_goal: Any
    boxes: Any
    lo: Any
    hi: Any
    dirs: Any
    nsub: Any
    k: Any
    s_car: Any
    lat: Any
    v: Any
    pose: Any
    track_idx: Any
    lost_t: Any
    queue: CollisionQueue
    brake: BrakeStop
    goal_est: Any
    last_replan_t: Any
    ph_seen: Any
    dyn_t0: Any
    done: Any
    success: Any
    collided: Any
    t_done: Any
    n_replan: Any
    n_unnecessary: Any
    n_jumps: Any
    n_replan_moving: Any
    n_reason: Any
    first: Any


class StepLog(NamedTuple):
    """Per-step record (each ``()``; ``(S, T)`` after a batched run)."""

    t: Any
    v: Any
    queue_size: Any
    brake_dist: Any
    replan: Any
    reason: Any
    necessary: Any
    x: Any
    y: Any
    heading: Any
    collided: Any
    done: Any


class _Pre(NamedTuple):
    state: SimState
    replan: Any
    reason: Any
    necessary: Any
    request: PlanRequest
    at_gear_shift: Any


# ---------------------------------------------------------------- perception / truth

def _dyn_boxes(sc: Scenario, cfg: SimConfig, t, dyn_t0, sweep):
    """Dynamic obstacle boxes ``(D, 5)`` and active mask ``(D,)`` at time ``t``."""
    walked = sc.dyn_speed * jnp.maximum(t - dyn_t0, 0.0)
    active = sc.dyn_valid & (t >= dyn_t0) & (walked <= 2 * cfg.dyn_lead)
    ext = sc.dyn_speed * sweep
    centre = sc.dyn_point + sc.dyn_dir * (walked - cfg.dyn_lead + 0.5 * ext)[:, None]
    heading = jnp.arctan2(sc.dyn_dir[:, 1], sc.dyn_dir[:, 0])
    boxes = jnp.concatenate([centre, (sc.dyn_size[:, 0] + ext)[:, None], sc.dyn_size[:, 1:2], heading[:, None]], -1)
    return boxes, active


def _true_obstacles(sc: Scenario, cfg: SimConfig, t, dyn_t0):
    db, da = _dyn_boxes(sc, cfg, t, dyn_t0, 0.0)
    return jnp.concatenate([sc.real, db]), jnp.concatenate([sc.real_valid, da])


def _perceived(sc: Scenario, cfg: SimConfig, t, pose, ph_seen, dyn_t0):
    db, da = _dyn_boxes(sc, cfg, t, dyn_t0, cfg.sweep_s)
    ph_on = sc.phantom_valid & (t >= ph_seen) & (t - ph_seen <= sc.phantom_dur)
    boxes = jnp.concatenate([sc.real, sc.phantom, db])
    valid = jnp.concatenate([sc.real_valid, ph_on, da])
    near = jnp.linalg.norm(boxes[:, :2] - pose[:2], axis=-1) <= cfg.sensor_range
    return boxes, valid & near


# ---------------------------------------------------------------- plan installation

def _install(state: SimState, plan: Plan, cfg: SimConfig, goal) -> SimState:
    lo, hi, dirs, nsub = sub_trajectories(plan.traj.gear, plan.valid, cfg.supervisor.max_sub)
    boxes = poses_to_boxes(plan.traj.xy, plan.traj.theta, _vehicle(cfg))
    return state._replace(plan=plan, plan_goal=goal, boxes=boxes, lo=lo, hi=hi, dirs=dirs, nsub=nsub,
                          k=jnp.zeros((), jnp.int32), s_car=jnp.zeros(()), lat=jnp.zeros(()),
                          track_idx=jnp.zeros((), jnp.int32), queue=queue_clear(state.queue),
                          brake=brake_init(), last_replan_t=state.t)


def _vehicle(cfg: SimConfig):
    return getattr(cfg.planner, "vehicle", SimplePlanner().vehicle)


def init_state(sc: Scenario, cfg: SimConfig, plan_fn: Callable | None = None) -> SimState:
    """State at ``t = 0``. The first plan (to the first goal observation, from the
    start) is made by the first step's planner call and is not counted as a re-plan;
    until then the car holds a placeholder plan of the planner's shape.

    ``plan_fn`` (default ``cfg.planner``) only gives the plan's shape (``jax.eval_shape``).
    """
    plan_fn = cfg.planner if plan_fn is None else plan_fn
    key, k1 = jax.random.split(sc.key)
    goal_est = _observe_goal(sc, cfg, sc.start, k1)
    P, D = sc.phantom.shape[0], sc.dyn_point.shape[0]
    req = PlanRequest(jnp.asarray(sc.start, jnp.float32), jnp.zeros(()), jnp.ones((), jnp.int32), goal_est,
                      jnp.zeros((1, 5)), jnp.zeros((1,), bool), jnp.asarray(sc.park))
    shape = jax.eval_shape(plan_fn, req)
    plan = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shape)
    plan = plan._replace(valid=plan.valid.at[0].set(True), traj=dataclasses.replace(plan.traj, 
        x=plan.traj.x + sc.start[0], y=plan.traj.y + sc.start[1], theta=plan.traj.theta + sc.start[2]))
    z = jnp.zeros(())
    zi = jnp.zeros((), jnp.int32)
    st = SimState(t=z, step=zi, key=key, plan=plan, plan_goal=goal_est, boxes=None, lo=None, hi=None, dirs=None,
                  nsub=None, k=zi, s_car=z, lat=z, v=z, pose=jnp.asarray(sc.start, jnp.float32), track_idx=zi,
                  lost_t=z, queue=queue_init(cfg.supervisor.queue_size), brake=brake_init(), goal_est=goal_est,
                  last_replan_t=z, ph_seen=jnp.full((P,), jnp.inf), dyn_t0=jnp.full((D,), jnp.inf),
                  done=jnp.zeros((), bool), success=jnp.zeros((), bool), collided=jnp.zeros((), bool),
                  t_done=jnp.full((), jnp.nan), n_replan=zi, n_unnecessary=zi, n_jumps=zi, n_replan_moving=zi,
                  n_reason=jnp.zeros((5,), jnp.int32), first=jnp.ones((), bool))
    return _install(st, plan, cfg, goal_est)


def _observe_goal(sc: Scenario, cfg: SimConfig, pose, key):
    dist = jnp.linalg.norm(pose[:2] - sc.goal[:2])
    bias = sc.goal_bias * jnp.minimum(1.0, dist / cfg.bias_range) ** 2
    n = jax.random.normal(key, (3,)) * jnp.stack([sc.goal_sigma, sc.goal_sigma, sc.yaw_sigma])
    return sc.goal + bias + n


def _trigger(sc: Scenario, pose, t, ph_seen, dyn_t0):
    ph_near = jnp.linalg.norm(sc.phantom[:, :2] - pose[:2], axis=-1) <= sc.phantom_range
    ph_seen = jnp.where(jnp.isinf(ph_seen) & ph_near & sc.phantom_valid, t, ph_seen)
    dyn_near = jnp.linalg.norm(sc.dyn_point - pose[:2], axis=-1) <= sc.dyn_range
    dyn_t0 = jnp.where(jnp.isinf(dyn_t0) & dyn_near & sc.dyn_valid, t, dyn_t0)
    return ph_seen, dyn_t0


# ---------------------------------------------------------------- one step, in two halves

def step_pre(state: SimState, sc: Scenario, strategy, cfg: SimConfig) -> _Pre:
    """Perception, tracking, collision queue, brake-stop point and the re-plan decision."""
    sup = cfg.supervisor
    t = state.t + sup.dt
    key, kg = jax.random.split(state.key)
    obs = _observe_goal(sc, cfg, state.pose, kg)
    a = cfg.goal_ema
    dyaw = jnp.arctan2(jnp.sin(obs[2] - state.goal_est[2]), jnp.cos(obs[2] - state.goal_est[2]))
    goal_est = jnp.concatenate([(1 - a) * state.goal_est[:2] + a * obs[:2], (state.goal_est[2] + a * dyaw)[None]])
    ph_seen, dyn_t0 = _trigger(sc, state.pose, t, state.ph_seen, state.dyn_t0)
    ob, ov = _perceived(sc, cfg, t, state.pose, ph_seen, dyn_t0)

    plan = state.plan
    xy = plan.traj.xy
    k = state.k
    lo_k, hi_k, dir_k = state.lo[k], state.hi[k], state.dirs[k]
    start = jnp.maximum(state.track_idx, lo_k)
    tp = find_tracking_point_directional(xy, plan.traj.gear, state.pose[:2], state.pose[2], dir_k, start, hi_k,
                                         sup.track_window, sup.track_max_dist)
    at_point = jnp.linalg.norm(xy[start] - state.pose[:2]) <= sup.at_point_tol
    track_idx = jnp.where(tp.found, tp.index, start)
    lost_t = jnp.where(tp.found | at_point, 0.0, state.lost_t + sup.dt)

    check = (state.step % sup.collision_every) == 0
    c_idx, c_s, c_found = collision_arc_length(state.boxes, plan.s_abs, track_idx, hi_k, ob, ov)
    new_collision = check & c_found & ~state.done
    q = queue_push(state.queue, t, c_s, xy[c_idx], new_collision)
    q = queue_expire(q, t, sup.window_s)
    brake = update_brake_stop(state.brake, q, sup.brake_safety)

    stopped = state.v < sup.v_stopped
    s_hi = plan.s_abs[hi_k]
    at_end = s_hi - state.s_car < sup.at_point_tol
    at_gear_shift = (k < state.nsub - 1) & at_end
    at_final = (k == state.nsub - 1) & at_end
    at_brake = brake.active & (brake.s - state.s_car < sup.at_point_tol)
    moved = goal_moved(goal_est, state.plan_goal, sup)
    lost_stopped = (lost_t >= sup.lost_time) & stopped

    now_done = ~state.done & ~state.first & at_final & stopped & ~at_brake & plan.ok
    pos_err = jnp.linalg.norm(state.pose[:2] - sc.goal[:2])
    yaw_err = jnp.abs(jnp.arctan2(jnp.sin(state.pose[2] - sc.goal[2]), jnp.cos(state.pose[2] - sc.goal[2])))
    good = (pos_err <= cfg.success_pos) & (yaw_err <= cfg.success_yaw) & ~state.collided
    done = state.done | now_done
    success = state.success | (now_done & good)
    t_done = jnp.where(now_done, t, state.t_done)

    replan, reason = replan_decision(strategy, sup, stopped=stopped, at_gear_shift=at_gear_shift,
                                     at_brake_stop=at_brake, goal_moved=moved, new_collision=new_collision,
                                     lost_stopped=lost_stopped, since_replan=t - state.last_replan_t, done=done,
                                     at_blocked_end=at_final & ~plan.ok & ~state.first)
    # Was the re-plan needed? The rest of the plan hits a real obstacle now, or its end
    # misses the true goal, or the car is lost.
    tb, tv = _true_obstacles(sc, cfg, t, dyn_t0)
    last = last_valid_index(plan.valid)
    idx = jnp.arange(xy.shape[0])
    rest = (idx >= track_idx) & (idx <= last)
    blocked = jnp.any(box_has_overlap(state.boxes[:, None], tb[None]) & tv[None] & rest[:, None])
    end = jnp.stack([plan.traj.x[last], plan.traj.y[last], plan.traj.theta[last]])
    end_err = jnp.linalg.norm(end[:2] - sc.goal[:2])
    end_yaw = jnp.abs(jnp.arctan2(jnp.sin(end[2] - sc.goal[2]), jnp.cos(end[2] - sc.goal[2])))
    wrong_end = (end_err > cfg.success_pos) | (end_yaw > cfg.success_yaw)
    necessary = blocked | wrong_end | lost_stopped

    replan = replan | state.first
    next_k = jnp.where(at_gear_shift & stopped, k + 1, k)
    phase = jnp.where((next_k == state.nsub - 1) & (state.dirs[next_k] < 0) & sc.park, -1, 1).astype(jnp.int32)
    goal_req = jnp.where(state.first, state.plan_goal, goal_est)
    req = PlanRequest(state.pose, state.v, phase, goal_req, ob, ov, jnp.asarray(sc.park))
    st = state._replace(t=t, key=key, goal_est=goal_est, ph_seen=ph_seen, dyn_t0=dyn_t0, track_idx=track_idx,
                        lost_t=lost_t, queue=q, brake=brake, done=done, success=success, t_done=t_done)
    return _Pre(st, replan, reason, necessary, req, at_gear_shift & stopped)


def step_post(pre: _Pre, new_plan: Plan, sc: Scenario, cfg: SimConfig):
    """Install the new plan (when re-planning), move the car, check true collisions.

    Returns:
        (state, :class:`StepLog`).
    """
    sup = cfg.supervisor
    st0 = pre.state
    replan = pre.replan
    old_last = last_valid_index(st0.plan.valid)
    new_last = last_valid_index(new_plan.valid)
    jump = jnp.linalg.norm(new_plan.traj.xy[new_last] - st0.plan.traj.xy[old_last]) > cfg.jump_thresh
    installed = _install(st0, new_plan, cfg, jnp.where(st0.first, st0.plan_goal, st0.goal_est))
    st = jax.tree.map(lambda a, b: jnp.where(replan, a, b), installed, st0)
    shift = ~replan & pre.at_gear_shift
    k = jnp.where(shift, st.k + 1, st.k)
    track_idx = jnp.where(shift, st.lo[jnp.minimum(k, st.lo.shape[0] - 1)], st.track_idx)
    moving = st0.v >= sup.v_stopped
    first = st0.first
    replan = replan & ~first
    st = st._replace(k=k, track_idx=track_idx, first=jnp.zeros((), bool),
                     n_replan=st.n_replan + replan, n_unnecessary=st.n_unnecessary + (replan & ~pre.necessary),
                     n_jumps=st.n_jumps + (replan & jump), n_replan_moving=st.n_replan_moving + (replan & moving),
                     n_reason=st.n_reason + (replan & (jnp.arange(5) == pre.reason)))

    # Car motion.
    plan = st.plan
    s_hi = plan.s_abs[st.hi[st.k]]
    s_stop = jnp.where(st.brake.active, jnp.minimum(s_hi, st.brake.s), s_hi)
    d = jnp.maximum(s_stop - st.s_car, 0.0)
    vmax = jnp.where(st.dirs[st.k] > 0, getattr(cfg.planner, "v_fwd", 3.0), getattr(cfg.planner, "v_rev", 1.5))
    v = jnp.minimum(jnp.minimum(st.v + cfg.accel * sup.dt, vmax),
                    jnp.minimum(jnp.sqrt(2 * cfg.a_brake * d), d / sup.dt))
    v = jnp.maximum(v, st.v - cfg.a_emergency * sup.dt)
    v = jnp.where(st.lost_t >= sup.lost_time, jnp.maximum(st.v - cfg.a_brake * sup.dt, 0.0), v)
    v = jnp.where(st.done, 0.0, jnp.maximum(v, 0.0))
    s_car = jnp.minimum(st.s_car + v * sup.dt, s_hi)
    v = jnp.where(st.s_car + v * sup.dt > s_hi + 1e-6, (s_hi - st.s_car) / sup.dt, v)
    key, kn = jax.random.split(st.key)
    lat = jnp.where(v > 0, jnp.clip(0.9 * st.lat + cfg.lat_sigma * jax.random.normal(kn), -cfg.lat_max, cfg.lat_max),
                    st.lat)
    p, h, _ = interpolate_pose(plan.traj.xy, plan.traj.theta, plan.s_abs, s_car)
    pose = jnp.concatenate([p + lat * jnp.stack([-jnp.sin(h), jnp.cos(h)]), h[None]])

    tb, tv = _true_obstacles(sc, cfg, st.t, st.dyn_t0)
    car = poses_to_boxes(pose[:2], pose[2], _vehicle(cfg))
    hit = jnp.any(box_has_overlap(car[None], tb) & tv)
    st = st._replace(step=st.step + 1, key=key, s_car=s_car, lat=lat, v=v, pose=pose,
                     collided=st.collided | (hit & ~st.done))
    log = StepLog(t=st.t, v=v, queue_size=queue_size(st.queue),
                  brake_dist=jnp.where(st.brake.active, st.brake.s - s_car, jnp.nan), replan=replan,
                  reason=pre.reason, necessary=pre.necessary, x=pose[0], y=pose[1], heading=pose[2],
                  collided=st.collided, done=st.done)
    return st, log


def _step(state, sc, strategy, cfg: SimConfig):
    pre = step_pre(state, sc, strategy, cfg)
    new_plan = jax.lax.cond(pre.replan, cfg.planner, lambda r: pre.state.plan, pre.request)
    return step_post(pre, new_plan, sc, cfg)


def run_one(sc: Scenario, strategy, cfg: SimConfig):
    """One closed-loop run as a ``lax.scan`` of ``cfg.steps`` steps; the planner sits in a
    ``lax.cond`` and runs only on re-plans. Returns (final state, logs ``(T,)``)."""
    s0 = init_state(sc, cfg)
    return jax.lax.scan(lambda s, _: _step(s, sc, strategy, cfg), s0, None, length=cfg.steps)


def _run_batch(sc: Scenario, strategy, cfg: SimConfig):
    """``lax.scan`` over time of ``vmap``-ed step halves; the ``vmap``-ed planner runs in a
    ``lax.cond`` only on steps where some run of the batch re-plans."""
    pre_b = jax.vmap(step_pre, in_axes=(0, 0, 0, None))
    post_b = jax.vmap(step_post, in_axes=(0, 0, 0, None))
    plan_b = jax.vmap(cfg.planner)

    def body(state, _):
        pre = pre_b(state, sc, strategy, cfg)
        new_plan = jax.lax.cond(jnp.any(pre.replan), plan_b, lambda r: pre.state.plan, pre.request)
        return post_b(pre, new_plan, sc, cfg)

    s0 = jax.vmap(init_state, in_axes=(0, None))(sc, cfg)
    final, logs = jax.lax.scan(body, s0, None, length=cfg.steps)
    return final, jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), logs)


_simulate = jax.jit(_run_batch, static_argnums=2)
_simulate_map = jax.jit(lambda sc, strategy, cfg: jax.lax.map(lambda a: run_one(a[0], a[1], cfg), (sc, strategy)),
                        static_argnums=2)


def simulate(scenarios: Scenario, strategy, cfg: SimConfig = SimConfig(), sequential: bool = False):
    """Batched closed loop over the leading axis of ``scenarios``.

    Default: ``lax.scan`` over time of ``vmap``-ed steps, the planner evaluated
    (for the whole batch) only on steps where some run re-plans. With
    ``sequential=True``: ``lax.map`` of single runs, each planner call in its own
    ``lax.cond`` (same results; better when re-plans are rare but scattered).
    ``strategy``: ``()`` or ``(S,)`` int codes, traced (one compilation serves all
    three strategies and both scenario kinds). Returns (final states, logs ``(S, T)``).
    """
    _check_strategy(strategy)
    n = jax.tree.leaves(scenarios)[0].shape[0]
    strategy = jnp.broadcast_to(jnp.asarray(strategy, jnp.int32), (n,))
    return (_simulate_map if sequential else _simulate)(scenarios, strategy, cfg)


def _check_strategy(strategy):
    if is_concrete(strategy):
        a = np.asarray(strategy)
        if not np.issubdtype(a.dtype, np.integer) or np.any((a < 0) | (a > 2)):
            raise ValueError(f"strategy must be LAZY (0), PERIODIC (1) or IMMEDIATE (2), got {strategy!r}")


_PLANNERS: dict = {}


def _jit_planner(planner):
    if planner not in _PLANNERS:
        _PLANNERS[planner] = jax.jit(planner)
    return _PLANNERS[planner]


_pre_jit = jax.jit(step_pre, static_argnums=3)
_post_jit = jax.jit(step_post, static_argnums=3)


def simulate_host(sc: Scenario, strategy, cfg: SimConfig = SimConfig(), planner: Callable | None = None):
    """The same loop for one scenario in Python, calling ``planner`` (any callable
    ``PlanRequest -> Plan`` with the plan size of the first plan) only on re-plans.

    Returns (final state, list of :class:`StepLog`).
    """
    _check_strategy(strategy)
    planner = cfg.planner if planner is None else planner
    state = init_state(sc, cfg, planner)
    if not isinstance(planner, jax.stages.Wrapped):
        try:
            hash(planner)
            planner = _jit_planner(planner)
        except TypeError:  # unhashable: call it as it is
            pass
    logs = []
    strategy = jnp.asarray(strategy, jnp.int32)
    for _ in range(cfg.steps):
        pre = _pre_jit(state, sc, strategy, cfg)
        new_plan = planner(pre.request) if bool(pre.replan) else pre.state.plan
        state, log = _post_jit(pre, new_plan, sc, cfg)
        logs.append(log)
        if bool(state.done):
            break
    return state, logs


def run_summary(final: SimState) -> dict:
    """Per-run figures (numpy arrays over the batch)."""
    f = jax.tree.map(np.asarray, final)
    return {"replans": f.n_replan, "unnecessary": f.n_unnecessary, "collided": f.collided, "success": f.success,
            "time_to_goal": f.t_done, "end_jumps": f.n_jumps, "replans_moving": f.n_replan_moving,
            "done": f.done, "reasons": f.n_reason}
