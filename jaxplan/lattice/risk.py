"""Time-aware collision risk of candidates against moving obstacles.

The car's box at step ``k`` is checked against every obstacle's predicted box at the
same step with the geometry core's ``box_separation`` (SAT on the four box axes;
negative = overlap). Per candidate: the minimum signed separation over obstacles at
every step, collision yes/no, the first colliding sample time, and the time to
collision (TTC): the zero crossing of the minimum separation, linearly
interpolated between the last free and the first colliding sample (exact for two
boxes closing at constant velocity without rotation; ``0`` when already
overlapping at ``t = 0``; ``inf`` without collision).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.geometry.boxes import box_separation_axes, poses_to_boxes
from jaxplan.geometry.lines import safe_norm
from jaxplan.types import Obstacles, Trajectory, VehicleParams, pytree_dataclass

BIG = 1e6  # separation reported when there is no obstacle
FAR = 1e6  # invalid obstacle entries are moved this far away (they then block nothing)


@pytree_dataclass(data_fields=("min_sep", "collided", "first_t", "ttc"))
class Risk:
    """Attributes: ``min_sep (..., N, T)`` metres; ``collided (..., N)`` bool;
    ``first_t (..., N)`` first colliding sample time (inf if none); ``ttc (..., N)``."""

    min_sep: Any
    collided: Any
    first_t: Any
    ttc: Any


def align_obstacles(obstacles: Obstacles, t) -> Obstacles:
    """Obstacle predictions at the candidates' times ``t`` ``(T,)`` (``Obstacles.at_times``).

    The predictions are read at their own stamps ``obstacles.t`` (any step, seconds from
    now) and interpolated to ``t``: dynamic obstacles are invalid outside their
    recording, static ones are held.
    """
    return obstacles.at_times(t)


def _obstacle_parts(obstacles: Obstacles):
    """Centres ``(K, T, 2)`` (invalid entries moved far away), unit axes, half sizes."""
    b = obstacles.boxes
    far = jnp.asarray(FAR, b.dtype)
    c = jnp.where(obstacles.valid[..., None], b[..., :2], far)
    u = jnp.stack([jnp.cos(b[..., 4]), jnp.sin(b[..., 4])], -1)
    return lax.optimization_barrier((c, u, 0.5 * b[..., 2:4]))


def car_parts(xy, axis, vehicle: VehicleParams):
    """The car's box centres ``(..., 2)`` and half sizes ``(2,)`` from reference points and unit headings."""
    c = xy + jnp.asarray(vehicle.center_offset, xy.dtype) * axis
    return c, 0.5 * jnp.asarray([vehicle.length, vehicle.width], xy.dtype)


def min_separation(car_boxes, obstacles: Obstacles):
    """Minimum signed separation over obstacles at every step.

    Args:
        car_boxes: ``(N, T, 5)`` the car's box per candidate and step.
        obstacles: boxes ``(K, T, 5)``, valid ``(K, T)``, same T.

    Returns:
        ``(N, T)``; about ``FAR`` where no obstacle is valid.
    """
    u = jnp.stack([jnp.cos(car_boxes[..., 4]), jnp.sin(car_boxes[..., 4])], -1)
    return min_separation_axes(car_boxes[..., :2], u, 0.5 * car_boxes[..., 2:4], obstacles)


def min_separation_axes(center, axis, half, obstacles: Obstacles):
    """``min_separation`` for car boxes given as centres ``(N, T, 2)``, unit headings
    ``(N, T, 2)`` and half sizes ``(2,)`` or ``(N, T, 2)`` (no trigonometry per pair)."""
    K = obstacles.boxes.shape[-3]
    if K == 0:
        return jnp.full(center.shape[:-1], BIG, center.dtype)
    oc, ou, oh = _obstacle_parts(obstacles)
    center, axis = lax.optimization_barrier((center, axis))
    sep = box_separation_axes(center[:, None], axis[:, None], half, oc[None], ou[None], oh[None])  # (N, K, T)
    return jnp.min(sep, axis=-2)


def min_separation_broad(center, axis, half, obstacles: Obstacles, group_size: int, budget: int, margin: float = 1.0):
    """``min_separation_axes`` with a broad phase over groups of candidates.

    Candidates come in groups of ``group_size`` (for the lattice: the lateral offsets
    of one speed profile, which stay close together). Per group and step, a circle
    bounds every car box of the group; only (group, obstacle, step) triples whose
    circles come within ``margin`` get the exact SAT test, for every candidate of the
    group. Up to ``budget`` triples are checked that way; with more near triples the
    dense check runs instead, so the result never depends on the budget.

    Returns:
        ``(N, T)``: the exact SAT separation wherever some obstacle is within the
        margin; elsewhere a positive stand-in above ``margin`` (centre distance minus
        bounding radii), so collision flags and the smooth collision feature
        (``sep_eps << margin``) are unaffected.
    """
    N, T = center.shape[:2]
    K = obstacles.boxes.shape[-3]
    if K == 0:
        return jnp.full((N, T), BIG, center.dtype)
    P = group_size
    G = N // P
    oc, ou, oh = _obstacle_parts(obstacles)
    center, axis = lax.optimization_barrier((center, axis))
    cg, ug = center.reshape(G, P, T, 2), axis.reshape(G, P, T, 2)
    lo, hi = jnp.min(cg, axis=1), jnp.max(cg, axis=1)  # (G, T, 2)
    mid = 0.5 * (lo + hi)
    r_car = (
        jnp.sqrt(jnp.sum(jnp.asarray(half) ** 2, -1))
        if jnp.ndim(half) == 1
        else jnp.max(jnp.sqrt(jnp.sum(half**2, -1)))
    )
    r_grp = 0.5 * safe_norm(hi - lo) + r_car  # (G, T); hi = lo at t = 0
    r_obs = safe_norm(oh)  # (K, T)
    d = safe_norm(mid[:, None] - oc[None]) - r_grp[:, None] - r_obs[None]  # (G, K, T)
    valid = obstacles.valid[None]
    near = valid & (d <= margin)
    stand_in = jnp.min(jnp.where(valid & ~near, d, BIG), axis=1)  # (G, T)
    count = jnp.sum(near)

    def sparse(_):
        g, k, t = jnp.nonzero(near, size=budget, fill_value=0)
        ok = jnp.arange(budget) < count
        sep = box_separation_axes(
            cg[g, :, t], ug[g, :, t], half, oc[k, t][:, None], ou[k, t][:, None], oh[k, t][:, None]
        )  # (M, P)
        sep = jnp.where(ok[:, None], sep, BIG)
        ms = jnp.broadcast_to(stand_in[:, None, :], (G, P, T))
        return ms.at[g, :, t].min(sep).reshape(N, T)

    def dense(_):
        return min_separation_axes(center, axis, half, obstacles)

    return lax.cond(count <= budget, sparse, dense, None)


def risk_from_separation(min_sep, t) -> Risk:
    """Collision flags, first collision time and TTC from ``min_sep (..., N, T)`` and ``t (T,)``."""
    hit = min_sep < 0
    collided = jnp.any(hit, axis=-1)
    k = jnp.argmax(hit, axis=-1)
    first_t = jnp.where(collided, t[k], jnp.inf)
    kp = jnp.maximum(k - 1, 0)
    sep_k = jnp.take_along_axis(min_sep, k[..., None], axis=-1)[..., 0]
    sep_p = jnp.take_along_axis(min_sep, kp[..., None], axis=-1)[..., 0]
    frac = sep_p / jnp.maximum(sep_p - sep_k, 1e-12)
    ttc = jnp.where(k == 0, 0.0, t[kp] + frac * (t[k] - t[kp]))
    return Risk(min_sep, collided, first_t, jnp.where(collided, ttc, jnp.inf))


def trajectory_boxes(traj: Trajectory, vehicle: VehicleParams):
    """The car's boxes ``(..., T, 5)`` along a trajectory."""
    return poses_to_boxes(jnp.stack([traj.x, traj.y], axis=-1), traj.theta, vehicle)


def collision_risk(traj: Trajectory, obstacles: Obstacles, vehicle: VehicleParams) -> Risk:
    """Risk of every candidate ``traj (N, T)`` against ``obstacles`` (read at the times ``traj.t``)."""
    obstacles = align_obstacles(obstacles, traj.t[0])
    sep = min_separation(trajectory_boxes(traj, vehicle), obstacles)
    return risk_from_separation(sep, traj.t[0])


collision_risk_jit = jax.jit(collision_risk)


def inflate(obstacles: Obstacles, buffer_lon: float, buffer_lat: float) -> Obstacles:
    """The obstacles with boxes longer by ``2 buffer_lon`` and wider by ``2 buffer_lat`` (m)."""
    b = obstacles.boxes
    grow = jnp.asarray([0.0, 0.0, 2 * buffer_lon, 2 * buffer_lat, 0.0], b.dtype)
    return Obstacles(b + grow, obstacles.valid, obstacles.t, obstacles.static)


def min_separation_topk(
    center, axis, half, obstacles: Obstacles, group_size: int, k: int, buffer=(0.0, 0.0), group_valid=None
):
    """Minimum separation to the plain and to the inflated obstacles with a fixed-size broad phase.

    Candidates come in groups of ``group_size`` (the lattice: the offsets and lateral times of
    one lane and speed profile). Per group and step a circle bounds every car box of the group;
    the ``k`` obstacles whose (inflated) bounding circles come nearest get the exact SAT test
    for every candidate of the group; for the others the circle distance stands in. That
    distance never exceeds the true separation, so the result is conservative: a collision is
    never missed, and a false one needs more than ``k`` obstacles within reach of one group at
    one step.

    Args:
        center, axis: ``(N, T, 2)``; half: ``(2,)`` the car's half sizes.
        obstacles: boxes ``(K, T, 5)``; group_size: ``P`` dividing ``N``; k: obstacles kept.
        buffer: ``(lon, lat)`` inflation (m) of the obstacles along and across their heading.
        group_valid: optional ``(N // P,)`` bool; groups not valid are not checked exactly.

    Returns:
        (sep ``(N, T)`` to the plain boxes, sep_inflated ``(N, T)``).
    """
    N, T = center.shape[:2]
    K = obstacles.boxes.shape[-3]
    if K == 0:
        big = jnp.full((N, T), BIG, center.dtype)
        return big, big
    k = min(k, K)
    P = group_size
    G = N // P
    oc, ou, oh = _obstacle_parts(obstacles)
    buf = jnp.asarray(buffer, oh.dtype)
    ohi = oh + buf
    center, axis = lax.optimization_barrier((center, axis))
    cg, ug = center.reshape(G, P, T, 2), axis.reshape(G, P, T, 2)
    lo, hi = jnp.min(cg, axis=1), jnp.max(cg, axis=1)  # (G, T, 2)
    mid = 0.5 * (lo + hi)
    r_car = jnp.sqrt(jnp.sum(jnp.asarray(half) ** 2, -1))
    r_grp = 0.5 * jnp.linalg.norm(hi - lo, axis=-1) + r_car  # (G, T)
    r_obs = jnp.linalg.norm(ohi, axis=-1)  # (K, T)
    d = (
        jnp.linalg.norm(mid[:, :, None] - jnp.swapaxes(oc, 0, 1)[None], axis=-1) - r_grp[..., None] - r_obs.T[None]
    )  # (G, T, K)
    ok = obstacles.valid.T[None]
    if group_valid is not None:
        ok = ok & group_valid[:, None, None]
    d = jnp.where(ok, d, BIG)
    neg, idx = lax.top_k(-d, min(k + 1, K))  # nearest first
    rest = -neg[..., k] if K > k else jnp.full((G, T), BIG, d.dtype)  # the (k+1)-th nearest: bounds the rest
    idx = idx[..., :k]
    tt = jnp.arange(T)[None, :, None]
    c_sel, u_sel, h_sel, hi_sel = oc[idx, tt], ou[idx, tt], oh[idx, tt], ohi[idx, tt]  # (G, T, k, 2)
    ca, ua = cg[:, :, :, None], ug[:, :, :, None]  # (G, P, T, 1, 2)
    sep = box_separation_axes(ca, ua, half, c_sel[:, None], u_sel[:, None], h_sel[:, None])  # (G, P, T, k)
    sep_i = box_separation_axes(ca, ua, half, c_sel[:, None], u_sel[:, None], hi_sel[:, None])
    rest = rest[:, None]
    out = jnp.minimum(jnp.min(sep, -1), rest).reshape(N, T)
    out_i = jnp.minimum(jnp.min(sep_i, -1), rest).reshape(N, T)
    return out, out_i


def first_contact(sep, t, center, axis, speed, obstacles: Obstacles, half, dt):
    """First contact of each candidate and the impact speed there.

    Args:
        sep: ``(N, T)`` separation to the plain obstacles (negative = overlap).
        t: ``(T,)``; center, axis: ``(N, T, 2)`` the car's box centres and headings;
        speed: ``(N, T)``; obstacles: ``(K, T)`` (aligned); half: ``(2,)``; dt: step (s).

    Returns:
        (first_t ``(N,)`` (inf: no contact), impact ``(N,)``: the relative speed (m/s) of the car
        and the obstacle it touches first, at that step; 0 without contact).
    """
    hit = sep < 0
    any_hit = jnp.any(hit, axis=-1)
    k = jnp.argmax(hit, axis=-1)  # (N,)
    K = obstacles.boxes.shape[-3]
    if K == 0:
        return jnp.full(any_hit.shape, jnp.inf, sep.dtype), jnp.zeros(any_hit.shape, sep.dtype)
    oc, ou, oh = _obstacle_parts(obstacles)
    vel = jnp.diff(obstacles.boxes[..., :2], axis=-2) / dt
    vel = jnp.concatenate([vel, vel[:, -1:]], axis=-2)
    moving = obstacles.valid & jnp.concatenate([obstacles.valid[:, 1:], obstacles.valid[:, -1:]], axis=-1)
    vel = jnp.where((moving & ~obstacles.static[:, None])[..., None], vel, 0.0)  # (K, T, 2)
    take = lambda a: jnp.take_along_axis(a, k[:, None, None], axis=1)[:, 0]  # (N, T, 2) -> (N, 2)
    c, u = take(center), take(axis)
    s_k = jnp.take_along_axis(speed, k[:, None], axis=1)[:, 0]
    sep_k = box_separation_axes(
        c[:, None], u[:, None], half, oc[:, k].swapaxes(0, 1), ou[:, k].swapaxes(0, 1), oh[:, k].swapaxes(0, 1)
    )  # (N, K)
    j = jnp.argmin(sep_k, axis=-1)
    v_obs = vel[j, k]  # (N, 2)
    rel = s_k[:, None] * u - v_obs
    impact = jnp.where(any_hit, jnp.linalg.norm(rel, axis=-1), 0.0)
    return jnp.where(any_hit, t[k], jnp.inf), impact


PAIR_CHUNK = 1 << 18  # (candidate, obstacle, step) triples per chunk of the dense check


def min_separation_pair(center, axis, half, obstacles: Obstacles, buffer=(0.0, 0.0), group_size: int = 1):
    """``min_separation_axes`` to the plain and to the inflated obstacles in one pass, over
    chunks of candidates (whole groups of ``group_size``) of at most ``PAIR_CHUNK`` triples, so
    that memory stays bounded under ``vmap`` over many scenes.

    Args:
        center, axis: ``(N, T, 2)``; half: ``(2,)``; obstacles: ``(K, T)``; buffer: ``(lon, lat)`` (m).

    Returns:
        (sep ``(N, T)``, sep_inflated ``(N, T)``).
    """
    N, T = center.shape[:2]
    K = obstacles.boxes.shape[-3]
    if K == 0:
        big = jnp.full(center.shape[:-1], BIG, center.dtype)
        return big, big
    oc, ou, oh = _obstacle_parts(obstacles)
    center, axis = lax.optimization_barrier((center, axis))
    ohi = oh + jnp.asarray(buffer, oh.dtype)

    def one(ca):
        c, a = ca  # (P, T, 2)
        x = (c[:, None], a[:, None], half)
        sep = box_separation_axes(*x, oc[None], ou[None], oh[None])  # (P, K, T)
        sep_i = box_separation_axes(*x, oc[None], ou[None], ohi[None])
        return jnp.min(sep, axis=-2), jnp.min(sep_i, axis=-2)

    P = group_size
    G = N // P
    per = max(1, PAIR_CHUNK // (P * K * T))
    if per >= G:
        return one((center, axis))
    cg, ag = center.reshape(G, P, T, 2), axis.reshape(G, P, T, 2)
    sep, sep_i = lax.map(one, (cg, ag), batch_size=per)
    return sep.reshape(N, T), sep_i.reshape(N, T)
