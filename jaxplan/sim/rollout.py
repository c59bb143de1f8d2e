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

from jaxplan.compile_options import jit, options_key, release_compiled
from jaxplan.geometry.frenet import to_frenet
from jaxplan.models.braking import braking_profile
from jaxplan.planner import EgoState, Planner, check_params, planner_compiler_options
from jaxplan.sim.agents import AgentParams, agent_boxes, agent_paths, agents_step, init_agents
from jaxplan.sim.metrics.goal import goal_reached
from jaxplan.sim.prediction import PREDICTIONS, lane_cache, planner_view
from jaxplan.sim.tracking import TRACKERS
from jaxplan.types import Obstacles, pytree_dataclass

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
            obstacle (a collision-point check of the installed plan; the planner still runs every
            cycle inside the batched scan, so this saves planning work on a car, not here).
        agents: ``"log"`` (the traffic replays its recording) or ``"idm"`` (every dynamic obstacle
            follows its recorded path with an IDM gap to what is ahead of it, the car included:
            ``jaxplan.sim.agents``).
        prediction: what the planner sees of the traffic: ``"oracle"`` (the recorded future; with
            IDM agents re-anchored where they are) or ``"cv"`` (the present, extrapolated at
            constant speed along each obstacle's lane: ``jaxplan.sim.prediction``).
        agent_params: ``AgentParams`` of the IDM agents.
        remat: recompute each planning cycle in the backward pass (``jax.checkpoint``) instead of
            storing its intermediates: memory for a gradient through a drive grows with the cycles'
            states only (no effect on a drive without a gradient).
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
    remat: bool = False

    def validate(self, planner: Planner | None = None) -> SimConfig:
        if self.n_steps < 1 or self.replan_every < 1:
            raise ValueError(
                f"SimConfig: n_steps and replan_every must be >= 1, got {self.n_steps}, {self.replan_every}"
            )
        if self.replan not in ("periodic", "lazy"):
            raise ValueError(f"SimConfig.replan must be 'periodic' or 'lazy', got {self.replan!r}")
        if self.tracking not in TRACKERS:
            raise ValueError(f"SimConfig.tracking must be one of {', '.join(TRACKERS)}, got {self.tracking!r}")
        self.check_traffic()
        if planner is not None:
            if abs(planner.dt - self.dt) > 1e-9:
                raise ValueError(f"planner dt {planner.dt} differs from the simulation's dt {self.dt}")
            if planner.horizon_steps < self.replan_every + 1:
                raise ValueError(
                    f"the planner's horizon ({planner.horizon_steps} steps) is shorter than the "
                    f"re-plan period ({self.replan_every} steps)"
                )
        return self

    def check_traffic(self) -> SimConfig:
        """The traffic settings (``agents``, ``prediction``, ``agent_params``; part of ``validate``,
        which every drive runs when it is traced)."""
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


@pytree_dataclass(
    data_fields=(
        "t",
        "x",
        "y",
        "heading",
        "v",
        "a",
        "kappa",
        "valid",
        "end_step",
        "plan_ok",
        "fallback",
        "replanned",
        "info",
        "traffic",
    )
)
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
    d, v, acc = braking_profile(ego.v, a, k * dt)
    c, s = jnp.cos(ego.heading), jnp.sin(ego.heading)
    z = jnp.zeros_like(k)
    return EgoState(ego.x + c * d, ego.y + s * d, ego.heading + z, v, acc, z)


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


@pytree_dataclass(data_fields=("ego", "done", "plan", "idx", "plan_ok", "agents"))
class DriveState:
    """Where a drive stands between planning cycles (one scene; add leading axes for a batch).

    Attributes:
        ego: ``EgoState`` of the car (reference point).
        done: ``()`` the drive has ended.
        plan: the installed plan (``Trajectory`` ``(H,)``); idx: ``()`` the index on it the car is at.
        plan_ok: ``()`` the planner's ``ok`` for the installed plan.
        agents: the IDM agents' state (None with ``log`` agents).
    """

    ego: Any
    done: Any
    plan: Any
    idx: Any
    plan_ok: Any
    agents: Any = None


@pytree_dataclass(data_fields=("states", "was_done", "ok", "fallback", "replanned", "info", "moved"))
class DriveChunk:
    """What consecutive planning cycles produced (``C`` cycles of ``K = replan_every`` steps each):
    ``states`` (``EgoState`` ``(C, K)``), ``was_done (C, K)``, ``ok, fallback, replanned (C,)``,
    the planner's ``info`` ``(C, ...)``, and the IDM agents' boxes and valid flags after each step
    (``moved``: ``((C, K, K_obs, 5), (C, K, K_obs))``; None with ``log`` agents)."""

    states: Any
    was_done: Any
    ok: Any
    fallback: Any
    replanned: Any
    info: Any
    moved: Any = None


class _Drive:
    """One scene's closed loop (unbatched): what every cycle shares, and the cycle itself."""

    def __init__(self, planner: Planner, params, scene, config: SimConfig):
        config.validate(planner)  # host-side, when traced: before anything compiles
        self.planner, self.params, self.scene, self.config = planner, params, scene, config
        self.veh = planner.vehicle
        self.K = config.replan_every
        self.C = config.n_cycles
        self.H = planner.horizon_steps
        self.track = TRACKERS[config.tracking]
        self.f = jnp.result_type(float)
        self.dt = jnp.asarray(config.dt, self.f)
        self.t_end = scene.goal.time[1]
        self.min_left = int(round(config.lazy_min_remaining / config.dt))
        self.idm = config.agents == "idm"
        self.paths = agent_paths(scene.obstacles, scene.obstacle_sl, self.dt) if self.idm else None
        self.lanes = lane_cache(scene) if config.prediction == "cv" else None
        self.view_len = (self.C - 1) * self.K + self.H  # steps of the planner's view: every cycle's window fits

    def ego0(self) -> EgoState:
        e = EgoState.from_box_centre(self.scene.start, self.veh)
        return jax.tree_util.tree_map(lambda a: jnp.asarray(a, self.f), e)

    def view(self, step, agents):  # what the planner sees (the scene itself for oracle predictions of the log)
        return planner_view(
            self.scene, step, self.H, self.view_len, self.config.prediction, self.paths, agents, self.lanes
        )

    def ego_box(self, ego):
        f2 = ego.x.dtype
        return jnp.concatenate(
            [
                ego.box_centre(self.veh),
                jnp.stack([jnp.asarray(self.veh.length, f2), jnp.asarray(self.veh.width, f2), ego.heading]),
            ]
        )

    def reached(self, ego, t):
        return goal_reached(self.scene.goal, ego.box_centre(self.veh), ego.heading, ego.v, t)

    def start(self) -> DriveState:
        ego0 = self.ego0()
        done0 = (self.config.stop_at_goal & self.reached(ego0, 0.0)) | (self.t_end <= 1e-6)
        plan0 = jax.eval_shape(lambda: self.planner.plan(self.params, self.scene, ego0, 0)).trajectory
        plan0 = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), plan0)
        agents0 = init_agents(self.paths) if self.paths is not None else None  # idm
        return DriveState(ego0, done0, plan0, jnp.asarray(0), jnp.asarray(False), agents0)

    def cycle(self, st: DriveState, c):
        config, K, H, veh = self.config, self.K, self.H, self.veh
        ego, done, plan, idx, plan_ok, agents = st.ego, st.done, st.plan, st.idx, st.plan_ok, st.agents
        step = c * K
        seen = self.view(step, agents)
        out = self.planner.plan(self.params, seen, ego, step)
        if config.replan == "lazy":  # keep the installed plan unless it is short, abnormal or in conflict
            need = (
                (c == 0)
                | ~plan_ok
                | (H - 1 - idx < max(self.min_left, K))
                | plan_conflicts(plan, idx, seen, step, veh, config.lazy_margin)
            )
        else:
            need = jnp.asarray(True)
        plan = jax.tree_util.tree_map(lambda a, b: jnp.where(need, a, b), out.trajectory, plan)
        idx = jnp.where(need, 0, idx)
        plan_ok = jnp.where(need, out.ok, plan_ok)
        traj = _shift(plan, idx)
        head = jax.tree_util.tree_map(lambda a: a[..., : K + 1], traj)
        finite = _finite(head)
        safe = jax.tree_util.tree_map(lambda a: jnp.where(finite, a, 0.0), traj)
        nxt = jax.lax.cond(
            finite, lambda: self.track(safe, ego, K, veh, config), lambda: _brake(ego, K, config.dt, config.a_fallback)
        )

        # freeze once the drive has ended; the end is checked at every tracked step
        def step_fn(c2, j):
            e, d, ag = c2
            new = jax.tree_util.tree_map(lambda a: a[j], nxt)
            t = (step + j + 1) * self.dt
            if self.idm:  # the agents react to the car where it is now, then both move on
                ag = agents_step(self.paths, ag, step + j, self.ego_box(e), e.v, config.dt, config.agent_params)
                moved = agent_boxes(self.paths, ag, step + j + 1)
            else:
                moved = None
            e = jax.tree_util.tree_map(lambda a, b: jnp.where(d, a, b), e, new)
            end_now = (config.stop_at_goal & self.reached(e, t)) | (t >= self.t_end - 1e-6)
            return (e, d | end_now, ag), (e, d, moved)

        (ego_n, done_n, agents_n), (states, was_done, moved) = lax.scan(step_fn, (ego, done, agents), jnp.arange(K))
        nst = DriveState(ego_n, done_n, plan, idx + K, plan_ok, agents_n)
        return nst, DriveChunk(states, was_done, out.ok, ~finite, need & ~done, out.info, moved)

    def log(self, chunk: DriveChunk) -> DriveLog:
        """The ``DriveLog`` of a whole drive from its cycles (``C`` of them)."""
        config, K, C = self.config, self.K, self.C
        ego0 = self.ego0()
        flat = jax.tree_util.tree_map(lambda a: a.reshape((C * K,) + a.shape[2:])[: config.n_steps], chunk.states)
        was_done = chunk.was_done.reshape(C * K)[: config.n_steps]
        seq = jax.tree_util.tree_map(lambda a0, a: jnp.concatenate([jnp.reshape(a0, (1,)), a]), ego0, flat)
        valid = jnp.concatenate([jnp.ones((1,), bool), ~was_done])  # the step that ends the drive is part of it
        centre = seq.box_centre(self.veh)
        n = config.n_steps + 1
        t = jnp.arange(n, dtype=self.f) * self.dt
        end_step = jnp.max(jnp.where(valid, jnp.arange(n), 0))
        if self.paths is not None:  # idm; the agents at every step: (C, K, K_obstacles, ...) -> (K_obstacles, N, ...)
            b0, v0 = agent_boxes(self.paths, init_agents(self.paths), 0)
            mb, mv = (a.reshape((C * K,) + a.shape[2:])[: config.n_steps] for a in chunk.moved)
            traffic = Obstacles(
                jnp.swapaxes(jnp.concatenate([b0[None], mb]), 0, 1),
                jnp.swapaxes(jnp.concatenate([v0[None], mv]), 0, 1),
                t,
                self.paths.static,
            )
        else:
            traffic = self.scene.obstacles.window(0, n)
        return DriveLog(
            t,
            centre[:, 0],
            centre[:, 1],
            seq.heading,
            seq.v,
            seq.a,
            seq.kappa,
            valid,
            end_step,
            chunk.ok,
            chunk.fallback,
            chunk.replanned,
            chunk.info,
            traffic,
        )


def drive_start(planner: Planner, params, scene, config: SimConfig) -> DriveState:
    """A drive's state before its first cycle (one scene; ``params`` the planner's)."""
    return _Drive(planner, params, scene, config).start()


def drive_cycles(planner: Planner, params, scene, state: DriveState, c0, n: int, config: SimConfig):
    """Planning cycles ``c0 .. c0 + n - 1`` of a drive (one scene; ``c0`` may be traced, ``n`` static).

    Returns:
        ``(DriveState after them, DriveChunk of them)``.
    """
    d = _Drive(planner, params, scene, config)
    cycle = jax.checkpoint(d.cycle) if config.remat else d.cycle
    return lax.scan(cycle, state, jnp.asarray(c0) + jnp.arange(n))


def drive_log(planner: Planner, params, scene, chunk: DriveChunk, config: SimConfig) -> DriveLog:
    """The ``DriveLog`` of a drive from all its cycles' ``DriveChunk`` (``config.n_cycles`` of them)."""
    return _Drive(planner, params, scene, config).log(chunk)


def drive_one(planner: Planner, params, scene, config: SimConfig) -> DriveLog:
    """One scene's drive (unbatched; ``rollout`` batches it): every cycle in one ``lax.scan``."""
    _, chunk = drive_cycles(
        planner, params, scene, drive_start(planner, params, scene, config), 0, config.n_cycles, config
    )
    return drive_log(planner, params, scene, chunk, config)


def _rollout(planner: Planner, params, scenes, config: SimConfig) -> DriveLog:
    return jax.vmap(lambda s: drive_one(planner, params, s, config))(scenes)


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


def rollout(planner: Planner, scenes, config: SimConfig = SimConfig(), params=None) -> DriveLog:
    """Drive every scene of a batch (leading axis) with ``planner``; jitted (``planner`` and
    ``config`` static, ``params`` traced: new params never recompile) with the planner's XLA
    options (``planner_compiler_options``): the lattice planner's drives run 1.15-1.47x faster
    with its options (``jaxplan.compile_options``).

    Args:
        planner: a ``Planner`` (hashable; static).
        scenes: a batched ``Scene`` (``jaxplan.scenarios.batch.stack_scenes``).
        config: ``SimConfig``.
        params: the planner's params (a pytree shaped as ``planner.init_params()``, shared by every
            scene; default those). Inside a caller's ``jit`` or ``grad``, ``drive_one`` under
            ``jax.vmap`` is the same drive without this function's own ``jit``.

    Returns:
        ``DriveLog`` with a leading scene axis.

    Raises:
        ValueError: a setting of ``config`` is out of range, or ``params`` are not shaped as the
            planner's (when traced, before anything compiles).
    """
    params = check_params(planner, params)
    return planner_program(planner)(planner, params, scenes, config=config)


def _starts(planner: Planner, params, scenes, config: SimConfig) -> DriveState:
    return jax.vmap(lambda s: drive_start(planner, params, s, config))(scenes)


def _advance(planner: Planner, params, scenes, state: DriveState, c0, config: SimConfig, n: int):
    return jax.vmap(lambda s, st: drive_cycles(planner, params, s, st, c0, n, config))(scenes, state)


def _logs(planner: Planner, params, scenes, chunk: DriveChunk, config: SimConfig) -> DriveLog:
    return jax.vmap(lambda s, ch: drive_log(planner, params, s, ch, config))(scenes, chunk)


class ChunkedRollout:
    """``rollout`` of one planner and config in chunks of ``chunk_cycles`` planning cycles, with a
    host loop between the chunks that stops as soon as every drive of the batch has ended (or has
    reached ``cycles``). The drives are those of ``rollout``: the same cycles, states and outputs up
    to each drive's end (the cycles after the last drive's end are not run: their entries repeat
    the last state, marked ended).

    One compiled program per batch shape for any drive length, so that scenes of different
    lengths share it. ``compile(scenes)`` compiles ahead of time and returns the seconds it took
    (a drive's time is then the drive alone).

    Args:
        planner: the ``Planner`` (static).
        config: ``SimConfig``; ``n_steps`` is the longest drive.
        chunk_cycles: cycles per compiled call.
        params: the planner's params (default ``planner.init_params()``); traced, as in ``rollout``:
            a call with other params runs the same compiled programs.
    """

    def __init__(self, planner: Planner, config: SimConfig, chunk_cycles: int = 6, params=None):
        if chunk_cycles < 1:
            raise ValueError(f"ChunkedRollout: chunk_cycles must be >= 1, got {chunk_cycles}")
        self.planner, self.config = planner, config
        self.params = check_params(planner, params)
        self.n = min(chunk_cycles, config.n_cycles)
        self._programs: dict = {}

    def _key(self, scenes):
        leaves, tree = jax.tree_util.tree_flatten(scenes)
        return tree, tuple((x.shape, str(x.dtype), str(getattr(x, "sharding", ""))) for x in leaves)

    def compile(self, scenes) -> float:
        """Compile the programs for batches shaped as ``scenes``; seconds taken (0 when compiled before)."""
        import time

        key = self._key(scenes)
        if key in self._programs:
            return 0.0
        if release_compiled():  # many programs compiled in this process: start afresh
            self._programs.clear()
        t = time.perf_counter()
        p, w, cfg = self.planner, self.params, self.config
        start = planner_program(p, _starts, ("planner", "config")).lower(p, w, scenes, config=cfg).compile()
        state = jax.eval_shape(functools.partial(_starts, p, config=cfg), w, scenes)
        adv = (
            planner_program(p, _advance, ("planner", "config", "n"))
            .lower(p, w, scenes, state, jnp.asarray(0), config=cfg, n=self.n)
            .compile()
        )
        _, chunk = jax.eval_shape(
            functools.partial(_advance, p, config=cfg, n=self.n), w, scenes, state, jnp.asarray(0)
        )
        full = jax.tree_util.tree_map(
            lambda a: jax.ShapeDtypeStruct((a.shape[0], cfg.n_cycles) + a.shape[2:], a.dtype), chunk
        )
        logs = planner_program(p, _logs, ("planner", "config")).lower(p, w, scenes, full, config=cfg).compile()
        self._programs[key] = (start, adv, logs)
        return time.perf_counter() - t

    def __call__(self, scenes, cycles: int | None = None, params=None) -> DriveLog:
        """Drive a batch (leading scene axis); ``cycles``: at most this many cycles (default all);
        ``params``: the planner's params for these drives (default the driver's), run by the same
        compiled programs.

        Returns:
            ``DriveLog`` of numpy arrays with a leading scene axis.
        """
        import numpy as np

        self.compile(scenes)
        start, adv, logs = self._programs[self._key(scenes)]
        C = self.config.n_cycles
        limit = C if cycles is None else max(1, min(C, cycles))
        w = self.params if params is None else check_params(self.planner, params)
        state = start(w, scenes)
        parts, c0 = [], 0
        while c0 < limit:
            state, chunk = adv(w, scenes, state, jnp.asarray(c0))
            parts.append(jax.tree_util.tree_map(np.asarray, chunk))
            c0 += self.n
            if bool(np.all(np.asarray(state.done))):
                break
        got = jax.tree_util.tree_map(lambda *a: np.concatenate(a, axis=1), *parts)
        ran = got.ok.shape[1]
        if ran < C:  # the cycles not run: the last state, ended

            def fill(a, value=None):
                rest = (
                    np.repeat(a[:, -1:], C - ran, axis=1)
                    if value is None
                    else np.full((a.shape[0], C - ran) + a.shape[2:], value, a.dtype)
                )
                return np.concatenate([a, rest], axis=1)

            got = DriveChunk(
                jax.tree_util.tree_map(fill, got.states),
                fill(got.was_done, True),
                fill(got.ok, True),
                fill(got.fallback, False),
                fill(got.replanned, False),
                jax.tree_util.tree_map(fill, got.info),
                None if got.moved is None else jax.tree_util.tree_map(fill, got.moved),
            )
        elif ran > C:
            got = jax.tree_util.tree_map(lambda a: a[:, :C], got)
        return jax.tree_util.tree_map(np.asarray, logs(w, scenes, got))
