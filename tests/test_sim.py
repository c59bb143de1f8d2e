"""Closed-loop driving: Scene building, metrics against independent oracles, the rollout."""
import dataclasses
import functools
import json
import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shapely.geometry import Point, Polygon
from shapely.ops import unary_union

from jaxplan.baselines import BrakePlanner, IDMPlanner
from jaxplan.compile_options import NO_YNN, options_supported, options_key
from jaxplan.plan_context import road_context
from jaxplan.planner import SIM_VEHICLE, EgoState
from jaxplan.scenarios import builtin
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.scenarios.build import build_scene
from jaxplan.scenarios.loader import parse_scenario
from jaxplan.scenarios.scene import SceneRecord
from jaxplan.sim import SimConfig, rollout
from jaxplan.sim.metrics.goal import goal_reached, heading_in
from jaxplan.sim.metrics.offroad import offroad_steps
from jaxplan.sim.metrics.overlap import overlap
from jaxplan.sim.rollout import DriveLog

CAR = BrakePlanner().vehicle


def _road_dict(obstacles=(), n_lanes=2, v0=12.0, kappa=0.0, heading=0.3, goal_t=(0.0, 12.0), start_lane=0):
    """A scenario object: straight (or curved) road of ``n_lanes``, the car in ``start_lane``."""
    road = builtin.SyntheticRoad(kappa, heading)
    start, th0 = road.pose(builtin.START_S, start_lane * builtin.LANE)
    gc, gth = road.pose(builtin.START_S + 120.0, 0.5 * (n_lanes - 1) * builtin.LANE)
    obs = [builtin.road_obstacle(i + 1, road, *o) if len(o) == 2 else builtin.road_obstacle(i + 1, road, o[0], o[1], role=o[2])
           for i, o in enumerate(obstacles)]
    return {"id": "TEST", "dt": 0.1, "lanelets": builtin.road_lanelets(road, n_lanes, 20.0), "obstacles": obs,
            "planning_problems": [{"id": 1, "initial_state": {"t": 0.0, "position": start.tolist(),
                                                             "orientation": float(th0), "velocity": v0},
                                   "goals": [{"rectangle": {"center": gc.tolist(), "length": 20.0,
                                                            "width": n_lanes * builtin.LANE,
                                                            "orientation": float(gth)}, "time": list(goal_t)}]}]}


def _record(d):
    sc = parse_scenario(d, d["id"])
    scene, route = build_scene(sc)
    return SceneRecord(d["id"], scene, sc, route)


def test_scene_lanes_route_and_goal():
    d = _road_dict(n_lanes=3, start_lane=1)
    rec = _record(d)
    sc = rec.scene
    n = sc.lane_offset.shape[0] // 2
    at = np.argmin(np.abs(sc.route.s - sc.route_start_s))
    assert sc.lane_valid[n, at] and sc.lane_valid[n + 1, at] and sc.lane_valid[n - 1, at]
    assert not sc.lane_valid[n + 2, at] and not sc.lane_valid[n - 2, at]
    np.testing.assert_allclose([sc.lane_offset[n + 1, at], sc.lane_offset[n - 1, at]], [3.5, -3.5], atol=1e-3)
    np.testing.assert_allclose([sc.road_left[at], sc.road_right[at]], [5.25, -5.25], atol=1e-3)
    assert sc.goal.s_range[0] == pytest.approx(sc.route_start_s + 110.0, abs=0.5)
    np.testing.assert_allclose(sc.start[:4], [0.0, 0.0, d["planning_problems"][0]["initial_state"]["orientation"],
                                              12.0], atol=1e-9)
    sc.validate()


def test_a_scene_without_obstacles_has_one_invalid_one():
    """A scenario with no other road user: the scene holds one obstacle that is never valid (no
    zero-size arrays for the kernels), and a planning cycle's context finds no leader."""
    rec = _record(_road_dict())
    sc = rec.scene
    assert sc.obstacles.boxes.shape[0] == 1 and not sc.obstacles.valid.any()
    assert sc.obstacle_sl.shape[:2] == sc.obstacles.boxes.shape[:2] and sc.obstacle_type.shape == (1,)
    sc.validate()
    ego = EgoState.from_box_centre(jnp.asarray(sc.start), SIM_VEHICLE)
    ctx = road_context(sc, ego, 0, 71, SIM_VEHICLE)
    assert int(ctx.leader_index) == -1


@pytest.mark.parametrize("t_close, step, region, counts", [(14.0, 0, False, True), (4.0, 0, False, False),
                                                           (14.0, 100, False, False), (6.5, 0, False, True),
                                                           (5.5, 0, False, False), (4.0, 0, True, True)])
def test_a_dead_end_counts_only_where_the_car_can_reach_it_before_the_goal_window_closes(t_close, step, region, counts):
    """One lane of 150 m, the car at 15 m/s with its front about 120 m before the end, a limit of
    20 m/s, a goal of time only: the end of the road is where the planners' context has it only
    when the front, at 20 m/s, gets there before the window closes (the drive ends then): 14 s from
    now yes, 4 s no, 14 s from the start seen at 10 s no; 6.5 s and 5.5 s on either side of 6 s.
    With a goal region ahead the end stays (a place to stop in the region's time window)."""
    d = _road_dict(n_lanes=1, v0=15.0, goal_t=(t_close, t_close))
    for lane in d["lanelets"]:
        lane["left"], lane["right"] = lane["left"][:76], lane["right"][:76]  # 150 m from s = 0
    if region:  # 60-80 m ahead of the car
        goal = d["planning_problems"][0]["goals"][0]
        cx, cy = goal["rectangle"]["center"]
        goal["rectangle"]["center"] = [cx - 50.0 * np.cos(0.3), cy - 50.0 * np.sin(0.3)]
    else:
        del d["planning_problems"][0]["goals"][0]["rectangle"]
    sc = _record(d).scene
    ego = EgoState.from_box_centre(jnp.asarray(sc.start), SIM_VEHICLE)
    ctx = road_context(sc, ego, step, 71, SIM_VEHICLE)
    end = float(sc.route_end_s)
    to_end = end - (float(ctx.s) + SIM_VEHICLE.front_offset)
    assert 117.0 < to_end < 123.0 and np.isfinite(end)  # the scene is what the cases assume
    assert (float(ctx.route_end_s) == pytest.approx(end)) if counts else np.isinf(float(ctx.route_end_s))


def test_route_smoothing_keeps_lines_and_arcs_and_removes_kinks():
    """``smooth_polyline``: a straight line and a circular arc keep their shape (curvature of
    the arc within 1 % away from the ends); a kinked polyline (what lanelet centre lines are)
    gets a continuous curvature: its spike spread out, no point moved more than ``max_dev``."""
    from jaxplan.geometry.frenet import reference_line
    from jaxplan.scenarios.polylines import smooth_polyline

    def kappa(xy):
        ref = reference_line(jnp.asarray(xy))
        return np.asarray(ref.kappa), np.asarray(ref.s)

    u = np.arange(0.0, 200.0, 0.6)
    line = np.stack([u, 0.5 * u], -1) / np.sqrt(1.25)
    np.testing.assert_allclose(smooth_polyline(line, 15.0, 0.1), line, atol=1e-6)
    R = 40.0
    arc = R * np.stack([np.sin(u / R), 1 - np.cos(u / R)], -1)[: int(0.9 * np.pi * R / 0.6)]
    k, _ = kappa(smooth_polyline(arc, 15.0, 0.1))
    np.testing.assert_allclose(k[30:-30], 1.0 / R, rtol=0.01)
    # straights meeting at 3 degrees every 25 m (lanelet centre lines kink by a few degrees)
    pts = [np.zeros(2)]
    for i in range(8):
        a = np.radians(3.0) * (i % 2)
        pts.append(pts[-1] + 25.0 * np.array([np.cos(a), np.sin(a)]))
    from jaxplan.scenarios.polylines import arc_length, resample_polyline

    poly = np.asarray(pts)
    ds = arc_length(poly)
    kinked = resample_polyline(poly, ds, np.arange(0.0, ds[-1], 0.6))
    sm = smooth_polyline(kinked, 15.0, 0.1)
    assert np.linalg.norm(sm - kinked, axis=1).max() <= 0.1 + 1e-9
    (k0, s0), (k1, s1) = kappa(kinked), kappa(sm)
    dk0 = np.abs(np.diff(k0) / np.diff(s0)).max()
    dk1 = np.abs(np.diff(k1) / np.diff(s1)).max()
    assert np.abs(k1).max() < 0.25 * np.abs(k0).max() and dk1 < 0.05 * dk0
    # the heading change over the whole line is kept (within a degree)
    th = lambda xy: np.arctan2(*(xy[-1] - xy[-40])[::-1])  # noqa: E731
    assert abs(th(sm) - th(kinked)) < np.radians(1.0)
    assert np.array_equal(smooth_polyline(kinked, 0.0, 0.1), kinked)
    with pytest.raises(ValueError, match="max_dev"):
        smooth_polyline(kinked, 15.0, 0.0)


def test_static_obstacle_held_past_the_recording():
    rec = _record(_road_dict(obstacles=[(80.0, 0.0, "static")]))
    obs = rec.scene.obstacles
    assert bool(obs.static[0]) and obs.boxes.shape[1] == 1
    w = jax.tree_util.tree_map(jnp.asarray, obs).window(150, 20)
    assert bool(np.all(w.valid)) and np.allclose(w.boxes[0, -1], obs.boxes[0, 0])


def _log(xy, heading, v, dt=0.1, valid=None):
    n = xy.shape[0]
    z = np.zeros(n)
    return DriveLog(jnp.arange(n) * dt, jnp.asarray(xy[:, 0]), jnp.asarray(xy[:, 1]), jnp.asarray(heading),
                    jnp.asarray(v), jnp.asarray(z), jnp.asarray(z), jnp.ones(n, bool) if valid is None else valid,
                    jnp.asarray(n - 1), jnp.ones(1, bool), jnp.zeros(1, bool), jnp.ones(1, bool), {})


def _box_poly(x, y, L, W, h):
    c, s = math.cos(h), math.sin(h)
    return Polygon([(x + c * dx - s * dy, y + s * dx + c * dy)
                    for dx, dy in ((L / 2, W / 2), (-L / 2, W / 2), (-L / 2, -W / 2), (L / 2, -W / 2))])


def test_overlap_matches_shapely_and_fault_rule(rng):
    lead_s = 60.0 + 5.0 * np.arange(251) * 0.1
    rec = _record(_road_dict(obstacles=[(lead_s, np.zeros(251)), (70.0, 3.5, "static")]))
    scene = jax.tree_util.tree_map(jnp.asarray, rec.scene)
    obs = rec.scene.obstacles
    N, n = 201, 400
    # each trial: the car far away except at one step j, near one of the obstacles
    j = rng.integers(0, N, n)
    o = rng.integers(0, 2, n)
    box = obs.boxes[o, np.where(o == 0, j, 0)]
    xy = box[:, :2] + rng.normal(0.0, 2.5, (n, 2))
    head = rng.uniform(-np.pi, np.pi, n)
    pos = np.full((n, N, 2), 1e4)
    pos[np.arange(n), j] = xy

    @jax.jit
    def hits(pos, head):
        return jax.vmap(lambda p, h: overlap(_log(p, jnp.full(N, h), jnp.zeros(N)), scene, CAR)["collided"])(pos, head)

    ours = np.asarray(hits(jnp.asarray(pos), jnp.asarray(head)))
    ref = []
    for i in range(n):
        car = _box_poly(xy[i, 0], xy[i, 1], CAR.length, CAR.width, head[i])
        ref.append(any(car.intersection(_box_poly(*obs.boxes[q, j[i] if q == 0 else 0])).area > 1e-6 for q in (0, 1)))
    assert 50 < sum(ref) < n - 50
    np.testing.assert_array_equal(ours, ref)
    # fault: closing in on the leader from behind is at fault; being caught up from behind is not
    lead = obs.boxes[0, :30]
    u = np.array([math.cos(lead[0, 4]), math.sin(lead[0, 4])])
    q = np.arange(30)[:, None]
    for sign, fault in ((-1.0, True), (1.0, False)):
        xy = lead[:, :2] + sign * u * (6.0 - 0.3 * q)
        m = overlap(_log(xy, np.full(30, lead[0, 4]), np.full(30, 5.0)), scene, CAR)
        assert bool(m["collided"]) and bool(m["at_fault"]) == fault and int(m["obstacle"]) == 0


def test_blind_zone_matches_shapely(rng):
    """The ``blindzone`` metric's kernel against shapely: the zone drawn as a polygon in the
    obstacle's frame (beside it, ZONE_GAP .. ZONE_GAP + ZONE_WIDTH off its side, BLIND_BACK behind
    its rear to BLIND_FRONT ahead of it); only moving obstacles count."""
    from jaxplan.sim.metrics.blindzone import BLIND_BACK, BLIND_FRONT, ZONE_GAP, ZONE_WIDTH, blind_zone_steps

    n, K = 3000, 2
    obs = np.concatenate([rng.uniform(-5, 5, (n, K, 2)), np.tile([4.5, 1.9], (n, K, 1)),
                          rng.uniform(-np.pi, np.pi, (n, K, 1))], -1)
    car = np.concatenate([rng.uniform(-9, 9, (n, 2)), np.tile([CAR.length, CAR.width], (n, 1)),
                          rng.uniform(-np.pi, np.pi, (n, 1))], -1)
    moving = rng.random((n, K)) < 0.8
    ours = np.asarray(jax.jit(blind_zone_steps)(jnp.asarray(car), jnp.asarray(obs.swapaxes(0, 1)), jnp.asarray(moving.T)))

    def zone(b, side):
        x, y, L, W, h = b
        c, s = math.cos(h), math.sin(h)
        lo, hi = -L / 2 - BLIND_BACK, -L / 2 + BLIND_FRONT
        a, d = side * (W / 2 + ZONE_GAP), side * (W / 2 + ZONE_GAP + ZONE_WIDTH)
        return Polygon([(x + c * u - s * v, y + s * u + c * v) for u, v in ((lo, a), (hi, a), (hi, d), (lo, d))])

    ref = []
    for i in range(n):
        cp = _box_poly(*car[i])
        ref.append(any(moving[i, k] and any(cp.intersection(zone(obs[i, k], sd)).area > 1e-6 for sd in (1, -1))
                       for k in range(K)))
    ref = np.asarray(ref)
    assert 300 < ref.sum() < n - 300
    # touching (zero-area contact) may go either way
    assert np.mean(ours != ref) < 1e-3


def _beside(box, along, across, heading_offset=0.0):
    """Car poses ``(n, 2)``, headings ``(n,)`` placed ``along`` / ``across`` (n,) metres from obstacle boxes ``(n, 5)``."""
    h = box[:, 4]
    u = np.stack([np.cos(h), np.sin(h)], -1)
    nrm = np.stack([-np.sin(h), np.cos(h)], -1)
    return box[:, :2] + along[:, None] * u + across[:, None] * nrm, h + heading_offset


def test_fault_is_judged_at_every_obstacles_first_contact():
    """Only a moving obstacle hitting the car squarely from behind excuses it, whichever contact of
    the drive it is: a car that slides sideways into a neighbour whose centre is 0.5 m behind its own is
    at fault (the rule that looked only at whose centre was ahead excused it); a car rear-ended by a
    faster one is not; a drive hit from behind first and then driving into a parked car is at fault."""
    t = np.arange(60)
    nb = _record(_road_dict(obstacles=[(60.0 + 1.0 * t, np.full(60, 3.5))], n_lanes=2))
    scene = jax.tree_util.tree_map(jnp.asarray, nb.scene)
    box = np.asarray(nb.scene.obstacles.boxes[0, :60])
    # slide sideways from the own lane (3.5 m across) into the neighbour, 0.5 m ahead of it
    xy, h = _beside(box, np.full(60, 0.5), np.linspace(-3.5, -0.5, 60))
    m = overlap(_log(xy, h, np.full(60, 10.0)), scene, CAR)
    assert bool(m["collided"]) and bool(m["at_fault"]) and int(m["obstacles_at_fault"]) == 1
    # the same slide 3 m ahead of it: the neighbour's centre is behind the car's rear bumper, but beside it
    # (not squarely behind): at fault
    xy, h = _beside(box, np.full(60, 3.0), np.linspace(-3.5, -0.5, 60))
    m = overlap(_log(xy, h, np.full(60, 10.0)), scene, CAR)
    assert bool(m["collided"]) and bool(m["at_fault"])
    # rear-ended: the car stands in the lane and a car (10 m/s) closes in from squarely behind
    fast = _record(_road_dict(obstacles=[(30.0 + 1.0 * t, np.zeros(60))]))
    fscene = jax.tree_util.tree_map(jnp.asarray, fast.scene)
    fb = np.asarray(fast.scene.obstacles.boxes[0, :60])
    stand = fb[40, :2] + (CAR.length / 2 + 4.6 / 2 - 0.3) * np.array([np.cos(fb[40, 4]), np.sin(fb[40, 4])])
    xy = np.repeat(stand[None], 60, 0)
    m = overlap(_log(xy, np.full(60, fb[0, 4]), np.zeros(60)), fscene, CAR)
    assert bool(m["collided"]) and not bool(m["at_fault"]) and int(m["first_step"]) <= 40
    # the same contact as the drive's last step, and as the last step of the other car's recording: its
    # motion is then its step before's (it was judged standing, and the car at fault)
    k = int(m["first_step"])
    m = overlap(_log(xy[: k + 1], np.full(k + 1, fb[0, 4]), np.zeros(k + 1)), fscene, CAR)
    assert bool(m["collided"]) and int(m["first_step"]) == k and not bool(m["at_fault"])
    ended = dataclasses.replace(fscene, obstacles=dataclasses.replace(
        fscene.obstacles, valid=fscene.obstacles.valid.at[0, k + 1:].set(False)))
    m = overlap(_log(xy, np.full(60, fb[0, 4]), np.zeros(60)), ended, CAR)
    assert bool(m["collided"]) and int(m["first_step"]) == k and not bool(m["at_fault"])
    # a car standing squarely behind, whose recording ends as the car backs into it: the car's fault
    still = dataclasses.replace(ended, obstacles=dataclasses.replace(
        ended.obstacles, boxes=jnp.broadcast_to(ended.obstacles.boxes[:, k:k + 1], ended.obstacles.boxes.shape)))
    back = stand[None] + np.linspace(2.0, 0.0, k + 1)[:, None] * np.array([np.cos(fb[0, 4]), np.sin(fb[0, 4])])
    back = np.concatenate([back, np.repeat(stand[None], 59 - k, 0)])
    m = overlap(_log(back, np.full(60, fb[0, 4]), np.zeros(60)), still, CAR)
    assert bool(m["collided"]) and 0 < int(m["first_step"]) <= k and bool(m["at_fault"])
    # hit from behind, then pushed on into a parked car ahead: the second contact is the car's fault
    both = _record(_road_dict(obstacles=[(30.0 + 1.0 * t, np.zeros(60)), (0.0, 0.0, "static")]))
    bscene = jax.tree_util.tree_map(jnp.asarray, both.scene)
    parked = np.asarray(both.scene.obstacles.boxes[1, 0])
    xy2 = xy.copy()
    u = np.array([np.cos(fb[0, 4]), np.sin(fb[0, 4])])
    xy2[45:] = parked[:2] - (CAR.length / 2 + 4.6 / 2 - 0.2) * u  # against the parked car from step 45
    m = overlap(_log(xy2, np.full(60, fb[0, 4]), np.zeros(60)), bscene, CAR)
    assert bool(m["collided"]) and int(m["obstacle"]) == 0 and bool(m["at_fault"])
    assert int(m["fault_obstacle"]) == 1 and int(m["fault_step"]) == 45 and int(m["obstacles_hit"]) == 2


def test_offroad_matches_shapely(rng):
    d = _road_dict(n_lanes=2, kappa=1 / 80.0)
    rec = _record(d)
    scene = jax.tree_util.tree_map(jnp.asarray, rec.scene)
    road = unary_union([Polygon(np.concatenate([ln.left, ln.right[::-1]])) for ln in rec.scenario.lanes])
    n = 2000
    # poses about the road's edges (the route runs along lane 0: edges at l = -1.75 and +5.25)
    sc = rec.scene
    s = rng.uniform(sc.route_start_s, sc.route_end_s - 10.0, n)
    l = np.where(rng.random(n) < 0.5, -1.75, 5.25) + rng.normal(0.0, 1.2, n)
    i = np.clip(np.searchsorted(sc.route.s, s), 1, len(sc.route.s) - 1)
    th = sc.route.theta[i]
    xy = sc.route.xy[i] + l[:, None] * np.stack([-np.sin(th), np.cos(th)], -1)
    head = th + rng.normal(0.0, 0.4, n)
    fn = jax.jit(lambda lg: offroad_steps(lg, scene, CAR))
    ours = np.asarray(fn(_log(xy, head, np.zeros(n))))
    ref, keep = [], []
    for i in range(n):
        car = _box_poly(xy[i, 0], xy[i, 1], CAR.length, CAR.width, head[i])
        out = car.difference(road)
        ref.append(out.area > 1e-6)
        # unambiguous cases only: inside by more than 5 cm, or poking out by more than 5 cm
        poke = max((road.distance(Point(p)) for g in getattr(out, "geoms", [out]) if not g.is_empty
                    for p in g.exterior.coords), default=0.0)
        keep.append(poke > 0.05 if ref[-1] else car.exterior.distance(road.exterior) > 0.05)
    ref, keep = np.array(ref), np.array(keep)
    assert ref[keep].sum() > 300 and (~ref[keep]).sum() > 100
    np.testing.assert_array_equal(ours[keep], ref[keep])


def test_offroad_sees_a_road_edge_dipping_between_outline_samples():
    """A notch in the road edge narrower than the outline's sample spacing: the box is off the road
    wherever shapely says so (the rule on road-edge vertices; outline samples alone miss most of them).
    Seen failing with the outline samples alone: 24 of the 41 poses wrong."""
    road = np.array([[0.0, -2.0], [100.0, -2.0], [100.0, 2.0], [50.7, 2.0], [50.2, 1.5], [49.7, 2.0], [0.0, 2.0]])
    rec = _record(_road_dict())
    scene = dataclasses.replace(rec.scene, drivable=road[None], drivable_valid=np.ones((1, len(road)), bool))
    scene = jax.tree_util.tree_map(jnp.asarray, scene)
    x = np.linspace(47.0, 53.4, 41)
    xy = np.stack([x, np.full_like(x, 0.8)], -1)  # the box's side at y = 1.6, where the notch is 0.2 m wide
    ours = np.asarray(jax.jit(lambda lg: offroad_steps(lg, scene, CAR))(_log(xy, np.zeros(len(x)), np.zeros(len(x)))))
    ref = np.array([_box_poly(p[0], p[1], CAR.length, CAR.width, 0.0).difference(Polygon(road)).area > 1e-6
                    for p in xy])
    assert 10 < ref.sum() < len(x) - 10
    np.testing.assert_array_equal(ours, ref)


def test_goal_predicate_against_shapely_and_heading_intervals(rng):
    rec = _record(_road_dict())
    goal = jax.tree_util.tree_map(jnp.asarray, rec.scene.goal)
    poly = Polygon(np.asarray(rec.scene.goal.region[0]))
    pts = np.asarray(poly.centroid.coords)[0] + rng.normal(0.0, 12.0, (500, 2))
    ours = np.asarray(goal_reached(goal, jnp.asarray(pts), jnp.zeros(500), jnp.zeros(500), jnp.full(500, 5.0)))
    np.testing.assert_array_equal(ours, [poly.contains(Point(p)) for p in pts])
    assert not bool(goal_reached(goal, jnp.asarray(pts[ours][0]), 0.0, 0.0, 12.5))  # after the time interval
    th = rng.uniform(-10, 10, 2000)
    lo = rng.uniform(-4, 4, 2000)
    hi = lo + rng.uniform(0, 3, 2000)
    brute = [any(lo[i] <= th[i] + 2 * np.pi * k <= hi[i] for k in range(-4, 5)) for i in range(2000)]
    np.testing.assert_array_equal(np.asarray(heading_in(th, lo, hi)), brute)


@functools.lru_cache(maxsize=None)
def _brake_case():
    """Three scenes (a stopped car too close to brake for, one far enough, a free curve),
    judged by the survivability check, then driven by the same compiled brake rollout."""
    recs = [_record(_road_dict(obstacles=[(builtin.START_S + 9.0, 0.0, "static")], v0=15.0)),
            _record(_road_dict(obstacles=[(builtin.START_S + 40.0, 0.0, "static")], v0=15.0)),
            _record(_road_dict(v0=10.0, kappa=1 / 150.0))]
    return recs, builtin.survivable(recs)


def test_survivability_check_drops_what_braking_cannot_survive():
    _, ok = _brake_case()
    assert list(ok) == [False, True, True]


def test_brake_rollout_is_analytic_and_batched_equals_single():
    from jaxplan.sim.drive import run_planner

    recs, _ = _brake_case()
    cfg = SimConfig(n_steps=120, stop_at_goal=False)  # what survivable() ran: its compiled rollout is reused
    batch = stack_scenes([r.scene for r in recs], min_steps=cfg.n_steps + 1)
    log, m, _ = run_planner(BrakePlanner(decel=builtin.SURVIVAL_DECEL), batch, cfg)
    t = np.arange(121) * 0.1
    np.testing.assert_allclose(log.v[1], np.maximum(15.0 - 5.0 * t, 0.0), atol=1e-4)
    d = np.hypot(np.diff(log.x[1]), np.diff(log.y[1])).sum()
    assert d == pytest.approx(15.0 ** 2 / 10.0, abs=0.05)
    assert list(m["overlap.collided"]) == [True, False, False] and not m["offroad.offroad"].any()
    assert m["comfort.max_abs_accel"][1] == pytest.approx(5.0, abs=1e-3)
    # what the road asks when braking from the start: nothing on the straight roads, v0^2 kappa
    # on the arc (its largest at the start)
    np.testing.assert_allclose(m["comfort.lat_accel_floor"], [0.0, 0.0, 10.0**2 / 150.0], atol=0.02)
    one = rollout(BrakePlanner(decel=5.0), jax.tree_util.tree_map(lambda a: a[2:3], batch), cfg)
    np.testing.assert_allclose(np.asarray(one.x[0]), log.x[2], atol=1e-5)
    np.testing.assert_allclose(np.asarray(one.y[0]), log.y[2], atol=1e-5)
    # lazy re-planning keeps the installed plan while it is long enough and free: braking at a
    # constant deceleration is the same drive either way, with a fraction of the re-plans
    lazy = rollout(BrakePlanner(decel=5.0), jax.tree_util.tree_map(lambda a: a[2:3], batch),
                   dataclasses.replace(cfg, replan="lazy"))
    np.testing.assert_allclose(np.asarray(lazy.x[0]), log.x[2], atol=1e-3)
    np.testing.assert_allclose(np.asarray(lazy.v[0]), log.v[2], atol=1e-4)
    assert int(one.replanned[0].sum()) == 40 and 1 <= int(lazy.replanned[0].sum()) <= 8


@dataclasses.dataclass(frozen=True)
class _BrakeWithOptions(BrakePlanner):
    compiler_options: ClassVar[dict] = NO_YNN


def test_release_compiled_frees_the_memory_maps_of_compiled_programs():
    """Every compiled program maps memory regions of its own; ``release_compiled`` frees them once
    the process maps more than its share of the kernel's limit, and does nothing below it."""
    from jaxplan.compile_options import memory_maps, release_compiled

    if memory_maps() is None:
        pytest.skip("no /proc/self/maps on this system")
    fs = [jax.jit(lambda x, i=i: jnp.sin(x) * i + jnp.cumsum(x) @ x) for i in range(60)]
    before = memory_maps()[0]
    for i, f in enumerate(fs):
        f(jnp.ones(8 + i)).block_until_ready()
    grown = memory_maps()[0]
    assert grown > before + 60, (before, grown)
    assert not release_compiled(share=1.0)  # below the kernel's limit: nothing is released
    assert memory_maps()[0] >= grown - 5
    assert release_compiled(share=0.0)
    assert memory_maps()[0] < grown - 60, (grown, memory_maps())


def test_the_drive_is_compiled_with_the_planners_xla_options():
    """A planner's ``compiler_options`` reach the program its drive runs (and the one that times its
    plan); a planner without them drives in the plain program. The options change no result."""
    from jaxplan.sim.drive import plan_at_start, time_plans
    from jaxplan.sim.rollout import compiled_with

    recs, _ = _brake_case()
    cfg = SimConfig(n_steps=120, stop_at_goal=False)
    batch = stack_scenes([r.scene for r in recs], min_steps=cfg.n_steps + 1)
    one = jax.tree_util.tree_map(lambda a: a[2:3], batch)
    key = options_key(NO_YNN)
    with_options = rollout(_BrakeWithOptions(decel=5.0), one, cfg)
    program = compiled_with(key)
    assert program._cache_size() == 1
    assert program.applied == (NO_YNN if options_supported(key) else {})
    plain = rollout(BrakePlanner(decel=5.0), one, cfg)
    assert compiled_with(()).applied == {} and compiled_with(())._cache_size() >= 1
    for f in ("x", "y", "v"):
        np.testing.assert_allclose(np.asarray(getattr(with_options, f)), np.asarray(getattr(plain, f)), atol=1e-5)
    assert time_plans(_BrakeWithOptions(decel=5.0), one, 1)["plan_ms_median"] > 0
    assert compiled_with(key, plan_at_start, ("planner",))._cache_size() == 1
    with pytest.raises(TypeError, match="compiler_options: needs a dict"):
        rollout(_BadOptions(), one, cfg)  # refused before anything compiles


@dataclasses.dataclass(frozen=True)
class _BadOptions(BrakePlanner):
    compiler_options: ClassVar[str] = "xla_cpu_experimental_ynn_fusion_type="


def test_lazy_policy_sees_a_conflict_on_the_installed_plan():
    from jaxplan.sim.rollout import plan_conflicts

    recs, _ = _brake_case()
    scene = jax.tree_util.tree_map(jnp.asarray, recs[0].scene)  # a stopped car 9 m ahead
    ego = EgoState.from_box_centre(scene.start, CAR)
    idm = IDMPlanner()
    cruise = idm.plan(idm.init_params(), scene, dataclasses.replace(ego, v=jnp.asarray(0.0)), 0).trajectory
    through = dataclasses.replace(cruise, x=cruise.x + jnp.cos(ego.heading) * jnp.arange(51) * 1.5,
                                  y=cruise.y + jnp.sin(ego.heading) * jnp.arange(51) * 1.5)
    assert bool(plan_conflicts(through, 0, scene, 0, CAR, 0.2))
    assert not bool(plan_conflicts(cruise, 0, scene, 0, CAR, 0.2))  # standing still behind it


IDM_STEPS = 120


def _idm_records():
    """A stopped car on a curve and a free road: the IDM drives of this module (one compiled rollout)."""
    stop = _record(_road_dict(obstacles=[(110.0, 0.0, "static")], v0=12.0, kappa=1 / 120.0))
    free = dataclasses_replace(_record(_road_dict(v0=15.0)), name="FREE")
    return stop, free


def test_drive_idm_stops_reaches_goals_writes_the_format_and_bicycle_tracks(tmp_path):
    from jaxplan.sim.drive import drive

    stop, free = _idm_records()
    cfg = SimConfig(n_steps=IDM_STEPS)
    res = drive([stop, free], ["idm"], str(tmp_path), cfg, progress=False)
    r_stop, r_free = res.rows["idm"]
    assert not r_stop["overlap.collided"] and not r_stop["goal.reached"] and r_stop["end_time"] == pytest.approx(12.0)
    assert r_free["goal.reached"] and r_free["end_time"] == pytest.approx(r_free["goal.time"])
    for rec, row in ((stop, r_stop), (free, r_free)):
        out = json.loads((tmp_path / rec.name / "driven.json").read_text())
        assert set(out) == {"scenario", "planner", "dt", "vehicle", "states"}
        st = np.array(out["states"])
        assert len(st) == round(row["end_time"] / 0.1) + 1 and np.allclose(np.diff(st[:, 0]), 0.1)
        start = rec.scenario.origin + np.array([rec.scenario.ego.x, rec.scenario.ego.y])
        np.testing.assert_allclose(st[0, 1:3], start, atol=1e-3)  # world coordinates, box centre
        assert (tmp_path / rec.name / "drive.png").exists()
    assert st[-1, 4] > 1.0 and json.loads((tmp_path / "TEST" / "driven.json").read_text())["states"][-1][4] < 0.5
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["drive.idm.goal_share"] == 0.5 and len(metrics["rows"]) == 2
    head = f"\n| idm | 2 | {metrics['drive.idm.success_share']:.1%} | 50.0% |"
    assert head in (tmp_path / "report.md").read_text()  # the headline row: success, then goal
    # the results folder's report opens with the closed-loop headline of a drive in a sub-folder
    from jaxplan.eval.report import write_report

    top = tmp_path / "top"
    (top / "drive").mkdir(parents=True)
    (top / "metrics.json").write_text(json.dumps({"tiny.n": 1}))
    (top / "drive" / "metrics.json").write_text((tmp_path / "metrics.json").read_text())
    text = open(write_report(str(top))).read()
    assert text.index("## Closed loop: `drive/` (2 scenes") < text.index("## tiny") and head in text
    # the same drives through the bicycle tracker stay within 0.5 m of the exact ones
    batch = stack_scenes([stop.scene, free.scene], min_steps=cfg.n_steps + 1)
    exact = rollout(IDMPlanner(), batch, cfg)
    bike = rollout(IDMPlanner(), batch, SimConfig(n_steps=120, tracking="bicycle"))
    gap = np.hypot(exact.x - bike.x, exact.y - bike.y)[np.asarray(exact.valid & bike.valid)]
    assert float(gap.max()) < 0.5


def dataclasses_replace(obj, **kw):
    import dataclasses

    return dataclasses.replace(obj, **kw)


@pytest.mark.parametrize("case,msg", [
    ("no_problem", "planning_problems"), ("no_lanelets", "no lanelets"), ("goal_point", "goal region"),
])
def test_drive_cli_bad_scenarios_one_line(tmp_path, capsys, case, msg):
    from jaxplan.cli import main

    d = _road_dict()
    if case == "no_problem":
        d["planning_problems"] = []
    elif case == "no_lanelets":
        d["lanelets"] = []
    else:
        d["planning_problems"][0]["goals"][0] = {"position": [1.0, 2.0], "time": [0.0, 3.0]}
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    rc = main(["drive", str(p), "--planner", "idm", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and msg in err[0] and "bad.json" in err[0]


def test_drive_cli_unknown_planner(tmp_path, capsys):
    from jaxplan.cli import main

    rc = main(["drive", "--builtin", "--planner", "nosuch", "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "nosuch" in err[0] and "lattice" in err[0]


@pytest.mark.parametrize(
    "spec, words",
    [
        ("pathspeed:nosuch=1", ["no option nosuch", "nonblocking"]),
        ("pathspeed:nonblocking", ["'nonblocking' is not OPTION=VALUE"]),
        ("pathspeed:lane_change=maybe", ["option lane_change needs true or false", "'maybe'"]),
        ("idm,idm", ["named twice"]),
    ],
)
def test_drive_cli_bad_planner_option_one_line(tmp_path, capsys, spec, words):
    from jaxplan.cli import main

    rc = main(["drive", "--builtin", "--planner", spec, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and all(w in err[0] for w in words), err


def test_planner_spec_sets_config_options():
    """``NAME:OPTION=VALUE`` makes the planner with those config options (booleans, numbers); keyword
    options given to ``make_planner`` come on top."""
    from jaxplan.planner import make_planner, planner_spec

    assert planner_spec("pathspeed:nonblocking=false:horizon=6.5") == ("pathspeed", {"nonblocking": False, "horizon": 6.5})
    p = make_planner("pathspeed:nonblocking=false:lane_change=true")
    assert p.nonblocking is False and p.lane_change is True
    assert make_planner("pathspeed:path_points=40", path_points=50).path_points == 50
    assert make_planner("pathspeed") == make_planner("pathspeed", nonblocking=True)


SHARD_SCRIPT = """
import sys, numpy as np, jax
sys.path.insert(0, sys.argv[2])  # the tests' folder: the same scenes as the test process
from test_sim import IDM_STEPS, _idm_records
from jaxplan.baselines import IDMPlanner
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.sim.drive import run_planner
from jaxplan.sim.rollout import SimConfig
batch = stack_scenes([r.scene for r in _idm_records()], min_steps=IDM_STEPS + 1)
log, m, _ = run_planner(IDMPlanner(), batch, SimConfig(n_steps=IDM_STEPS))
np.savez(sys.argv[1], x=log.x, y=log.y, v=log.v, collided=m["overlap.collided"], devices=jax.device_count())
"""


def test_sharded_drives_equal_single_device(tmp_path):
    """The drives of ``_idm_records`` sharded over one more (forced host) device in a child process
    equal this process's drives (to float32 rounding) (on one device under ``make test``: the rollout that ``drive``
    compiles above, no new compile)."""
    import os
    import subprocess
    import sys

    from conftest import cpu_devices_env
    from jaxplan.sim.drive import run_planner

    n = jax.device_count() + 1
    batch = stack_scenes([r.scene for r in _idm_records()], min_steps=IDM_STEPS + 1)
    log, m, _ = run_planner(IDMPlanner(), batch, SimConfig(n_steps=IDM_STEPS))
    here = dict(x=log.x, y=log.y, v=log.v, collided=m["overlap.collided"])
    script = tmp_path / "shard.py"
    script.write_text(SHARD_SCRIPT)
    env = cpu_devices_env(n)
    r = subprocess.run([sys.executable, str(script), str(tmp_path / "d.npz"), os.path.dirname(__file__)], env=env,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    more = np.load(tmp_path / "d.npz")
    assert int(more["devices"]) == n
    assert np.asarray(here["collided"]).shape == (2,) and np.isfinite(here["x"]).any()
    # the same drives up to float32 rounding (the params are runtime values, so the two programs
    # may order an operation differently: a few 1-ulp differences)
    np.testing.assert_array_equal(here["collided"], more["collided"])
    for k in ("x", "y", "v"):
        np.testing.assert_allclose(here[k], more[k], rtol=1e-6, atol=1e-5)


def test_summary_counts_lateral_accelerations_over_the_limit_that_the_road_allowed():
    from jaxplan.planner import EMERGENCY_LAT_ACCEL
    from jaxplan.sim.drive import summarize

    row = lambda lat, floor: {"success": True, "comfort.max_abs_lat_accel": lat, "comfort.lat_accel_floor": floor}
    e = EMERGENCY_LAT_ACCEL
    out = summarize([row(e + 1.0, e - 3.0), row(e + 1.0, e + 3.0), row(e - 1.0, e - 3.0), row(e + 0.5, e)])
    assert out["lat_accel_over_limit"] == 3.0
    assert out["lat_accel_over_limit_avoidable"] == 2.0
