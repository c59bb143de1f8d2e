"""``pathspeed``: the decoupled path-speed planner as a road ``Planner`` (``jaxplan.planner``).

Each cycle (one scene, jittable; the simulator batches it with ``jax.vmap``):

1. the ``RoadContext`` (predictions from this step, the lane speed limits, the goal);
2. the **path**: ``jaxplan.bounds.plan_path`` (path decision around the blocking
   obstacles, bounds, path QP, recomputed at the path's heading) from the car, with the
   route path's points behind the car before it and a join back to the route's lane after
   its end (``bounds_route_path``). When its QP fails, it is not clear of the blocking
   obstacles or something blocks it, the speed is planned on the route's centre line joined
   from the car's pose (``route_path``) instead, with a stop before the bounds path's
   blockage. The speed is planned on both paths, and the route path is also taken when the
   bounds path's speed plan cannot avoid the moving obstacles while the route path's can
   (a bypass into a lane with traffic beside the car), or costs more by ``BOUNDS_YIELD`` lane
   changes; ``info["path_bounds"]`` says which path was used (and ``path_qp_ok``,
   ``path_clear``, ``path_blocked`` why). With ``lane_change`` a third path joins another
   lane: the lane the car is in where the route leaves it within reach (``car_lane``: the route
   changes lanes ahead, or the car is beside it), else the neighbour lane (``neighbour_lane``:
   the left one, else the right, running the same way ahead, not away from a goal region
   ahead); the car takes it when its speed plan is collision-free and cheaper than the lane's
   by the lane change's cost (the speed plan sees that lane's traffic over the whole horizon: a
   gap that closes, or a car from behind that would have to brake, makes it collide or cost
   more), and stays in it while that holds (``info["lane_change"]``). With ``tight`` the first path
   is planned once more without the clearance buffer around obstacles, a way past that only
   the exact overlap leaves open, taken when the buffered plan collides or is hit from behind
   (``info["tight"]``);
3. the **speed**: the ST boundaries of the predictions on that path (blocking,
   non-blocking with decisions, a wall before the path's blockage and the end of the
   map), the DP over the reachable band (``dp.py``, its costs ``costs.py``) towards the set speed
   (``jaxplan.plan_context.set_speed``, the lattice's) with the lane speed limit, the
   curvature limit, the time-headway follow distance and the goal's window, then the
   smoothing QP (``smooth.py``) for the executed profile;
4. the **composed trajectory**: the profile along the path, ``horizon_steps`` points every
   ``dt`` from the car.

``ok`` is False when the DP found no collision-free profile, the QP needed slack (it could
not keep the DP's corridor within the acceleration limits) or did not converge, or the
plan is not finite. ``nonblocking=False`` drops the non-blocking boundaries' costs (the
``speed`` suite's and ``jaxplan drive --planner pathspeed:nonblocking=false``'s comparison).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.bounds.path_planner import PathConfig, plan_path
from jaxplan.geometry.frenet import ReferenceLine, frenet_to_cartesian_state, ref_state, wrap_angle
from jaxplan.geometry.quintic import cartesian_to_frenet_state, quintic_coeffs, quintic_eval
from jaxplan.plan_context import RoadContext, goal_region_ahead, road_context, route_sample, set_speed
from jaxplan.planner import SIM_VEHICLE, EgoState, PlanOutput
from jaxplan.speed.compose import compose_profile
from jaxplan.speed.costs import REAR_CONTACT
from jaxplan.speed.dp import plan_one
from jaxplan.speed.problem import CostWeights, SpeedConfig, SpeedRoad
from jaxplan.speed.smooth import SmoothWeights, smooth_plan
from jaxplan.speed.st_boundary import car_extent
from jaxplan.types import Obstacles, VehicleParams, pytree_dataclass, weights_from


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


def _frenet_start(ref, s, l, heading, kappa):
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


def _total_points(n_path: int, n_ext: int) -> tuple[int, int]:
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
    metres; ``_n_behind(n)`` of them behind it)."""
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
    f = ref.xy.dtype
    u = path_stations(n, back, ahead, f)
    sr = ctx.s + u
    start = _frenet_start(ref, ctx.s, ctx.l, ego.heading, ego.kappa)
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
    goal_near = ctx.goal_s[0] - ctx.s < ahead
    in_goal = (l_lane >= ctx.goal_l[0]) & (l_lane <= ctx.goal_l[1])
    return l_lane.astype(f), left | right, ~goal_near | in_goal


LANE_ID_JUMP = 1.0  # m: a lane offset that changes more than this between route points is another lane


def car_lane(scene, ctx: RoadContext, sr) -> tuple[Any, Any]:
    """The lane the car is in, followed along the route: ``(offset (N,), near (N,))`` at the
    route stations ``sr (N,)`` (ascending). From the centre of the same-direction lane nearest
    the car at ``ctx.s``, each station ahead takes the centre offset of the same-direction lane
    nearest the one before, where it is within half that lane's width (``near``; elsewhere the
    offset goes on straight: the lane ends there, or the route's own lane changes between two
    route points, ``LANE_ID_JUMP``); stations behind the car take that lane's offset under its
    index at the car. Where the route changes lanes, this is the lane it leaves."""
    f = scene.route.xy.dtype
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


def speed_road(scene, ctx: RoadContext, path, v_max: float, vehicle: VehicleParams, v_set=0.0) -> SpeedRoad:
    """What the road asks of the speed on ``path``: the lane speed limit at each path point
    (read at its route station; raised to the set speed ``v_set`` where that is higher: a goal
    that cannot be met at the limit, ``set_speed``), a stop before the path's blockage (the car's reference point
    before ``path.blocked_s``) and, without a goal region ahead (the drive ends there; the map
    often ends just past it), before the end of the mapped road (the car's front), the
    goal's stations (box centre, along the route), time window and speeds, where the path
    leaves the car's lane (``lane_leave_s``)."""
    f = path.xy.dtype
    lim = route_sample(scene, scene.speed_limit, path.route_s)
    front, _ = car_extent(vehicle, f)
    end = ctx.route_end_s - ctx.s
    goal_ahead = goal_region_ahead(ctx.goal_s, ctx.s + jnp.asarray(vehicle.center_offset, f))
    end = jnp.where(jnp.isfinite(end) & ~goal_ahead, end, jnp.inf)
    stop = jnp.minimum(path.blocked_s + front, end)
    goal_s = ctx.goal_s - ctx.s
    return SpeedRoad(
        path.s,
        jnp.minimum(jnp.maximum(lim, v_set), v_max),
        stop,
        goal_s.astype(f),
        ctx.goal_t.astype(f),
        ctx.goal_v.astype(f),
        lane_leave_s(path),
    )


BOUNDS_YIELD = 1.0  # lane changes' costs by which the route path's plan must be cheaper than the bounds path's
LANE_SHIFT = 1.0  # m: a path that moves further sideways than this from the car leaves its lane
LANE_RETURN_MARGIN = 0.1  # lane changes' cost share that staying in the neighbour lane costs
LANE_GO_V = 1.0  # m/s: a lane change's plan must end faster than this
LANE_GAIN = 5.0  # m: and further along than the lane's own plan, or
LANE_DECISIVE = 2.0  # cheaper by this many lane changes' costs
LANE_MOVING = 0.01  # the car's lateral slope (dl/ds) above which it is moving over
LANE_HOLD = 1.0  # lane changes' cost share of turning back a move under way
# the plan without the clearance buffer is taken when the buffered one costs more by at least
# this many seconds of contact with a vehicle behind (REAR_CONTACT), or collides
TIGHT_GAIN_S = 0.1


def lane_leave_s(path) -> Any:
    """``()`` the first station ahead of the car where ``path`` is more than ``LANE_SHIFT``
    sideways of the car's own offset (``inf``: nowhere)."""
    l_car = jnp.interp(0.0, path.s, path.l)
    away = path.valid & (path.s >= 0) & (jnp.abs(path.l - l_car) > LANE_SHIFT)
    return jnp.min(jnp.where(away, path.s, jnp.inf)).astype(path.xy.dtype)


@dataclasses.dataclass(frozen=True)
class PathSpeedPlanner:
    """The path-speed planner (static config; see the module docstring).

    Attributes:
        vehicle, dt, horizon: the car, the trajectory's step and length (s).
        nonblocking: plan with the non-blocking boundaries (no-bypass, blind zone, keep clear).
        speed: the DP's grid and limits (its horizon must equal ``horizon``, its ``qp_dt`` ``dt``).
        smooth: the smoothing QP's weights.
        path: the bounds path's ``PathConfig`` (its ``vehicle`` is set to ``vehicle``), or None
            to plan the speed on the route path (``route_path``) only.
        path_points: points of the route path (the fallback, and the points behind the car).
        ext_points: points after the bounds path's end that join the route's lane again.
        lane_change: also plan the speed on a path into the neighbour lane (``neighbour_lane``),
            or along the car's own lane where the route leaves it (``car_lane``), and take it
            when it is collision-free and cheaper by the lane change's cost
            (``CostWeights.w_lane_change``).
        tight: also plan the speed on the first path with no clearance buffer around the
            obstacles (``speed.buffer`` 0: only the exact overlap blocks), and take that plan
            where the lane-keeping plan (the first path's, or the route path's where the first
            is a usable bounds path) collides, or costs more by ``TIGHT_GAIN_S`` seconds of
            contact with a vehicle behind (stopping for an oncoming car that passes 0.1 m clear,
            and being hit from behind); ``info["tight"]``.
    """

    vehicle: VehicleParams = SIM_VEHICLE
    dt: float = 0.1
    horizon: float = 7.0
    nonblocking: bool = True
    speed: SpeedConfig = SpeedConfig()
    smooth: SmoothWeights = SmoothWeights()
    path: PathConfig | None = PathConfig()
    path_points: int = 96
    ext_points: int = 24
    lane_change: bool = True
    tight: bool = True

    def __post_init__(self):
        self.speed.validate()
        if self.path is not None and self.path.vehicle != self.vehicle:
            object.__setattr__(self, "path", dataclasses.replace(self.path, vehicle=self.vehicle))
        if abs(self.speed.horizon - self.horizon) > 1e-9 or abs(self.speed.qp_dt - self.dt) > 1e-9:
            raise ValueError(
                f"PathSpeedPlanner: speed.horizon ({self.speed.horizon}) and speed.qp_dt "
                f"({self.speed.qp_dt}) must equal horizon ({self.horizon}) and dt ({self.dt})"
            )

    @property
    def path_ahead(self) -> float:
        """Metres of path ahead of the car (what the horizon covers at ``v_max``, and some)."""
        return self.speed.v_max * self.horizon + 30.0

    @property
    def horizon_steps(self) -> int:
        return int(round(self.horizon / self.dt)) + 1

    def init_params(self, weights: Mapping | None = None) -> CostWeights:
        """The speed DP's ``CostWeights`` as a pytree of float arrays: the defaults, with the values
        of ``weights`` (``{field: value}``) in their place (``v_cruise`` is set every cycle)."""
        return weights_from(CostWeights, weights)

    def cost_weights(self, params: CostWeights, v_cruise) -> CostWeights:
        """``params`` for one cycle: ``v_cruise`` set, the non-blocking weights zero without them."""
        f = jnp.result_type(v_cruise)
        w = jax.tree_util.tree_map(lambda x: jnp.asarray(x, f), params)
        w = dataclasses.replace(w, v_cruise=v_cruise)
        if not self.nonblocking:
            z = jnp.zeros((), f)
            w = dataclasses.replace(w, w_no_bypass=z, w_blind=z, w_keep_clear=z)
        return w

    def route_path(self, scene, ctx: RoadContext, ego: EgoState, n: int, target_l=0.0) -> RoutePath:
        """``route_path`` with this planner's lateral acceleration and car width, from 20 m
        behind the car to ``path_ahead`` ahead of it."""
        return route_path(scene, ctx, ego, n, 20.0, self.path_ahead, target_l, self.speed.a_lat_max, self.vehicle.width)

    def plan_path(self, scene, ctx: RoadContext, ego: EgoState):
        """The paths of this cycle: ``(bp, rp, pp, use)``: the bounds path as a ``RoutePath``
        (None without ``self.path``), the route path (``route_path``, with the bounds path's
        blockage, if any, as its stop), the bounds ``PathPlan`` (or None) and whether the bounds
        path may be used (``()`` bool: its QP solved, it is clear of every blocking obstacle
        and nothing blocks it)."""
        ahead = self.path_ahead
        if self.path is None:
            return None, self.route_path(scene, ctx, ego, self.path_points), None, jnp.asarray(False)
        total, ext = _total_points(self.path.n_points, self.ext_points)
        rp = self.route_path(scene, ctx, ego, total)
        pp = plan_path(scene, ctx, self.path)
        bp = bounds_route_path(scene, ctx, pp, rp, ext, ahead)
        blocked = jnp.isfinite(pp.blocked_s)
        # the blockage on the route path: at the route station of the bounds path's blockage
        stop_r = jnp.interp(pp.blocked_s, pp.s, pp.route_s) - ctx.s
        rp = dataclasses.replace(rp, blocked_s=jnp.where(blocked, stop_r, rp.blocked_s))
        return bp, rp, pp, pp.ok & ~blocked

    def speed_plan(self, params: CostWeights, scene, ego: EgoState, step) -> dict:
        """One cycle up to the speed profile, as a dict: ``ctx`` (the ``RoadContext``),
        ``path`` (the ``RoutePath`` the speed is planned on), ``bounds`` (the bounds
        ``PathPlan`` or None), ``use_bounds`` (``()`` bool, ``path`` is the bounds path),
        ``tight`` (``()`` bool, the plan without the clearance buffer was taken), ``path_plans``
        (every path's ``SpeedPlan``, stacked: the bounds path if any, the route path, the
        neighbour lane's with ``lane_change``, the first path's without the buffer with ``tight``),
        ``ref``, ``s0`` (the path as a reference line, the car's station on it), ``plan`` (the
        DP's ``SpeedPlan``) and ``profile`` (the executed ``SpeedProfile``)."""
        H = self.horizon_steps
        ctx = road_context(scene, ego, step, H, self.vehicle)
        f = scene.route.xy.dtype
        bp, rp, pp, use = self.plan_path(scene, ctx, ego)
        v0 = jnp.maximum(jnp.asarray(ego.v, f), 0.0)
        a0 = jnp.asarray(ego.a, f)
        v_set = set_speed(scene, ctx, ego, self.vehicle, self.horizon, self.speed.a_lat_max).astype(f)
        w = self.cost_weights(params, v_set)
        obs = ctx.obstacles
        obs = Obstacles(obs.boxes, obs.valid, obs.t - obs.t[0], obs.static)

        def on(path, buffer):
            ref, s0 = path_reference(path)
            road = speed_road(scene, ctx, path, self.speed.v_max, self.vehicle, v_set)
            return path, ref, s0, plan_one(ref, obs, v0, a0, s0, None, road, self.vehicle, self.speed, w, buffer)

        # every path has one shape: one vmapped speed plan (the DP is traced once)
        paths = [rp] if bp is None else [bp, rp]
        if self.lane_change:
            ahead_lane = jnp.maximum(v0, ctx.v_set) * self.horizon + 20.0
            l_nb, runs, goal_ok = neighbour_lane(scene, ctx, ahead_lane)
            # where the route leaves the car's lane within reach (it changes lanes, or the car is
            # beside it), the other path stays in the car's lane instead, while that lane runs on
            u = path_stations(rp.s.shape[0], 20.0, self.path_ahead, f)
            l_car, near = car_lane(scene, ctx, ctx.s + u)
            reach = (u >= 0) & (u <= ahead_lane)
            width = jnp.maximum(ctx.lane_width[scene.own_lane], 1.0)
            leaves = jnp.any(reach & (jnp.abs(l_car) > 0.5 * width)) & jnp.all(near | ~reach)
            l_goal = jnp.interp(ctx.goal_s[0] - ctx.s, u, l_car)
            goal_near = ctx.goal_s[0] - ctx.s < ahead_lane
            goal_car = ~goal_near | ((l_goal >= ctx.goal_l[0]) & (l_goal <= ctx.goal_l[1]))
            l_nb = jnp.where(leaves, l_car, l_nb)  # (N,)
            runs = leaves | runs
            goal_ok = jnp.where(leaves, goal_car, goal_ok)
            paths.append(self.route_path(scene, ctx, ego, rp.s.shape[0], l_nb))
        nb = len(paths) - 1  # the neighbour lane's path (with lane_change)
        buffers = [self.speed.buffer] * len(paths)
        if self.tight:  # the first path again, without the clearance buffer
            paths.append(paths[0])
            buffers.append(0.0)
        stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *paths)
        every = jax.vmap(on)(stacked, jnp.asarray(buffers, f))
        plans = every[3]
        if bp is None:
            keep = jnp.asarray(0)
        else:
            # the path decision sees blocking obstacles only; the speed plan on each path sees
            # the moving ones too: the bounds path is taken when its speed plan is collision-free
            # and the route path's is not cheaper by BOUNDS_YIELD lane changes (a bounds path
            # that keeps behind a slow car while the route moves over into a free lane), or when
            # neither is collision-free and it costs less (a bypass into a lane where traffic
            # already is would be hit whatever the speed; then the car stays in its lane and stops).
            bp_ok = use  # the bounds path itself is usable (its QP solved, clear, not blocked)
            route_cheaper = plans.feasible[1] & (plans.cost[1] + BOUNDS_YIELD * w.w_lane_change < plans.cost[0])
            use = use & ((plans.feasible[0] & ~route_cheaper) | (~plans.feasible[1] & (plans.cost[0] <= plans.cost[1])))
            keep = jnp.where(use, 0, 1)
        change = jnp.asarray(False)
        costs = jnp.full((2,), jnp.inf, f)  # the lane's and the lane change's, as compared
        if self.lane_change:
            # the neighbour lane when its plan is collision-free and cheaper than the lane's by the
            # share of a lane still to move over (plus a margin: with nothing to gain the car goes
            # back to the route's lane); not toward a goal region ahead in another lane unless the
            # lane's own plan collides
            shift = jnp.abs(jnp.interp(0.0, u, l_nb) - ctx.l) / width
            # hysteresis from the car's own motion: a move under way (the car's slope to the route
            # toward one lane) costs LANE_HOLD lane changes to turn back
            _, slope, _ = _frenet_start(scene.route, ctx.s, ctx.l, ego.heading, ego.kappa)
            side = jnp.sign(jnp.interp(ahead_lane, u, l_nb))  # the other lane's side of the route
            toward = slope * side  # > 0: moving over to the other lane's side
            hold = w.w_lane_change * LANE_HOLD
            c_nb = (
                plans.cost[nb]
                + w.w_lane_change * (shift + LANE_RETURN_MARGIN)
                + jnp.where(toward < -LANE_MOVING, hold, 0.0)
            )
            c_keep = plans.cost[keep] + jnp.where(toward > LANE_MOVING, hold, 0.0)
            there = shift < 0.5
            under_way = there | (toward > LANE_MOVING)  # in that lane, or moving over to it
            # moving over must get the car further and keep it going (not stop in the other lane
            # instead), unless the lane's own plan collides or costs far more (a car closing in from
            # behind)
            further = (plans.s[nb, -1] > plans.s[keep, -1] + LANE_GAIN) & (plans.v[nb, -1] > LANE_GO_V)
            decisive = c_nb + LANE_DECISIVE * w.w_lane_change < c_keep
            gain = further | decisive | ~plans.feasible[keep] | under_way
            ok_nb = runs & (goal_ok | ~plans.feasible[keep]) & gain & plans.feasible[nb]
            change = ok_nb & (c_nb < c_keep)
            costs = jnp.stack([c_keep, jnp.where(ok_nb, c_nb, jnp.inf)]).astype(f)
            use = use & ~change
            keep = jnp.where(change, nb, keep)
        tight = jnp.asarray(False)
        if self.tight:
            # the plan without the buffer where the first path's buffered plan collides or is hit
            # from behind for longer than TIGHT_GAIN_S, and the plain overlap leaves a way
            # (instead of the first path's plan, or of the route path's where the first is a usable
            # bounds path: both keep the lane)
            it = len(paths) - 1
            gain = REAR_CONTACT * self.speed.big * TIGHT_GAIN_S
            lane_kept = (keep == 0) if bp is None else (keep == 0) | ((keep == 1) & bp_ok)
            tight = lane_kept & plans.feasible[it] & (plans.cost[it] < plans.cost[keep] - gain)
            keep = jnp.where(tight, it, keep)
            if bp is not None:
                use = jnp.where(tight, True, use)
        path, ref, s0, plan = jax.tree_util.tree_map(lambda x: x[keep], every)
        prof = smooth_plan(plan, v0, a0, self.speed, self.smooth)
        return dict(
            ctx=ctx,
            path=path,
            bounds=pp,
            use_bounds=use,
            lane_change=change,
            tight=tight,
            lane_costs=costs,
            path_plans=plans,
            ref=ref,
            s0=s0,
            plan=plan,
            profile=prof,
        )

    def plan(self, params: CostWeights, scene, ego: EgoState, step) -> PlanOutput:
        return self.output(self.speed_plan(params, scene, ego, step))

    def output(self, c: dict) -> PlanOutput:
        """The ``PlanOutput`` of a cycle (``speed_plan``'s dict): the profile composed along
        the path, ``ok`` and ``info``."""
        plan, prof, pp = c["plan"], c["profile"], c["bounds"]
        traj = compose_profile(c["ref"], c["s0"], prof)
        finite = jnp.all(jnp.isfinite(traj.x)) & jnp.all(jnp.isfinite(traj.y)) & jnp.all(jnp.isfinite(traj.v))
        cl = plan.scene.classified
        ok = plan.feasible & prof.ok & (prof.slack < 0.05) & finite
        f = traj.x.dtype
        no = jnp.asarray(False)
        info = {
            "dp_feasible": plan.feasible,
            "qp_ok": prof.ok,
            "qp_slack": prof.slack,
            "qp_r_prim": prof.r_prim,
            "qp_r_dual": prof.r_dual,
            "blocking": cl.is_blocking,
            "behind": cl.behind,
            "no_bypass": cl.no_bypass,
            "blind_zone": cl.blind_zone,
            # the path: the bounds path used, or the route path as the fallback and why
            "path_bounds": c["use_bounds"],
            "lane_change": c["lane_change"],
            # the plan without the clearance buffer was taken (``tight``)
            "tight": c["tight"],
            # the lane's plan and the neighbour lane's as compared (inf: not an option)
            "lane_cost_keep": c["lane_costs"][0],
            "lane_cost_change": c["lane_costs"][1],
            "path_qp_ok": no if pp is None else pp.qp_ok,
            "path_clear": no if pp is None else pp.collision_free,
            "path_blocked": no if pp is None else jnp.isfinite(pp.blocked_s),
            "path_stop_s": c["path"].blocked_s.astype(f),
            "path_max_abs_l": jnp.max(jnp.abs(c["path"].l)).astype(f),
        }
        return PlanOutput(traj, ok, info)


def plan_speed_for(planner: PathSpeedPlanner, scene, ego: EgoState, step, params: CostWeights | None = None):
    """The DP plan and the executed profile of one cycle (for pictures): ``(plan, profile)``
    (``params``: default ``planner.init_params()``)."""
    c = planner.speed_plan(planner.init_params() if params is None else params, scene, ego, step)
    return c["plan"], c["profile"]
