"""Closed-loop simulator: a car, noisy perception, a planner callback and the supervisor.

One simulation step (``dt``, default 0.1 s) is:

1. **Perception.** The goal slot is observed with a bias that shrinks with the
   square of the distance to it plus white noise; the believed goal is an
   exponential average of the observations. Obstacles within ``sensor_range``, one
   perception slot each, as their box *now* and their velocity: real static boxes
   (always there), phantoms (false positives that show for a short time when the car
   first comes near, then vanish) and pedestrians that cross the path and leave.
2. **Supervisor** (``jaxplan.replan.supervisor.supervise``, the same for every
   strategy): installs an arrived plan after checking it, tracking, collision points,
   queue, brake-stop point, the re-plan decision.
3. **Planner** for the runs whose supervisor asked, from the request's start (ahead of
   the car when it moves); its plan arrives ``latency_s`` later.
4. **Car.** Exact tracking with noise: the car advances along the plan and carries a
   small random lateral offset; its speed follows the shared longitudinal law
   (``jaxplan.replan.longitudinal.speed_step``) towards the supervisor's stop point
   (end of the sub-trajectory or brake-stop point). Speed is signed by the gear.
5. **Truth.** Collisions of the car box with real obstacles and pedestrians; success
   when the car stops at the end of its plan within tolerance of the *true* goal.

``simulate`` runs the loop as one jitted ``lax.scan`` over time of ``vmap``-ed
steps; in each step the planner runs only for the runs that asked (gathered in chunks
of ``plan_chunk``), so its cost follows the number of re-plans, not the batch size.
``simulate_host`` runs the same jitted halves of a step in a Python loop for one
scenario and calls the planner only on re-plans: for planners that are not jittable.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.boxes import box_has_overlap, poses_to_boxes
from jaxplan.replan.longitudinal import arrival_times, move, speed_step
from jaxplan.replan.path_planner import ApproachPlanner
from jaxplan.replan.planner import Plan, PlanRequest
from jaxplan.replan.prediction import plan_separation
from jaxplan.replan.supervisor import (
    CarState,
    Decision,
    Perception,
    SupervisorConfig,
    SupervisorState,
    init,
    submit,
    supervise,
)
from jaxplan.replan.trajectory import interpolate_pose, last_valid_index
from jaxplan.types import is_concrete


class ManeuverScenario(NamedTuple):
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
class ManeuverSimConfig:
    """Simulator settings (static, hashable). The car's longitudinal limits are the
    supervisor's ``limits``; the planner must plan with the same ones. A planner that says
    how close its plans may pass the obstacles (a ``clearance`` attribute, in metres) must
    keep at least the supervisor's ``clearance``: the supervisor grows the car by that much
    when it checks a new plan, so it would reject every plan that passes closer."""

    supervisor: SupervisorConfig = SupervisorConfig()
    planner: Callable = ApproachPlanner()
    steps: int = 400
    sensor_range: float = 10.0
    bias_range: float = 20.0
    goal_ema: float = 0.2
    lat_sigma: float = 0.02
    lat_max: float = 0.1
    dyn_lead: float = 4.0
    success_pos: float = 0.35
    success_yaw: float = 0.12
    plan_chunk: int = 8

    def __post_init__(self):
        lim = getattr(self.planner, "limits", None)
        if lim is not None and lim != self.supervisor.limits:
            raise ValueError("ManeuverSimConfig: planner.limits must equal supervisor.limits (one longitudinal model)")
        keeps = getattr(self.planner, "clearance", None)
        if keeps is not None and self.supervisor.clearance > float(keeps) + 1e-9:
            raise ValueError(
                f"ManeuverSimConfig: supervisor.clearance ({self.supervisor.clearance} m) exceeds the planner's "
                f"clearance ({float(keeps):.4f} m): the supervisor would reject every plan that passes an obstacle "
                "closer than its clearance; use SupervisorConfig(clearance=planner.clearance) or less"
            )
        if self.steps < 1 or self.plan_chunk < 1:
            raise ValueError("ManeuverSimConfig.steps and plan_chunk must be >= 1")

    @property
    def vehicle(self):
        return getattr(self.planner, "vehicle", ApproachPlanner().vehicle)


class WorldState(NamedTuple):
    t: Any
    key: Any
    sup: SupervisorState
    pose: Any
    v: Any
    s: Any
    lat: Any
    goal_est: Any
    ph_seen: Any
    dyn_t0: Any
    done: Any
    success: Any
    collided: Any
    t_done: Any
    n_unnecessary: Any


class StepLog(NamedTuple):
    """Per-step record (each ``()``; ``(S, T)`` after a batched run). ``v`` is signed
    (> 0 forward), ``gear`` the gear of the sub-trajectory driven; ``brake_dist`` the
    distance to the brake-stop point (nan: none); ``replan`` a request this step,
    ``installed`` / ``rejected`` a plan that arrived this step."""

    t: Any
    v: Any
    gear: Any
    queue_size: Any
    brake_dist: Any
    replan: Any
    reason: Any
    installed: Any
    rejected: Any
    necessary: Any
    x: Any
    y: Any
    heading: Any
    collided: Any
    done: Any


class _Pre(NamedTuple):
    world: WorldState
    dec: Decision
    necessary: Any


# ---------------------------------------------------------------- perception / truth


def _dyn_boxes(sc: ManeuverScenario, cfg: ManeuverSimConfig, t, dyn_t0):
    """Pedestrian boxes ``(D, 5)``, velocities ``(D, 2)`` and active mask ``(D,)`` at time ``t``."""
    walked = sc.dyn_speed * jnp.maximum(t - dyn_t0, 0.0)
    active = sc.dyn_valid & (t >= dyn_t0) & (walked <= 2 * cfg.dyn_lead)
    centre = sc.dyn_point + sc.dyn_dir * (walked - cfg.dyn_lead)[:, None]
    heading = jnp.arctan2(sc.dyn_dir[:, 1], sc.dyn_dir[:, 0])
    boxes = jnp.concatenate([centre, sc.dyn_size, heading[:, None]], -1)
    return boxes, sc.dyn_dir * sc.dyn_speed[:, None], active


def _true_obstacles(sc: ManeuverScenario, cfg: ManeuverSimConfig, t, dyn_t0):
    db, dv, da = _dyn_boxes(sc, cfg, t, dyn_t0)
    return (
        jnp.concatenate([sc.real, db]),
        jnp.concatenate([jnp.zeros_like(sc.real[:, :2]), dv]),
        jnp.concatenate([sc.real_valid, da]),
    )


def _perceive(sc: ManeuverScenario, cfg: ManeuverSimConfig, t, pose, ph_seen, dyn_t0) -> Perception:
    db, dv, da = _dyn_boxes(sc, cfg, t, dyn_t0)
    ph_on = sc.phantom_valid & (t >= ph_seen) & (t - ph_seen <= sc.phantom_dur)
    boxes = jnp.concatenate([sc.real, sc.phantom, db])
    vel = jnp.concatenate([jnp.zeros_like(sc.real[:, :2]), jnp.zeros_like(sc.phantom[:, :2]), dv])
    valid = jnp.concatenate([sc.real_valid, ph_on, da])
    near = jnp.linalg.norm(boxes[:, :2] - pose[:2], axis=-1) <= cfg.sensor_range
    return Perception(boxes, vel, valid & near)


def _observe_goal(sc: ManeuverScenario, cfg: ManeuverSimConfig, pose, key):
    dist = jnp.linalg.norm(pose[:2] - sc.goal[:2])
    bias = sc.goal_bias * jnp.minimum(1.0, dist / cfg.bias_range) ** 2
    n = jax.random.normal(key, (3,)) * jnp.stack([sc.goal_sigma, sc.goal_sigma, sc.yaw_sigma])
    return sc.goal + bias + n


def _trigger(sc: ManeuverScenario, pose, t, ph_seen, dyn_t0):
    ph_near = jnp.linalg.norm(sc.phantom[:, :2] - pose[:2], axis=-1) <= sc.phantom_range
    ph_seen = jnp.where(jnp.isinf(ph_seen) & ph_near & sc.phantom_valid, t, ph_seen)
    dyn_near = jnp.linalg.norm(sc.dyn_point - pose[:2], axis=-1) <= sc.dyn_range
    dyn_t0 = jnp.where(jnp.isinf(dyn_t0) & dyn_near & sc.dyn_valid, t, dyn_t0)
    return ph_seen, dyn_t0


def _plan_shape(cfg: ManeuverSimConfig, n_obs: int):
    """Shapes of the planner's plan (``jax.eval_shape``)."""
    z3 = jnp.zeros((3,))
    req = PlanRequest(
        z3,
        jnp.zeros(()),
        jnp.ones((), jnp.int32),
        jnp.ones((), jnp.int32),
        z3,
        jnp.zeros((n_obs, 5)),
        jnp.zeros((n_obs, 2)),
        jnp.zeros((n_obs,), bool),
        jnp.zeros((), bool),
        z3,
        z3,
    )
    return jax.eval_shape(cfg.planner, req)


def init_state(sc: ManeuverScenario, cfg: ManeuverSimConfig) -> WorldState:
    """State at ``t = 0``: the car stands at the start and the first tick asks for the first plan
    (not counted as a re-plan)."""
    key, k1 = jax.random.split(sc.key)
    goal_est = _observe_goal(sc, cfg, sc.start, k1)
    P, D, R = sc.phantom.shape[0], sc.dyn_point.shape[0], sc.real.shape[0]
    like = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), _plan_shape(cfg, R + P + D))
    sup = init(like, sc.start, goal_est, R + P + D, cfg.supervisor, cfg.vehicle)
    z = jnp.zeros(())
    return WorldState(
        t=z,
        key=key,
        sup=sup,
        pose=jnp.asarray(sc.start, jnp.float32),
        v=z,
        s=z,
        lat=z,
        goal_est=goal_est,
        ph_seen=jnp.full((P,), jnp.inf, jnp.float32),
        dyn_t0=jnp.full((D,), jnp.inf, jnp.float32),
        done=jnp.zeros((), bool),
        success=jnp.zeros((), bool),
        collided=jnp.zeros((), bool),
        t_done=jnp.full((), jnp.nan, jnp.float32),
        n_unnecessary=jnp.zeros((), jnp.int32),
    )


# ---------------------------------------------------------------- one step, in two halves


def step_pre(w: WorldState, sc: ManeuverScenario, strategy, cfg: ManeuverSimConfig) -> _Pre:
    """Perception and the supervisor's tick."""
    sup_cfg = cfg.supervisor
    t = w.t + sup_cfg.dt
    key, kg = jax.random.split(w.key)
    obs = _observe_goal(sc, cfg, w.pose, kg)
    a = cfg.goal_ema
    dyaw = jnp.arctan2(jnp.sin(obs[2] - w.goal_est[2]), jnp.cos(obs[2] - w.goal_est[2]))
    goal_est = jnp.concatenate([(1 - a) * w.goal_est[:2] + a * obs[:2], (w.goal_est[2] + a * dyaw)[None]])
    ph_seen, dyn_t0 = _trigger(sc, w.pose, t, w.ph_seen, w.dyn_t0)
    per = _perceive(sc, cfg, t, w.pose, ph_seen, dyn_t0)
    sup, dec = supervise(w.sup, CarState(w.pose, w.v, w.s), per, goal_est, t, strategy, sc.park, sup_cfg, cfg.vehicle)
    # Was a re-plan needed? The rest of the current sub-trajectory meets a real obstacle (time-aware,
    # true motion), or the plan's end misses the true goal, or the car is lost.
    plan = sup.plan
    s = jnp.where(dec.installed, w.s - dec.s_offset, w.s)
    tb, tvel, tv = _true_obstacles(sc, cfg, t, dyn_t0)
    tau = arrival_times(plan.s_abs, s, jnp.abs(w.v), dec.s_end, dec.vmax, sup_cfg.limits)
    sep = plan_separation(sup.boxes, tau, plan.valid, tb, tvel, jnp.zeros(tv.shape), tv, 0.0, 0.0)
    blocked = jnp.any(sep < 0)
    last = last_valid_index(plan.valid)
    end_err = jnp.linalg.norm(plan.traj.xy[last] - sc.goal[:2])
    end_yaw = jnp.abs(
        jnp.arctan2(jnp.sin(plan.traj.theta[last] - sc.goal[2]), jnp.cos(plan.traj.theta[last] - sc.goal[2]))
    )
    necessary = blocked | (end_err > cfg.success_pos) | (end_yaw > cfg.success_yaw) | dec.lost | ~plan.ok
    world = w._replace(t=t, key=key, sup=sup, s=s, goal_est=goal_est, ph_seen=ph_seen, dyn_t0=dyn_t0)
    return _Pre(world, dec, necessary)


def step_post(pre: _Pre, new_plan: Plan, sc: ManeuverScenario, cfg: ManeuverSimConfig):
    """Hand the new plan (when one was asked) to the supervisor, move the car, check the truth.

    Returns:
        (state, ``StepLog``).
    """
    sup_cfg = cfg.supervisor
    w, dec = pre.world, pre.dec
    sup = submit(w.sup, new_plan, dec)
    dt = sup_cfg.dt
    speed = jnp.abs(w.v)
    v = speed_step(speed, dec.stop_s - w.s, dec.vmax, sup_cfg.limits, dt)
    v = jnp.where(dec.lost, jnp.maximum(speed - sup_cfg.limits.decel * dt, 0.0), v)
    v = jnp.where(w.done, 0.0, v)
    s, v = move(w.s, v, dec.s_end, dt)
    key, kn = jax.random.split(w.key)
    lat = jnp.where(
        v > 0, jnp.clip(0.9 * w.lat + cfg.lat_sigma * jax.random.normal(kn), -cfg.lat_max, cfg.lat_max), w.lat
    )
    plan = sup.plan
    p, h, _ = interpolate_pose(plan.traj.xy, plan.traj.theta, plan.s_abs, s)
    pose = jnp.concatenate([p + lat * jnp.stack([-jnp.sin(h), jnp.cos(h)]), h[None]])
    v_signed = dec.direction * v

    tb, _, tv = _true_obstacles(sc, cfg, w.t, w.dyn_t0)
    car = poses_to_boxes(pose[:2], pose[2], cfg.vehicle)
    hit = jnp.any(box_has_overlap(car[None], tb) & tv)
    collided = w.collided | (hit & ~w.done)
    now_done = dec.arrived & ~w.done
    pos_err = jnp.linalg.norm(w.pose[:2] - sc.goal[:2])
    yaw_err = jnp.abs(jnp.arctan2(jnp.sin(w.pose[2] - sc.goal[2]), jnp.cos(w.pose[2] - sc.goal[2])))
    good = (pos_err <= cfg.success_pos) & (yaw_err <= cfg.success_yaw) & ~w.collided
    w = w._replace(
        key=key,
        sup=sup,
        pose=pose,
        v=v_signed,
        s=s,
        lat=lat,
        collided=collided,
        done=w.done | now_done,
        success=w.success | (now_done & good),
        t_done=jnp.where(now_done, w.t, w.t_done),
        n_unnecessary=w.n_unnecessary + (dec.reason > 0) * ~pre.necessary,
    )
    log = StepLog(
        t=w.t,
        v=v_signed,
        gear=dec.direction,
        queue_size=jnp.sum(sup.queue.valid).astype(jnp.int32),
        brake_dist=jnp.where(sup.brake.active, sup.brake.s - s, jnp.nan),
        replan=dec.reason > 0,
        reason=dec.reason,
        installed=dec.installed,
        rejected=jnp.any(dec.rejected),
        necessary=pre.necessary,
        x=pose[0],
        y=pose[1],
        heading=pose[2],
        collided=collided,
        done=w.done,
    )
    return w, log


# ---------------------------------------------------------------- batched loop


def _plan_for(planner, requests: PlanRequest, ask, fallback: Plan, chunk: int) -> Plan:
    """Plans ``(B, ...)`` for the runs with ``ask`` (others get ``fallback``): the asking runs
    are gathered in chunks of ``chunk`` and planned with ``vmap``, as many chunks as needed."""
    b = ask.shape[0]
    c = min(chunk, b)
    order = jnp.argsort(~ask, stable=True).astype(jnp.int32)  # asking runs first
    n_chunks = (jnp.sum(ask) + c - 1) // c
    plan_c = jax.vmap(planner)

    def body(i, out):
        idx = jax.lax.dynamic_slice(order, (jnp.minimum(i * c, b - c),), (c,))
        res = plan_c(jax.tree.map(lambda a: a[idx], requests))
        return jax.tree.map(lambda o, r: o.at[idx].set(r), out, res)

    return jax.lax.fori_loop(0, n_chunks, body, fallback)


def _run_batch(sc: ManeuverScenario, strategy, cfg: ManeuverSimConfig):
    pre_b = jax.vmap(step_pre, in_axes=(0, 0, 0, None))
    post_b = jax.vmap(step_post, in_axes=(0, 0, 0, None))

    def body(state, _):
        pre = pre_b(state, sc, strategy, cfg)
        new_plan = _plan_for(cfg.planner, pre.dec.request, pre.dec.replan, pre.world.sup.pending_plan, cfg.plan_chunk)
        return post_b(pre, new_plan, sc, cfg)

    s0 = jax.vmap(init_state, in_axes=(0, None))(sc, cfg)
    final, logs = jax.lax.scan(body, s0, None, length=cfg.steps)
    return final, jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), logs)


# the jitted batch simulation ``simulate`` runs (strategy static)
simulate_batch = jax.jit(_run_batch, static_argnums=2)


def simulate(scenarios: ManeuverScenario, strategy, cfg: ManeuverSimConfig = ManeuverSimConfig()):
    """Batched closed loop over the leading axis of ``scenarios``: ``lax.scan`` over time of
    ``vmap``-ed steps, the planner run only for the runs that ask.

    ``strategy``: ``()`` or ``(S,)`` int codes, traced (one compilation serves all three
    strategies and both scenario kinds). Returns (final states, logs ``(S, T)``).
    """
    _check_strategy(strategy)
    n = jax.tree.leaves(scenarios)[0].shape[0]
    strategy = jnp.broadcast_to(jnp.asarray(strategy, jnp.int32), (n,))
    return simulate_batch(scenarios, strategy, cfg)


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


def simulate_host(
    sc: ManeuverScenario, strategy, cfg: ManeuverSimConfig = ManeuverSimConfig(), planner: Callable | None = None
):
    """The same loop for one scenario in Python, calling ``planner`` (any callable
    ``PlanRequest -> Plan`` with the plan size of ``cfg.planner``) only on re-plans.

    Returns (final state, list of ``StepLog``).
    """
    _check_strategy(strategy)
    planner = cfg.planner if planner is None else planner
    if not isinstance(planner, jax.stages.Wrapped):
        try:
            hash(planner)
            planner = _jit_planner(planner)
        except TypeError:  # unhashable: call it as it is
            pass
    state = jax.jit(init_state, static_argnums=1)(sc, cfg)
    logs = []
    strategy = jnp.asarray(strategy, jnp.int32)
    for _ in range(cfg.steps):
        pre = _pre_jit(state, sc, strategy, cfg)
        new_plan = planner(pre.dec.request) if bool(pre.dec.replan) else pre.world.sup.pending_plan
        state, log = _post_jit(pre, new_plan, sc, cfg)
        logs.append(log)
        if bool(state.done):
            break
    return state, logs


def run_summary(final: WorldState) -> dict:
    """Per-run figures (numpy arrays over the batch)."""
    f = jax.tree.map(np.asarray, final)
    sup = f.sup
    return {
        "replans": sup.n_replan,
        "unnecessary": f.n_unnecessary,
        "collided": f.collided,
        "success": f.success,
        "time_to_goal": f.t_done,
        "end_jumps": sup.n_jumps,
        "replans_moving": sup.n_replan_moving,
        "done": f.done,
        "reasons": sup.n_reason,
        "rejected": sup.n_rejected,
    }
