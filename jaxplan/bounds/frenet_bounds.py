"""Per-point Frenet path bounds from obstacles: contour-corner, exact and centre-line.

A frame is T trajectory points given in the Frenet frame ``(s, l)`` of a
reference line (the decision trajectory ``traj(i)``). At each point the car's
contour follows from the Cartesian position and the heading of consecutive
points. Each obstacle (a convex contour per point, so static or moving) gets a
side and one bound:

* side: **left** when the Frenet ``l`` of the obstacle's centre (mean of its
  vertices) at that point's time exceeds ``traj(i).l``, right otherwise. (Our
  reading of the seed's "transverse distance compared with the obstacle's":
  the obstacle's lateral position against the decision length.)
* ``method="contour"`` (the seed): where the car at ``traj(i)`` overlaps the
  obstacle, the contour-corner distance ``d`` along the trajectory normal l1
  (away from the obstacle) is turned into a Frenet lateral length by mapping
  the moved reference point back to Frenet (``|l(p + d u) - traj(i).l|``, which
  carries the curvature of the reference line; ``normal="frenet"`` instead
  measures ``d`` along the reference line's normal, where no conversion is
  needed). Left: ``upper = traj(i).l - d'``; right: ``lower = traj(i).l + d'``.
  Where they do not overlap the seed defines no distance; the bound is then
  the exact free distance (below), so the methods differ only on overlaps.
* ``method="exact"``: the ground truth. Moving the reference point along the
  reference normal at ``s_i`` (heading kept) is a straight line in the plane,
  so the shifts that overlap form an interval ``(t_lo, t_hi)``
  (``overlap_interval``): left ``upper = l + t_lo``, right ``lower = l + t_hi``.
* ``method="centerline"`` (prior art): the obstacle's centre projected to
  ``(s_o, l_o)`` and widened by half widths and a buffer: left
  ``upper = l_o - W_o/2 - W_car/2 - buffer``, right ``lower = l_o + ...``,
  applied where ``|s_o - s_car_centre| <= (L_o + L_car)/2``. ``L_o``, ``W_o``
  are the obstacle's extents along and across its first edge (length and
  width for a box).

Lane limits clip everything; the combined bound per point is the tightest.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.bounds.corners import contour_construction
from jaxplan.bounds.distance import overlap_interval
from jaxplan.geometry.boxes import box_corners, headings_from_path, vehicle_corners
from jaxplan.geometry.frenet import ReferenceLine, ref_state, to_cartesian, to_frenet
from jaxplan.geometry.lines import normalize, perpendicular
from jaxplan.types import Obstacles, VehicleParams, check_finite, check_polygons, is_concrete

METHODS = ("contour", "exact", "centerline")


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


def _frame(ref, s, l, vehicle, obs, valid, vmask, lane_lower, lane_upper, buffer, method, normal):
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
    cnt = jnp.maximum(jnp.sum(vmask, -1, keepdims=True), 1)
    centre = jnp.sum(jnp.where(vmask[..., None], obs, 0.0), -2) / cnt  # (T, K, 2)
    s_o, l_o = to_frenet(ref, centre)
    left = l_o > l[:, None]
    lc = l[:, None]
    t_lo, t_hi, hit = overlap_interval(car[:, None], obs, n_ref[:, None], None, vmask)
    overlap = hit & (t_lo < 0) & (t_hi > 0)
    ex_upper = jnp.where(hit, lc + t_lo, jnp.inf)
    ex_lower = jnp.where(hit, lc + t_hi, -jnp.inf)
    case = jnp.zeros(left.shape, jnp.int32)
    if method == "exact":
        upper_k, lower_k = ex_upper, ex_lower
        block = hit
    elif method == "contour":
        nvec = n_ref if normal == "frenet" else n_trj
        u = jnp.where(left[..., None], -nvec[:, None], nvec[:, None])  # (T, K, 2)
        con = contour_construction(car[:, None], obs, u, vmask)
        d = con.distance
        case = con.case
        if normal == "frenet":
            adj = d
        else:
            moved = xy[:, None] + d[..., None] * u
            _, l_m = to_frenet(ref, moved)
            adj = jnp.abs(l_m - lc)
        upper_k = jnp.where(overlap, lc - adj, ex_upper)
        lower_k = jnp.where(overlap, lc + adj, ex_lower)
        block = hit
    else:
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
    return PathBounds(lower, upper, lb > lane_lower, ub < lane_upper, lower <= upper, lower_k, upper_k,
                      left, overlap & valid, block, jnp.where(valid, case, 0), xy, heading)


def path_bounds(ref: ReferenceLine, s, l, vehicle: VehicleParams, obstacle_corners, obstacle_valid=None,
                vertex_valid=None, lane_lower=-jnp.inf, lane_upper=jnp.inf, *, method: str = "contour",
                normal: str = "trajectory", buffer: float = 0.0) -> PathBounds:
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
        normal: ``"trajectory"`` (the seed's l1) or ``"frenet"`` (contour method only).
        buffer: lateral buffer of the centre-line method (m).

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
    dtype = jnp.result_type(s, l, obs, float)
    s, l, obs = s.astype(dtype), l.astype(dtype), obs.astype(dtype)
    K, T, M = obs.shape[-4], obs.shape[-3], obs.shape[-2]
    lead = jnp.broadcast_shapes(s.shape[:-1], obs.shape[:-4])
    valid = jnp.ones(obs.shape[:-2], bool) if obstacle_valid is None else jnp.asarray(obstacle_valid, bool)
    vmask = jnp.ones(obs.shape[:-1], bool) if vertex_valid is None else jnp.asarray(vertex_valid, bool)
    lane_lower = jnp.broadcast_to(jnp.asarray(lane_lower, dtype), lead + (T,)).reshape((-1, T))
    lane_upper = jnp.broadcast_to(jnp.asarray(lane_upper, dtype), lead + (T,)).reshape((-1, T))
    flat = lambda x, tail: jnp.broadcast_to(x, lead + tail).reshape((-1,) + tail)
    args = (flat(s, (T,)), flat(l, (T,)), flat(obs, (K, T, M, 2)), flat(valid, (K, T)), flat(vmask, (K, T, M)),
            lane_lower, lane_upper)
    buf = jnp.asarray(buffer, dtype)

    def one(s1, l1, o1, v1, m1, lo1, up1):
        return _frame(ref, s1, l1, vehicle, o1, v1, m1, lo1, up1, buf, method, normal)

    out = jax.vmap(one)(*args)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


path_bounds_jit = jax.jit(path_bounds, static_argnames=("method", "normal"))
