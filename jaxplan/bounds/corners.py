"""Contour-corner collision-avoiding distance (the primary / auxiliary corner construction).

Built on ``overlap_polygon_tagged`` (car = A, obstacle = B). For one car contour,
one obstacle contour and the direction ``u`` in which the car is to move:

* **Primary overlap corner Ph**: a vertex of the overlap polygon that is a
  corner of one contour inside the other. Rule when there are several: the
  *deepest along the normal*, i.e. the one that must travel furthest along l3
  to leave the other contour (a car corner moves by ``+u``, an obstacle corner
  moves relative to the car by ``-u``). Ties go to the first in the polygon's
  order.
* **Auxiliary overlap corners Po1, Po2**: Ph's two neighbours on the overlap
  polygon. In the single-corner case (see below) both are edge crossings on one edge of the
  other contour; that edge is the contour edge, on line l2 = Po1 Po2, with
  ends Pl1, Pl2 (the obstacle's corners when Ph is a car corner, the car's
  corners when Ph is an obstacle corner).
* **l3** through Ph along ``w`` (``w = u`` for a car corner, ``-u`` for an
  obstacle corner; l3 is parallel to the trajectory normal l1);
  ``Pi' = l2 x l3``. If Pi' lies ahead on the contour edge: distance
  ``|Pi' - Ph|`` (small curvature). Otherwise (large curvature): the target
  auxiliary corner is the one with the smaller projection on ``w`` (if Po1 is
  the forward one, the target is Po2, and reversely); l4 = Ph -> target;
  the target contour corner is the Pl with the larger projection on ``w``;
  l5 through it parallel to l4; ``Pi = l5 x l3``; distance ``|Pi - Ph|``.
  If Pi' lies *behind* Ph (moving along ``w`` takes Ph away from l2, so l3
  leaves the other contour through another edge) l2 = Po1 Po2 is not the
  way out and the rule below for the other cases is used.

The construction above covers the single-corner case: Ph is the only corner inside
the other contour and its neighbours are on one edge of it (``CASE_ON_EDGE``,
``CASE_OFF_EDGE``). Cases outside it, with the rule used (see ``CASE_*``):

* several corners inside, Ph's neighbours not on one edge of the other
  contour, or Pi' behind Ph: Ph is still the deepest corner; l2 is the other contour's edge
  where l3 leaves it, so Pi' is always on the edge and the distance is Ph's
  exit distance along l3 (the small-curvature formula).
* no corner inside (edges only cross) or a degenerate construction: the
  construction has nothing to offer; the exact distance (``exact_avoid_distance``) is used.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.bounds.distance import exact_avoid_distance
from jaxplan.geometry.lines import dot2, line_intersection
from jaxplan.geometry.polygons import (
    CORNER_OF_A,
    CORNER_OF_B,
    EDGE_CROSSING,
    has_overlap,
    overlap_polygon_tagged,
    polygon_edges,
)
from jaxplan.types import check_polygons, check_trailing, is_concrete

CASE_NONE = 0  # no overlap: distance 0
CASE_ON_EDGE = 1  # single corner, Pi' on the contour edge (small curvature)
CASE_OFF_EDGE = 2  # single corner, Pi' off the edge: l4 / l5 construction (large curvature)
CASE_DEEPEST = 3  # several corners / neighbours on different edges: exit of the deepest corner along l3
CASE_NO_CORNER = 4  # edges cross, no corner inside: exact distance
CASE_DEGENERATE = 5  # parallel lines or a construction behind Ph: exact distance

_BIG = 1e30


class ContourConstruction(NamedTuple):
    """Every point and line of the construction for one car/obstacle pair, ``(...)`` leading dims.

    Attributes:
        distance: ``(...)`` the collision-avoiding distance along ``u`` (0 without overlap).
        case: ``(...)`` int, one of ``CASE_*``.
        primary_is_car: ``(...)`` bool, Ph is a car corner (the car enters the obstacle).
        ph, po1, po2, pl1, pl2, pi_first, pi_second: ``(..., 2)`` points Ph, Po1, Po2,
            Pl1, Pl2, Pi' = l2 x l3 and Pi = l5 x l3 (equal to Pi' in the small-curvature case).
        target_aux: ``(...)`` int 1 or 2, the target auxiliary corner (large curvature).
        target_contour: ``(...)`` int 1 or 2, the target contour corner (large curvature).
        depth: ``(..., N+M)`` exit distance along l3 of each overlap-polygon corner (-inf if not a corner).
    """

    distance: jnp.ndarray
    case: jnp.ndarray
    primary_is_car: jnp.ndarray
    ph: jnp.ndarray
    po1: jnp.ndarray
    po2: jnp.ndarray
    pl1: jnp.ndarray
    pl2: jnp.ndarray
    pi_first: jnp.ndarray
    pi_second: jnp.ndarray
    target_aux: jnp.ndarray
    target_contour: jnp.ndarray
    depth: jnp.ndarray


def _ray_exit(p, w, v, valid):
    """Exit of the ray ``p + t w`` (p inside) from convex ``v (N, 2)``: (t, edge index)."""
    _, n, ok = polygon_edges(v, valid)
    c = dot2(n, w[None, :])
    h = dot2(n, v - p[None, :])
    go = ok & (c > 0)
    t = jnp.where(go, h / jnp.where(go, c, 1.0), jnp.inf)
    j = jnp.argmin(t)
    return jnp.maximum(t[j], 0.0), j


def _next_index(valid):
    """Index of the next valid vertex for every slot of a prefix mask ``(N,)``."""
    idx = jnp.arange(valid.shape[0])
    nxt_ok = jnp.roll(valid, -1) & (idx < valid.shape[0] - 1)
    return jnp.where(nxt_ok, idx + 1, 0)


def _single(car, obs, obs_valid, u, with_exact=True):
    """The construction for one car ``(4, 2)``, obstacle ``(M, 2)`` + mask, direction ``u (2,)``."""
    dtype = car.dtype
    car_valid = jnp.ones(car.shape[0], bool)
    op = overlap_polygon_tagged(car, obs, car_valid, obs_valid)
    overlap = has_overlap(car, obs, car_valid, obs_valid) & (jnp.sum(op.valid) >= 3)
    K = op.vertices.shape[0]
    is_a = op.valid & (op.source == CORNER_OF_A)
    is_b = op.valid & (op.source == CORNER_OF_B)

    # Depth of each corner: its exit distance along l3 from the other contour.
    def exit_a(p):
        return _ray_exit(p, u, obs, obs_valid)

    def exit_b(p):
        return _ray_exit(p, -u, car, car_valid)

    ta, ja = jax.vmap(exit_a)(op.vertices)
    tb, jb = jax.vmap(exit_b)(op.vertices)
    depth = jnp.where(is_a, ta, jnp.where(is_b, tb, -jnp.inf))
    has_corner = jnp.any(is_a | is_b)
    r = jnp.argmax(depth)
    car_primary = is_a[r]
    ph = op.vertices[r]
    w = jnp.where(car_primary, u, -u)
    exit_t = jnp.where(car_primary, ta[r], tb[r])
    n_corners = jnp.sum(is_a | is_b)

    # Neighbours on the overlap polygon (valid vertices form a prefix, CCW).
    count = jnp.maximum(jnp.sum(op.valid), 1)
    prv, nxt = (r - 1) % count, (r + 1) % count
    po1, po2 = op.vertices[prv], op.vertices[nxt]
    other_edge = jnp.where(car_primary, op.index_b, op.index_a)  # edge of the other contour
    single = (
        (op.source[prv] == EDGE_CROSSING)
        & (op.source[nxt] == EDGE_CROSSING)
        & (other_edge[prv] == other_edge[nxt])
        & (n_corners == 1)
    )

    # The other contour's edge ends Pl1, Pl2 (padded to a common size).
    M = obs.shape[0]
    pad = max(M - 4, 0)
    car_p = jnp.concatenate([car, jnp.broadcast_to(car[:1], (pad, 2))], axis=0)
    car_pv = jnp.concatenate([car_valid, jnp.zeros((pad,), bool)])
    obs_p = jnp.concatenate([obs, jnp.broadcast_to(obs[:1], (max(4 - M, 0), 2))], axis=0)
    obs_pv = jnp.concatenate([obs_valid, jnp.zeros((max(4 - M, 0),), bool)])
    other = jnp.where(car_primary, obs_p, car_p)
    other_valid = jnp.where(car_primary, obs_pv, car_pv)
    j_single = jnp.maximum(other_edge[nxt], 0)
    j_exit = jnp.where(car_primary, ja[r], jb[r])
    j = jnp.where(single, j_single, j_exit)
    nx = _next_index(other_valid)
    pl1, pl2 = other[j], other[nx[j]]

    # l2 x l3: Pi'.
    l2_dir = jnp.where(single, po2 - po1, pl2 - pl1)
    l2_pt = jnp.where(single, po1, pl1)
    pi1, t1, s2, ok1 = line_intersection(ph, w, l2_pt, l2_dir)
    # On the contour edge: Pi' between Pl1 and Pl2, and ahead of Ph.
    s_edge = dot2(pi1 - pl1, pl2 - pl1) / jnp.maximum(dot2(pl2 - pl1, pl2 - pl1), 1e-30)
    tol = 1e-6
    on_edge = ok1 & (t1 >= -tol) & (s_edge >= -tol) & (s_edge <= 1 + tol)

    # Large curvature: l4 through Ph and the trailing auxiliary corner, l5 through the
    # forward contour corner parallel to l4, Pi = l5 x l3.
    pr1, pr2 = dot2(po1 - ph, w), dot2(po2 - ph, w)
    target_aux = jnp.where(pr1 > pr2, 2, 1)  # Po1 forward -> target Po2, and reversely
    po_t = jnp.where(target_aux == 1, po1, po2)
    q1, q2 = dot2(pl1 - ph, w), dot2(pl2 - ph, w)
    target_contour = jnp.where(q1 >= q2, 1, 2)
    pl_t = jnp.where(target_contour == 1, pl1, pl2)
    pi2, t2, _, ok2 = line_intersection(ph, w, pl_t, po_t - ph)
    off_ok = ok2 & (t2 >= -tol)

    # Pi' behind Ph (l3 leaves through another edge) is outside the single-corner case: deepest-exit rule.
    ahead = ok1 & (t1 >= -tol)
    case_single = jnp.where(on_edge, CASE_ON_EDGE, jnp.where(off_ok, CASE_OFF_EDGE, CASE_DEGENERATE))
    case = jnp.where(
        ~overlap,
        CASE_NONE,
        jnp.where(~has_corner, CASE_NO_CORNER, jnp.where(single & ahead, case_single, CASE_DEEPEST)),
    )
    dist_single = jnp.where(on_edge, jnp.maximum(t1, 0.0), jnp.maximum(t2, 0.0))
    un = jnp.linalg.norm(u)
    exact = exact_avoid_distance(car, obs, u, car_valid, obs_valid) if with_exact else jnp.nan
    dist = jnp.where(
        case == CASE_NONE,
        0.0,
        jnp.where(
            (case == CASE_ON_EDGE) | (case == CASE_OFF_EDGE),
            dist_single,
            jnp.where(case == CASE_DEEPEST, exit_t, exact),
        ),
    )
    pi_second = jnp.where(case == CASE_OFF_EDGE, pi2, pi1)
    del un, K, dtype
    return ContourConstruction(
        dist,
        case.astype(jnp.int32),
        car_primary,
        ph,
        po1,
        po2,
        pl1,
        pl2,
        pi1,
        pi_second,
        target_aux.astype(jnp.int32),
        target_contour.astype(jnp.int32),
        depth,
    )


def contour_construction(vehicle_corners, obstacle_corners, normal, obstacle_valid=None, with_exact: bool = True):
    """The contour-corner construction with all its points, batched over leading dims.

    Args:
        vehicle_corners: ``(..., 4, 2)`` car contour, counter-clockwise.
        obstacle_corners: ``(..., K, 2)`` convex obstacle contour, counter-clockwise.
        normal: ``(..., 2)`` unit direction in which the car moves (along the trajectory
            normal l1, away from the obstacle).
        obstacle_valid: ``(..., K)`` prefix mask or None.
        with_exact: compute the exact distance for the cases outside the single-corner case (static);
            False leaves NaN there (for callers that have the exact distance already).

    Returns:
        ``ContourConstruction`` with leading dims the broadcast of the inputs'.
    """
    if is_concrete(vehicle_corners, obstacle_corners, normal, obstacle_valid):
        check_trailing("vehicle_corners", vehicle_corners, (4, 2), coords=2)
        check_polygons(vehicle_corners, None, "vehicle_corners")
        check_polygons(obstacle_corners, obstacle_valid, "obstacle_corners")
        check_trailing("normal", normal, (2,))
    car = jnp.asarray(vehicle_corners)
    obs = jnp.asarray(obstacle_corners)
    u = jnp.asarray(normal)
    dtype = jnp.result_type(car, obs, u, float)
    car, obs, u = car.astype(dtype), obs.astype(dtype), u.astype(dtype)
    ov = jnp.ones(obs.shape[:-1], bool) if obstacle_valid is None else jnp.asarray(obstacle_valid, bool)
    lead = jnp.broadcast_shapes(car.shape[:-2], obs.shape[:-2], ov.shape[:-1], u.shape[:-1])
    K = obs.shape[-2]
    car = jnp.broadcast_to(car, lead + (4, 2)).reshape((-1, 4, 2))
    obs = jnp.broadcast_to(obs, lead + (K, 2)).reshape((-1, K, 2))
    ov = jnp.broadcast_to(ov, lead + (K,)).reshape((-1, K))
    u = jnp.broadcast_to(u, lead + (2,)).reshape((-1, 2))
    out = jax.vmap(lambda a, b, c, d: _single(a, b, c, d, with_exact))(car, obs, ov, u)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


def contour_avoid_distance(vehicle_corners, obstacle_corners, normal, obstacle_valid=None):
    """The contour-corner collision-avoiding distance of a car contour from an obstacle contour.

    Args:
        vehicle_corners: ``(..., 4, 2)`` car contour, counter-clockwise.
        obstacle_corners: ``(..., K, 2)`` convex obstacle contour, counter-clockwise.
        normal: ``(..., 2)`` unit direction in which the car is to move (the
            trajectory normal l1 pointing away from the obstacle).
        obstacle_valid: ``(..., K)`` prefix mask or None.

    Returns:
        ``(...)`` distance ``|Pi - Ph|`` in metres; 0 where there is no overlap.
    """
    return contour_construction(vehicle_corners, obstacle_corners, normal, obstacle_valid).distance


contour_construction_jit = jax.jit(contour_construction)
contour_avoid_distance_jit = jax.jit(contour_avoid_distance)
