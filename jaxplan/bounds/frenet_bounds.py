"""Per-point Frenet path bounds from obstacles: contour-corner, exact, centre-line and SL-box.

A frame is T trajectory points given in the Frenet frame ``(s, l)`` of a
reference line (the decision trajectory ``traj(i)``). At each point the car's
contour follows from the Cartesian position and the heading of consecutive
points. Each obstacle (a convex contour per point, so static or moving) gets a
side and one bound:

* side: **left** when the obstacle's centre (mean of its vertices) lies left of
  ``traj(i)`` along the reference normal at the point (its offset from the point
  along that normal; the obstacles that give a bound there are near the point).
  This is the per-frame side rule; the planner's side decision against the
  free corridor is ``jaxplan.bounds.decision``.
* ``method="contour"`` (``jaxplan.bounds.corners``): where the car at ``traj(i)`` overlaps the
  obstacle in the single-corner case (one corner inside, its neighbours on one edge:
  ``CASE_ON_EDGE`` / ``CASE_OFF_EDGE``), the contour-corner distance ``d``; with
  ``normal="frenet"`` (default) it is measured along the reference normal, the
  direction of the Frenet bound, so it is the bound's distance itself; with
  ``normal="trajectory"`` along the trajectory normal l1 and mapped back to Frenet
  (``|l(p + d u) - traj(i).l|``, which under-estimates where l1 and the reference
  normal differ). Left: ``upper = traj(i).l - d'``; right: ``lower = traj(i).l + d'``.
  Overlaps outside the single-corner case (``CASE_EXACT``), beyond the broad phase's budget
  (``CASE_UNCONSTRUCTED``) and non-overlapping pairs get the exact bound: the
  construction defines nothing there. Broad phase: the construction runs only for the
  ``n_construct`` deepest overlapping pairs of a frame; the exact interval of every
  pair costs about 60 flops (``box_overlap_interval``, for rectangles).
* ``method="exact"``: the ground truth. Moving the reference point along the
  reference normal at ``s_i`` (heading kept) is a straight line in the plane,
  so the shifts that overlap form an interval ``(t_lo, t_hi)``
  (``overlap_interval``): left ``upper = l + t_lo``, right ``lower = l + t_hi``.
* ``method="centerline"`` (prior art): the obstacle's centre projected to
  ``(s_o, l_o)`` and widened by half widths and a buffer: left
  ``upper = l_o - W_o/2 - W_car/2 - buffer``, right ``lower = l_o + ...``,
  applied where ``|s_o - s_car_centre| <= (L_o + L_car)/2``. ``L_o``, ``W_o``
  are the obstacle's extents along and across its first edge (length and
  width for a box); it ignores the obstacle's yaw.
* ``method="slbox"`` (Apollo's path bounds): the obstacle's SL box (the ``s`` and
  ``l`` ranges of its corners projected on the reference line) where it meets the
  ``s`` range of the car's corners; left ``upper = l_min - reach_left - buffer``,
  right ``lower = l_max + reach_right + buffer`` with the car's lateral reach from
  its reference point at its heading.

Lane limits clip everything; the combined bound per point is the tightest.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.bounds.corners import CASE_NONE, CASE_OFF_EDGE, CASE_ON_EDGE, contour_construction
from jaxplan.bounds.distance import box_overlap_interval, overlap_interval
from jaxplan.geometry.boxes import box_corners, headings_from_path, vehicle_corners
from jaxplan.geometry.frenet import ReferenceLine, ref_state, to_cartesian, to_frenet
from jaxplan.geometry.lines import normalize, perpendicular
from jaxplan.types import Obstacles, VehicleParams, check_finite, check_polygons, is_concrete

METHODS = ("contour", "exact", "centerline", "slbox")
CASE_EXACT = 6  # an overlap outside the single-corner case: the exact distance
CASE_UNCONSTRUCTED = 7  # an overlap beyond the broad phase's budget: the exact distance


class PathBounds(NamedTuple):
    """Bounds of one or more frames; ``...`` = frame batch dims, T points, K obstacles.

    Attributes:
        lower, upper: ``(..., T)`` combined bounds on ``l`` (lane limits included).
        lower_active, upper_active: ``(..., T)`` bool, an obstacle sets the bound.
        feasible: ``(..., T)`` bool, ``lower <= upper``.
        obstacle_lower, obstacle_upper: ``(..., T, K)`` each obstacle's bound
            (``-inf`` / ``+inf`` where it gives none).
        left: ``(..., T, K)`` bool, the obstacle is on the left.
        overlap: ``(..., T, K)`` bool, the car at ``traj(i)`` overlaps it.
        blocking: ``(..., T, K)`` bool, the obstacle gives a bound at that point.
        case: ``(..., T, K)`` int, contour construction case (``CASE_*``; 0 for other methods).
        xy: ``(..., T, 2)`` Cartesian points; heading: ``(..., T)``.
    """

    lower: jnp.ndarray
    upper: jnp.ndarray
    lower_active: jnp.ndarray
    upper_active: jnp.ndarray
    feasible: jnp.ndarray
    obstacle_lower: jnp.ndarray
    obstacle_upper: jnp.ndarray
    left: jnp.ndarray
    overlap: jnp.ndarray
    blocking: jnp.ndarray
    case: jnp.ndarray
    xy: jnp.ndarray
    heading: jnp.ndarray


def obstacle_contours(obstacles: Obstacles):
    """Box obstacles as contours: ``(..., K, T, 4, 2)`` corners and ``(..., K, T)`` valid."""
    if is_concrete(obstacles):
        obstacles.validate()
    valid = jnp.asarray(obstacles.valid, bool)
    boxes = jnp.where(valid[..., None], obstacles.boxes, jnp.array([0.0, 0.0, 1.0, 1.0, 0.0]))
    return box_corners(boxes), valid


def _extents(v, m):
    """Length and width of convex contours ``(..., M, 2)``: extents along / across edge 0."""
    e = normalize(v[..., 1, :] - v[..., 0, :])
    p = perpendicular(e)
    a = jnp.sum(v * e[..., None, :], -1)
    b = jnp.sum(v * p[..., None, :], -1)
    rng = lambda x: jnp.max(jnp.where(m, x, -jnp.inf), -1) - jnp.min(jnp.where(m, x, jnp.inf), -1)
    return rng(a), rng(b)


def _box_params(corners):
    """Centre, unit axis and half sizes ``(..., 2)`` of rectangles given by 4 corners (CCW)."""
    c = jnp.mean(corners, axis=-2)
    e0 = corners[..., 0, :] - corners[..., 1, :]  # front-left minus rear-left: along the length
    e1 = corners[..., 1, :] - corners[..., 2, :]  # rear-left minus rear-right: across
    ln0, ln1 = jnp.linalg.norm(e0, axis=-1), jnp.linalg.norm(e1, axis=-1)
    return c, e0 / jnp.maximum(ln0, 1e-12)[..., None], 0.5 * jnp.stack([ln0, ln1], -1)


def _frame(
    ref, s, l, vehicle, obs, valid, vmask, lane_lower, lane_upper, buffer, method, normal, n_construct, rectangles
):
    """One frame: s, l ``(T,)``; obs ``(K, T, M, 2)``; valid ``(K, T)``; vmask ``(K, T, M)``."""
    dtype = s.dtype
    xy = to_cartesian(ref, s, l)
    heading = headings_from_path(xy)
    car = vehicle_corners(xy, vehicle, heading)  # (T, 4, 2)
    _, th_r, _, _ = ref_state(ref, s)
    n_ref = jnp.stack([-jnp.sin(th_r), jnp.cos(th_r)], -1)  # (T, 2)
    n_trj = jnp.stack([-jnp.sin(heading), jnp.cos(heading)], -1)
    obs = jnp.swapaxes(obs, 0, 1)  # (T, K, M, 2)
    valid = jnp.swapaxes(valid, 0, 1)  # (T, K)
    vmask = jnp.swapaxes(vmask, 0, 1)  # (T, K, M)
    K = obs.shape[1]
    cnt = jnp.maximum(jnp.sum(vmask, -1, keepdims=True), 1)
    centre = jnp.sum(jnp.where(vmask[..., None], obs, 0.0), -2) / cnt  # (T, K, 2)
    lc = l[:, None]
    # Side: the obstacle centre's offset along the reference normal at the point (local, so
    # no projection of every obstacle onto the whole line; only nearby pairs give a bound).
    l_o = lc + jnp.sum((centre - xy[:, None]) * n_ref[:, None], -1)
    left = l_o > lc
    if rectangles:
        ca, ua, ha = _box_params(car)
        cb, ub, hb = _box_params(obs)
        t_lo, t_hi, hit = box_overlap_interval(ca[:, None], ua[:, None], ha[:, None], cb, ub, hb, n_ref[:, None])
    else:
        t_lo, t_hi, hit = overlap_interval(car[:, None], obs, n_ref[:, None], None, vmask)
    overlap = hit & (t_lo < 0) & (t_hi > 0)
    ex_upper = jnp.where(hit, lc + t_lo, jnp.inf)
    ex_lower = jnp.where(hit, lc + t_hi, -jnp.inf)
    case = jnp.zeros(left.shape, jnp.int32)
    if method == "exact":
        upper_k, lower_k = ex_upper, ex_lower
        block = hit
    elif method == "contour":
        # Broad phase: the construction runs only for the (at most n_construct) deepest
        # overlapping pairs (point, obstacle) of the frame; every other pair has the exact
        # bound (the same number where the car does not overlap; CASE_UNCONSTRUCTED where it does).
        T_ = obs.shape[0]
        J = min(n_construct, T_ * K)
        ovv = (overlap & valid).reshape(-1)
        depth = jnp.where(ovv, jnp.minimum(-t_lo, t_hi).reshape(-1), -jnp.inf)
        _, idx = jax.lax.top_k(depth, J)  # (J,) flat pair indices
        ti, ki = idx // K, idx % K
        sel_ov = ovv[idx]
        sel_left = left[ti, ki]
        nvec = n_ref if normal == "frenet" else n_trj
        u = jnp.where(sel_left[:, None], -nvec[ti], nvec[ti])  # (J, 2)
        con = contour_construction(car[ti], obs[ti, ki], u, vmask[ti, ki], with_exact=False)
        single = sel_ov & ((con.case == CASE_ON_EDGE) | (con.case == CASE_OFF_EDGE))
        lc_sel = l[ti]
        if normal == "frenet":
            adj = con.distance
        else:
            moved = xy[ti] + con.distance[:, None] * u
            _, l_m = to_frenet(ref, moved)
            adj = jnp.abs(l_m - lc_sel)
        upper_k = ex_upper.at[ti, ki].set(jnp.where(single, lc_sel - adj, ex_upper[ti, ki]))
        lower_k = ex_lower.at[ti, ki].set(jnp.where(single, lc_sel + adj, ex_lower[ti, ki]))
        case = jnp.where(overlap, CASE_UNCONSTRUCTED, CASE_NONE).astype(jnp.int32)
        case = case.at[ti, ki].set(jnp.where(sel_ov, jnp.where(single, con.case, CASE_EXACT), case[ti, ki]))
        block = hit
    elif method == "slbox":
        # Apollo-style: the obstacle's SL bounding box (its corners projected on the line)
        # against the car's SL box at the point; lateral bound = the box's l edge less the
        # car's lateral reach.
        s_c, l_c = to_frenet(ref, obs)  # (T, K, M)
        big = jnp.asarray(jnp.inf, dtype)
        s_min = jnp.min(jnp.where(vmask, s_c, big), -1)
        s_max = jnp.max(jnp.where(vmask, s_c, -big), -1)
        l_min = jnp.min(jnp.where(vmask, l_c, big), -1)
        l_max = jnp.max(jnp.where(vmask, l_c, -big), -1)
        cs, cl = to_frenet(ref, car)  # (T, 4)
        reach_l = jnp.max(cl, -1) - l
        reach_r = l - jnp.min(cl, -1)
        block = (jnp.max(cs, -1)[:, None] > s_min) & (jnp.min(cs, -1)[:, None] < s_max)
        upper_k = jnp.where(block, l_min - reach_l[:, None] - buffer, jnp.inf)
        lower_k = jnp.where(block, l_max + reach_r[:, None] + buffer, -jnp.inf)
    else:
        s_o, l_o = to_frenet(ref, centre)
        L_o, W_o = _extents(obs, vmask)
        ctr = xy + jnp.asarray(vehicle.center_offset, dtype) * jnp.stack([jnp.cos(heading), jnp.sin(heading)], -1)
        s_c, _ = to_frenet(ref, ctr)
        half = 0.5 * W_o + 0.5 * jnp.asarray(vehicle.width, dtype) + buffer
        block = jnp.abs(s_o - s_c[:, None]) <= 0.5 * (L_o + jnp.asarray(vehicle.length, dtype))
        upper_k = jnp.where(block, l_o - half, jnp.inf)
        lower_k = jnp.where(block, l_o + half, -jnp.inf)
    block = block & valid
    upper_k = jnp.where(block & left, upper_k, jnp.inf)
    lower_k = jnp.where(block & ~left, lower_k, -jnp.inf)
    ub = jnp.min(upper_k, axis=-1)
    lb = jnp.max(lower_k, axis=-1)
    upper = jnp.minimum(ub, lane_upper)
    lower = jnp.maximum(lb, lane_lower)
    return PathBounds(
        lower,
        upper,
        lb > lane_lower,
        ub < lane_upper,
        lower <= upper,
        lower_k,
        upper_k,
        left,
        overlap & valid,
        block,
        jnp.where(valid, case, 0),
        xy,
        heading,
    )


def path_bounds(
    ref: ReferenceLine,
    s,
    l,
    vehicle: VehicleParams,
    obstacle_corners,
    obstacle_valid=None,
    vertex_valid=None,
    lane_lower=-jnp.inf,
    lane_upper=jnp.inf,
    *,
    method: str = "contour",
    normal: str = "frenet",
    buffer: float = 0.0,
    n_construct: int = 16,
    rectangles: bool = False,
) -> PathBounds:
    """Per-point lower / upper bounds on the Frenet offset ``l``, with masks.

    Args:
        ref: reference line (shared by all frames).
        s, l: ``(..., T)`` the decision trajectory in Frenet coordinates.
        vehicle: car size; trajectory points are its reference point.
        obstacle_corners: ``(..., K, T, M, 2)`` convex contours, counter-clockwise,
            one per obstacle and point time (repeat for static obstacles); see
            ``obstacle_contours`` for ``Obstacles``.
        obstacle_valid: ``(..., K, T)`` bool or None (padding / unknown = False).
        vertex_valid: ``(..., K, T, M)`` prefix masks of the contours, or None.
        lane_lower, lane_upper: scalars or ``(..., T)`` lane limits on ``l``.
        method: ``"contour"``, ``"exact"`` or ``"centerline"`` (static).
        normal: ``"frenet"`` (default: the reference line's normal, the direction of the
            Frenet bound, along which the contour-corner distance is the bound itself) or
            ``"trajectory"`` (the trajectory normal l1; the distance along it is mapped back to Frenet,
            which under-estimates where l1 and the reference normal differ). Contour only.
        buffer: lateral buffer of the centre-line and SL-box baselines (m).
        n_construct: contour method: the construction runs for at most this many
            overlapping (point, obstacle) pairs per frame (the deepest; a broad phase), the
            others get the exact bound (``CASE_UNCONSTRUCTED``).
        rectangles: the contours are rectangles of 4 corners (``box_corners``; checked on
            concrete input): the exact interval then has a closed form (``box_overlap_interval``).

    Returns:
        ``PathBounds``.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if normal not in ("trajectory", "frenet"):
        raise ValueError(f"normal must be 'trajectory' or 'frenet', got {normal!r}")
    s, l = jnp.asarray(s), jnp.asarray(l)
    obs = jnp.asarray(obstacle_corners)
    if is_concrete(s, l, obs, obstacle_valid, vertex_valid):
        check_finite("s", s)
        check_finite("l", l)
        if s.shape != l.shape or s.ndim < 1:
            raise ValueError(f"s and l must share a shape (..., T), got {s.shape} and {l.shape}")
        if obs.ndim < 4 or obs.shape[-1] != 2 or obs.shape[-3] != s.shape[-1]:
            raise ValueError(f"obstacle_corners: expected (..., K, T={s.shape[-1]}, M, 2), got {obs.shape}")
        if obs.shape[-4] and obs.size:
            vm = None if vertex_valid is None else vertex_valid
            check_polygons(obs, vm, "obstacle_corners")
        if rectangles:
            o = np.asarray(obs, np.float64)
            if o.shape[-2] != 4 or (vertex_valid is not None and not np.all(vertex_valid)):
                raise ValueError("obstacle_corners: rectangles=True needs 4 valid corners per contour")
            e0, e1 = o[..., 0, :] - o[..., 1, :], o[..., 1, :] - o[..., 2, :]
            cos = np.abs(np.sum(e0 * e1, -1)) / np.maximum(
                np.linalg.norm(e0, axis=-1) * np.linalg.norm(e1, axis=-1), 1e-12
            )
            if o.size and (
                np.max(cos) > 1e-3
                or np.max(np.abs(o[..., 0, :] - o[..., 1, :] + o[..., 2, :] - o[..., 3, :]))
                > 1e-3 * max(1.0, np.abs(o).max())
            ):
                raise ValueError("obstacle_corners: rectangles=True but a contour is not a rectangle")
    dtype = jnp.result_type(s, l, obs, float)
    s, l, obs = s.astype(dtype), l.astype(dtype), obs.astype(dtype)
    K, T, M = obs.shape[-4], obs.shape[-3], obs.shape[-2]
    lead = jnp.broadcast_shapes(s.shape[:-1], obs.shape[:-4])
    valid = jnp.ones(obs.shape[:-2], bool) if obstacle_valid is None else jnp.asarray(obstacle_valid, bool)
    vmask = jnp.ones(obs.shape[:-1], bool) if vertex_valid is None else jnp.asarray(vertex_valid, bool)
    lane_lower = jnp.broadcast_to(jnp.asarray(lane_lower, dtype), lead + (T,)).reshape((-1, T))
    lane_upper = jnp.broadcast_to(jnp.asarray(lane_upper, dtype), lead + (T,)).reshape((-1, T))
    flat = lambda x, tail: jnp.broadcast_to(x, lead + tail).reshape((-1,) + tail)
    args = (
        flat(s, (T,)),
        flat(l, (T,)),
        flat(obs, (K, T, M, 2)),
        flat(valid, (K, T)),
        flat(vmask, (K, T, M)),
        lane_lower,
        lane_upper,
    )
    buf = jnp.asarray(buffer, dtype)

    def one(s1, l1, o1, v1, m1, lo1, up1):
        return _frame(ref, s1, l1, vehicle, o1, v1, m1, lo1, up1, buf, method, normal, n_construct, rectangles)

    out = jax.vmap(one)(*args)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


path_bounds_jit = jax.jit(path_bounds, static_argnames=("method", "normal", "n_construct", "rectangles"))
