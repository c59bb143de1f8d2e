"""``pathspeed``: the decoupled path-speed planner as a road ``Planner`` (``jaxplan.planner``).

Each cycle (one scene, jittable; the simulator batches it with ``jax.vmap``):

1. the ``RoadContext`` (predictions from this step, the lane speed limits, the goal);
2. the **path** (built by ``jaxplan.speed.paths``): ``jaxplan.bounds.plan_path`` (path
   decision around the blocking obstacles, bounds, path QP, recomputed at the path's heading)
   from the car, with the
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
   is planned once more without the clearance buffer around obstacles and the crossing margin,
   a way past that only the exact overlap leaves open, taken when the buffered plan is hit from behind
   or collides while a vehicle is behind the car (``info["tight"]``);
3. the **speed**: the ST boundaries of the predictions on that path (blocking,
   non-blocking with decisions, a wall before the path's blockage and the end of the
   map), the DP over the reachable band (``dp.py``, its costs ``costs.py``) towards the set speed
   (``jaxplan.plan_context.set_speed``, the lattice's) with the lane speed limit, the
   curvature limit, the time-headway follow distance and the goal's window, then the
   smoothing QP (``smooth.py``) for the executed profile;
4. the **composed trajectory**: the profile along the path, ``horizon_steps`` points every
   ``dt`` from the car.

``describe`` turns the ``info`` of a few cycles into words for the drive report: the paths
taken, how many plans found no collision-free profile, and what blocked the last one.

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
import numpy as np

from jaxplan.bounds.path_planner import PathConfig, plan_path
from jaxplan.plan_context import (
    RoadContext,
    gentle_stop_speed,
    goal_region_ahead,
    road_context,
    route_sample,
    set_speed,
)
from jaxplan.planner import SIM_VEHICLE, EgoState, PlanOutput, tally
from jaxplan.speed.compose import compose_profile
from jaxplan.speed.costs import REAR_CONTACT
from jaxplan.speed.dp import plan_one
from jaxplan.speed.paths import (
    RoutePath,
    bounds_route_path,
    car_lane,
    frenet_start,
    merging_in,
    other_lane,
    own_lane_width,
    path_reference,
    route_path,
    total_points,
)
from jaxplan.speed.problem import CostWeights, SpeedConfig, SpeedRoad
from jaxplan.speed.smooth import SmoothWeights, smooth_plan
from jaxplan.speed.st_boundary import car_extent
from jaxplan.types import Obstacles, VehicleParams, weights_from


def speed_road(scene, ctx: RoadContext, path, v_max: float, vehicle: VehicleParams, v_set=0.0) -> SpeedRoad:
    """What the road asks of the speed on ``path``: the lane speed limit at each path point
    (read at its route station; raised to the set speed ``v_set`` where that is higher: a goal
    that cannot be met at the limit, ``set_speed``), a stop before the path's blockage (the car's reference point
    before ``path.blocked_s``) and, without a goal region ahead (the drive ends there; the map
    often ends just past it), before the end of the mapped road (the car's front; the limit
    falls as the set speed's does, slowing at ``CURVE_DECEL`` to stand there), the
    goal's stations (box centre, along the route), time window and speeds, where the path
    leaves the car's lane (``lane_leave_s``)."""
    f = path.xy.dtype
    lim = route_sample(scene, scene.speed_limit, path.route_s)
    front, _ = car_extent(vehicle, f)
    end = ctx.route_end_s - ctx.s
    goal_ahead = goal_region_ahead(ctx.goal_s, ctx.s + jnp.asarray(vehicle.center_offset, f))
    end = jnp.where(jnp.isfinite(end) & ~goal_ahead, end, jnp.inf)
    stop = jnp.minimum(path.blocked_s + front, end)
    # a dead end is approached as gently as the set speed does, not at the DP's limits
    v_end = gentle_stop_speed(jnp.where(jnp.isfinite(end), end - front - path.s, jnp.inf))
    goal_s = ctx.goal_s - ctx.s
    return SpeedRoad(
        path.s,
        jnp.minimum(jnp.minimum(jnp.maximum(lim, v_set), v_end), v_max),
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
# this many seconds of contact with a vehicle behind (REAR_CONTACT), or collides while one is behind
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
            obstacles and no crossing margin (``speed.buffer`` and ``speed.pass_margin`` 0: only
            the exact overlap blocks), and take that plan
            where the lane-keeping plan (the first path's, or the route path's where the first
            is a usable bounds path) collides while a vehicle is behind the car, or costs more by
            ``TIGHT_GAIN_S`` seconds of contact with a vehicle behind (stopping for an oncoming car
            that passes 0.1 m clear, and being hit from behind); ``info["tight"]``.
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
        total, ext = total_points(self.path.n_points, self.ext_points)
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
        ``n_obstacles`` (the scene's obstacle count: ``ctx``'s obstacles beyond it are stop
        lines), ``path`` (the ``RoutePath`` the speed is planned on), ``bounds`` (the bounds
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
        # vehicles moving over into the car's lane: passed without the crossing margin when they
        # drive the car's way
        lane = car_lane(scene, ctx, ctx.s + rp.s)  # the car's lane at the route path's stations
        merging = merging_in(ctx, rp.s, lane[0])

        def on(path, buffer, margin):
            ref, s0 = path_reference(path)
            road = speed_road(scene, ctx, path, self.speed.v_max, self.vehicle, v_set)
            plan = plan_one(ref, obs, v0, a0, s0, None, road, self.vehicle, self.speed, w, buffer, merging, margin)
            return path, ref, s0, plan

        # every path has one shape: one vmapped speed plan (the DP is traced once)
        paths = [rp] if bp is None else [bp, rp]
        if self.lane_change:
            ahead_lane = jnp.maximum(v0, ctx.v_set) * self.horizon + 20.0
            u = rp.s  # the route path's stations, the other lane's path's too
            l_nb, runs, goal_ok = other_lane(scene, ctx, u, ahead_lane, lane)  # (N,), (), ()
            paths.append(self.route_path(scene, ctx, ego, rp.s.shape[0], l_nb))
        nb = len(paths) - 1  # the neighbour lane's path (with lane_change)
        buffers = [self.speed.buffer] * len(paths)
        margins = [True] * len(paths)
        if self.tight:  # the first path again, without the clearance buffer and the crossing margin
            paths.append(paths[0])
            buffers.append(0.0)
            margins.append(False)
        stacked = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *paths)
        every = jax.vmap(on)(stacked, jnp.asarray(buffers, f), jnp.asarray(margins))
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
            shift = jnp.abs(jnp.interp(0.0, u, l_nb) - ctx.l) / own_lane_width(scene, ctx)
            # hysteresis from the car's own motion: a move under way (the car's slope to the route
            # toward one lane) costs LANE_HOLD lane changes to turn back
            _, slope, _ = frenet_start(scene.route, ctx.s, ctx.l, ego.heading, ego.kappa)
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
            # a lane-keeping plan that collides yields to it only with a vehicle behind the car
            # (with none, stopping short of the buffer is safe: an obstacle beside the path that
            # the path moves toward on later cycles is not passed at a hand's breadth)
            followed = jnp.any(plans.scene.classified.rear.hit[keep])
            cheaper = plans.cost[it] < plans.cost[keep] - gain
            tight = lane_kept & plans.feasible[it] & cheaper & (plans.feasible[keep] | followed)
            keep = jnp.where(tight, it, keep)
            if bp is not None:
                use = jnp.where(tight, True, use)
        path, ref, s0, plan = jax.tree_util.tree_map(lambda x: x[keep], every)
        prof = smooth_plan(plan, v0, a0, self.speed, self.smooth)
        return dict(
            ctx=ctx,
            n_obstacles=scene.obstacles.boxes.shape[-3],  # the scene's; the stop lines follow in ctx
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

    def describe(self, info: dict) -> str:
        """Words for the ``info`` of a few consecutive plans (numpy ``(C,)`` each, ``blocking``
        ``(C, K)``): the path each took, the plans with no collision-free speed profile and the
        obstacles that blocked the last one."""
        names = [
            "lane change" if c else "no clearance" if t else "bounds path" if b else "route path"
            for c, t, b in zip(info["lane_change"], info["tight"], info["path_bounds"])
        ]
        words = tally("paths", names)
        stuck = int(np.sum(~np.asarray(info["dp_feasible"], bool)))
        if stuck:
            words += f"; {stuck} with no collision-free speed profile"
        K = int(np.asarray(info["n_obstacles"])[-1])
        held = [f"obstacle {k}" if k < K else "a stop line" for k in np.flatnonzero(np.asarray(info["blocking"])[-1])]
        if held:
            words += "; blocking the last: " + ", ".join(dict.fromkeys(held))
        return words

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
            "blocking": cl.is_blocking,  # the scene's obstacles, then the stop lines (light_targets)
            "n_obstacles": jnp.asarray(c["n_obstacles"]),
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
