"""Prediction baselines for imitation, on the same demonstrations and the same metric
as the lattice: constant velocity, constant acceleration (both along the start
heading) and the IDM along the lane, driven by the recorded leader.

Every baseline sees what the lattice sees: the start state fitted on the past
(``demos.fit_start_state``), the reference line and the other vehicles' recorded
futures. Batched over demonstrations (leading axis ``B``), jitted.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.geometry.boxes import poses_to_boxes
from jaxplan.geometry.frenet import reference_line, to_cartesian, to_frenet
from jaxplan.lattice.risk import min_separation
from jaxplan.tuning.demos import Demo
from jaxplan.tuning.metrics import displacement
from jaxplan.tuning.traffic import FrenetTraffic, IDMParams, frenet_traffic, idm_rollout
from jaxplan.types import Obstacles, VehicleParams

VEHICLE = VehicleParams(reference="center")  # the lattice's car for imitation (positions at its centre)
CAR_LENGTH = VEHICLE.length  # also the IDM's car


def _along_heading(ego, s):
    """Positions ``(..., T, 2)`` at distances ``s (..., T)`` along the start heading."""
    u = jnp.stack([jnp.cos(ego[..., 2]), jnp.sin(ego[..., 2])], -1)
    return ego[..., None, :2] + s[..., None] * u[..., None, :]


@jax.jit
def constant_velocity(demos: Demo):
    """``(B, T, 2)``: the start speed kept along the start heading."""
    return _along_heading(demos.ego, demos.ego[..., 3:4] * demos.t)


@jax.jit
def constant_acceleration(demos: Demo):
    """``(B, T, 2)``: the start acceleration kept along the start heading until the car stops."""
    v0, a0, t = demos.ego[..., 3:4], demos.ego[..., 4:5], demos.t
    t_stop = jnp.where(a0 < 0, -v0 / jnp.where(a0 < 0, a0, -1.0), jnp.inf)
    tt = jnp.minimum(t, t_stop)
    return _along_heading(demos.ego, v0 * tt + 0.5 * a0 * tt * tt)


@functools.partial(jax.jit, static_argnames=("dt",))
def demo_traffic(demos: Demo, dt: float = 0.1):
    """The other vehicles of each demonstration in its reference line's Frenet frame
    (``FrenetTraffic`` ``(B, K, T)``) and the start's ``(s0, l0)`` ``(B,)`` each."""

    def one(d):
        ref = reference_line(d.ref_xy)
        obs = Obstacles(d.obstacles, d.obstacle_valid, d.t, d.obstacle_static)
        s0, l0 = to_frenet(ref, d.ego[:2])
        return frenet_traffic(ref, obs, dt), s0, l0

    return jax.vmap(one)(demos)


@functools.partial(jax.jit, static_argnames=("dt",))
def idm_stations(traffic: FrenetTraffic, s0, l0, v0, params: IDMParams, dt: float = 0.1):
    """``(..., B, T)`` IDM stations for every demonstration (``demo_traffic``) and every
    parameter set of ``params`` (fields ``(...)``, e.g. a grid)."""
    one = lambda tr, a, b, c, p: idm_rollout(tr, a, b, c, CAR_LENGTH, p, dt)[0]
    per_demo = jax.vmap(one, in_axes=(0, 0, 0, 0, None))
    f = per_demo
    for _ in range(jnp.ndim(params.headway)):
        f = jax.vmap(f, in_axes=(None, None, None, None, 0))
    return f(traffic, s0, l0, v0, params)


@jax.jit
def _stations_to_xy(ref_xy, s, l0):
    return jax.vmap(lambda r, si, li: to_cartesian(reference_line(r), si, jnp.broadcast_to(li, si.shape)))(
        ref_xy, s, l0
    )


GRID_BATCH = 16  # IDM parameter sets per compiled call (a single set is padded to it: one compile for all uses)


@functools.partial(jax.jit, static_argnames=("dt",))
def _idm_grid_xy(demos: Demo, params: IDMParams, dt: float):
    """``(P, B, T, 2)`` IDM positions for ``GRID_BATCH`` parameter sets (fields ``(P,)``)."""
    traffic, s0, l0 = demo_traffic(demos, dt)
    st = idm_stations(traffic, s0, l0, demos.ego[:, 3], params, dt)  # (P, B, T)
    return jax.vmap(lambda si: _stations_to_xy(demos.ref_xy, si, l0))(st)


def _param_batch(params: IDMParams) -> IDMParams:
    """Parameter sets ``(P,)`` padded to ``GRID_BATCH`` by repeating the last one."""
    leaves = [jnp.atleast_1d(jnp.asarray(x, jnp.float32)) for x in dataclasses.astuple(params)]
    n = max(x.shape[0] for x in leaves)
    if n > GRID_BATCH:
        raise ValueError(f"at most {GRID_BATCH} IDM parameter sets per call, got {n}")
    full = [
        jnp.concatenate([jnp.broadcast_to(x, (n,)), jnp.repeat(jnp.broadcast_to(x, (n,))[-1:], GRID_BATCH - n)])
        for x in leaves
    ]
    return IDMParams(*full)


def idm(demos: Demo, params: IDMParams = IDMParams(), dt: float = 0.1):
    """``(B, T, 2)``: the IDM car along the reference line at the start's offset, following
    the recorded leader (the nearest recorded vehicle ahead in its lane at each step)."""
    return _idm_grid_xy(demos, _param_batch(params), dt)[0]


IDM_GRID = {
    "v_ratio": (1.0, 1.1, 1.2),
    "v_extra": (0.0, 2.0, 4.0),
    "headway": (0.3, 0.6, 1.0, 1.5),
    "a_max": (0.3, 0.6, 1.2),
    "b_comf": (0.5, 1.0, 2.0),
}


def chunks(demos: Demo, chunk: int):
    """``(part, n)`` pieces of ``chunk`` demonstrations, the last one padded (one compiled shape)."""
    B = demos.ego.shape[0]
    for i in range(0, B, chunk):
        d = jax.tree_util.tree_map(lambda x: x[i : i + chunk], demos)
        n = d.ego.shape[0]
        if n < chunk:
            d = jax.tree_util.tree_map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], chunk - n, 0)]), d)
        yield d, n


CHUNK = 32  # demonstrations per compiled call of every imitation kernel


def calibrate_idm(demos: Demo, grid: dict = IDM_GRID, dt: float = 0.1, chunk: int = CHUNK) -> tuple[IDMParams, float]:
    """The IDM parameters of ``grid`` (every combination; ``s_jam`` 2 m and ``delta`` 4 unless
    given) with the least mean ADE3 on ``demos``.

    Returns:
        (params, mean ADE3).
    """
    names = list(grid)
    combos = np.array(list(itertools.product(*(grid[n] for n in names))), np.float32)  # (P, n)
    fixed = {k: v for k, v in (("s_jam", 2.0), ("delta", 4.0)) if k not in grid}
    total = np.zeros(len(combos))
    for c0 in range(0, len(combos), GRID_BATCH):
        c = combos[c0 : c0 + GRID_BATCH]
        p = _param_batch(
            IDMParams(
                **{n: jnp.asarray(c[:, j]) for j, n in enumerate(names)},
                **{k: jnp.full(len(c), v, jnp.float32) for k, v in fixed.items()},
            )
        )
        for d, n in chunks(demos, chunk):
            e = displacement(_idm_grid_xy(d, p, dt), d.human_xy, d.human_valid)["ade3"]  # (P, B)
            total[c0 : c0 + len(c)] += np.asarray(e)[: len(c), :n].sum(1)
    ade = total / demos.ego.shape[0]
    best = int(np.argmin(ade))
    return IDMParams(**{n: float(combos[best, j]) for j, n in enumerate(names)}, **fixed), float(ade[best])


@jax.jit
def collides(xy, demos: Demo):
    """``(B,)`` whether a predicted path ``xy (B, T, 2)`` overlaps a recorded vehicle at the same
    time (the lattice's car, headings along the path; the geometry core's SAT separation)."""
    d = xy[:, 1:] - xy[:, :-1]
    step = jnp.linalg.norm(d, axis=-1)
    th = jnp.arctan2(d[..., 1], d[..., 0])
    th = jnp.concatenate([demos.ego[:, 2:3], th], 1)
    # keep the last heading while (nearly) stopped
    keep = jnp.concatenate([jnp.zeros_like(step[:, :1], bool), step < 1e-3], 1)
    th = lax.associative_scan(lambda a, b: (jnp.where(b[1], a[0], b[0]), a[1] & b[1]), (th, keep), axis=1)[0]

    def one(p, h, dm):
        boxes = poses_to_boxes(p, h, VEHICLE)
        obs = Obstacles(dm.obstacles, dm.obstacle_valid, dm.t, dm.obstacle_static).aligned(p.shape[0])
        return jnp.any(min_separation(boxes[None], obs)[0] < 0)

    return jax.vmap(one)(xy, th, demos)


def predict(fn, demos: Demo, chunk: int = CHUNK) -> np.ndarray:
    """``fn(demos) -> (B, T, 2)`` in padded chunks (the compiled shape of every other call)."""
    return np.concatenate([np.asarray(fn(d))[:n] for d, n in chunks(demos, chunk)])


def predict_errors(predict, demos: Demo, chunk: int = CHUNK) -> dict:
    """``displacement`` (numpy, ``(B,)`` each) of ``predict(demos) -> (B, T, 2)``, in chunks of
    ``chunk`` demonstrations (padded: one compiled shape), and ``collided``: the prediction
    overlaps a recorded vehicle (``collides``)."""
    parts = []
    for d, n in chunks(demos, chunk):
        xy = predict(d)
        e = displacement(xy, d.human_xy, d.human_valid)
        e["collided"] = collides(xy, d)
        parts.append({k: np.asarray(v)[:n] for k, v in e.items()})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


BASELINES = {"constant_velocity": constant_velocity, "constant_acceleration": constant_acceleration}
