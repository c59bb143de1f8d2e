"""What a road planner reads off a ``Scene`` at one planning cycle (jittable, one scene).

``road_context(scene, ego, step, horizon_steps, vehicle)`` gathers, once per cycle, the
quantities every road planner needs, so that no planner recomputes them its own way:

- the obstacle predictions from ``step`` on (``Obstacles.window``: static obstacles held,
  dynamic ones gone when their recording ends) and their Frenet coordinates on the route;
- the car's Frenet state on the route; the lanes beside the route and the road's edges
  at the car; the set speed (the lowest speed limit over the distance ahead the car covers
  in ``SPEED_LOOKAHEAD`` seconds, at least 30 m: a car slows before a lower limit);
- the goal in route coordinates with its time window relative to now;
- the leader: the nearest obstacle ahead whose box overlaps the car's lane corridor now;
- traffic lights as stop targets (``light_targets``): every stop line on the route (``Scene.lights``)
  whose light forbids crossing becomes a virtual stopped obstacle, appended after the scene's
  obstacles (so every planner that reads the context stops for it the way it stops behind a
  stopped car): a ``LIGHT_DEPTH`` m deep box from the stop line on, across the whole road
  (``road_right .. road_left`` at the line, ``LIGHT_SIDE`` m beyond each edge), valid at the
  future steps where the light shows red or red-yellow, and at yellow steps while the car can
  still stop before the line at ``YELLOW_DECEL`` (a yellow it cannot stop for is driven through);
  never once the car's front is past the line (a red it has already entered is cleared). Green
  and inactive lights let the car through.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from jaxplan.geometry.frenet import ref_state, to_frenet
from jaxplan.planner import EgoState
from jaxplan.scenarios.lights import YELLOW, colors_at, must_stop
from jaxplan.types import Obstacles, VehicleParams, pytree_dataclass

SPEED_LOOKAHEAD = 3.0  # s
NO_LEADER = 1e4  # gap (m) reported when nothing is ahead
YELLOW_DECEL = 4.0  # m/s^2: a yellow light is a stop target while the car can stop before the line at this
LIGHT_DEPTH = 1.0  # m: depth of a stop line's virtual box, from the line on
LIGHT_SIDE = 0.5  # m: the box reaches this far beyond the road's edges


def curvature_speed(kappa, a_lat):
    """``(...)`` the speed at which curvature ``kappa (...)`` (1/m) takes lateral acceleration
    ``a_lat`` (m/s^2): ``sqrt(a_lat / |kappa|)`` (finite on a straight: ``|kappa|`` at least 1e-6)."""
    return jnp.sqrt(a_lat / jnp.maximum(jnp.abs(kappa), 1e-6))


def curve_speed(scene, s, reach, a_lat, decel, n: int = 32):
    """``()`` the highest speed at ``s`` from which the car can slow, at ``decel`` (m/s^2), to
    the curvature limit ``sqrt(a_lat / |kappa|)`` of the route at every point of the
    ``reach`` metres ahead (``n`` samples): ``min_i sqrt(v_curve(s_i)^2 + 2 decel (s_i - s))``."""
    f = scene.route.xy.dtype
    d = jnp.linspace(0.0, 1.0, n, dtype=f) * reach
    v_curve = curvature_speed(route_sample(scene, scene.route.kappa, s + d), a_lat)
    return jnp.min(jnp.sqrt(v_curve**2 + 2.0 * decel * d))


GOAL_SPEEDUP = 1.2  # the set speed may exceed the limit by this factor to reach a goal before its window closes
GOAL_INSIDE = 2.0  # m: the timing aims this far inside the goal region's ends (at most a quarter of its length)
CURVE_LAT_ACC = 0.8  # share of the comfortable lateral acceleration the set speed leaves for curves
CURVE_DECEL = 2.0  # m/s^2: the set speed slows this gently before a curve or a dead end


def goal_region_ahead(goal_s, s_centre):
    """``()`` bool: a goal region lies on the route (``goal_s (2,)`` finite) and its far end is
    ahead of the car's box centre at station ``s_centre ()``."""
    goal_s = jnp.asarray(goal_s)
    return jnp.all(jnp.isfinite(goal_s)) & (goal_s[1] > s_centre)


def goal_inside(goal_s):
    """``(2,)`` the part of the goal region ``goal_s (2,)`` that planners aim for: its ends moved
    ``GOAL_INSIDE`` metres in (at most a quarter of its length each), so that arriving on time
    does not mean arriving on its edge."""
    goal_s = jnp.asarray(goal_s)
    m = jnp.minimum(GOAL_INSIDE, 0.25 * jnp.maximum(goal_s[1] - goal_s[0], 0.0))
    m = jnp.where(jnp.isfinite(m), m, 0.0)
    return jnp.stack([goal_s[0] + m, goal_s[1] - m])


def goal_speed(v_set, s_centre, goal_s, goal_t, goal_v=None, reach=None):
    """The set speed ``()`` bent towards the goal's timing and speed: no faster than reaching
    the far end of the goal region when its time window opens, no slower than reaching its near
    end when the window closes (both ends moved in, ``goal_inside``; at most ``GOAL_SPEEDUP``
    times the limit); once the region is within ``reach``, inside the goal's speed range (a
    tenth of the range in from either end).

    Args:
        v_set: ``()`` the speed limit ahead; s_centre: ``()`` the car's box centre on the route.
        goal_s: ``(2,)`` the goal region on the route; goal_t: ``(2,)`` its time window from now.
        goal_v: ``(2,)`` the goal's speed range (None or infinite: none); reach: ``()`` metres
            ahead within which the goal's speed range holds (the plan's reach).
    """
    has = jnp.all(jnp.isfinite(goal_s))
    aim = goal_inside(goal_s)
    d_far = jnp.where(has, aim[1] - s_centre, jnp.inf)
    d_near = jnp.where(has, aim[0] - s_centre, 0.0)
    v_hi = jnp.where(goal_t[0] > 0.1, jnp.maximum(d_far, 0.0) / jnp.maximum(goal_t[0], 0.1), jnp.inf)
    v_lo = jnp.where(
        jnp.isfinite(goal_t[1]) & (goal_t[1] > 0.1), jnp.maximum(d_near, 0.0) / jnp.maximum(goal_t[1], 0.1), 0.0
    )
    v = jnp.maximum(jnp.minimum(v_set, v_hi), jnp.minimum(v_lo, GOAL_SPEEDUP * v_set))
    if goal_v is not None:
        lo, hi = goal_v[0], goal_v[1]
        span = jnp.where(jnp.isfinite(hi - lo), hi - lo, 0.0)
        near = has & (goal_s[0] - s_centre < reach) & (goal_s[1] > s_centre)
        v_in = jnp.clip(
            v,
            jnp.where(jnp.isfinite(lo), lo + 0.1 * span, -jnp.inf),
            jnp.where(jnp.isfinite(hi), hi - 0.1 * span, jnp.inf),
        )
        v = jnp.where(near, jnp.maximum(v_in, 0.0), v)
    return jnp.where(has, v, v_set)


def set_speed(scene, ctx: RoadContext, ego: EgoState, vehicle: VehicleParams, horizon: float, lat_acc):
    """``()`` the speed a road planner cruises at this cycle: the limit ahead (``ctx.v_set``)
    bent towards the goal's timing and speed (``goal_speed``, the goal's speed range within the
    reach ``max(v, 5) * horizon``), never above the speed from which the car slows at
    ``CURVE_DECEL`` to the route's curvature limit (``CURVE_LAT_ACC * lat_acc``) on that reach,
    nor, without a goal region ahead, above the speed from which it stops as gently before a
    dead end of the road (``ctx.route_end_s``, the car's front)."""
    f = scene.route.xy.dtype
    s_centre = ctx.s + jnp.asarray(vehicle.center_offset, f)
    reach = jnp.maximum(jnp.asarray(ego.v, f), 5.0) * horizon
    v = goal_speed(ctx.v_set, s_centre, ctx.goal_s, ctx.goal_t, ctx.goal_v, reach)
    v = jnp.minimum(v, curve_speed(scene, ctx.s, reach, CURVE_LAT_ACC * lat_acc, CURVE_DECEL))
    d_end = ctx.route_end_s - (ctx.s + front_offset(vehicle, f))
    dead_end = ~goal_region_ahead(ctx.goal_s, s_centre) & jnp.isfinite(d_end)
    v_end = gentle_stop_speed(jnp.where(jnp.isfinite(d_end), d_end, 0.0))
    return jnp.where(dead_end, jnp.minimum(v, v_end), v)


def gentle_stop_speed(distance):
    """``(...)`` the speed from which the car stands after ``distance (...)`` metres, slowing at
    ``CURVE_DECEL`` (0 where ``distance <= 0``; ``inf`` where it is ``inf``)."""
    return jnp.sqrt(2.0 * CURVE_DECEL * jnp.maximum(distance, 0.0))


def route_sample(scene, values, s):
    """Linear interpolation of per-route-point ``values (..., R)`` at arc lengths ``s (...)``
    (clamped to the route's ends)."""
    return jnp.vectorize(lambda v, q: jnp.interp(q, scene.route.s, v), signature="(r),()->()")(values, s)


@pytree_dataclass(
    data_fields=(
        "obstacles",
        "obstacle_s",
        "obstacle_l",
        "s",
        "l",
        "v_set",
        "lane_offset",
        "lane_width",
        "lane_valid",
        "lane_same_dir",
        "road_left",
        "road_right",
        "t_now",
        "goal_t",
        "goal_s",
        "goal_l",
        "goal_v",
        "route_end_s",
        "leader_gap",
        "leader_v",
        "leader_index",
        "ego",
    )
)
class RoadContext:
    """One planning cycle's view of the scene (``K`` obstacles, ``H`` steps, ``L`` lanes).

    Attributes:
        obstacles: ``Obstacles`` ``(K, H, 5)`` at ``t = 0, dt, ...`` from now.
        obstacle_s, obstacle_l: ``(K, H)`` Frenet coordinates of their centres on the route.
        s, l: ``()`` the car's reference point on the route.
        v_set: ``()`` set speed (m/s) from the speed limits ahead.
        lane_offset, lane_width, lane_valid, lane_same_dir: ``(L,)`` lanes at the car's ``s``.
        road_left, road_right: ``()`` the drivable corridor's edges at ``s``.
        t_now: ``()`` time of this cycle from the scenario start.
        goal_t: ``(2,)`` the goal's time window from now (s); goal_s, goal_l, goal_v: ``(2,)``.
        route_end_s: ``()`` where the mapped road ends on the route; without a goal region ahead,
            ``inf`` where the car's front cannot get there before the goal's time window closes
            (the drive ends then) even at its speed or the highest speed limit within the
            look-ahead, whichever is higher.
        leader_gap: ``()`` bumper-to-bumper distance (m) along the route to the leader now
            (``NO_LEADER`` without one); leader_v: ``()`` its speed along the route;
            leader_index: ``()`` its obstacle index (-1 without one).
        ego: the ``EgoState`` the context was built for (heading, speed, curvature).
    """

    obstacles: Any
    obstacle_s: Any
    obstacle_l: Any
    s: Any
    l: Any
    v_set: Any
    lane_offset: Any
    lane_width: Any
    lane_valid: Any
    lane_same_dir: Any
    road_left: Any
    road_right: Any
    t_now: Any
    goal_t: Any
    goal_s: Any
    goal_l: Any
    goal_v: Any
    route_end_s: Any
    leader_gap: Any
    leader_v: Any
    leader_index: Any
    ego: Any = None


def front_offset(vehicle: VehicleParams, dtype):
    """``()`` metres from the car's reference point to its front bumper."""
    return jnp.asarray(vehicle.front_offset, dtype)


def light_targets(scene, s_front, v, step, horizon_steps: int):
    """The stop lines' virtual obstacles of one scene (see the module docstring; ``NL`` lines).

    Args:
        scene: ``Scene`` (one) with ``lights``.
        s_front: ``()`` the arc length of the car's front on the route now; v: ``()`` its speed.
        step: ``()`` int, the simulation step now.
        horizon_steps: ``H`` (static).

    Returns:
        ``Obstacles`` ``(NL, H, 5)`` (valid where the line is a stop target), and their Frenet
        ``s, l`` ``(NL, H)``.
    """
    lights = scene.lights
    ref = scene.route
    f = ref.xy.dtype
    H = horizon_steps
    color = colors_at(lights, jnp.asarray(step) + jnp.arange(H)).T  # (NL, H)
    d = jnp.asarray(lights.s, f) - s_front  # (NL,) front to line
    can_stop = d >= jnp.square(jnp.maximum(v, 0.0)) / (2.0 * YELLOW_DECEL)
    stop = must_stop(color) | ((color == YELLOW) & can_stop[:, None])
    stop = stop & (jnp.asarray(lights.valid) & (d >= 0.0))[:, None]
    s_c = jnp.asarray(lights.s, f) + 0.5 * LIGHT_DEPTH
    left = route_sample(scene, scene.road_left, lights.s) + LIGHT_SIDE
    right = route_sample(scene, scene.road_right, lights.s) - LIGHT_SIDE
    l_c = 0.5 * (left + right)
    xy, th, _, _ = ref_state(ref, s_c)
    c = xy + l_c[:, None] * jnp.stack([-jnp.sin(th), jnp.cos(th)], -1)
    box = jnp.stack([c[:, 0], c[:, 1], jnp.full_like(th, LIGHT_DEPTH), left - right, th], -1)  # (NL, 5)
    NL = box.shape[0]
    boxes = jnp.broadcast_to(box[:, None, :], (NL, H, 5)).astype(f)
    t = jnp.arange(H, dtype=f) * scene.dt
    obs = Obstacles(boxes, stop, t, jnp.zeros((NL,), bool))
    return obs, jnp.broadcast_to(s_c[:, None], (NL, H)), jnp.broadcast_to(l_c[:, None], (NL, H))


def road_context(scene, ego: EgoState, step, horizon_steps: int, vehicle: VehicleParams) -> RoadContext:
    """The ``RoadContext`` of one scene at simulation step ``step`` (see the module docstring).

    Its obstacles are the scene's ``K`` followed by one virtual obstacle per stop line
    (``light_targets``) when the scene has any."""
    obs: Obstacles = scene.obstacles.window(step, horizon_steps)
    dt = scene.dt
    ref = scene.route
    f = ref.xy.dtype
    s, l = to_frenet(ref, jnp.stack([ego.x, ego.y]).astype(f))
    sl = scene.obstacles.window_of(scene.obstacle_sl, step, horizon_steps)
    os_, ol = sl[..., 0], sl[..., 1]
    lights = getattr(scene, "lights", None)
    if lights is not None and lights.s.shape[-1]:  # static: scenes without stop lines keep K obstacles
        lo, ls, ll = light_targets(scene, s + front_offset(vehicle, f), jnp.asarray(ego.v, f), step, horizon_steps)
        obs = Obstacles(
            jnp.concatenate([obs.boxes, lo.boxes.astype(obs.boxes.dtype)]),
            jnp.concatenate([obs.valid, lo.valid]),
            obs.t,
            jnp.concatenate([jnp.asarray(obs.static, bool), lo.static]),
        )
        os_, ol = jnp.concatenate([os_, ls.astype(os_.dtype)]), jnp.concatenate([ol, ll.astype(ol.dtype)])
    ahead = jnp.maximum(30.0, ego.v * SPEED_LOOKAHEAD)
    probe = s + jnp.linspace(0.0, 1.0, 16, dtype=f) * ahead
    limits = route_sample(scene, scene.speed_limit, probe)  # (16,) the speed limits ahead
    v_set = jnp.min(limits)
    at = lambda v: route_sample(scene, v, s)
    lane_valid = route_sample(scene, scene.lane_valid.astype(f), s) > 0.5
    same = route_sample(scene, scene.lane_same_dir.astype(f), s) > 0.5
    t_now = jnp.asarray(step, f) * dt
    # the leader: nearest obstacle ahead (now) whose lateral extent overlaps the car's
    half_w = 0.5 * jnp.asarray(vehicle.width, f)
    b0 = obs.boxes[:, 0]
    ext = 0.5 * (
        jnp.abs(b0[:, 2] * jnp.sin(b0[:, 4] - _heading_at(ref, os_[:, 0])))
        + jnp.abs(b0[:, 3] * jnp.cos(b0[:, 4] - _heading_at(ref, os_[:, 0])))
    )
    ext_s = 0.5 * (
        jnp.abs(b0[:, 2] * jnp.cos(b0[:, 4] - _heading_at(ref, os_[:, 0])))
        + jnp.abs(b0[:, 3] * jnp.sin(b0[:, 4] - _heading_at(ref, os_[:, 0])))
    )
    front = s + front_offset(vehicle, f)
    gap = os_[:, 0] - ext_s - front
    in_lane = jnp.abs(ol[:, 0] - l) < ext + half_w
    cand = obs.valid[:, 0] & in_lane & (os_[:, 0] > s)
    gap = jnp.where(cand, gap, NO_LEADER)
    k = jnp.argmin(gap)
    has = gap[k] < NO_LEADER
    hdg = _heading_at(ref, os_[:, 0])
    if obs.boxes.shape[1] > 1:
        vel = (obs.boxes[:, 1, :2] - obs.boxes[:, 0, :2]) / dt
        ok1 = obs.valid[:, 1] & obs.valid[:, 0]
    else:
        vel, ok1 = jnp.zeros_like(b0[:, :2]), obs.valid[:, 0]
    v_along = jnp.where(ok1, vel[:, 0] * jnp.cos(hdg) + vel[:, 1] * jnp.sin(hdg), 0.0)
    # without a goal region ahead, the drive ends when the goal's time window closes: how far the car's
    # front can get by then, at its speed or the highest limit ahead, whichever is higher (a dead end
    # beyond is no end to plan for; with a goal region ahead the end stays, a place the car may stop)
    t_close = scene.goal.time[1] - t_now
    v_reach = jnp.maximum(ego.v, jnp.max(limits))
    reach = jnp.where(jnp.isfinite(t_close), v_reach * jnp.maximum(t_close, 0.0), jnp.inf)
    reach = jnp.where(goal_region_ahead(scene.goal.s_range, s + jnp.asarray(vehicle.center_offset, f)), jnp.inf, reach)
    return RoadContext(
        obs,
        os_,
        ol,
        s,
        l,
        v_set,
        at(scene.lane_offset),
        at(scene.lane_width),
        lane_valid,
        same,
        at(scene.road_left),
        at(scene.road_right),
        t_now,
        scene.goal.time - t_now,
        scene.goal.s_range,
        scene.goal.l_range,
        scene.goal.speed,
        jnp.where(front + reach >= scene.route_end_s, scene.route_end_s, jnp.inf),
        jnp.where(has, gap[k], NO_LEADER),
        jnp.where(has, v_along[k], 0.0),
        jnp.where(has, k, -1),
        ego,
    )


def _heading_at(ref, s):
    return ref_state(ref, s)[1]
