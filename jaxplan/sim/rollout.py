"""Closed-loop driving: any ``Planner`` drives a batch of ``Scene``s among their traffic.

The traffic (``SimConfig.agents``): ``log`` replays the recording (non-reactive: it drives
through the car); ``idm`` moves every dynamic obstacle along its recorded path with an IDM
that keeps a gap to whatever is ahead on it, the car included (``jaxplan.sim.agents``).
What the planner sees (``SimConfig.prediction``): ``oracle``, the recorded future (as
CommonRoad benchmarks do; with IDM agents re-anchored where each one actually is), or ``cv``,
the present extrapolated at constant speed along each obstacle's lane
(``jaxplan.sim.prediction``); static obstacles at every time. The log records the traffic as
it was at every step (``DriveLog.traffic``; ``driven_scene`` gives the scene the metrics
judge). Every ``replan_every`` steps the planner plans from the car's state; between
re-plans the car follows the plan through the tracking model (``exact`` or ``bicycle``,
``jaxplan.sim.tracking``). A plan with a NaN or inf in the steps the car would follow is
not followed: the car brakes at ``a_fallback`` along its heading instead (counted).

A drive ends at the first step where the goal is reached (``stop_at_goal``), after the
goal's time interval ends, or at ``n_steps``; its log is valid up to that step. One
``lax.scan`` over planning cycles (each plans once and tracks ``replan_every`` steps),
``jax.vmap`` over scenes, jitted with the planner as a static argument (and with its XLA options).
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.compile_options import jit, options_key
from jaxplan.geometry.frenet import to_frenet
from jaxplan.planner import EgoState, Planner, planner_compiler_options
from jaxplan.sim.agents import AgentParams, agent_boxes, agent_paths, agents_step, init_agents
from jaxplan.sim.metrics.goal import goal_reached
from jaxplan.sim.prediction import PREDICTIONS, lane_cache, planner_view
from jaxplan.sim.tracking import TRACKERS
from jaxplan.types import Obstacles, _pytree

AGENTS = ("log", "idm")


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Static settings of a closed-loop run (hashable).

    Attributes:
        n_steps: steps of ``dt`` simulated (the log has ``n_steps + 1`` states).
        replan_every: steps between re-plans (3 = 0.3 s at dt 0.1).
        tracking: ``"exact"`` or ``"bicycle"``.
        dt: the step (s); must equal the scenes' and the planner's.
        stop_at_goal: end the drive at the first step that meets the goal.
        a_fallback: braking (m/s^2) when a plan is not finite.
        lookahead_time, min_lookahead, speed_gain, substeps: the bicycle tracker (pure
            pursuit look-ahead ``max(min_lookahead, lookahead_time * v)`` m, speed feedback
            gain 1/s, Euler substeps per step).
        replan: ``"periodic"`` (a new plan every ``replan_every`` steps) or ``"lazy"``: every
            ``replan_every`` steps the installed plan is checked and replaced only when it is
            abnormal (the planner's ``ok`` was False), has less than ``lazy_min_remaining``
            seconds left, or its remaining part comes within ``lazy_margin`` m of a predicted
            obstacle (seed 003's rule for road driving; the planner still runs every cycle
            inside the batched scan, so this saves planning work on a car, not here).
        agents: ``"log"`` (the traffic replays its recording) or ``"idm"`` (every dynamic obstacle
            follows its recorded path with an IDM gap to what is ahead of it, the car included:
            ``jaxplan.sim.agents``).
        prediction: what the planner sees of the traffic: ``"oracle"`` (the recorded future; with
            IDM agents re-anchored where they are) or ``"cv"`` (the present, extrapolated at
            constant speed along each obstacle's lane: ``jaxplan.sim.prediction``).
        agent_params: ``AgentParams`` of the IDM agents.
    """

    n_steps: int = 150
    replan_every: int = 3
    tracking: str = "exact"
    dt: float = 0.1
    stop_at_goal: bool = True
    a_fallback: float = -8.0
    lookahead_time: float = 0.8
    min_lookahead: float = 3.0
    speed_gain: float = 1.0
    substeps: int = 4
    replan: str = "periodic"
    lazy_min_remaining: float = 2.0
    lazy_margin: float = 0.2
    agents: str = "log"
    prediction: str = "oracle"
    agent_params: AgentParams = AgentParams()

    def validate(self, planner: Planner | None = None) -> "SimConfig":
        if self.n_steps < 1 or self.replan_every < 1:
            raise ValueError(f"SimConfig: n_steps and replan_every must be >= 1, got {self.n_steps}, {self.replan_every}")
        if self.replan not in ("periodic", "lazy"):
            raise ValueError(f"SimConfig.replan must be 'periodic' or 'lazy', got {self.replan!r}")
        if self.tracking not in TRACKERS:
            raise ValueError(f"SimConfig.tracking must be one of {', '.join(TRACKERS)}, got {self.tracking!r}")
        self.check_traffic()
        if planner is not None:
            if abs(planner.dt - self.dt) > 1e-9:
                raise ValueError(f"planner dt {planner.dt} differs from the simulation's dt {self.dt}")
            if planner.horizon_steps < self.replan_every + 1:
                raise ValueError(f"the planner's horizon ({planner.horizon_steps} steps) is shorter than the "
                                 f"re-plan period ({self.replan_every} steps)")
        return self

    def check_traffic(self) -> "SimConfig":
        """The traffic settings (``agents``, ``prediction``, ``agent_params``); ``drive_one`` checks
        them when it is traced."""
        if self.agents not in AGENTS:
            raise ValueError(f"SimConfig.agents must be one of {', '.join(AGENTS)}, got {self.agents!r}")
        if self.prediction not in PREDICTIONS:
            raise ValueError(f"SimConfig.prediction must be one of {', '.join(PREDICTIONS)}, got {self.prediction!r}")
        if not isinstance(self.agent_params, AgentParams):
            raise ValueError(f"SimConfig.agent_params must be an AgentParams, got {type(self.agent_params).__name__}")
        self.agent_params.validate()
        return self

    @property
    def n_cycles(self) -> int:
        return -(-self.n_steps // self.replan_every)


@_pytree(data_fields=("t", "x", "y", "heading", "v", "a", "kappa", "valid", "end_step", "plan_ok", "fallback",
                      "replanned", "info", "traffic"))
class DriveLog:
    """A drive (add leading batch axes for batches): ``N = n_steps + 1`` states at
    ``t = k dt``, positions of the car's **box centre**.

    Attributes:
        t, x, y, heading, v, a, kappa: ``(N,)``.
        valid: ``(N,)`` bool, True up to the drive's end.
        end_step: ``()`` the last valid step.
        plan_ok: ``(C,)`` the planner's ``ok`` at each cycle (C = cycles); fallback: ``(C,)``
            the plan was not finite and the car braked instead; replanned: ``(C,)`` a new plan was
            installed at that cycle (always, periodic; when needed, lazy) before the drive ended.
        info: the planner's info pytree, ``(C, ...)``.
        traffic: ``Obstacles`` ``(K, N, 5)`` the obstacles as they were at every logged step
            (``valid``, ``static``, ``t = k dt``): the recording with ``log`` agents, the simulated
            agents with ``idm`` ones. ``driven_scene`` puts them in the scene for the metrics.
    """

    t: Any
    x: Any
    y: Any
    heading: Any
    v: Any
    a: Any
    kappa: Any
    valid: Any
    end_step: Any
    plan_ok: Any
    fallback: Any
    replanned: Any
    info: Any
    traffic: Any = None


def driven_scene(log: DriveLog, scene):
    """The scene as driven: ``scene`` with its obstacles replaced by the log's traffic
    (``DriveLog.traffic``, ``N`` steps from ``t = 0``) and their Frenet coordinates on the route,
    so that the metrics (``jaxplan.sim.metrics.evaluate(log, driven_scene(log, scene), vehicle)``,
    which read ``scene.obstacles.window(0, N)``) judge the drive against where the traffic
    really was. Works on one drive or a batch (a leading axis on both), inside or outside jit.
    With ``log`` agents the obstacles are the recording's first ``N`` steps, as before.

    Args:
        log: ``DriveLog`` (with ``traffic``).
        scene: the ``Scene`` it was driven in.

    Returns:
        ``Scene`` with ``obstacles`` ``(K, N, 5)`` and ``obstacle_sl`` ``(K, N, 2)``.
    """
    if log.traffic is None:
        raise ValueError("driven_scene: the DriveLog has no traffic (a log from rollout has it)")
    if jnp.ndim(scene.dt) > 0:
        return jax.vmap(driven_scene)(log, scene)
    obs = log.traffic
    s, l = to_frenet(scene.route, obs.boxes[..., :2])
    return dataclasses.replace(scene, obstacles=obs, obstacle_sl=jnp.stack([s, l], -1))


def _brake(ego: EgoState, n: int, dt: float, a: float) -> EgoState:
    """States ``(n,)`` braking at ``a`` along the current heading."""
    k = jnp.arange(1, n + 1, dtype=jnp.result_type(ego.x))
    tc = jnp.minimum(k * dt, ego.v / -a)
    d = ego.v * tc + 0.5 * a * tc ** 2
    v = jnp.maximum(ego.v + a * k * dt, 0.0)
    c, s = jnp.cos(ego.heading), jnp.sin(ego.heading)
    z = jnp.zeros_like(k)
    return EgoState(ego.x + c * d, ego.y + s * d, ego.heading + z, v, jnp.where(v > 0, a, 0.0), z)


def _finite(tree) -> Any:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree_util.tree_leaves(tree)]))


def _shift(traj, idx):
    """The trajectory from index ``idx`` on (padded with its last point), times from there."""
    H = traj.x.shape[-1]
    k = jnp.clip(idx + jnp.arange(H), 0, H - 1)
    out = jax.tree_util.tree_map(lambda a: a[k], traj)
    return dataclasses.replace(out, t=out.t - traj.t[jnp.clip(idx, 0, H - 1)])


def plan_conflicts(traj, idx, scene, step, vehicle, margin: float):
    """Whether the installed plan, from index ``idx`` on, overlaps a predicted obstacle box
    (grown by ``margin`` m) at the same future step (the lazy policy's collision check)."""
    from jaxplan.geometry.boxes import box_separation, poses_to_boxes

    H = traj.x.shape[-1]
    rest = _shift(traj, idx)
    obs = scene.obstacles.window(step, H)
    car = poses_to_boxes(jnp.stack([rest.x, rest.y], -1), rest.theta, vehicle)  # (H, 5)
    sep = box_separation(car[None], obs.boxes)  # (K, H)
    inside = (jnp.arange(H) + idx) < H
    return jnp.any(obs.valid & inside[None] & (sep < margin))


def drive_one(planner: Planner, scene, config: SimConfig) -> DriveLog:
    """One scene's drive (unbatched; ``rollout`` batches it)."""
    veh = planner.vehicle
    K = config.replan_every
    C = config.n_cycles
    H = planner.horizon_steps
    track = TRACKERS[config.tracking]
    ego0 = EgoState.from_box_centre(scene.start, veh)
    f = jnp.result_type(float)
    ego0 = jax.tree_util.tree_map(lambda a: jnp.asarray(a, f), ego0)
    dt = jnp.asarray(config.dt, f)
    t_end = scene.goal.time[1]
    min_left = int(round(config.lazy_min_remaining / config.dt))
    config.check_traffic()
    idm = config.agents == "idm"
    paths = agent_paths(scene.obstacles, scene.obstacle_sl, dt) if idm else None
    agents0 = init_agents(paths) if idm else None
    lanes = lane_cache(scene) if config.prediction == "cv" else None
    view_len = (C - 1) * K + H  # steps of the planner's view: every cycle's window fits

    def view(step, agents):  # what the planner sees (the scene itself for oracle predictions of the log)
        return planner_view(scene, step, H, view_len, config.prediction, paths, agents, lanes)

    def ego_box(ego):
        f2 = ego.x.dtype
        return jnp.concatenate([ego.box_centre(veh), jnp.stack([jnp.asarray(veh.length, f2),
                                                                jnp.asarray(veh.width, f2), ego.heading])])

    def reached(ego, t):
        c = ego.box_centre(veh)
        return goal_reached(scene.goal, c, ego.heading, ego.v, t)

    def cycle(carry, c):
        ego, done, plan, idx, plan_ok, agents = carry
        step = c * K
        seen = view(step, agents)
        out = planner.plan(seen, ego, step)
        if config.replan == "lazy":  # keep the installed plan unless it is short, abnormal or in conflict
            need = (c == 0) | ~plan_ok | (H - 1 - idx < max(min_left, K)) | \
                plan_conflicts(plan, idx, seen, step, veh, config.lazy_margin)
        else:
            need = jnp.asarray(True)
        plan = jax.tree_util.tree_map(lambda a, b: jnp.where(need, a, b), out.trajectory, plan)
        idx = jnp.where(need, 0, idx)
        plan_ok = jnp.where(need, out.ok, plan_ok)
        traj = _shift(plan, idx)
        head = jax.tree_util.tree_map(lambda a: a[..., :K + 1], traj)
        finite = _finite(head)
        safe = jax.tree_util.tree_map(lambda a: jnp.where(finite, a, 0.0), traj)
        nxt = jax.lax.cond(finite, lambda: track(safe, ego, K, veh, config),
                           lambda: _brake(ego, K, config.dt, config.a_fallback))
        # freeze once the drive has ended; the end is checked at every tracked step
        def step_fn(c2, j):
            e, d, ag = c2
            new = jax.tree_util.tree_map(lambda a: a[j], nxt)
            t = (step + j + 1) * dt
            if idm:  # the agents react to the car where it is now, then both move on
                ag = agents_step(paths, ag, step + j, ego_box(e), e.v, config.dt, config.agent_params)
                moved = agent_boxes(paths, ag, step + j + 1)
            else:
                moved = None
            e = jax.tree_util.tree_map(lambda a, b: jnp.where(d, a, b), e, new)
            end_now = (config.stop_at_goal & reached(e, t)) | (t >= t_end - 1e-6)
            return (e, d | end_now, ag), (e, d, moved)

        (ego_n, done_n, agents_n), (states, was_done, moved) = lax.scan(step_fn, (ego, done, agents), jnp.arange(K))
        carry = (ego_n, done_n, plan, idx + K, plan_ok, agents_n)
        return carry, (states, was_done, out.ok, ~finite, need & ~done, out.info, moved)

    done0 = (config.stop_at_goal & reached(ego0, 0.0)) | (t_end <= 1e-6)
    plan0 = jax.eval_shape(lambda: planner.plan(scene, ego0, 0)).trajectory
    plan0 = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), plan0)
    carry0 = (ego0, done0, plan0, jnp.asarray(0), jnp.asarray(False), agents0)
    _, (states, was_done, ok, fallback, replanned, info, moved) = lax.scan(cycle, carry0, jnp.arange(C))
    flat = jax.tree_util.tree_map(lambda a: a.reshape((C * K,) + a.shape[2:])[:config.n_steps], states)
    was_done = was_done.reshape(C * K)[:config.n_steps]
    seq = jax.tree_util.tree_map(lambda a0, a: jnp.concatenate([jnp.reshape(a0, (1,)), a]), ego0, flat)
    valid = jnp.concatenate([jnp.ones((1,), bool), ~was_done])  # the step that ends the drive is part of it
    centre = seq.box_centre(veh)
    n = config.n_steps + 1
    t = jnp.arange(n, dtype=f) * dt
    end_step = jnp.max(jnp.where(valid, jnp.arange(n), 0))
    if idm:  # the agents at every step: (C, K, K_obstacles, ...) -> (K_obstacles, N, ...)
        b0, v0 = agent_boxes(paths, agents0, 0)
        mb, mv = (a.reshape((C * K,) + a.shape[2:])[:config.n_steps] for a in moved)
        traffic = Obstacles(jnp.swapaxes(jnp.concatenate([b0[None], mb]), 0, 1),
                            jnp.swapaxes(jnp.concatenate([v0[None], mv]), 0, 1), t, paths.static)
    else:
        traffic = scene.obstacles.window(0, n)
    return DriveLog(t, centre[:, 0], centre[:, 1], seq.heading, seq.v, seq.a, seq.kappa, valid, end_step, ok,
                    fallback, replanned, info, traffic)


def _rollout(planner: Planner, scenes, config: SimConfig) -> DriveLog:
    return jax.vmap(lambda s: drive_one(planner, s, config))(scenes)


def compiled_with(options: tuple, fun=_rollout, static=("planner", "config")):
    """``fun`` (arguments ``static`` static) jitted with the XLA ``options`` (``compile_options.options_key``
    of them; ``jaxplan.compile_options.jit``): one program cache per options."""
    return _compiled(options, fun, static)  # one cache key however the defaults were passed


@functools.cache
def _compiled(options: tuple, fun, static: tuple):
    return jit(fun, options=dict(options), static_argnames=static)


def planner_program(planner: Planner, fun=_rollout, static=("planner", "config")):
    """``compiled_with`` the XLA options of ``planner`` (``planner_compiler_options``)."""
    return compiled_with(options_key(planner_compiler_options(planner)), fun, static)


def rollout(planner: Planner, scenes, config: SimConfig = SimConfig()) -> DriveLog:
    """Drive every scene of a batch (leading axis) with ``planner``; jitted (``planner`` and
    ``config`` static) with the planner's XLA options (``planner_compiler_options``): the lattice
    planner's drives run 1.15-1.47x faster with its options (``jaxplan.compile_options``).

    Args:
        planner: a ``Planner`` (hashable; static).
        scenes: a batched ``Scene`` (``jaxplan.scenarios.scene.stack_scenes``).
        config: ``SimConfig``.

    Returns:
        ``DriveLog`` with a leading scene axis.
    """
    return planner_program(planner)(planner, scenes, config=config)
