"""Park-out: selection rules, the full park-out condition and the drive / re-plan loop."""
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
from jaxplan.parking.grid import Grid, footprint_hits_grid, row_prefix
from jaxplan.parking.pursuit import Rollout, rollout
from jaxplan.parking.scenes import Scene, render_grid
from jaxplan.parking.two_corner import footprint_hits_points, two_corner_points
from jaxplan.types import VehicleParams, is_concrete


def is_out(pose, d, config: ParkoutConfig):
    """Full park-out: ``y >= d`` and ``|heading - out_heading| < out_tol``. ``(..., 3) -> (...)``."""
    return (pose[..., 1] >= d) & (jnp.abs(wrap_angle(pose[..., 2] - config.out_heading)) < config.out_tol)


def select_forward(fwd: Rollout, bwd: Rollout, d, config: ParkoutConfig):
    """The selection rule: forward if its end is out, else the longer move (ties go backward)."""
    return is_out(fwd.end_pose, d, config) | (bwd.length < fwd.length)


class Plan(NamedTuple):
    """One planning cycle: the chosen move and both candidates.

    Attributes:
        trajectory: the chosen ``Rollout`` (poses, gear per point, valid mask, ...).
        forward, backward: both candidates.
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


def _usable_margin(check, pose, config: ParkoutConfig):
    """``config.margin``, or with ``shrink_margin`` the largest of four margins from
    ``margin`` down to ``min_margin`` that is clear at ``pose`` (else ``min_margin``)."""
    if not config.shrink_margin:
        return jnp.asarray(config.margin, pose.dtype)
    cands = jnp.linspace(config.margin, config.min_margin, 4).astype(pose.dtype)
    clear = ~jax.vmap(lambda mm: check(pose, margin=mm))(cands)
    return jnp.where(jnp.any(clear), cands[jnp.argmax(clear)], cands[-1])


def _plan(pose, check, vehicle, config: ParkoutConfig) -> Plan:
    """One planning cycle; ``check(poses, margin=...) -> bool`` is the collision model."""
    margin = _usable_margin(check, pose, config)
    hits = functools.partial(check, margin=margin)
    R = turning_radius(vehicle)
    d = stop_line(vehicle, config.c)
    curves = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), forward_curve(pose, R, d + config.overshoot),
                                    backward_curve(pose, R, config.theta1, config.theta2, config.back_cap))
    stop_y = jnp.stack([d + 0.0 * pose[1], jnp.full_like(pose[1], jnp.inf)])
    both = jax.vmap(lambda c, y: rollout(pose, c, hits, vehicle, config, y, config.out_heading))(curves, stop_y)
    f, b = (jax.tree_util.tree_map(lambda x: x[i], both) for i in (0, 1))
    use = select_forward(f, b, d, config)
    chosen = jax.tree_util.tree_map(lambda x, y: jnp.where(use, x, y), f, b)
    return Plan(chosen, f, b, use, is_out(chosen.end_pose, d, config), margin)


def _grid_hits(grid: Grid, vehicle, config):
    prefix = row_prefix(grid.cells)
    return functools.partial(footprint_hits_grid, prefix, grid.pose, vehicle=vehicle, config=config)


def _batched(fn, pose, *args):
    """Apply a one-instance kernel over the leading dims of ``pose (..., 3)``."""
    lead = pose.shape[:-1]
    if not lead:
        return fn(pose, *args)
    flat = jax.tree_util.tree_map(lambda x: x.reshape((-1,) + x.shape[len(lead):]), (pose, args))
    out = jax.vmap(fn)(flat[0], *flat[1])
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


@functools.partial(jax.jit, static_argnames=("config",))
def _plan_parkout_jit(pose, grid, config, vehicle):
    def one(p, g):
        return _plan(p, _grid_hits(g, vehicle, config), vehicle, config)

    return _batched(one, pose, grid)


def plan_parkout(pose, grid: Grid, config: ParkoutConfig = ParkoutConfig(),
                 vehicle: VehicleParams = VehicleParams()) -> Plan:
    """Plan one park-out move on an occupancy grid (jitted).

    Args:
        pose: ``(..., 3)`` current rear-axle pose in the initial world frame.
        grid: ``Grid`` with ``cells (..., rows, cols)`` and the ``pose (..., 3)``
            it was read at (usually the current pose).
        config: static sizes and thresholds; vehicle: car geometry.

    Returns:
        ``Plan``; ``plan.trajectory`` holds ``poses (..., T, 3)``, ``gear (..., T)``
        and ``valid (..., T)``.
    """
    if is_concrete(pose, grid, vehicle):
        vehicle.validate()
        config.check_vehicle(vehicle)
        grid.validate(config)
        p = jnp.asarray(pose)
        if p.shape[-1:] != (3,) or p.shape[:-1] != jnp.shape(grid.pose)[:-1]:
            raise ValueError(f"pose: expected (..., 3) matching grid.pose {jnp.shape(grid.pose)}, got {p.shape}")
    pose = jnp.asarray(pose, jnp.result_type(float))
    return _plan_parkout_jit(pose, grid, config, vehicle)


class ParkoutResult(NamedTuple):
    """The whole park-out of one scene (or a batch, leading dims ``...``).

    Attributes:
        poses: ``(..., M, T, 3)`` each executed move (``M = config.max_moves``).
        valid: ``(..., M, T)`` bool, points driven.
        gear: ``(..., M)`` gear of each move (0 if not driven).
        success: ``(...)`` the car ended fully out.
        stuck: ``(...)`` the planner found no move longer than ``min_progress``.
        moves: ``(...)`` number of moves driven.
        path_length: ``(...)`` total length driven.
        final_pose: ``(..., 3)``.
    """

    poses: jnp.ndarray
    valid: jnp.ndarray
    gear: jnp.ndarray
    success: jnp.ndarray
    stuck: jnp.ndarray
    moves: jnp.ndarray
    path_length: jnp.ndarray
    final_pose: jnp.ndarray


def _park_out_one(scene: Scene, key, config: ParkoutConfig, vehicle, model: str):
    dtype = scene.boxes.dtype
    start = jnp.zeros(3, dtype)
    if model == "two_corner":
        ref = jnp.stack([jnp.asarray(vehicle.center_offset, dtype), jnp.zeros((), dtype)])
        pts, ok = two_corner_points(scene.boxes, scene.valid, ref)

    M, T = config.max_moves, config.steps
    kd = jnp.asarray(key, jnp.uint32).reshape(-1)

    def cond(state):
        return (state[0] < M) & ~state[2]

    def move(state):
        k, pose, done, success, stuck, poses, valid, gear, length = state
        seed = jnp.stack([kd[0] ^ (k.astype(jnp.uint32) * jnp.uint32(0x85EBCA6B)), kd[-1]])
        if model == "grid":
            hits = _grid_hits(render_grid(scene, pose, seed, config, vehicle), vehicle, config)
        else:
            hits = functools.partial(footprint_hits_points, pts, ok, vehicle=vehicle)
        plan = _plan(pose, hits, vehicle, config)
        tr = plan.trajectory
        go = ~done & (tr.length >= config.min_progress)
        now_stuck = ~done & ~go
        out = go & plan.out
        poses = poses.at[k].set(tr.poses)
        valid = valid.at[k].set(tr.valid & go)
        gear = gear.at[k].set(jnp.where(go, tr.gear[0], 0).astype(jnp.int32))
        length = length.at[k].set(jnp.where(go, tr.length, 0.0))
        return (k + 1, jnp.where(go, tr.end_pose, pose), done | now_stuck | out, success | out, stuck | now_stuck,
                poses, valid, gear, length)

    f = jnp.zeros((), bool)
    init = (jnp.zeros((), jnp.int32), start, f, f, f, jnp.zeros((M, T, 3), dtype), jnp.zeros((M, T), bool),
            jnp.zeros((M,), jnp.int32), jnp.zeros((M,), dtype))
    _, pose, done, success, stuck, poses, valid, gear, length = lax.while_loop(cond, move, init)
    poses = jnp.where(valid.any(-1)[:, None, None], poses, pose)
    return ParkoutResult(poses, valid, gear, success, stuck, jnp.sum(gear != 0), jnp.sum(length), pose)


@functools.partial(jax.jit, static_argnames=("config", "model"))
def _park_out_jit(scene, key, config, vehicle, model):
    lead = scene.edge_noise.shape
    if not lead:
        return _park_out_one(scene, key, config, vehicle, model)
    n = math.prod(lead)
    flat = jax.tree_util.tree_map(lambda x: x.reshape((n,) + x.shape[len(lead):]), scene)
    keys = jnp.stack([jnp.broadcast_to(jnp.asarray(key, jnp.uint32).reshape(-1)[-1], (n,)) + jnp.uint32(7919),
                      jnp.arange(n, dtype=jnp.uint32)], -1)
    out = jax.vmap(lambda s, k: _park_out_one(s, k, config, vehicle, model))(flat, keys)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


def park_out(scene: Scene, key=None, config: ParkoutConfig = ParkoutConfig(),
             vehicle: VehicleParams = VehicleParams(), model: str = "grid") -> ParkoutResult:
    """Drive out of the slot: read the grid, plan, drive the chosen move, repeat.

    Stops once the car is fully out (``success``), when no move makes progress
    (``stuck``), or after ``config.max_moves`` moves. Scenes may carry leading
    batch dims (one batched call).

    Args:
        scene: ``Scene`` in the initial world frame (the car starts at the origin).
        key: legacy PRNG key (uint32 ``(2,)``) or a uint32 seed for the grid noise.
        model: ``"grid"`` (the occupancy grid) or ``"two_corner"`` (the baseline
            that keeps the two nearest corners of each obstacle and no grid).
    """
    if model not in ("grid", "two_corner"):
        raise ValueError(f"model must be 'grid' or 'two_corner', got {model!r}")
    if is_concrete(scene, vehicle):
        vehicle.validate()
        config.check_vehicle(vehicle)
    key = jax.random.PRNGKey(0) if key is None else key
    return _park_out_jit(scene, key, config, vehicle, model)
