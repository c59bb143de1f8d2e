"""Park-out: the two-curve selection rules, the full park-out condition and the drive / re-plan loop.

Everything here is one scene's kernel (``jax.vmap`` for batches) in the slot
frame. The obstacle information is a *collision model*: a ``GridModel`` (the
occupancy grid's cell table and frame pose) or a ``PointModel`` (the two-corner
baseline's points); ``hits_fn`` turns either into ``poses (..., 3) -> (...)
bool`` with a margin.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.geometry import wrap_angle
from jaxplan.parking.circles import backward_curve, forward_curve, stop_line, turning_radius
from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.grid import Grid, cell_table, footprint_hits_grid
from jaxplan.parking.pursuit import Rollout, rollout
from jaxplan.parking.two_corner import footprint_hits_points
from jaxplan.types import VehicleParams, is_concrete


class GridModel(NamedTuple):
    """Collision model of one occupancy grid: ``table (cols + 1, rows)`` (``cell_table``), frame ``pose (3,)``.

    ``table`` may also hold many grids' tables ``(n, cols + 1, rows)`` shared by a
    batch, with ``base`` the flat offset of this grid's (``i * rows * (cols + 1)``).
    """

    table: jnp.ndarray
    pose: jnp.ndarray
    base: jnp.ndarray | int = 0


class PointModel(NamedTuple):
    """Collision model of obstacle points ``(P, 2)`` with mask ``ok (P,)`` (the two-corner baseline)."""

    points: jnp.ndarray
    ok: jnp.ndarray


def grid_model(grid: Grid) -> GridModel:
    """``GridModel`` of a grid (any leading dims)."""
    pose = jnp.asarray(grid.pose)
    return GridModel(cell_table(grid.cells), pose, jnp.zeros(pose.shape[:-1], jnp.int32))


def hits_fn(model, vehicle, config: ParkoutConfig):
    """``check(poses (..., 3), margin=...) -> (...) bool`` for a ``GridModel`` or ``PointModel``."""
    if isinstance(model, GridModel):
        return functools.partial(
            footprint_hits_grid, model.table, model.pose, vehicle=vehicle, config=config, base=model.base
        )

    def check(poses, margin=0.0):
        return footprint_hits_points(model.points, model.ok, poses, vehicle=vehicle, margin=margin)

    return check


def is_out(pose, d, config: ParkoutConfig):
    """Full park-out: ``y >= d`` and ``|heading - out_heading| < out_tol``. ``(..., 3) -> (...)``."""
    return (pose[..., 1] >= d) & (jnp.abs(wrap_angle(pose[..., 2] - config.out_heading)) < config.out_tol)


def select_forward(fwd: Rollout, bwd: Rollout, d, config: ParkoutConfig):
    """The selection rule: forward if its end is out, else the longer move (ties go backward)."""
    return is_out(fwd.end_pose, d, config) | (bwd.length < fwd.length)


class ParkoutPlan(NamedTuple):
    """One planning cycle: the chosen move and both candidates.

    Attributes:
        trajectory: the chosen ``Rollout`` (poses, gear per point, valid mask, ...),
            ``config.steps`` points.
        forward, backward: both candidates (the backward one padded to ``config.steps``).
        use_forward: ``(...)`` bool, which one was chosen.
        out: ``(...)`` the chosen move ends fully out.
        margin: ``(...)`` the footprint margin the collision check used.
    """

    trajectory: Rollout
    forward: Rollout
    backward: Rollout
    use_forward: jnp.ndarray
    out: jnp.ndarray
    margin: jnp.ndarray


def usable_margin(check, pose, config: ParkoutConfig):
    """``config.margin``, or with ``shrink_margin`` the largest of four margins from
    ``margin`` down to ``min_margin`` that is clear at ``pose`` (else ``min_margin``)."""
    if not config.shrink_margin:
        return jnp.asarray(config.margin, pose.dtype)
    cands = jnp.linspace(config.margin, config.min_margin, 4).astype(pose.dtype)
    clear = ~jax.vmap(lambda mm: check(pose, margin=mm))(cands)
    return jnp.where(jnp.any(clear), cands[jnp.argmax(clear)], cands[-1])


def _pad(r: Rollout, T: int) -> Rollout:
    """A rollout padded to ``T`` points (the last point repeated, not valid)."""
    n = r.poses.shape[-2]
    if n == T:
        return r
    rep = lambda x, fill: jnp.concatenate([x, jnp.broadcast_to(fill, (T - n,) + x.shape[1:])], 0)  # noqa: E731
    return r._replace(
        poses=rep(r.poses, r.poses[-1]),
        gear=rep(r.gear, r.gear[-1]),
        steer=rep(r.steer, r.steer[-1]),
        s=rep(r.s, r.s[-1]),
        valid=rep(r.valid, False),
    )


def _plan(pose, check, vehicle, config: ParkoutConfig) -> ParkoutPlan:
    """One planning cycle; ``check(poses, margin=...) -> bool`` is the collision model."""
    margin = usable_margin(check, pose, config)
    hits = functools.partial(check, margin=margin)
    R = turning_radius(vehicle)
    d = stop_line(vehicle, config.c)
    f = rollout(
        pose,
        forward_curve(pose, R, d + config.overshoot),
        hits,
        vehicle,
        config,
        d + 0.0 * pose[1],
        config.out_heading,
        steps=config.steps,
    )
    b = rollout(
        pose,
        backward_curve(pose, R, config.theta1, config.theta2, config.back_cap),
        hits,
        vehicle,
        config,
        None,
        config.out_heading,
        steps=config.back_steps,
    )
    return choose(f, _pad(b, config.steps), margin, vehicle, config)


def _batched(fn, pose, *args):
    """Apply a one-instance kernel over the leading dims of ``pose (..., 3)``."""
    lead = pose.shape[:-1]
    if not lead:
        return fn(pose, *args)
    flat = jax.tree_util.tree_map(lambda x: x.reshape((-1,) + x.shape[len(lead) :]), (pose, args))
    out = jax.vmap(fn)(flat[0], *flat[1])
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


@functools.partial(jax.jit, static_argnames=("config",))
def _plan_parkout_jit(pose, grid, config, vehicle):
    def one(p, g):
        return _plan(p, hits_fn(grid_model(g), vehicle, config), vehicle, config)

    return _batched(one, pose, grid)


def _check_inputs(pose, grid: Grid, config: ParkoutConfig, vehicle):
    vehicle.validate()
    config.check_vehicle(vehicle)
    grid.validate(config)
    p = jnp.asarray(pose)
    if p.shape[-1:] != (3,) or p.shape[:-1] != jnp.shape(grid.pose)[:-1]:
        raise ValueError(f"pose: expected (..., 3) matching grid.pose {jnp.shape(grid.pose)}, got {p.shape}")
    if not bool(jnp.all(jnp.isfinite(p))):
        raise ValueError("pose: contains NaN or inf")


def plan_parkout(
    pose, grid: Grid, config: ParkoutConfig = ParkoutConfig(), vehicle: VehicleParams = VehicleParams()
) -> ParkoutPlan:
    """Plan one park-out move with the two reference curves (forward, backward) on an occupancy grid (jitted).

    Args:
        pose: ``(..., 3)`` current rear-axle pose in the slot frame.
        grid: ``Grid`` with ``cells (..., rows, cols)`` and its frame's ``pose (..., 3)``.
        config: static sizes and thresholds; vehicle: car geometry.

    Returns:
        ``ParkoutPlan``; ``plan.trajectory`` holds ``poses (..., T, 3)``, ``gear (..., T)``
        and ``valid (..., T)``.
    """
    if is_concrete(pose, grid, vehicle):
        _check_inputs(pose, grid, config, vehicle)
    pose = jnp.asarray(pose, jnp.result_type(float))
    return _plan_parkout_jit(pose, grid, config, vehicle)


class ParkoutResult(NamedTuple):
    """The whole park-out of one scene (or a batch, leading dims ``...``).

    Attributes:
        poses: ``(..., M, T, 3)`` each executed move (``M = config.max_moves``,
            ``T = config.steps``), rear-axle poses in the slot frame.
        valid: ``(..., M, T)`` bool, points driven (a prefix of each move).
        gear: ``(..., M)`` gear of each move (0 if not driven).
        steer: ``(..., M, T)`` front steering angle leaving each point [rad].
        success: ``(...)`` the car ended fully out.
        stuck: ``(...)`` failed: no move of at least ``min_progress`` was left
            (the other failures ran out of moves or stopped making progress).
        moves: ``(...)`` number of moves driven (each ends at a standstill).
        path_length: ``(...)`` total length driven.
        final_pose: ``(..., 3)``.
        searched: ``(...)`` the plan comes from the search (the two-curve loop failed).
    """

    poses: jnp.ndarray
    valid: jnp.ndarray
    gear: jnp.ndarray
    steer: jnp.ndarray
    success: jnp.ndarray
    stuck: jnp.ndarray
    moves: jnp.ndarray
    path_length: jnp.ndarray
    final_pose: jnp.ndarray
    searched: jnp.ndarray


class LoopState(NamedTuple):
    """The two-curve loop's state for one scene (see ``two_curve_step``)."""

    k: jnp.ndarray
    pose: jnp.ndarray
    done: jnp.ndarray
    success: jnp.ndarray
    stuck: jnp.ndarray
    stall: jnp.ndarray
    best: jnp.ndarray
    poses: jnp.ndarray
    valid: jnp.ndarray
    gear: jnp.ndarray
    steer: jnp.ndarray
    length: jnp.ndarray


def loop_init(start, config: ParkoutConfig) -> LoopState:
    """Initial ``LoopState`` at rear-axle pose ``start (3,)``."""
    M, T = config.max_moves, config.steps
    dtype = start.dtype
    f = jnp.zeros((), bool)
    return LoopState(
        jnp.zeros((), jnp.int32),
        start,
        f,
        f,
        f,
        jnp.zeros((), jnp.int32),
        jnp.stack([start[1], wrap_angle(start[2])]),
        jnp.zeros((M, T, 3), dtype),
        jnp.zeros((M, T), bool),
        jnp.zeros((M,), jnp.int32),
        jnp.zeros((M, T), dtype),
        jnp.zeros((M,), dtype),
    )


PROGRESS_EPS = 0.01  # m of lateral offset or rad of heading that count as progress


def two_curve_step(st: LoopState, check, vehicle, config: ParkoutConfig) -> LoopState:
    """Plan one move with the two-curve rules and drive it (a no-op once ``st.done``).

    The loop stops when the car is out (``success``), when no move of at least
    ``min_progress`` is left (``stuck``), after ``max_moves`` moves, or when two
    moves in a row gained neither lateral offset nor heading (the two curves'
    moves only make progress by turning the nose out).
    """
    return apply_plan(st, _plan(st.pose, check, vehicle, config), config)


def apply_plan(st: LoopState, plan: ParkoutPlan, config: ParkoutConfig) -> LoopState:
    """Drive the chosen move of ``plan`` from ``st`` (the second half of ``two_curve_step``)."""
    tr = plan.trajectory
    go = ~st.done & (tr.length >= config.min_progress)
    now_stuck = ~st.done & ~go
    out = go & plan.out
    end = jnp.where(go, tr.end_pose, st.pose)
    yt = jnp.stack([end[1], wrap_angle(end[2])])
    gain = jnp.any(yt > st.best + PROGRESS_EPS)
    stall = jnp.where(go, jnp.where(gain, 0, st.stall + 1), st.stall)
    k = st.k
    kk = jnp.minimum(k, config.max_moves - 1)
    done = st.done | now_stuck | out | (go & (stall >= 2)) | (go & (k + 1 >= config.max_moves))
    return LoopState(
        k=jnp.where(go, k + 1, k),
        pose=end,
        done=done,
        success=st.success | out,
        stuck=st.stuck | now_stuck,
        stall=stall,
        best=jnp.where(go, jnp.maximum(st.best, yt), st.best),
        poses=st.poses.at[kk].set(jnp.where(go, tr.poses, st.poses[kk])),
        valid=st.valid.at[kk].set(jnp.where(go, tr.valid, st.valid[kk])),
        gear=st.gear.at[kk].set(jnp.where(go, tr.gear[0].astype(jnp.int32), st.gear[kk])),
        steer=st.steer.at[kk].set(jnp.where(go, tr.steer, st.steer[kk])),
        length=st.length.at[kk].set(jnp.where(go, tr.length, st.length[kk])),
    )


def choose(f: Rollout, b: Rollout, margin, vehicle, config: ParkoutConfig) -> ParkoutPlan:
    """The two-curve ``ParkoutPlan`` from its two candidates (``b`` padded to ``config.steps``)."""
    d = stop_line(vehicle, config.c)
    use = select_forward(f, b, d, config)
    chosen = jax.tree_util.tree_map(lambda x, y: jnp.where(use, x, y), f, b)
    return ParkoutPlan(chosen, f, b, use, is_out(chosen.end_pose, d, config), margin)


def loop_result(st: LoopState, searched=False) -> ParkoutResult:
    """``ParkoutResult`` of a finished loop (points after a move's end repeat it, undriven moves the final pose)."""
    n = jnp.maximum(jnp.sum(st.valid, -1) - 1, 0)
    ends = jnp.take_along_axis(st.poses, n[:, None, None], axis=1)  # (M, 1, 3)
    poses = jnp.where(st.valid[..., None], st.poses, ends)
    poses = jnp.where(st.valid.any(-1)[:, None, None], poses, st.pose)
    return ParkoutResult(
        poses,
        st.valid,
        st.gear,
        st.steer,
        st.success,
        st.stuck & ~st.success,
        jnp.sum(st.gear != 0),
        jnp.sum(st.length),
        st.pose,
        jnp.asarray(searched),
    )


def two_curve_loop(start, model, config: ParkoutConfig, vehicle) -> ParkoutResult:
    """The two-curve drive / re-plan loop for one scene (``lax.while_loop``; jittable, vmappable).

    Args:
        start: ``(3,)`` rear-axle start pose in the slot frame.
        model: ``GridModel`` or ``PointModel`` of this scene.
    """
    check = hits_fn(model, vehicle, config)
    st = lax.while_loop(
        lambda s: ~s.done, lambda s: two_curve_step(s, check, vehicle, config), loop_init(start, config)
    )
    return loop_result(st)


@functools.partial(jax.jit, static_argnames=("config",))
def _two_curve_loop_jit(start, model, config, vehicle):
    lead = start.shape[:-1]
    if not lead:
        return two_curve_loop(start, model, config, vehicle)
    n = math.prod(lead)
    flat = jax.tree_util.tree_map(lambda x: x.reshape((n,) + x.shape[len(lead) :]), (start, model))
    out = jax.vmap(lambda s, m: two_curve_loop(s, m, config, vehicle))(*flat)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


def park_out_grid(
    start, grid: Grid, config: ParkoutConfig = ParkoutConfig(), vehicle: VehicleParams = VehicleParams()
) -> ParkoutResult:
    """The two-curve loop on given grids, in one jitted call (no search; see ``plan_grids`` for the fast
    batch driver with the search). ``start (..., 3)``, ``grid.cells (..., rows, cols)``."""
    if is_concrete(start, grid, vehicle):
        _check_inputs(start, grid, config, vehicle)
    start = jnp.asarray(start, jnp.result_type(float))
    return _two_curve_loop_jit(start, grid_model(grid), config, vehicle)
