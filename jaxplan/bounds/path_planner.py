"""The path half of the path-speed planner: decide, bound, optimise, check (one scene, jittable).

``plan_path(scene, ctx, config) -> PathPlan`` for one planning cycle (``ctx`` is the
``RoadContext`` of ``jaxplan.plan_context.road_context``):

1. **Stations.** ``N = config.n_points`` stations along the route from the car's ``s``,
   spacing ``ds = clip(v * time_horizon / (N - 1), ds_min, ds_max)`` (a slow car plans a
   short, dense path, a fast one a long one).
2. **Blocking obstacles** (the path's business; the speed planner handles the others on
   the ST graph): obstacles flagged ``static``, and dynamic ones present now that move
   less than ``static_speed`` (m/s) over the horizon (a stopped car), with one footprint:
   the box now, lengthened along its heading to cover what it moves over the horizon.
   Moving obstacles, however slow, are *not* blocking: the speed planner follows or
   yields to them, and a blockage (a stop) is never caused by something that drives on.
3. **Road bounds**: the drivable corridor's edges about the route (the lanes beside the
   route that are contiguous with the route lane, opposite-direction lanes only with
   ``opposite_lanes``; never beyond ``road_left/right``), less the car body's reach at its
   heading and ``edge_buffer``. With ``nudge``, narrowed away from *moving* obstacles that reach
   into the car's lane from one side over the horizon (an oncoming car over the centre line, a
   neighbour drifting in; ``nudge_edges``) about when the car meets them: the path keeps
   ``nudge_buffer`` from them inside its own lane where the lane leaves room, and the speed plan
   yields to what is still in the way.
4. **Decision and corridor** (``jaxplan.bounds.decision``): each blocking obstacle's
   interval of offsets per station (exact overlap interval of the car's contour, the
   obstacle lengthened by ``lon_buffer + ds / 2`` so that the car's motion between stations
   is covered, widened by ``lat_buffer``, the buffer ramped in over ``buffer_ramp`` metres
   from the car), a side per obstacle against the free corridor, kept along ``s``, and the
   cut at a blockage.
5. **Path QP** (``jaxplan.bounds.optimize``): piecewise jerk inside the corridor, the
   curvature bound from the steering limit and from the lateral acceleration at the car's
   speed (``speed_curvature_cap``: ``a_lat_max / v(s)^2`` with the speed falling at most at
   ``lat_decel`` along the path, so a fast car changes lane over a long path; never below the
   route's own curvature, which the speed plan slows for), a heading
   bound (``heading_max`` about the route), a jerk bound, from the car's ``(l, l', l'')``.
6. **Recompute at the optimised heading**: the intervals depend on the car's heading at
   each station; they are recomputed at the optimised path's heading (decisions kept) and
   the QP re-solved (warm started), until the path's exact footprint (the car's box at
   each station's pose, SAT) is clear of every blocking obstacle, at most ``max_rounds``.
   From the third round on the intervals hold for every heading the rounds since the
   second produced (their range at each station), so the rounds cannot oscillate
   between two headings: a path whose heading stays in that range clears the obstacles.

``PathPlan`` resamples the result on a uniform arc-length grid along the path itself
(spacing ``ds``). ``ok`` = the QP solved, and the car's box at every valid point is clear
of every blocking obstacle. Past a blockage the points are not valid and ``blocked_s``
says where the car's reference point must stop before (the car at ``blocked_s`` overlaps
the blocking obstacle lengthened by ``lon_buffer``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.bounds.decision import NONE, car_reach, decide_corridor, obstacle_intervals
from jaxplan.bounds.optimize import optimize_path
from jaxplan.bounds.path_qp import PathQPConfig, PathWeights, curvature_bounds
from jaxplan.geometry.boxes import box_has_overlap, poses_to_boxes
from jaxplan.geometry.frenet import frenet_to_cartesian_state, ref_state
from jaxplan.geometry.quintic import cartesian_to_frenet_state
from jaxplan.solvers import ADMMSettings
from jaxplan.types import VehicleParams, pytree_dataclass

RANGE_MARGIN = 0.01  # m: the car's reach at headings between the sampled ones of a heading range


@dataclasses.dataclass(frozen=True)
class PathConfig:
    """Static settings of ``plan_path`` (frozen, hashable: static under ``jax.jit``).

    Attributes:
        vehicle: the car.
        n_points: ``N`` stations (and output points).
        time_horizon: s; the path is ``v * time_horizon`` long, within the ds limits.
        ds_min, ds_max: station spacing limits (m).
        lat_buffer: lateral buffer to blocking obstacles (m; Apollo's is 0.4).
        lon_buffer: blocking obstacles lengthened by this at each end (m), plus ``ds / 2``.
        buffer_ramp: the lateral buffer grows from 0 at the car to full over this (m), so a
            car already closer than the buffer to an obstacle beside it is not boxed in.
        edge_buffer: margin to the road's edges (m).
        static_speed: dynamic obstacles slower than this (m/s) over the horizon are blocking.
        nudge, nudge_buffer, nudge_window: keep ``nudge_buffer`` (m) sideways from moving obstacles
            that reach into the car's lane from one side, within ``nudge_window`` (s) of when the
            car gets there (``nudge_edges``).
        opposite_lanes: the corridor may use opposite-direction lanes (to pass a blockage).
        max_rounds: bounds-at-heading / QP rounds (4: on one frame of the bounds suite, R 8 m, the third
            round's QP is solved but its path turns past that round's heading range; the fourth
            clears it; the loop stops at the first clear path, so easy frames run one or two).
        heading_max: |heading - route heading| bound (rad).
        curvature_margin: the path's curvature stays below this share of the steering limit.
        a_lat_max, lat_decel: the curvature bound from the speed (``speed_curvature_cap``):
            lateral acceleration (m/s^2) at the speed the car keeps when braking at
            ``lat_decel`` (m/s^2) along the path.
        room_cap, min_gap: the decision's room rule (``decide_corridor``).
        weights: ``PathWeights`` values (ref, dl, ddl, dddl) as a tuple (hashable).
        qp: ``PathQPConfig``.
    """

    vehicle: VehicleParams = VehicleParams()
    n_points: int = 81
    time_horizon: float = 8.0
    ds_min: float = 0.5
    ds_max: float = 2.5
    lat_buffer: float = 0.3
    lon_buffer: float = 0.3
    buffer_ramp: float = 6.0
    edge_buffer: float = 0.1
    static_speed: float = 0.5
    nudge: bool = True
    nudge_buffer: float = 0.3
    nudge_window: float = 2.0
    opposite_lanes: bool = True
    max_rounds: int = 4
    heading_max: float = 0.5
    curvature_margin: float = 0.9
    a_lat_max: float = 3.0
    lat_decel: float = 2.0
    room_cap: float = 1.0
    min_gap: float = 0.0
    weights: tuple = (1.0, 10.0, 100.0, 1000.0)
    qp: PathQPConfig = PathQPConfig(jerk_max=0.2, admm=ADMMSettings(max_iter=2000))

    def __post_init__(self):
        if not self.a_lat_max > 0:
            raise ValueError(f"PathConfig.a_lat_max must be > 0, got {self.a_lat_max}")
        for name in ("lat_decel", "nudge_buffer", "nudge_window"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"PathConfig.{name} must be >= 0, got {getattr(self, name)}")


@pytree_dataclass(
    data_fields=(
        "s",
        "xy",
        "theta",
        "kappa",
        "l",
        "route_s",
        "lower",
        "upper",
        "valid",
        "blocked_s",
        "ok",
        "side",
        "blocking",
        "rounds",
        "qp_ok",
        "collision_free",
        "ds",
    )
)
class PathPlan:
    """The path of one scene on a uniform arc-length grid from the car (``N`` points, ``K`` obstacles).

    Attributes:
        s: ``(N,)`` distance along the path from the car's reference point (``i * ds``).
        xy: ``(N, 2)``; theta: ``(N,)`` heading (unwrapped); kappa: ``(N,)`` curvature.
        l: ``(N,)`` offset from the route; route_s: ``(N,)`` arc length on the route.
        lower, upper: ``(N,)`` the corridor the path was optimised in (bounds on ``l``).
        valid: ``(N,)`` False past a blockage (and past the optimised length).
        blocked_s: ``()`` distance along the path to the blockage (``inf`` if none).
        ok: ``()`` QP solved and the path clear of every blocking obstacle.
        side: ``(K,)`` int ``LEFT`` (1: obstacle on the car's left, bounds ``l`` above) /
            ``RIGHT`` (-1) / ``NONE`` (0: not blocking or never in the way).
        blocking: ``(K,)`` bool, the obstacle is blocking for the path (see the module doc).
        rounds: ``()`` rounds run; qp_ok, collision_free: ``()`` the two parts of ``ok``.
        ds: ``()`` the grid spacing (m).
    """

    s: Any
    xy: Any
    theta: Any
    kappa: Any
    l: Any
    route_s: Any
    lower: Any
    upper: Any
    valid: Any
    blocked_s: Any
    ok: Any
    side: Any
    blocking: Any
    rounds: Any
    qp_ok: Any
    collision_free: Any
    ds: Any


def _sample(scene, values, s):
    return jnp.interp(s, scene.route.s, values)


def corridor_edges(scene, opposite_lanes: bool):
    """Left / right edges ``(R,)`` of the lanes contiguous with the route's own lane, per route point."""
    c = scene.own_lane
    off, wid = scene.lane_offset, scene.lane_width
    ok = scene.lane_valid & (scene.lane_same_dir | opposite_lanes)
    ok = ok.at[c].set(True)
    left_ok = jnp.cumprod(ok[c:].astype(jnp.int32), axis=0).astype(bool)  # (L - c, R)
    right_ok = jnp.cumprod(ok[: c + 1][::-1].astype(jnp.int32), axis=0).astype(bool)
    left = jnp.max(jnp.where(left_ok, off[c:] + 0.5 * wid[c:], -jnp.inf), 0)
    right = jnp.min(jnp.where(right_ok, off[: c + 1][::-1] - 0.5 * wid[: c + 1][::-1], jnp.inf), 0)
    return jnp.minimum(left, scene.road_left), jnp.maximum(right, scene.road_right)


def blocking_footprints(obstacles, static_speed, dt):
    """One footprint per obstacle for the path and whether it is blocking.

    Args:
        obstacles: ``Obstacles`` ``(K, H, 5)`` from now (``RoadContext.obstacles``).

    Returns:
        (boxes ``(K, 5)``, blocking ``(K,)`` bool).
    """
    b, v = obstacles.boxes, obstacles.valid
    H = b.shape[1]
    static = jnp.asarray(obstacles.static, bool)
    last = H - 1 - jnp.argmax(v[:, ::-1], axis=1)
    first = jnp.argmax(v, axis=1)
    p0 = jnp.take_along_axis(b, first[:, None, None], 1)[:, 0]
    p1 = jnp.take_along_axis(b, last[:, None, None], 1)[:, 0]
    span = jnp.maximum(last - first, 1).astype(b.dtype) * dt
    disp = p1[:, :2] - p0[:, :2]
    speed = jnp.linalg.norm(disp, axis=-1) / span
    slow = v[:, 0] & (speed < static_speed)
    blocking = jnp.any(v, axis=1) & (static | slow)
    hd = jnp.stack([jnp.cos(p0[:, 4]), jnp.sin(p0[:, 4])], -1)
    along = jnp.where(static, 0.0, jnp.abs(jnp.sum(disp * hd, -1)))
    ctr = jnp.where(static[:, None], p0[:, :2], p0[:, :2] + 0.5 * disp)
    box = jnp.concatenate([ctr, (p0[:, 2] + along)[:, None], p0[:, 3:5]], -1)
    return box, blocking


def nudge_edges(route, ctx, blocking, st, l_pref, lane_half, edge_left, edge_right, vehicle, config: PathConfig):
    """The corridor's edges narrowed away from moving obstacles beside the car's lane.

    An obstacle that is not blocking (it moves), whose footprint, wherever it comes within the
    path's stations, stays on one side of the lane centre (``l_pref`` at the car) and reaches over
    that side's lane line there at some time bounds that side (traffic inside the next lane does
    not: a pass through that lane stays the speed plan's to time): at every station where the
    car's body and the obstacle overlap along the route at a time within ``nudge_window`` of when
    the car gets there at its present speed (at least 1 m/s), the car's body keeps
    ``nudge_buffer`` from the obstacle's near side. The narrowing is
    at most what the car can move over by then at ``a_lat_max`` (and a quarter of the heading
    bound), so the path can always follow it; it never moves an edge past the far side of the
    car's own lane less the car's width (the car shifts inside its lane, it is not pushed out of
    it); where both sides are nudged and the car no longer fits, that station keeps its edges.
    Obstacles over the lane centre (a leader, a crossing car) are left to the speed plan.

    Args:
        route: ``ReferenceLine``; ctx: ``RoadContext`` (``obstacles`` ``(K, H, 5)``,
            ``obstacle_s``, ``obstacle_l`` ``(K, H)``, ``ego``); blocking: ``(K,)`` bool (the path's).
        st, l_pref, lane_half: ``(N,)`` stations, the lane centre's offset and half width there.
        edge_left, edge_right: ``(N,)`` the edges the car's body stays inside.

    Returns:
        (edge_left, edge_right) ``(N,)`` each.
    """
    f = st.dtype
    obs = ctx.obstacles
    b, v = obs.boxes, obs.valid
    s_o, l_o = jnp.asarray(ctx.obstacle_s, f), jnp.asarray(ctx.obstacle_l, f)
    _, th_r, _, _ = ref_state(route, s_o)
    dh = b[..., 4] - th_r
    half_l, half_w = 0.5 * b[..., 2], 0.5 * b[..., 3]
    hl = jnp.abs(half_l * jnp.sin(dh)) + jnp.abs(half_w * jnp.cos(dh))  # (K, H) lateral half extent
    hs = jnp.abs(half_l * jnp.cos(dh)) + jnp.abs(half_w * jnp.sin(dh))  # along the route
    front, rear = jnp.asarray(vehicle.front_offset, f), jnp.asarray(vehicle.rear_offset, f)
    dist = st - st[0]
    v0 = jnp.maximum(jnp.asarray(ctx.ego.v, f), 0.0)
    t_car = dist / jnp.maximum(v0, 1.0)  # (N,) when the car gets to each station
    t_o = jnp.asarray(obs.t, f) - jnp.asarray(obs.t, f)[0]  # (H,)
    when = jnp.abs(t_o[None, :] - t_car[:, None]) <= config.nudge_window  # (N, H)
    # (N, K, H): the car's body at station i and the obstacle at time j overlap along the route
    ds = s_o[None] - st[:, None, None]
    near = v[None] & ~blocking[None, :, None] & when[:, None, :] & (ds >= rear - hs[None]) & (ds <= front + hs[None])
    inner_l, inner_r = l_o - hl, l_o + hl  # the near sides of an obstacle on the left / right
    seen = jnp.any(near, axis=0)  # (K, H)
    # on one side of the lane centre, and reaching over that side's lane line at some time
    c, half = l_pref[0], lane_half[0]
    left = jnp.all(jnp.where(seen, inner_l > c, True), -1) & jnp.any(seen & (inner_l < c + half), -1)  # (K,)
    right = jnp.all(jnp.where(seen, inner_r < c, True), -1) & jnp.any(seen & (inner_r > c - half), -1)
    buf = jnp.asarray(config.nudge_buffer, f)
    big = jnp.asarray(1e9, f)
    bound_l = jnp.min(jnp.where(near & left[None, :, None], inner_l[None] - buf, big), axis=(1, 2))  # (N,)
    bound_r = jnp.max(jnp.where(near & right[None, :, None], inner_r[None] + buf, -big), axis=(1, 2))
    width = jnp.asarray(vehicle.width + 2.0 * config.edge_buffer + 2.0 * RANGE_MARGIN, f)
    floor_l = jnp.maximum(edge_right, l_pref - lane_half) + width  # the car at its lane's right side
    ceil_r = jnp.minimum(edge_left, l_pref + lane_half) - width
    # how far the car can move over within ``dist``: two arcs at the lateral acceleration's curvature
    k_steer = config.curvature_margin * jnp.tan(jnp.asarray(vehicle.max_steer, f)) / jnp.asarray(vehicle.wheelbase, f)
    k_cap = jnp.minimum(k_steer, config.a_lat_max / jnp.maximum(v0 * v0, 1e-6))
    reach = jnp.minimum(0.25 * k_cap * dist * dist, 0.25 * dist * jnp.tan(jnp.asarray(config.heading_max, f)))
    new_l = edge_left - jnp.minimum(jnp.maximum(edge_left - jnp.maximum(bound_l, floor_l), 0.0), reach)
    new_r = edge_right + jnp.minimum(jnp.maximum(jnp.minimum(bound_r, ceil_r) - edge_right, 0.0), reach)
    fits = new_l - new_r >= width - 1e-3  # a nudge to a lane's side leaves exactly the width
    return jnp.where(fits, new_l, edge_left), jnp.where(fits, new_r, edge_right)


def _resample(S, values, s_out):
    return jnp.interp(s_out, S, values)


def plan_path(scene, ctx, config: PathConfig = PathConfig()) -> PathPlan:
    """The path of one scene at one planning cycle (see the module docstring).

    Args:
        scene: ``Scene`` (one, unbatched).
        ctx: its ``RoadContext`` now (``ctx.ego``: the car's heading, speed, curvature).
        config: ``PathConfig`` (static).

    Returns:
        ``PathPlan``.
    """
    return _plan(scene, ctx, config, ctx.ego)


def speed_curvature_cap(v0, dist, a_lat_max, decel):
    """``(N,)`` curvature bound at distances ``dist (N,)`` along the path for a car at speed
    ``v0 ()`` that brakes at most at ``decel`` (m/s^2): ``a_lat_max / v(s)^2`` with ``v(s)^2 =
    max(v0^2 - 2 decel s, 0)`` (unbounded where the car could have stopped)."""
    v2 = jnp.maximum(v0**2 - 2.0 * decel * dist, 0.0)
    return a_lat_max / jnp.maximum(v2, 1e-6)


def solve_path(ref, st, ds, boxes, blocking, edge_left, edge_right, l_pref, init, config: PathConfig, v0=None):
    """Decide, bound and optimise a path on route stations, recomputing at its heading.

    The core of ``plan_path``, for any reference line and obstacle footprints.

    Args:
        ref: ``ReferenceLine``; st: ``(N,)`` stations on it (spacing ``ds ()``), the car at ``st[0]``.
        boxes: ``(K, 5)`` blocking footprints, or ``(N, K, 5)`` per station.
        blocking: ``(K,)`` or ``(N, K)`` bool, which boxes bound the path.
        edge_left, edge_right: ``(N,)`` the corridor's edges the car body must stay inside.
        l_pref: ``(N,)`` preferred offset (lane centre).
        init: ``(3,)`` the car's ``(l, l', l'')`` at ``st[0]``.
        config: ``PathConfig``.
        v0: ``()`` the car's speed (the curvature bound from the lateral acceleration,
            ``speed_curvature_cap``), or None (the steering limit only).

    Returns:
        dict with ``corridor`` (``Corridor``), ``qp`` (``PathQPResult``), ``rounds``,
        ``clear`` (the car's boxes at the path's poses, and between them, miss every blocking
        box), ``xy (N, 2)``, ``theta (N,)``, ``kappa (N,)``, ``l, dl, ddl (N,)``
        (the car's offset kept where the QP failed), ``qp_input``: the last QP's bounds
        ``(lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi)`` each ``(N,)`` (for an oracle).
    """
    veh = config.vehicle
    f = ref.xy.dtype
    N = st.shape[0]
    base, th_r, k_r, _ = ref_state(ref, st)
    l0 = init[0]
    k_max = jnp.tan(jnp.asarray(veh.max_steer, f)) / jnp.asarray(veh.wheelbase, f)
    tan_h = jnp.tan(jnp.asarray(config.heading_max, f))
    dist = st - st[0]
    if v0 is not None:
        cap = speed_curvature_cap(jnp.asarray(v0, f), dist, config.a_lat_max, config.lat_decel)
        # never tighter than the route's own curvature: following the road is always allowed (the
        # speed plan slows for the curvature), only curving more than it is bounded by the speed
        k_max = jnp.minimum(config.curvature_margin * k_max, jnp.maximum(cap, jnp.abs(k_r)))
        ddl_lo, ddl_hi = -k_max - k_r, k_max - k_r
    else:
        ddl_lo, ddl_hi = curvature_bounds(k_r, k_max, config.curvature_margin)
    dth0 = jnp.arctan2(init[1], 1.0 - k_r[0] * l0)
    lat_buf = config.lat_buffer * jnp.clip(dist / config.buffer_ramp, 0.0, 1.0)
    lon_buf = config.lon_buffer + 0.5 * ds
    reach = ds * tan_h * jnp.ones((N,), f)
    w = PathWeights(*config.weights)
    dl_b = (jnp.full((N,), -tan_h, f).at[0].min(init[1]), jnp.full((N,), tan_h, f).at[0].max(init[1]))
    ddl_b = (ddl_lo.at[0].min(init[2]), ddl_hi.at[0].max(init[2]))
    if boxes.ndim == 2:
        box_n = jnp.broadcast_to(boxes, (N,) + boxes.shape)
        blk_n = jnp.broadcast_to(blocking, (N,) + blocking.shape)
    else:
        box_n, blk_n = boxes, blocking

    def bounds_at(d_lo, d_hi, margin, side):
        """The corridor for the car at any heading (relative to the route) in ``[d_lo, d_hi]``
        (``(N,)`` each): the union of the intervals at both ends and the middle, widened by
        ``margin`` (``RANGE_MARGIN``) for the headings between them; with ``d_lo == d_hi`` and
        ``margin == 0``, exactly the corridor at that one heading. The three headings are one
        vmapped call, so the interval kernel is traced once."""
        heads = jnp.stack([d_lo, 0.5 * (d_lo + d_hi), d_hi])  # (3, N)
        lo, hi, hit = jax.vmap(
            lambda h: obstacle_intervals(base, th_r, th_r + h, veh, box_n, blk_n, lat_buf + margin, lon_buf)
        )(heads)
        rl, rr = jax.vmap(lambda h: car_reach(veh, h))(heads)
        road_hi = edge_left - (jnp.max(rl, 0) + margin) - config.edge_buffer
        road_lo = edge_right + (jnp.max(rr, 0) + margin) + config.edge_buffer
        return decide_corridor(
            jnp.min(lo, 0),
            jnp.max(hi, 0),
            jnp.any(hit, 0),
            road_lo,
            road_hi,
            l0,
            reach,
            l_pref,
            side,
            room_cap=config.room_cap,
            min_gap=config.min_gap,
        )

    def qp_bounds(cor):
        """The QP's bounds on ``l`` from the corridor (the car's own offset at station 0)."""
        return (cor.lower.at[0].set(jnp.minimum(cor.lower[0], l0)), cor.upper.at[0].set(jnp.maximum(cor.upper[0], l0)))

    def solve(cor, warm):
        return optimize_path(*qp_bounds(cor), ds, l_pref, init, w, config.qp, dl_b, ddl_b, warm=warm)

    def pose(l, dl, ddl):
        xy, _, kap = frenet_to_cartesian_state(ref, st, l, dl, ddl)
        return xy, th_r + jnp.arctan2(dl, 1.0 - k_r * l), kap

    def clear(xy, th, valid):
        car = poses_to_boxes(xy, th, veh)  # (N, 5)
        hit = box_has_overlap(car[:, None], box_n) & blk_n & valid[:, None]
        mid = poses_to_boxes(0.5 * (xy[1:] + xy[:-1]), 0.5 * (th[1:] + th[:-1]), veh)
        vm = valid[1:] & valid[:-1]
        hit_m = (
            (box_has_overlap(mid[:, None], box_n[1:]) | box_has_overlap(mid[:, None], box_n[:-1]))
            & (blk_n[1:] | blk_n[:-1])
            & vm[:, None]
        )
        return ~jnp.any(hit) & ~jnp.any(hit_m)

    car_dth = jnp.zeros((N,), f).at[0].set(dth0)

    def body(state):
        """Round ``r``: 0 at the car's heading (decisions made afresh, the QP from zero);
        1 at the path's heading; later rounds at every heading seen since round 1, so that the
        bounds hold at the heading of any path that stays inside that range. One body for all
        rounds: the corridor and the QP are traced once."""
        r, cor, qp, _, d_lo, d_hi = state
        _, th, _ = pose(qp.l, qp.dl, qp.ddl)
        dth = jnp.where(qp.ok & (r > 0), th - th_r, car_dth)
        first = r <= 1
        d_lo = jnp.where(first, dth, jnp.minimum(d_lo, dth))
        d_hi = jnp.where(first, dth, jnp.maximum(d_hi, dth))
        margin = jnp.where(first, 0.0, RANGE_MARGIN).astype(f)
        cor2 = bounds_at(d_lo, d_hi, margin, jnp.where(r == 0, NONE, cor.side))
        qp2 = solve(cor2, (qp.z, qp.y))  # round 0: the zeros of the initial state (a cold start)
        xy2, th2, _ = pose(qp2.l, qp2.dl, qp2.ddl)
        return r + 1, cor2, qp2, qp2.ok & clear(xy2, th2, cor2.valid), d_lo, d_hi

    zero = lambda tree: jax.tree_util.tree_map(lambda x: jnp.zeros(x.shape, x.dtype), tree)
    cor0 = zero(jax.eval_shape(lambda: bounds_at(car_dth, car_dth, jnp.zeros((), f), None)))
    qp0 = zero(jax.eval_shape(lambda: solve(cor0, None)))
    rounds, cor, qp, fine, _, _ = jax.lax.while_loop(
        lambda s: (s[0] == 0) | ((s[0] < config.max_rounds) & ~s[3]),
        body,
        (jnp.asarray(0, jnp.int32), cor0, qp0, jnp.asarray(False), car_dth, car_dth),
    )
    l = jnp.where(qp.feasible, qp.l, l0)
    dl = jnp.where(qp.feasible, qp.dl, 0.0)
    ddl = jnp.where(qp.feasible, qp.ddl, 0.0)
    xy, th, kap = pose(l, dl, ddl)
    return dict(
        corridor=cor,
        qp=qp,
        rounds=rounds,
        clear=clear(xy, th, cor.valid),
        xy=xy,
        theta=th,
        kappa=kap,
        l=l,
        dl=dl,
        ddl=ddl,
        qp_input=(*qp_bounds(cor), *dl_b, *ddl_b),
    )


def _plan(scene, ctx, config, ego):
    veh = config.vehicle
    ref = scene.route
    f = ref.xy.dtype
    N = config.n_points
    dt = jnp.asarray(scene.dt, f)
    s0, l0 = jnp.asarray(ctx.s, f), jnp.asarray(ctx.l, f)
    v0 = jnp.maximum(jnp.asarray(ego.v, f), 0.0)
    ds = jnp.clip(v0 * config.time_horizon / (N - 1), config.ds_min, config.ds_max)
    st = s0 + ds * jnp.arange(N, dtype=f)
    _, th_r, k_r, _ = ref_state(ref, st)
    _, _, dl0, ddl0 = cartesian_to_frenet_state(
        ref, None, jnp.asarray(ego.heading, f), jnp.asarray(ego.kappa, f), sl=(s0, l0)
    )
    boxes, blocking = blocking_footprints(ctx.obstacles, config.static_speed, dt)
    left_e, right_e = corridor_edges(scene, config.opposite_lanes)
    front = veh.front_offset
    rear = veh.rear_offset
    edge_l = jnp.minimum(
        jnp.minimum(_sample(scene, left_e, st), _sample(scene, left_e, st + front)), _sample(scene, left_e, st + rear)
    )
    edge_r = jnp.maximum(
        jnp.maximum(_sample(scene, right_e, st), _sample(scene, right_e, st + front)),
        _sample(scene, right_e, st + rear),
    )
    l_pref = _sample(scene, scene.lane_offset[scene.own_lane], st)
    if config.nudge:
        lane_half = 0.5 * _sample(scene, scene.lane_width[scene.own_lane], st)
        edge_l, edge_r = nudge_edges(ref, ctx, blocking, st, l_pref, lane_half, edge_l, edge_r, veh, config)
    res = solve_path(ref, st, ds, boxes, blocking, edge_l, edge_r, l_pref, jnp.stack([l0, dl0, ddl0]), config, v0)
    cor, qp = res["corridor"], res["qp"]
    xy, th, kap, l = res["xy"], res["theta"], res["kappa"], res["l"]
    # Outputs on the path's own arc length.
    seg = jnp.linalg.norm(xy[1:] - xy[:-1], axis=-1)
    S = jnp.concatenate([jnp.zeros((1,), f), jnp.cumsum(seg)])
    s_out = ds * jnp.arange(N, dtype=f)
    S_end = S[-1]
    past = jnp.maximum(s_out - S_end, 0.0)
    x_o = _resample(S, xy[:, 0], s_out) + past * jnp.cos(th[-1])
    y_o = _resample(S, xy[:, 1], s_out) + past * jnp.sin(th[-1])
    b = cor.blocked_index
    blocked_s = jnp.where(b < N, S[jnp.minimum(b, N - 1)], jnp.inf)
    valid_o = (s_out <= S_end + 1e-4) & (s_out < blocked_s)
    side = jnp.where(blocking, cor.side, NONE)
    ok = qp.ok & res["clear"] & (b > 0)
    return PathPlan(
        s_out,
        jnp.stack([x_o, y_o], -1),
        _resample(S, th, s_out),
        _resample(S, kap, s_out),
        _resample(S, l, s_out),
        _resample(S, st, s_out) + past,
        _resample(S, cor.lower, s_out),
        _resample(S, cor.upper, s_out),
        valid_o,
        blocked_s,
        ok,
        side,
        blocking,
        res["rounds"],
        qp.ok,
        res["clear"],
        ds,
    )
