"""The paths the ``pathspeed`` planner plans its speed on (``jaxplan.speed.planner``), as
``RoutePath``s of one shape: the route's centre line (or an offset of it, fixed or per station)
joined from the car's pose (``route_path``, its join's length ``join_length``), the lane the car is
in followed along the route (``car_lane``), the neighbour lane to pass in (``neighbour_lane``; which
of the two the planner's other path joins: ``other_lane``), the
bounds path with the route's points behind the car and a join back to the route's lane after it
(``bounds_route_path``), and a path as a reference line for the speed plan (``path_reference``)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.geometry.frenet import ReferenceLine, frenet_to_cartesian_state, ref_state, wrap_angle
from jaxplan.geometry.quintic import cartesian_to_frenet_state, quintic_coeffs, quintic_eval
from jaxplan.plan_context import RoadContext, route_sample
from jaxplan.planner import SIM_VEHICLE, EgoState
from jaxplan.types import pytree_dataclass

__all__ = [
    "JOIN_MARGIN",
    "JOIN_SHARES",
    "LANE_ID_JUMP",
    "MAX_START_ANGLE",
    "MAX_START_DDL",
    "MERGE_SHIFT",
    "RoutePath",
    "bounds_route_path",
    "car_lane",
    "frenet_start",
    "join_length",
    "merging_in",
    "neighbour_lane",
    "other_lane",
    "own_lane_width",
    "path_reference",
    "path_stations",
    "route_path",
    "total_points",
    "toward_goal",
]


@pytree_dataclass(data_fields=("s", "xy", "theta", "kappa", "l", "route_s", "valid", "blocked_s", "ok"))
class RoutePath:
    """The path the speed is planned on (the fields of ``jaxplan.bounds``' ``PathPlan`` that
    the speed planner reads): ``s (N,)`` distance along the path from the car (negative behind
    it), ``xy (N, 2)``, ``theta (N,)`` unwrapped, ``kappa (N,)``, ``l (N,)`` offset from the
    route, ``route_s (N,)`` station on the route, ``valid (N,)``, ``blocked_s ()`` where the
    car's reference point must stop before (inf: nothing blocks it), ``ok ()``."""

    s: Any
    xy: Any
    theta: Any
    kappa: Any
    l: Any
    route_s: Any
    valid: Any
    blocked_s: Any
    ok: Any


def _quintic(p0, p1, length, u):
    """Quintic ``l(u)`` (and dl/du, d2l/du2) from ``p0 = (l, dl, ddl)`` at 0 to ``p1`` at
    ``length`` (``jaxplan.geometry.quintic``), held at ``p1``'s ``l`` beyond and continued
    straight behind 0; ``u (N,)``."""
    l0, d0, _ = p0
    l, dl, ddl = quintic_eval(quintic_coeffs(*p0, p1, length), length, u)
    behind = u < 0
    return jnp.where(behind, l0 + d0 * u, l), jnp.where(behind, d0, dl), jnp.where(behind, 0.0, ddl)


def _target(target_l, u):
    """The target offset ``target_l`` (``()``, or ``(N,)`` at ``u (N,)``, ascending) and its
    first and second derivatives in ``u`` (finite differences), each ``(N,)``."""
    t = jnp.broadcast_to(jnp.asarray(target_l, u.dtype), u.shape)
    if jnp.ndim(target_l) == 0:
        z = jnp.zeros_like(u)
        return t, z, z

    def slope(y):
        d = jnp.diff(y) / jnp.maximum(jnp.diff(u), 1e-6)
        return jnp.concatenate([d[:1], 0.5 * (d[1:] + d[:-1]), d[-1:]])

    dt = slope(t)
    return t, dt, slope(dt)


def _target_start(start, target, u):
    """``start`` less the target's ``(l, dl, ddl)`` at ``u = 0`` (``_target``'s triple)."""
    return tuple(x - jnp.interp(0.0, u, y) for x, y in zip(start, target))


def _join_route(ref, sr, start, target_l, length, u):
    """Points on the route at stations ``sr (N,)`` whose offset is the target ``target_l`` (``()``,
    or ``(N,)`` at the stations) plus a quintic in ``u (N,)`` (``sr = sr_0 + u``) from ``start =
    (l, dl/ds, d2l/ds2)`` less the target's at ``u = 0`` to zero at ``u = length``: ``(xy (N, 2),
    theta (N,), kappa (N,), l (N,))``."""
    target = _target(target_l, u)
    e, de, dde = _quintic(_target_start(start, target, u), 0.0, length, u)
    l, dl, ddl = target[0] + e, target[1] + de, target[2] + dde
    xy, _, kappa = frenet_to_cartesian_state(ref, sr, l, dl, ddl)
    _, th_r, kr, _ = ref_state(ref, sr)
    return xy, th_r + jnp.arctan2(dl, 1.0 - kr * l), kappa, l


MAX_START_ANGLE = 1.2  # rad: the car's heading off the route counts as at most this for its start slope
MAX_START_DDL = 0.5  # 1/m: and its start d2l/ds2 as at most this


def frenet_start(ref, s, l, heading, kappa):
    """The car's ``(l, dl/ds, d2l/ds2)`` on the route at ``(s, l)`` with ``heading``, ``kappa``
    (``cartesian_to_frenet_state``; the heading off the route counted as at most
    ``MAX_START_ANGLE``, the second derivative clipped to ``MAX_START_DDL``)."""
    _, th0, _, _ = ref_state(ref, s)
    heading = th0 + jnp.clip(wrap_angle(heading - th0), -MAX_START_ANGLE, MAX_START_ANGLE)
    _, _, dl0, ddl0 = cartesian_to_frenet_state(ref, None, heading, kappa, sl=(s, l))
    return l, dl0, jnp.clip(ddl0, -MAX_START_DDL, MAX_START_DDL)


def _n_behind(n: int) -> int:
    """Points of an ``n``-point ``route_path`` behind the car (``s < 0``)."""
    return max(2, n // 12) - 1


def total_points(n_path: int, n_ext: int) -> tuple[int, int]:
    """``(total, ext)``: a route path of ``total`` points has as many points behind the car as
    ``bounds_route_path`` puts before a bounds path of ``n_path`` points with ``ext`` (>=
    ``n_ext``) after it, so that the two are one shape."""
    for ext in range(n_ext, n_ext + 24):
        for nb in range(1, 64):
            if _n_behind(nb + n_path + ext) == nb:
                return nb + n_path + ext, ext
    raise ValueError(f"no route path size fits a bounds path of {n_path} points")


JOIN_SHARES = (1.0, 0.8, 0.65, 0.5, 0.4, 0.3)  # of the join's length: the shorter ones tried
JOIN_MARGIN = 0.2  # m: a join that swings past its target offset keeps this much of the lane's room


def join_length(start, target_l, v, a_lat, room):
    """The length (m) of the quintic that joins the offset ``target_l`` from ``start = (l,
    dl/ds, d2l/ds2)`` for a car at speed ``v``: ``clip(10 + 2.5 v, 15, 60)``; where that
    quintic swings past the target by more than ``room`` (a car already moving over fast
    toward it: it would leave the target lane), the longest of its ``JOIN_SHARES`` that does not
    and whose ``v^2 |d2l/ds2|`` stays within ``a_lat`` (or within the car's own at the start)."""
    longest = jnp.clip(10.0 + 2.5 * v, 15.0, 60.0)
    f = longest.dtype
    lengths = longest * jnp.asarray(JOIN_SHARES, f)
    x = jnp.linspace(0.0, 1.0, 33, dtype=f)
    side = jnp.sign(target_l - start[0])
    lat = jnp.maximum(a_lat, v * v * jnp.abs(start[2]))

    def fits(length):
        l, _, ddl = _quintic(start, target_l, length, length * x)
        return (jnp.max((l - target_l) * side) <= room) & (v * v * jnp.max(jnp.abs(ddl)) <= lat)

    ok = jax.vmap(fits)(lengths)
    return jnp.where(ok[0] | ~jnp.any(ok), longest, lengths[jnp.argmax(ok)])


def path_stations(n: int, back: float, ahead: float, dtype) -> Any:
    """``(n,)`` the stations of an ``n``-point ``route_path`` from the car (``-back`` to ``ahead``
    metres; ``_n_behind(n)`` of them behind it, one at the car, at least one ahead of it)."""
    if n < 3:
        raise ValueError(f"path_stations: n must be at least 3 (behind, at and ahead of the car), got {n}")
    nb = _n_behind(n) + 1
    return jnp.concatenate(
        [jnp.linspace(-back, 0.0, nb, dtype=dtype)[:-1], jnp.linspace(0.0, ahead, n - nb + 1, dtype=dtype)]
    )


def route_path(
    scene,
    ctx: RoadContext,
    ego: EgoState,
    n: int = 96,
    back: float = 20.0,
    ahead: float = 240.0,
    target_l=0.0,
    a_lat: float = 3.0,
    width: float = SIM_VEHICLE.width,
) -> RoutePath:
    """The route's centre line (offset ``target_l``: ``()``, or ``(n,)`` at ``path_stations``)
    joined from the car's pose: ``l(s)`` the target plus a quintic in the route station from the
    car's offset, heading and curvature less the target's to zero over ``join_length`` (its
    lateral acceleration ``a_lat``; the room past the target what a lane as wide as the car's own
    leaves a car ``width`` wide, less ``JOIN_MARGIN``); ``n`` points from ``back`` metres behind
    the car to ``ahead`` metres ahead of it (the path when the bounds path is off or fails)."""
    ref = scene.route
    f = jax.dtypes.canonicalize_dtype(ref.xy.dtype)  # a host-side float64 scene runs in float32
    u = path_stations(n, back, ahead, f)
    sr = ctx.s + u
    start = frenet_start(ref, ctx.s, ctx.l, ego.heading, ego.kappa)
    target_l = jnp.asarray(target_l, f)
    room = 0.5 * (ctx.lane_width[scene.own_lane] - width) - JOIN_MARGIN
    e0 = _target_start(start, _target(target_l, u), u)
    length = join_length(e0, jnp.zeros((), f), jnp.asarray(ego.v, f), a_lat, jnp.maximum(room, 0.0))
    xy, theta, kappa, l = _join_route(ref, sr, start, target_l, length, u)
    ones = jnp.ones_like(u, dtype=bool)
    return RoutePath(u, xy, theta, kappa, l, sr, ones, jnp.asarray(jnp.inf, f), jnp.asarray(True))


def neighbour_lane(scene, ctx: RoadContext, ahead) -> tuple[Any, Any, Any]:
    """The lane to pass in: ``(offset (), runs (), goal_ok ())``: the lane left of the route's own
    lane where it runs the same way over the next ``ahead`` metres, else the one on the right
    (``runs`` False when neither does); ``goal_ok`` False when the goal region is within
    ``ahead`` and not in that lane (the car is not led away from its goal)."""
    f = scene.route.xy.dtype
    c, L = scene.own_lane, scene.n_lanes
    q = ctx.s + jnp.linspace(0.0, 1.0, 16, dtype=f) * ahead

    def runs(i):
        if not 0 <= i < L:
            return jnp.asarray(False)
        ok = (route_sample(scene, scene.lane_valid[i].astype(f), q) > 0.5) & (
            route_sample(scene, scene.lane_same_dir[i].astype(f), q) > 0.5
        )
        return jnp.all(ok)

    left, right = runs(c + 1), runs(c - 1)
    i = jnp.where(left, min(c + 1, L - 1), max(c - 1, 0))
    l_lane = ctx.lane_offset[i]
    return l_lane.astype(f), left | right, toward_goal(ctx, l_lane, ahead)


def toward_goal(ctx: RoadContext, l, ahead) -> Any:
    """``()`` whether a lane at offset ``l`` (``()``) where the goal is does not lead the car away
    from it: the goal region is not within ``ahead`` metres, or ``l`` is inside its offsets."""
    goal_near = ctx.goal_s[0] - ctx.s < ahead
    return ~goal_near | ((l >= ctx.goal_l[0]) & (l <= ctx.goal_l[1]))


LANE_ID_JUMP = 1.0  # m: a lane offset that changes more than this between route points is another lane


def car_lane(scene, ctx: RoadContext, sr) -> tuple[Any, Any]:
    """The lane the car is in, followed along the route: ``(offset (N,), near (N,))`` at the
    route stations ``sr (N,)`` (ascending). From the centre of the same-direction lane nearest
    the car at ``ctx.s``, each station ahead takes the centre offset of the same-direction lane
    nearest the one before, where it is within half that lane's width (``near``; elsewhere the
    offset goes on straight: the lane ends there, or the route's own lane changes between two
    route points, ``LANE_ID_JUMP``); stations behind the car take that lane's offset under its
    index at the car. Where the route changes lanes, this is the lane it leaves."""
    f = jax.dtypes.canonicalize_dtype(scene.route.xy.dtype)  # a host-side float64 scene runs in float32
    rs, offset = jnp.asarray(scene.route.s), jnp.asarray(scene.lane_offset)
    R = rs.shape[0]
    j = jnp.clip(jnp.searchsorted(rs, sr, side="right") - 1, 0, R - 2)
    w = jnp.clip((sr - rs[j]) / jnp.maximum(rs[j + 1] - rs[j], 1e-6), 0.0, 1.0)
    same = jnp.asarray(scene.lane_valid) & jnp.asarray(scene.lane_same_dir)
    # a lane at the route point before a station is the same lane at the point after it under its
    # own index, or the next one where the route's own lane changes between the two points
    a, ok_a = offset[:, j], same[:, j]  # (L, N)
    L = offset.shape[0]

    def shifted(x, d):  # row i of x[:, j + 1] is lane i + d there (False/0 off the lanes)
        return jnp.where(((jnp.arange(L) + d >= 0) & (jnp.arange(L) + d < L))[:, None], jnp.roll(x, -d, axis=0), 0)

    b = jnp.concatenate([shifted(offset[:, j + 1], d) for d in (-1, 0, 1)])  # (3L, N)
    ok_b = jnp.concatenate([shifted(same[:, j + 1], d) for d in (-1, 0, 1)]).astype(bool)
    a, ok_a = jnp.tile(a, (3, 1)), jnp.tile(ok_a, (3, 1))
    ok = ok_a & ok_b & (jnp.abs(b - a) < LANE_ID_JUMP)
    offs = a + w * (b - a)
    half = 0.5 * jnp.tile(jnp.asarray(scene.lane_width)[:, j], (3, 1))
    d0 = jnp.where(ctx.lane_valid & ctx.lane_same_dir, jnp.abs(ctx.lane_offset - ctx.l), jnp.inf)
    i0 = jnp.argmin(d0)
    start = ctx.lane_offset[i0].astype(f)
    behind = offs[L + i0]  # that lane under its own index (rows L..2L-1 keep the index)

    def step(carry, k):
        prev, slope = carry
        d = jnp.where(ok[:, k], jnp.abs(offs[:, k] - prev), jnp.inf)
        i = jnp.argmin(d)
        near = d[i] < half[i, k]
        ahead = sr[k] > ctx.s
        du = sr[k] - sr[jnp.maximum(k - 1, 0)]
        new = jnp.where(ahead, jnp.where(near, offs[i, k], prev + slope * du), behind[k])
        slope = jnp.where(ahead & (du > 0), (new - prev) / jnp.maximum(du, 1e-6), slope)
        return (new, slope), (new, near | ~ahead)

    _, (track, near) = jax.lax.scan(step, (start, jnp.zeros((), f)), jnp.arange(sr.shape[0]))
    track = jnp.where(sr > ctx.s, track, behind)
    return track, near


def own_lane_width(scene, ctx: RoadContext) -> Any:
    """``()`` the width of the car's own lane (m), at least 1 m (the unit of a lane's share)."""
    return jnp.maximum(ctx.lane_width[scene.own_lane], 1.0)


def other_lane(scene, ctx: RoadContext, u, ahead, lane=None) -> tuple[Any, Any, Any]:
    """The lane of the planner's other path, at the route path's stations ``u (N,)`` from the car:
    ``(offset (N,), runs (), goal_ok ())``. Where the route leaves the car's lane within ``ahead``
    metres (it changes lanes there, or the car is beside it: ``car_lane`` more than half the own
    lane's width off the route) and that lane runs on that far, the car's lane (the car may stay
    in it instead of moving over); else ``neighbour_lane``'s. ``goal_ok`` as ``neighbour_lane``'s,
    for the offset where the goal region begins. ``lane``: ``car_lane(scene, ctx, ctx.s + u)``
    where the caller has it (None: computed here)."""
    l_nb, runs, goal_ok = neighbour_lane(scene, ctx, ahead)
    l_car, near = car_lane(scene, ctx, ctx.s + u) if lane is None else lane
    reach = (u >= 0) & (u <= ahead)
    leaves = jnp.any(reach & (jnp.abs(l_car) > 0.5 * own_lane_width(scene, ctx))) & jnp.all(near | ~reach)
    goal_car = toward_goal(ctx, jnp.interp(ctx.goal_s[0] - ctx.s, u, l_car), ahead)
    return jnp.where(leaves, l_car, l_nb), leaves | runs, jnp.where(leaves, goal_car, goal_ok)


def bounds_route_path(scene, ctx: RoadContext, pp, back: RoutePath, n_ext: int, ahead: float) -> RoutePath:
    """The bounds path ``pp`` (a ``jaxplan.bounds.PathPlan`` from the car) with the route
    path's points behind the car (``back``, those with ``s < 0``) before it and, after its
    last point, ``n_ext`` points that join the route's own lane again (a quintic from the
    path's end offset and slope) up to ``ahead`` metres from the car. ``s`` is the chord
    length along the points from the car; ``blocked_s`` the path's, ``ok`` the path's."""
    ref = scene.route
    f = ref.xy.dtype
    nb = _n_behind(back.s.shape[0])
    # the end of the bounds path on the route, and its slope there
    s_end, l_end, th_end = pp.route_s[-1], pp.l[-1], pp.theta[-1]
    _, th_r, k_r, _ = ref_state(ref, s_end)
    dth = wrap_angle(th_end - th_r)
    dl_end = (1.0 - k_r * l_end) * jnp.tan(jnp.clip(dth, -1.2, 1.2))
    reach = jnp.maximum(ctx.s + ahead - s_end, 1.0)
    u = reach * jnp.arange(1, n_ext + 1, dtype=f) / n_ext
    l_pref = jnp.interp(s_end, ref.s, scene.lane_offset[scene.own_lane])
    length = jnp.clip(0.5 * reach, 15.0, 60.0)
    xy_e, th_e, k_e, l_e = _join_route(ref, s_end + u, (l_end, dl_end, jnp.zeros((), f)), l_pref, length, u)
    xy = jnp.concatenate([back.xy[:nb], pp.xy, xy_e])
    theta = jnp.concatenate([back.theta[:nb], pp.theta, th_e])
    # unwrap across the joins (each part's heading is continuous)
    theta = jnp.concatenate([theta[:1], theta[:1] + jnp.cumsum(wrap_angle(jnp.diff(theta)))])
    kappa = jnp.concatenate([back.kappa[:nb], pp.kappa, k_e])
    l = jnp.concatenate([back.l[:nb], pp.l, l_e])
    route_s = jnp.concatenate([back.route_s[:nb], pp.route_s, s_end + u])
    seg = jnp.linalg.norm(jnp.diff(xy, axis=0), axis=-1)
    chord = jnp.concatenate([jnp.zeros((1,), f), jnp.cumsum(seg)])
    s = chord - chord[nb]  # the bounds path's first point is the car
    valid = jnp.concatenate([jnp.ones((nb,), bool), pp.valid, jnp.broadcast_to(~jnp.isfinite(pp.blocked_s), (n_ext,))])
    return RoutePath(s, xy, theta, kappa, l, route_s, valid, pp.blocked_s, pp.ok)


def path_reference(path) -> tuple[ReferenceLine, Any]:
    """The path as a ``ReferenceLine`` (chord arc lengths, the path's own heading and
    curvature) and the car's station on it."""
    xy = path.xy
    seg = jnp.linalg.norm(jnp.diff(xy, axis=0), axis=-1)
    s = jnp.concatenate([jnp.zeros((1,), xy.dtype), jnp.cumsum(jnp.maximum(seg, 1e-6))])
    ref = ReferenceLine(xy, s, path.theta, path.kappa)
    return ref, jnp.interp(jnp.zeros((), xy.dtype), path.s, s)


MERGE_SHIFT = 1.0  # m: an obstacle whose distance to the car's lane shrinks by more than this moves over into it


def merging_in(ctx: RoadContext, u, lane_l) -> Any:
    """``(K,)`` bool: the obstacles that move over into the car's lane.

    Args:
        ctx: the cycle's context (its obstacles' route-frame centres ``obstacle_s``,
            ``obstacle_l`` ``(K, H)``).
        u: ``(N,)`` ascending stations from the car; lane_l: ``(N,)`` the centre offset of the
            car's lane there (``car_lane``: it follows the lane where the route changes lanes).

    Over its prediction, an obstacle's sideways distance to the car's lane centre at its own
    station shrinks by more than ``MERGE_SHIFT`` from now. A vehicle in its own lane, beside a car
    (or a route) that moves over to it, keeps its distance: it is not merging in."""
    valid = ctx.obstacles.valid
    lane = jnp.interp(ctx.obstacle_s - ctx.s, u, lane_l)  # (K, H)
    d = jnp.abs(ctx.obstacle_l - lane)
    closest = jnp.min(jnp.where(valid, d, jnp.inf), -1)
    return valid[:, 0] & (d[:, 0] - closest > MERGE_SHIFT)
