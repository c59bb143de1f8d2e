"""Search over moves at several steering levels: the fallback when the two reference curves fail.

A beam search, one depth per move. Every node (a pose reached after some
moves) is expanded by constant-steering arcs at ``config.steer_levels`` (as
fractions of the largest steering angle), forward and backward, each driven
until its footprint would first touch a blocked cell (or up to
``config.arc_steps`` points) and ended either there or halfway. An arc that
reaches the park-out condition ends there and is a solution. Children are
ranked by driven length plus ``gear_penalty`` per gear change plus the
obstacle-free cost-to-go (``heuristic.cost_to_go``) -- greedy: children are
ranked by cost-to-go, ties broken by ``G_WEIGHT`` times the cost so far. Poses
within 10 cm and 3 degrees of a better child, or of any node of an earlier
depth, are dropped (no cycles), and the best ``config.beam`` children form the
next depth. The search stops at the first depth with a solution (the
cheapest one is taken), when no child is left, when the best cost-to-go has
not dropped by ``PROGRESS`` for ``PATIENCE`` depths, or after ``config.max_moves`` moves.
Each arc is one move: the car stops at its end (to change gear or to turn the
wheels at standstill).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.geometry import wrap_angle
from jaxplan.parking.circles import _advance, stop_line
from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.heuristic import CostToGo, lookup
from jaxplan.parking.parkout import ParkoutResult, hits_fn, is_out, usable_margin

PATIENCE = 6  # depths without a better cost-to-go before the search gives up
PROGRESS = 0.02  # m: a smaller drop of the best cost-to-go does not count as better
MOVE_COST = 0.25  # metres of driving charged per move (prefers fewer, longer moves)
ENDS = (1.0, 0.5)  # each arc ends at the last free point or halfway to it
G_WEIGHT = 0.1  # weight of the cost so far against the cost-to-go in the ranking


def primitives(config: ParkoutConfig, vehicle, dtype=jnp.float32):
    """Curvature and gear of every search arc, ``(P,)`` each (``P = 2 x len(steer_levels)``)."""
    lv = jnp.asarray(config.steer_levels, dtype)
    steer = jnp.concatenate([lv, lv]) * vehicle.max_steer
    gear = jnp.concatenate([jnp.ones_like(lv), -jnp.ones_like(lv)])
    return jnp.tan(steer) / vehicle.wheelbase, gear, steer


def arc_poses(pose, kappa, gear, steps: int, dl):
    """Poses ``(..., steps, 3)`` of constant-curvature arcs from ``pose (..., 3)`` at ``dl`` spacing."""
    s = gear[..., None] * dl * jnp.arange(steps, dtype=pose.dtype)
    return _advance(pose[..., None, :], kappa[..., None], s)


class _Carry(NamedTuple):
    depth: jnp.ndarray
    done: jnp.ndarray
    found: jnp.ndarray
    pose: jnp.ndarray  # (B, 3)
    cost: jnp.ndarray  # (B,)
    gear: jnp.ndarray  # (B,)
    alive: jnp.ndarray  # (B,)
    best_h: jnp.ndarray
    wait: jnp.ndarray
    h_pose: jnp.ndarray  # (M + 1, B, 3)
    h_parent: jnp.ndarray  # (M, B)
    h_prim: jnp.ndarray
    h_end: jnp.ndarray
    h_key: jnp.ndarray  # (M + 1, B) lattice labels of all nodes so far
    h_alive: jnp.ndarray  # (M + 1, B)
    sol: jnp.ndarray  # (3,) parent node, primitive, end index of the solving move


def _key(pose):
    """A lattice label of poses ``(..., 3)``: 10 cm and about 3 degrees."""
    ix = jnp.round(pose[..., 0] / 0.1).astype(jnp.int32)
    iy = jnp.round(pose[..., 1] / 0.1).astype(jnp.int32)
    it = jnp.round(wrap_angle(pose[..., 2]) / 0.05).astype(jnp.int32)
    return (ix * 73856093) ^ (iy * 19349663) ^ (it * 83492791)


def search_parkout(start, model, config: ParkoutConfig, vehicle, table: CostToGo) -> ParkoutResult:
    """Beam search for a park-out from ``start (3,)`` on one scene's collision model (jittable).

    Returns:
        ``ParkoutResult`` (one scene) with ``searched = True``; a failed search
        returns no moves and the start pose.
    """
    init, depth, finish = search_steps(hits_fn(model, vehicle, config), config, vehicle, table, start.dtype)
    return finish(lax.while_loop(lambda c: ~c.done, depth, init(start)), start)


def search_steps(check, config: ParkoutConfig, vehicle, table: CostToGo, dtype):
    """The search in three parts, for drivers that interleave scenes: ``init(start) -> carry``,
    ``depth(carry) -> carry`` (one depth; ``carry.done`` when finished) and ``finish(carry, start) ->
    ParkoutResult``. ``check`` is the scene's ``hits_fn``."""
    B, M, TA = config.beam, config.max_moves, config.arc_steps
    kap, gp, steer_p = primitives(config, vehicle, dtype)
    P, E = kap.shape[0], len(ENDS)
    d = stop_line(vehicle, config.c)
    dl = config.dl
    ends_frac = jnp.asarray(ENDS, dtype)

    def expand(c: _Carry):
        margin = jax.vmap(lambda p: usable_margin(check, p, config))(c.pose)  # (b,) nodes
        poses = arc_poses(c.pose[:, None, :], kap[None, :], gp[None, :], TA, dl)  # (b, P, TA, 3)
        hit = check(poses, margin=margin[:, None, None, None])
        clear = jnp.cumprod(~hit, axis=-1).astype(bool)
        nfree = jnp.sum(clear, -1)  # (B, P)
        outs = is_out(poses, d, config) & clear
        has_out = jnp.any(outs, -1)
        j_out = jnp.argmax(outs, -1)
        last = jnp.where(has_out, j_out, nfree - 1)
        ends = jnp.floor(last[..., None] * ends_frac).astype(jnp.int32)  # (B, P, E)
        succ = has_out[..., None] & (jnp.arange(E) == 0)
        endpose = jnp.take_along_axis(poses, jnp.maximum(ends, 0)[..., None], axis=-2)  # (B, P, E, 3)
        length = ends.astype(dtype) * dl
        rev = (c.gear[:, None, None] != 0) & (c.gear[:, None, None] != gp[None, :, None].astype(jnp.int32))
        cost = c.cost[:, None, None] + length + config.gear_penalty * rev + MOVE_COST
        ok = c.alive[:, None, None] & (length >= config.min_progress) & (nfree[..., None] > 0)
        h = jnp.where(succ, 0.0, lookup(table, endpose))
        return endpose, ends, cost, h, ok, succ

    def body(c: _Carry) -> _Carry:
        """One depth from ``b`` nodes (``B``, or 1 at the root) to the next ``B``."""
        b = c.pose.shape[0]
        endpose, ends, cost, h, ok, succ = expand(c)
        flat = lambda x: x.reshape((b * P * E,) + x.shape[3:])  # noqa: E731
        endpose, ends, cost, h, ok, succ = map(flat, (endpose, ends, cost, h, ok, succ))
        node = jnp.repeat(jnp.arange(b), P * E)
        prim = jnp.tile(jnp.repeat(jnp.arange(P), E), b)
        if b * P * E < B:  # fewer children than beam slots (the root with few primitives): pad, not alive
            pad = lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], B - b * P * E, 0)])  # noqa: E731
            endpose, ends, cost, h, succ, node, prim = map(pad, (endpose, ends, cost, h, succ, node, prim))
            ok = jnp.concatenate([ok, jnp.zeros((B - b * P * E,), bool)])
        # a solution at this depth: the cheapest one
        sc = jnp.where(ok & succ, cost, jnp.inf)
        i_sol = jnp.argmin(sc)
        found = jnp.isfinite(sc[i_sol])
        # otherwise the next beam: best children, one per lattice cell
        key = _key(endpose)
        seen = jnp.any((key[:, None] == c.h_key.reshape(-1)[None, :]) & c.h_alive.reshape(-1)[None, :], axis=1)
        f = jnp.where(ok & ~succ & ~seen, h + G_WEIGHT * cost, jnp.inf)
        order = jnp.argsort(f)
        fs, ks = f[order], key[order]
        earlier = jnp.tril(jnp.ones((fs.shape[0],) * 2, bool), -1)
        dup = jnp.any(earlier & (ks[:, None] == ks[None, :]) & jnp.isfinite(fs)[None, :], axis=1)
        fs = jnp.where(dup, jnp.inf, fs)
        sel = jnp.argsort(fs)[:B]
        pick = order[sel]
        alive = jnp.isfinite(fs[sel])
        best = jnp.min(jnp.where(alive, h[pick], jnp.inf))
        better = best < c.best_h - PROGRESS
        wait = jnp.where(better, 0, c.wait + 1)
        k = c.depth
        dead = ~jnp.any(alive) | (wait >= PATIENCE) | (k + 1 >= M)
        return _Carry(
            depth=k + 1,
            done=found | dead,
            found=found,
            pose=endpose[pick],
            cost=cost[pick],
            gear=gp[prim[pick]].astype(jnp.int32),
            alive=alive,
            best_h=jnp.minimum(best, c.best_h),
            wait=wait,
            h_pose=c.h_pose.at[k + 1].set(endpose[pick]),
            h_parent=c.h_parent.at[k].set(node[pick]),
            h_prim=c.h_prim.at[k].set(prim[pick]),
            h_end=c.h_end.at[k].set(ends[pick]),
            h_key=c.h_key.at[k + 1].set(key[pick]),
            h_alive=c.h_alive.at[k + 1].set(alive),
            sol=jnp.where(found, jnp.stack([node[i_sol], prim[i_sol], ends[i_sol]]), c.sol),
        )

    def init(start):
        """The root alone (one node, not a beam of copies) expanded to the first depth."""
        pose0 = jnp.broadcast_to(start, (B, 3))
        alive0 = jnp.arange(B) == 0
        zi = jnp.zeros((M, B), jnp.int32)
        root = _Carry(
            jnp.zeros((), jnp.int32),
            jnp.zeros((), bool),
            jnp.zeros((), bool),
            start[None],
            jnp.zeros((1,), dtype),
            jnp.zeros((1,), jnp.int32),
            jnp.ones((1,), bool),
            jnp.asarray(jnp.inf, dtype),
            jnp.zeros((), jnp.int32),
            jnp.zeros((M + 1, B, 3), dtype).at[0].set(pose0),
            zi,
            zi,
            zi,
            jnp.zeros((M + 1, B), jnp.int32).at[0].set(_key(pose0)),
            jnp.zeros((M + 1, B), bool).at[0].set(alive0),
            jnp.zeros((3,), jnp.int32),
        )
        return body(root)

    def depth(c):
        return jax.tree_util.tree_map(lambda a, b: jnp.where(c.done, a, b), c, body(c))

    return init, depth, functools.partial(_finish, kap=kap, gp=gp, steer_p=steer_p, config=config, dtype=dtype)


def _finish(c: _Carry, start, kap, gp, steer_p, config: ParkoutConfig, dtype) -> ParkoutResult:
    """Backtrack the solving moves of a finished search and lay them out as a ``ParkoutResult``."""
    M, T, TA, dl = config.max_moves, config.steps, config.arc_steps, config.dl
    j = c.depth - 1  # index of the solving move

    def back(n_next, i):
        last = i == j
        node = jnp.where(last, c.sol[0], c.h_parent[i, n_next])
        prim = jnp.where(last, c.sol[1], c.h_prim[i, n_next])
        end = jnp.where(last, c.sol[2], c.h_end[i, n_next])
        use = (i <= j) & c.found
        return jnp.where(i <= j, node, n_next), (node, prim, end, use)

    _, (node, prim, end, use) = lax.scan(back, jnp.zeros((), jnp.int32), jnp.arange(M), reverse=True)
    p0 = c.h_pose[jnp.arange(M), node]  # (M, 3)
    mp = arc_poses(p0, kap[prim], gp[prim], TA, dl)  # (M, TA, 3)
    valid = use[:, None] & (jnp.arange(TA) <= end[:, None])
    pad = T - TA
    poses = jnp.concatenate([mp, jnp.broadcast_to(mp[:, -1:], (M, pad, 3))], 1) if pad else mp
    valid = jnp.concatenate([valid, jnp.zeros((M, pad), bool)], 1) if pad else valid
    n = jnp.maximum(jnp.sum(valid, -1) - 1, 0)
    endp = jnp.take_along_axis(poses, n[:, None, None], axis=1)[:, 0]
    final = jnp.where(c.found, endp[jnp.clip(j, 0, M - 1)], start)
    poses = jnp.where(valid[..., None], poses, endp[:, None])
    poses = jnp.where(valid.any(-1)[:, None, None], poses, final)
    gear = jnp.where(use, gp[prim], 0).astype(jnp.int32)
    steer = jnp.broadcast_to(jnp.where(use, steer_p[prim], 0.0)[:, None], (M, T)).astype(dtype)
    length = jnp.sum(jnp.where(use, end.astype(dtype) * dl, 0.0))
    return ParkoutResult(poses, valid, gear, steer, c.found, ~c.found, jnp.sum(use), length, final, jnp.asarray(True))
