"""Traffic seen along a reference line: obstacles in the Frenet frame, the leader of a
point, and the intelligent driver model (IDM) driven by a recorded leader.

Kernels are written for one scene (``jax.vmap`` them over demonstrations); shapes in
the docstrings. Used by the imitation baselines (``baselines.idm``) and by the
scene-by-candidate features (``features``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.geometry.frenet import ReferenceLine, to_cartesian, to_frenet
from jaxplan.models.idm import idm_accel as idm_model
from jaxplan.types import Obstacles

NO_GAP = 1e3  # gap (m) reported when nobody is ahead


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FrenetTraffic:
    """Obstacles along a reference line, each field ``(K, T)``.

    Attributes:
        s, l: arc length and offset of each obstacle's centre.
        v: speed along the line, ``ds/dt`` (central differences, one-sided at the ends).
        length, width: box size.
        valid: known at that time.
    """

    s: jax.Array
    l: jax.Array
    v: jax.Array
    length: jax.Array
    width: jax.Array
    valid: jax.Array


def frenet_traffic(ref: ReferenceLine, obstacles: Obstacles, dt: float) -> FrenetTraffic:
    """Obstacles ``(K, T, 5)`` in the Frenet frame of ``ref`` (one scene)."""
    b = obstacles.boxes
    s, l = to_frenet(ref, b[..., :2])
    ok = obstacles.valid
    # ds/dt: central difference where both neighbours are known, else one-sided, else 0
    fwd = jnp.concatenate([(s[:, 1:] - s[:, :-1]) / dt, jnp.zeros_like(s[:, :1])], 1)
    ok_f = jnp.concatenate([ok[:, 1:] & ok[:, :-1], jnp.zeros_like(ok[:, :1])], 1)
    bwd = jnp.concatenate([jnp.zeros_like(s[:, :1]), (s[:, 1:] - s[:, :-1]) / dt], 1)
    ok_b = jnp.concatenate([jnp.zeros_like(ok[:, :1]), ok[:, 1:] & ok[:, :-1]], 1)
    v = jnp.where(ok_f & ok_b, 0.5 * (fwd + bwd), jnp.where(ok_f, fwd, jnp.where(ok_b, bwd, 0.0)))
    static = jnp.asarray(obstacles.static, bool)[:, None]
    v = jnp.where(static, 0.0, v)
    return FrenetTraffic(s, l, v, b[..., 2], b[..., 3], ok)


def leader(traffic: FrenetTraffic, s, l, length, band):
    """Gap to the nearest obstacle ahead of points ``(s, l)`` and its speed.

    An obstacle leads a point at step ``k`` when it is valid, its centre is ahead
    (``s_o > s``) and within ``band`` laterally (``|l_o - l| < band``).

    Args:
        traffic: ``FrenetTraffic`` ``(K, T)``.
        s, l: ``(..., T)`` the points over time.
        length: the car's length (m); the gap is bumper to bumper.
        band: lateral half-width (m).

    Returns:
        (gap ``(..., T)``, ``NO_GAP`` without a leader; leader speed ``(..., T)``; has_leader ``(..., T)``).
    """
    ds = traffic.s - s[..., None, :]  # (..., K, T)
    ahead = traffic.valid & (ds > 0) & (jnp.abs(traffic.l - l[..., None, :]) < band)
    gap = jnp.where(ahead, ds - 0.5 * (traffic.length + length), NO_GAP)
    k = jnp.argmin(gap, axis=-2)  # (..., T)
    g = jnp.min(gap, axis=-2)
    vl = jnp.take_along_axis(jnp.broadcast_to(traffic.v, gap.shape), k[..., None, :], axis=-2)[..., 0, :]
    has = jnp.any(ahead, axis=-2)
    return g, jnp.where(has, vl, 0.0), has


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class IDMParams:
    """Intelligent driver model parameters (array pytree; each ``(...)``).

    Attributes:
        v_ratio: desired speed as a multiple of the start speed (no speed limits in NGSIM US-101).
        v_extra: added to the desired speed (m/s).
        headway: desired time headway T (s).
        s_jam: jam distance s0 (m).
        a_max: maximum acceleration a (m/s^2).
        b_comf: comfortable deceleration b (m/s^2).
        delta: acceleration exponent.
    """

    v_ratio: jax.Array | float = 1.0
    v_extra: jax.Array | float = 1.0
    headway: jax.Array | float = 1.2
    s_jam: jax.Array | float = 2.0
    a_max: jax.Array | float = 1.0
    b_comf: jax.Array | float = 1.5
    delta: jax.Array | float = 4.0


def idm_accel(p: IDMParams, v, v_des, gap, v_lead, has_leader):
    """IDM acceleration (``jaxplan.models.idm.idm_accel`` with these parameters, unclipped); all
    args ``(...)``."""
    return idm_model(
        v,
        v_des,
        gap,
        v - v_lead,
        a_max=p.a_max,
        b_comf=p.b_comf,
        time_gap=p.headway,
        min_gap=p.s_jam,
        delta=p.delta,
        has_leader=has_leader,
    )


def idm_rollout(
    traffic: FrenetTraffic, s0, l0, v0, length, p: IDMParams, dt: float, band: float = 1.75, a_min: float = -8.0
):
    """Stations ``(T,)`` and speeds ``(T,)`` of an IDM car along the line at offset ``l0``,
    following whichever recorded obstacle leads it at each step (``leader``).

    Args:
        traffic: obstacles ``(K, T)`` in the line's frame.
        s0, l0, v0: ``()`` start station, offset, speed.
        length: the car's length (m).
        dt: step (s) of the obstacles' time axis.

    Returns:
        (s, v) each ``(T,)``, index 0 = the start.
    """
    v_des = p.v_ratio * v0 + p.v_extra
    T = traffic.s.shape[-1]

    def step(carry, k):
        s, v = carry
        sl = lambda x: lax.dynamic_index_in_dim(x, k, axis=-1, keepdims=True)
        tk = FrenetTraffic(
            *(sl(f) for f in (traffic.s, traffic.l, traffic.v, traffic.length, traffic.width, traffic.valid))
        )
        g, vl, has = leader(tk, s[None], l0[None], length, band)
        a = jnp.maximum(idm_accel(p, v, v_des, g[0], vl[0], has[0]), a_min)
        v_new = jnp.maximum(v + a * dt, 0.0)
        s_new = s + 0.5 * (v + v_new) * dt
        return (s_new, v_new), (s_new, v_new)

    init = (jnp.asarray(s0, traffic.s.dtype), jnp.asarray(v0, traffic.s.dtype))
    _, (s, v) = lax.scan(step, init, jnp.arange(T - 1))
    return jnp.concatenate([init[0][None], s]), jnp.concatenate([init[1][None], v])


def idm_xy(ref: ReferenceLine, obstacles: Obstacles, ego, length, p: IDMParams, dt: float, band: float = 1.75):
    """Positions ``(T, 2)`` of the IDM car started at ``ego (5,)`` [x, y, heading, v, a] on ``ref``."""
    traffic = frenet_traffic(ref, obstacles, dt)
    s0, l0 = to_frenet(ref, ego[:2])
    s, _ = idm_rollout(traffic, s0, l0, ego[3], length, p, dt, band)
    return to_cartesian(ref, s, jnp.broadcast_to(l0, s.shape))
