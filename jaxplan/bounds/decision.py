"""Path decision: a side per obstacle against the free corridor, cut at a blockage.

The path's reference point sits at stations ``s_i`` of a reference line (the route). At
each station, with the car's heading there, every obstacle occupies an interval of the
lateral offset ``l``: the offsets at which the car would overlap it (``obstacle_intervals``,
exact, from ``overlap_interval``: moving the reference point along the reference normal
at ``s_i`` with the heading kept is a straight line), widened by a lateral buffer. The
road gives ``[road_lo, road_hi]``.

``decide_corridor`` walks along ``s`` (``lax.scan``) as Apollo's path bounds decider does:

* obstacles already decided keep their side (``LEFT``: the obstacle is on the car's left,
  it bounds ``l`` from above; ``RIGHT``: from below), and narrow the corridor;
* the undecided obstacles present at ``s_i`` split what is left into gaps; a gap is
  *reachable* when it meets the offsets the path can reach from the previous station's
  reachable set (``+- dl_max * ds``; at the first station, the car's own offset);
* among the reachable gaps the one with room wins (the gap's width, capped at
  ``room_cap``: any gap with that much room is as good as a wider one; then the gap nearest
  the preferred offset, the lane centre; a small bonus for passing on the left); every
  undecided obstacle present is decided by the side of that gap it lies on, for the rest
  of the path;
* no reachable gap: **blockage**. The path ends at the last station before it; from there
  on the bounds repeat the last reachable set and the stations are not valid.

Everything is per scene with static shapes (``K`` obstacles, ``N`` stations); batch with
``jax.vmap``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.bounds.distance import box_overlap_interval
from jaxplan.geometry.boxes import car_reach  # noqa: F401 (the path planner's import)

LEFT, RIGHT, NONE = 1, -1, 0  # side of an obstacle seen from the car (as jaxplan.speed.nonblocking)
_INF = jnp.inf


class Corridor(NamedTuple):
    """The decided corridor of one scene (``N`` stations, ``K`` obstacles).

    Attributes:
        lower, upper: ``(N,)`` bounds on ``l`` (the chosen gap; past a blockage the last
            reachable set).
        reach_lo, reach_hi: ``(N,)`` the offsets reachable inside the chosen gaps.
        side: ``(K,)`` int ``LEFT`` / ``RIGHT`` / ``NONE`` (never in the corridor's way).
        valid: ``(N,)`` bool, False from the blockage on.
        blocked_index: ``()`` int, first blocked station (``N`` when none).
    """

    lower: jnp.ndarray
    upper: jnp.ndarray
    reach_lo: jnp.ndarray
    reach_hi: jnp.ndarray
    side: jnp.ndarray
    valid: jnp.ndarray
    blocked_index: jnp.ndarray


def obstacle_intervals(base_xy, ref_theta, car_theta, vehicle, boxes, valid, lat_buffer=0.0, lon_buffer=0.0):
    """Offsets at which the car overlaps each obstacle, per station.

    Args:
        base_xy: ``(N, 2)`` the reference line's points at the stations (``l = 0``).
        ref_theta: ``(N,)`` the reference line's heading there (its normal is the ``l`` axis).
        car_theta: ``(N,)`` the car's heading at each station.
        vehicle: ``VehicleParams``.
        boxes: ``(K, 5)`` obstacle boxes (one footprint each over the horizon), or
            ``(N, K, 5)`` one per station (moving obstacles at the station's time).
        valid: ``(K,)`` or ``(N, K)`` bool.
        lat_buffer: ``()`` or ``(N,)`` widening of each interval on both sides (m).
        lon_buffer: obstacles are lengthened by this on each end (m).

    Returns:
        (lo ``(N, K)``, hi ``(N, K)``, hit ``(N, K)``): the car with its reference point at
        ``l`` in ``(lo, hi)`` overlaps the obstacle (buffer included); ``hit`` False where no
        offset does (then lo = +inf, hi = -inf).
    """
    dtype = base_xy.dtype
    N = base_xy.shape[0]
    boxes = jnp.broadcast_to(boxes, (N,) + boxes.shape[-2:])
    valid = jnp.broadcast_to(valid, (N, boxes.shape[1]))
    unit = lambda h: jnp.stack([jnp.cos(h), jnp.sin(h)], -1)
    off = jnp.asarray(vehicle.center_offset, dtype)
    ctr = base_xy + off * unit(car_theta)
    half_car = 0.5 * jnp.stack([jnp.asarray(vehicle.length, dtype), jnp.asarray(vehicle.width, dtype)])
    half_obs = 0.5 * boxes[..., 2:4] + jnp.stack([lon_buffer, 0.0]).astype(dtype)
    nrm = jnp.stack([-jnp.sin(ref_theta), jnp.cos(ref_theta)], -1)
    t_lo, t_hi, hit = box_overlap_interval(
        ctr[:, None], unit(car_theta)[:, None], half_car, boxes[..., :2], unit(boxes[..., 4]), half_obs, nrm[:, None]
    )
    buf = jnp.broadcast_to(jnp.asarray(lat_buffer, dtype), car_theta.shape)[:, None]
    hit = hit & valid
    return jnp.where(hit, t_lo - buf, _INF), jnp.where(hit, t_hi + buf, -_INF), hit


def decide_corridor(
    lo, hi, hit, road_lo, road_hi, l0, reach, l_pref, side0=None, *, room_cap=1.0, min_gap=0.0, start_tol=1e-3
) -> Corridor:
    """Side decisions and the corridor along the stations (see the module docstring).

    Args:
        lo, hi, hit: ``(N, K)`` obstacle intervals (``obstacle_intervals``).
        road_lo, road_hi: ``(N,)`` the road's bounds on the reference point's ``l``.
        l0: ``()`` the car's offset at station 0.
        reach: ``(N,)`` how far ``l`` can move from station ``i - 1`` to ``i`` (``reach[0]`` unused).
        l_pref: ``(N,)`` preferred offset (the lane centre).
        side0: ``(K,)`` decisions kept from an earlier pass (default none).
        room_cap: gap width (m) beyond which more room does not count.
        min_gap: narrowest gap the reference point may use (m).
        start_tol: the car's own offset may lie this far inside an interval at station 0.

    Returns:
        ``Corridor``.
    """
    N, K = lo.shape
    dtype = lo.dtype
    side0 = jnp.zeros((K,), jnp.int32) if side0 is None else jnp.asarray(side0, jnp.int32)

    def step(carry, x):
        r_lo, r_hi, side, blocked, bidx, i = carry
        a, b, h, rl, rh, rch, pref = x
        present = h & (b > rl) & (a < rh)
        dec_l = present & (side == LEFT)
        dec_r = present & (side == RIGHT)
        und = present & (side == NONE)
        base_lo = jnp.maximum(rl, jnp.max(jnp.where(dec_r, b, -_INF), initial=-_INF))
        base_hi = jnp.minimum(rh, jnp.min(jnp.where(dec_l, a, _INF), initial=_INF))
        first = i == 0
        q_lo = jnp.where(first, l0 - start_tol, r_lo - rch)
        q_hi = jnp.where(first, l0 + start_tol, r_hi + rch)
        # Candidate gaps: from the corridor's lower edge or from an undecided interval's top.
        e = jnp.concatenate([base_lo[None], jnp.where(und, b, _INF)])  # (K+1,)
        inside = und[None, :] & (a[None, :] < e[:, None]) & (e[:, None] < b[None, :])
        above = und[None, :] & (a[None, :] >= e[:, None])
        top = jnp.minimum(base_hi, jnp.min(jnp.where(above, a[None, :], _INF), -1, initial=_INF))
        width = top - e
        ok = ~jnp.any(inside, -1) & (e >= base_lo) & jnp.isfinite(e) & (width >= min_gap)
        c_lo = jnp.maximum(e, q_lo)
        c_hi = jnp.minimum(top, q_hi)
        conn = ok & (c_hi >= c_lo)
        dist = jnp.abs(jnp.clip(pref, c_lo, c_hi) - pref)
        is_left = e >= pref  # the gap lies left of the preferred offset: the car passes on the left
        score = jnp.minimum(width, room_cap) - 0.05 * dist + 0.01 * is_left
        score = jnp.where(conn, score, -_INF)
        j = jnp.argmax(score)
        found = conn[j] & ~blocked
        g_lo, g_hi = e[j], top[j]
        new_side = jnp.where(und & found, jnp.where(a >= g_hi, LEFT, RIGHT), side)
        now_blocked = blocked | ~found
        out_lo = jnp.where(now_blocked, r_lo, g_lo)
        out_hi = jnp.where(now_blocked, r_hi, g_hi)
        n_lo = jnp.where(now_blocked, r_lo, c_lo[j])
        n_hi = jnp.where(now_blocked, r_hi, c_hi[j])
        bidx = jnp.where(now_blocked & ~blocked, i, bidx)
        return (n_lo, n_hi, new_side, now_blocked, bidx, i + 1), (out_lo, out_hi, n_lo, n_hi, ~now_blocked)

    l0 = jnp.asarray(l0, dtype)
    init = (l0, l0, side0, jnp.asarray(False), jnp.asarray(N, jnp.int32), jnp.asarray(0, jnp.int32))
    (_, _, side, _, bidx, _), (lower, upper, r_lo, r_hi, valid) = jax.lax.scan(
        step, init, (lo, hi, hit, road_lo, road_hi, reach, l_pref)
    )
    return Corridor(lower, upper, r_lo, r_hi, side, valid, bidx)
