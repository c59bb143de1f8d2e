"""Batch park-out planning that stops paying for finished scenes.

``plan_grids`` plans whole park-outs for a batch of grids: the two-curve loop runs in
``slots`` parallel lanes inside one jitted ``lax.while_loop``; each time a scene
finishes (out, stuck, out of moves or no progress) its lane takes the next
scene from the queue, so a slow scene holds one lane, not the batch. Scenes the
two-curve loop fails go to the search (``search``), which runs the same way:
``SEARCH_SLOTS`` lanes, one depth per iteration, refilled as searches finish. Each grid's cell
table is computed once and shared by all lanes (looked up by offset, never copied).

``park_out`` renders each scene's grid (once, at the start, in the slot frame)
and calls ``plan_grids``; the two-corner baseline uses points instead of grids.
"""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.grid import Grid, cell_table
from jaxplan.parking.heuristic import cost_to_go
from jaxplan.parking.parkout import (
    GridModel,
    ParkoutResult,
    PointModel,
    hits_fn,
    loop_init,
    loop_result,
    two_curve_step,
)
from jaxplan.parking.render import render_grids
from jaxplan.parking.scenes import ParkingScene
from jaxplan.parking.search import search_steps
from jaxplan.parking.two_corner import two_corner_points
from jaxplan.types import VehicleParams, is_concrete

CHUNKS = (8, 64, 512)  # scenes per jitted call (padded up to one of these: few compiles)
SEARCH_SLOTS = 8  # search lanes per call (at most; half the padded number of searches)


def _bucket(n: int) -> int:
    for c in CHUNKS:
        if n <= c:
            return c
    return CHUNKS[-1]


def _slot_model(models, idx, config: ParkoutConfig):
    """The collision model of scene ``idx`` out of a batch's models (no copy of grid tables)."""
    if isinstance(models, GridModel):
        stride = config.rows * (config.cols + 1)
        return GridModel(models.table, models.pose[idx], idx * stride)
    return PointModel(models.points[idx], models.ok[idx])


@functools.partial(jax.jit, static_argnames=("config", "slots"))
def run_two_curve(starts, models, n_real, config, vehicle, slots):
    """Two-curve loops of ``C`` scenes through ``slots`` lanes; returns a ``ParkoutResult`` with leading ``C``."""
    C = starts.shape[0]
    W = slots
    dtype = starts.dtype
    init_one = lambda s: loop_init(s, config)  # noqa: E731
    empty = jax.vmap(init_one)(starts)
    outs = jax.vmap(loop_result)(empty)  # output buffers, (C, ...)
    first = jnp.arange(W)
    scene = jnp.where(first < n_real, first, -1)
    state = jax.vmap(init_one)(starts[jnp.clip(first, 0, C - 1)])

    def step_one(st, idx):
        m = _slot_model(models, jnp.maximum(idx, 0), config)
        return two_curve_step(st, hits_fn(m, vehicle, config), vehicle, config)

    def cond(c):
        return jnp.any(c[1] >= 0)

    def body(c):
        state, scene, q, outs = c
        state = state._replace(done=state.done | (scene < 0))
        state = jax.vmap(step_one)(state, scene)
        fin = (scene >= 0) & state.done
        res = jax.vmap(loop_result)(state)
        dest = jnp.where(fin, scene, C)  # C: dropped
        outs = jax.tree_util.tree_map(lambda o, r: o.at[dest].set(r, mode="drop"), outs, res)
        rank = jnp.cumsum(fin) - 1
        nxt = q + rank
        take = fin & (nxt < n_real)
        new = jax.vmap(init_one)(starts[jnp.clip(nxt, 0, C - 1)])
        state = jax.tree_util.tree_map(
            lambda a, b: jnp.where(take.reshape((-1,) + (1,) * (a.ndim - 1)), b, a), state, new
        )
        scene = jnp.where(take, nxt, jnp.where(fin, -1, scene))
        return state, scene, q + jnp.sum(fin), outs

    q0 = jnp.minimum(jnp.asarray(W, jnp.int32), n_real)
    _, _, _, outs = lax.while_loop(cond, body, (state, scene, q0, outs))
    del dtype
    return outs


@functools.partial(jax.jit, static_argnames=("config", "slots"))
def run_search(starts, models, ids, n_ids, config, vehicle, table, slots):
    """Searches for the scenes ``ids[:n_ids]`` (indices into the chunk) through ``slots`` lanes, one depth
    per iteration; a lane whose search is done takes the next scene. Returns a ``ParkoutResult`` ``(Q, ...)``
    in the order of ``ids``."""
    Q, W, dtype = ids.shape[0], slots, starts.dtype

    def steps(q):
        i = ids[jnp.clip(q, 0, Q - 1)]
        check = hits_fn(_slot_model(models, i, config), vehicle, config)
        return search_steps(check, config, vehicle, table, dtype), starts[i]

    def start(q):
        (init, _, _), s0 = steps(q)
        c = init(s0)
        return c._replace(done=c.done | (q < 0))

    def finish(c, q):
        (_, _, fin), s0 = steps(q)
        return fin(c, s0)

    qs = jnp.arange(Q)
    outs = jax.vmap(finish)(jax.vmap(start)(jnp.full((Q,), -1)), qs)
    lane_q = jnp.where(jnp.arange(W) < n_ids, jnp.arange(W), -1)
    lanes = jax.vmap(start)(lane_q)

    def harvest(c):
        lanes, lane_q, nq, outs = c
        fin = (lane_q >= 0) & lanes.done
        res = jax.vmap(finish)(lanes, lane_q)
        dest = jnp.where(fin, lane_q, Q)
        outs = jax.tree_util.tree_map(lambda o, r: o.at[dest].set(r, mode="drop"), outs, res)
        nxt = nq + jnp.cumsum(fin) - 1
        take = fin & (nxt < n_ids)
        new = jax.vmap(start)(jnp.where(take, nxt, -1))
        lanes = jax.tree_util.tree_map(
            lambda a, b: jnp.where(take.reshape((-1,) + (1,) * (a.ndim - 1)), b, a), lanes, new
        )
        lane_q = jnp.where(take, nxt, jnp.where(fin, -1, lane_q))
        return lanes, lane_q, nq + jnp.sum(fin), outs

    def body(c):
        lanes, lane_q, nq, outs = c
        lanes = jax.vmap(lambda ln, q: steps(q)[0][1](ln))(lanes, lane_q)
        fin = (lane_q >= 0) & lanes.done
        return lax.cond(jnp.any(fin), harvest, lambda c: c, (lanes, lane_q, nq, outs))

    nq0 = jnp.minimum(jnp.asarray(W, jnp.int32), n_ids)
    _, _, _, outs = lax.while_loop(lambda c: jnp.any(c[1] >= 0), body, (lanes, lane_q, nq0, outs))
    return outs


@jax.jit
def _tables(cells):
    return cell_table(cells)


def _plan_models(starts, models, config: ParkoutConfig, vehicle, slots=None) -> ParkoutResult:
    """Two-curve loops, then the search for the failures, of ``n`` scenes (host loop over chunks).

    Chunks go round-robin to the local devices (e.g. ``XLA_FLAGS=--xla_force_host_platform_device_count=2``
    on a 2-core CPU) and run there concurrently: every kernel is dispatched before any result is read,
    and a chunk's search starts as soon as its own two-curve loops are done.
    """
    n = starts.shape[0]
    table = cost_to_go(vehicle, config) if config.search else None
    devs = jax.local_devices()
    size = min(CHUNKS[-1], _bucket(-(-n // len(devs))))
    jobs = []
    for ci, lo in enumerate(range(0, n, size)):
        hi = min(n, lo + size)
        C = _bucket(hi - lo)
        dev = devs[ci % len(devs)]
        idx = np.minimum(np.arange(lo, lo + C), hi - 1)
        put = lambda a: jax.device_put(jnp.asarray(a)[idx], dev)  # noqa: E731
        st = put(starts)
        m: GridModel | PointModel
        if isinstance(models, GridModel):
            m = GridModel(_tables(put(models.table)), put(models.pose))
        else:
            m = PointModel(put(models.points), put(models.ok))
        W = max(1, min(C // 2, 64)) if slots is None else min(int(slots), C)
        jobs.append((lo, hi, st, m, run_two_curve(st, m, jnp.asarray(hi - lo, jnp.int32), config, vehicle, W)))
    searches = []
    for lo, hi, st, m, res in jobs:
        failed = np.nonzero(~np.asarray(res.success)[: hi - lo])[0] if config.search else np.zeros(0, int)
        sr = None
        if len(failed):
            Q = _bucket(len(failed))
            ids = jnp.asarray(np.concatenate([failed, np.zeros(Q - len(failed), int)]), jnp.int32)
            sr = run_search(
                st,
                m,
                ids,
                jnp.asarray(len(failed), jnp.int32),
                config,
                vehicle,
                table,
                min(SEARCH_SLOTS, max(1, Q // 2)),
            )
        searches.append((failed, sr))
    parts = []
    for (lo, hi, _, _, res), (failed, sr) in zip(jobs, searches):
        res = jax.tree_util.tree_map(lambda a: np.array(a)[: hi - lo], res)
        if sr is not None:
            keep = np.asarray(sr.success)[: len(failed)]
            # a failed search keeps the two-curve attempt (it drove something; the search drives nothing)
            for a, b in zip(res, sr):
                a[failed[keep]] = np.asarray(b)[: len(failed)][keep]
        parts.append(res)
    return jax.tree_util.tree_map(lambda *a: np.concatenate(a), *parts)


def plan_grids(
    starts,
    grids: Grid,
    config: ParkoutConfig = ParkoutConfig(),
    vehicle: VehicleParams = VehicleParams(),
    slots: int | None = None,
) -> ParkoutResult:
    """Whole park-outs of ``n`` scenes from their grids (planning only; host driver, jitted kernels).

    Args:
        starts: ``(n, 3)`` rear-axle start poses in the slot frame.
        grids: ``Grid`` with ``cells (n, rows, cols)`` and frame poses ``(n, 3)``.
        slots: parallel lanes of the two-curve loop (default half the chunk, at most 64).

    Returns:
        ``ParkoutResult`` of numpy arrays with leading ``n``.
    """
    if is_concrete(starts, grids, vehicle):
        from jaxplan.parking.parkout import _check_inputs

        _check_inputs(starts, grids, config, vehicle)
        if np.ndim(starts) != 2:
            raise ValueError(f"starts: expected (n, 3), got {np.shape(starts)}")
    dtype = jnp.result_type(float)
    return _plan_models(
        jnp.asarray(starts, dtype),
        GridModel(jnp.asarray(grids.cells, bool), jnp.asarray(grids.pose, dtype)),
        config,
        vehicle,
        slots,
    )


def render_scenes(scene: ParkingScene, seed: int, config, vehicle) -> Grid:
    """The grids of ``n`` scenes ``(n,)`` (``render_grids`` in chunks padded to ``CHUNKS`` sizes: a few compiles
    for any batch size); scene ``i`` gets the noise of key ``(seed, i)``."""
    n = scene.batch_shape[0]
    size = CHUNKS[-1] if n >= CHUNKS[-1] else CHUNKS[1]  # a batch of 100 renders 128 grids, not 512
    cells = []
    for lo in range(0, n, size):
        hi = min(n, lo + size)
        C = _bucket(hi - lo)
        idx = np.minimum(np.arange(lo, lo + C), hi - 1)
        part = jax.tree_util.tree_map(lambda a: jnp.asarray(a)[idx], scene)
        g = render_grids(part, seed, config, vehicle, first=lo)
        cells.append(g.cells[: hi - lo])
    all_cells = jnp.concatenate(cells) if len(cells) > 1 else cells[0]
    jax.block_until_ready(all_cells)
    return Grid(cells=all_cells, pose=jnp.zeros((n, 3), jnp.result_type(float)))


def park_out(
    scene: ParkingScene,
    key=None,
    config: ParkoutConfig = ParkoutConfig(),
    vehicle: VehicleParams = VehicleParams(),
    model: str = "grid",
    slots: int | None = None,
    timing: dict | None = None,
) -> ParkoutResult:
    """Drive out of the slot: read the grid once at the start, plan every move, drive them.

    Args:
        scene: ``ParkingScene`` with one leading batch dim ``(n,)`` (or none).
        key: an integer seed (or legacy PRNG key; its last word is used) for the sensor noise.
        model: ``"grid"`` (the occupancy grid) or ``"two_corner"`` (the baseline
            that keeps the two nearest corners of each obstacle and no grid).
        timing: if a dict, receives ``render_s`` and ``plan_s`` (wall seconds).

    Returns:
        ``ParkoutResult`` of numpy arrays (leading ``n``, or none for one scene).
    """
    if model not in ("grid", "two_corner"):
        raise ValueError(f"model must be 'grid' or 'two_corner', got {model!r}")
    if is_concrete(scene, vehicle):
        vehicle.validate()
        config.check_vehicle(vehicle)
        scene.validate()
    single = scene.batch_shape == ()
    if single:
        scene = jax.tree_util.tree_map(lambda a: jnp.asarray(a)[None], scene)
    if len(scene.batch_shape) != 1:
        raise ValueError(f"scene: expected one batch dim (n,), got {scene.batch_shape}")
    seed = 0 if key is None else int(np.asarray(key).reshape(-1)[-1])
    dtype = jnp.result_type(float)
    starts = jnp.asarray(scene.start, dtype)
    t0 = time.perf_counter()
    if model == "grid":
        grids = render_scenes(scene, seed, config, vehicle)
        t1 = time.perf_counter()
        res = _plan_models(starts, GridModel(grids.cells, grids.pose), config, vehicle, slots)
    else:
        t1 = t0
        ref = starts[:, :2] + jnp.asarray(vehicle.center_offset, dtype) * jnp.stack(
            [jnp.cos(starts[:, 2]), jnp.sin(starts[:, 2])], -1
        )
        pts, ok = two_corner_points(scene.polygons, scene.valid, ref)
        res = _plan_models(starts, PointModel(pts, ok), config, vehicle, slots)
    if timing is not None:
        timing["render_s"] = t1 - t0
        timing["plan_s"] = time.perf_counter() - t1
    if single:
        res = jax.tree_util.tree_map(lambda a: a[0], res)
    return res
