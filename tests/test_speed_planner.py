"""The ``pathspeed`` planner in closed loop on built-in scenes that in-lane braking survives:
no collision of its own, the driven accelerations within the limits, the trajectory from the
car's state, parity of the batched plan with the simulator's; the composed path (the bounds
path, checked with shapely; the route path and the stop before a blockage when the road is
blocked) and the route path. On synthetic roads in the same compiled drive: it passes a slow
leader and a stopped car through the free neighbour lane, keeps its lane while a faster car
comes up in the next one, keeps its lane decision from one cycle to the next, and leaves room
to a car closing in from behind."""
import dataclasses
import functools
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely.geometry as sg
from test_sim import _record, _road_dict

from jaxplan.plan_context import CURVE_DECEL, road_context
from jaxplan.planner import EgoState, make_planner
from jaxplan.scenarios import builtin
from jaxplan.speed import SpeedConfig
from jaxplan.speed.paths import route_path
from jaxplan.speed.planner import PathSpeedPlanner

KINDS = ("stopped_car", "slow_leader", "cut_in", "dense_next_lane")
SQUEEZE_L = 0.5 * 1.61 + 0.5 * 1.8 + 0.15  # the oncoming car's offset: 0.15 m between the boxes
STEPS = 120  # 12 s
TT = np.arange(251) * 0.1
START = builtin.START_S  # the car's station on the synthetic roads


def _synthetic():
    """``{name: record}``: synthetic two-lane roads, the car in the right lane at 12 m/s (15 m/s in
    BEHIND). SLOW: a car 25 m ahead at 4 m/s; STOPPED: a car standing 40 m ahead; FASTER: the slow
    car, and a car at 20 m/s in the next lane 15 m behind (moving over in front of it would make it
    brake harder than 3 m/s^2); BEHIND: one lane, the car at 10 m/s between a car 20 m ahead at 10 m/s
    and a car 10 m behind at 11.5 m/s (keeping the follow distance gets the car rear-ended within 4 s;
    closing up to the car ahead leaves room until the goal's time); SQUEEZE: one lane, the car at 10
    m/s, an oncoming car passing 0.15 m clear of it (inside the speed plan's 0.3 m buffer, outside
    the car) and a car 14 m behind at 12 m/s (stopping for the oncoming car gets the car hit);
    ALONE: SQUEEZE without the car behind;
    MAPEND: one lane that ends 120 m ahead of the car (15 m/s), a goal region 75-95 m ahead to be
    met at 13-20 m/s (the drive ends there: the end of the map beyond it is no reason to slow);
    DEADEND: one lane that ends 100 m ahead of the car (15 m/s), a goal of time only (11-12 s);
    FAREND: one lane that ends 70 m ahead of the car (15 m/s, limit 20 m/s), a goal of time only
    (3.0-3.3 s: the drive ends before the car could get there)."""
    lane0 = np.zeros(251)
    slow = (START + 25.0 + 4.0 * TT, lane0)
    roads = {"SLOW": _road_dict(obstacles=[slow]),
             "STOPPED": _road_dict(obstacles=[(START + 40.0 + 0.0 * TT, lane0)]),
             "FASTER": _road_dict(obstacles=[slow, (START - 15.0 + 20.0 * TT, np.full(251, builtin.LANE))]),
             "BEHIND": _road_dict(obstacles=[(START + 20.0 + 10.0 * TT, lane0), (START - 10.0 + 11.5 * TT, lane0)],
                                  n_lanes=1, v0=10.0, goal_t=(0.0, 8.0)),
             "SQUEEZE": _road_dict(obstacles=[(START + 70.0 - 10.0 * TT, np.full(251, SQUEEZE_L)),
                                              (START - 14.0 + 12.0 * TT, lane0)], n_lanes=1, v0=10.0, goal_t=(0.0, 8.0)),
             "ALONE": _road_dict(obstacles=[(START + 70.0 - 10.0 * TT, np.full(251, SQUEEZE_L))], n_lanes=1, v0=10.0,
                                 goal_t=(0.0, 8.0)),
             "MAPEND": _road_dict(n_lanes=1, v0=15.0, goal_t=(0.0, 10.0)),
             "DEADEND": _road_dict(n_lanes=1, v0=15.0, goal_t=(11.0, 12.0)),
             "FAREND": _road_dict(n_lanes=1, v0=15.0, goal_t=(3.0, 3.3))}
    mapend = roads["MAPEND"]
    for lane in mapend["lanelets"]:
        lane["left"], lane["right"] = lane["left"][:76], lane["right"][:76]  # 150 m of road from s = 0
    goal = mapend["planning_problems"][0]["goals"][0]
    cx, cy = goal["rectangle"]["center"]  # 120 m ahead on the straight road (heading 0.3): 35 m back
    goal["rectangle"]["center"] = [cx - 35.0 * np.cos(0.3), cy - 35.0 * np.sin(0.3)]
    goal["velocity"] = [13.0, 20.0]
    for lane in roads["DEADEND"]["lanelets"]:
        lane["left"], lane["right"] = lane["left"][:66], lane["right"][:66]  # 130 m of road from s = 0
    del roads["DEADEND"]["planning_problems"][0]["goals"][0]["rectangle"]
    for lane in roads["FAREND"]["lanelets"]:
        lane["left"], lane["right"] = lane["left"][:51], lane["right"][:51]  # 100 m of road from s = 0
    del roads["FAREND"]["planning_problems"][0]["goals"][0]["rectangle"]
    return {k: dataclasses.replace(_record(d), name=k) for k, d in roads.items()}


@functools.lru_cache(maxsize=None)
def _rollout():
    """The built-in scenes (one per kind, survivable) and the synthetic ones in one batch: one
    compiled rollout."""
    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.builtin import builtin_dicts
    from jaxplan.scenarios.loader import parse_scenario
    from jaxplan.sim.metrics.registry import evaluate_batch
    from jaxplan.sim.rollout import SimConfig, rollout

    dicts = builtin_dicts(1, seed=3, kinds=KINDS)
    synthetic = _synthetic()
    scenes = [build_scene(parse_scenario(d, d["id"]))[0] for d in dicts] + [r.scene for r in synthetic.values()]
    cfg = SimConfig(n_steps=STEPS)
    batch = stack_scenes(scenes, min_steps=STEPS + 80)
    planner = make_planner("pathspeed")
    log = rollout(planner, batch, cfg)
    metrics = {k: np.asarray(v) for k, v in evaluate_batch(log, batch, planner.vehicle).items()}
    return planner, batch, log, metrics, synthetic


@functools.lru_cache(maxsize=None)
def _drives():
    """The built-in scenes' part of ``_rollout``: ``(planner, batch, log, metrics)``."""
    planner, batch, log, m, _ = _rollout()
    n = len(KINDS)
    part = lambda tree: jax.tree_util.tree_map(lambda x: x[:n], tree)  # noqa: E731
    return planner, part(batch), part(log), {k: v[:n] for k, v in m.items()}


def _synthetic_drive(name):
    """``(log, metrics, record)`` of one synthetic drive (numpy)."""
    _, _, log, m, synthetic = _rollout()
    i = len(KINDS) + list(synthetic).index(name)
    return (jax.tree_util.tree_map(lambda x: np.asarray(x)[i], log), {k: v[i] for k, v in m.items()},
            synthetic[name])


DENSE = KINDS.index("dense_next_lane")


def test_closed_loop_is_safe_and_within_the_limits():
    planner, batch, log, m = _drives()
    others = np.arange(len(KINDS)) != DENSE
    assert not m["overlap.at_fault"][others].any()
    assert not m["overlap.collided"][others].any()
    # the drive metric differentiates the driven states: the executed profile's limits hold
    cfg = planner.speed
    assert np.all(m["comfort.max_abs_accel"] <= -cfg.a_brake + 0.05)
    assert np.all(m["comfort.max_abs_accel"] <= 8.0)
    assert np.all(m["progress.route_m"] > 10.0)  # it drives (a stopped car ahead stops it later)
    assert np.mean(np.asarray(log.plan_ok)) > 0.8
    assert not np.asarray(log.fallback).any()


def _blocked(batch, i):
    """Scene ``i`` of ``batch`` with its nearest obstacle ahead in the lane widened to 40 m
    (static): no way around it."""
    sc = jax.tree_util.tree_map(lambda x: x[i], batch)
    b0 = np.asarray(sc.obstacles.boxes)[:, 0]
    ok = np.asarray(sc.obstacles.valid)[:, 0]
    x, y, h = (float(v) for v in np.asarray(sc.start)[:3])
    lon = (b0[:, 0] - x) * np.cos(h) + (b0[:, 1] - y) * np.sin(h)  # in the car's frame
    lat = -(b0[:, 0] - x) * np.sin(h) + (b0[:, 1] - y) * np.cos(h)
    ahead = ok & (np.abs(lat) < 2.5) & (lon > 8.0)
    k = int(np.argmin(np.where(ahead, lon, np.inf)))
    assert ahead[k]
    ob = sc.obstacles
    boxes = ob.boxes.at[k, :, 3].set(40.0).at[k, :, :2].set(ob.boxes[k, 0, :2])
    ob = type(ob)(boxes, ob.valid.at[k].set(True), ob.t, ob.static.at[k].set(True))
    return dataclasses.replace(sc, obstacles=ob)


@functools.lru_cache(maxsize=None)
def _plans():
    """One jitted cycle (``speed_plan`` and the composed trajectory) at step 0 of each of the
    drives' scenes and of the stopped-car scene made impassable, stacked as a batch."""
    from jaxplan.speed.compose import compose_profile

    planner, batch, _, _ = _drives()
    scenes = [jax.tree_util.tree_map(lambda x: x[i], batch) for i in range(len(KINDS))] + [_blocked(batch, 0)]
    egos = [EgoState.from_box_centre(s.start, planner.vehicle) for s in scenes]

    @jax.jit
    def one(s, e):  # one scene at a time: compiles faster than the vmapped plan (the rollout checks batching)
        c = planner.speed_plan(planner.init_params(), s, e, 0)
        return planner.output(c), c, compose_profile(c["ref"], c["s0"], c["profile"])

    stack = lambda xs: jax.tree_util.tree_map(lambda *x: jnp.stack(x), *xs)
    out, c, tr = stack([one(s, e) for s, e in zip(scenes, egos)])
    return planner, stack(scenes), stack(egos), out, c, tr


def test_closed_loop_dense_next_lane_has_no_at_fault_collision():
    """The route leads into the next lane, where a dense, faster platoon drives: the car must not
    move across in front of it (it was hit from the side at about 2 s, its fault, until the ST
    boundaries followed the route's bend exactly instead of widening the car's band on both sides)."""
    _, _, _, m = _drives()
    assert not m["overlap.at_fault"][DENSE]


def test_plan_starts_at_the_car_and_matches_the_simulator():
    planner, _, log, _ = _drives()
    _, _, ego, out, _, _ = _plans()
    n = len(KINDS)
    out = jax.tree_util.tree_map(lambda x: x[:n], out)
    ego = jax.tree_util.tree_map(lambda x: x[:n], ego)
    tr = out.trajectory
    H = planner.horizon_steps
    assert tr.x.shape == (len(KINDS), H)
    assert np.allclose(tr.t[:, 1] - tr.t[:, 0], planner.dt)
    assert np.allclose(tr.x[:, 0], ego.x, atol=1e-3) and np.allclose(tr.y[:, 0], ego.y, atol=1e-3)
    assert np.allclose(tr.v[:, 0], ego.v, atol=1e-4)
    dh = np.angle(np.exp(1j * (np.asarray(tr.theta[:, 0]) - np.asarray(ego.heading))))
    assert np.all(np.abs(dh) < 1e-3)
    assert np.all(np.asarray(tr.v) >= 0) and np.all(np.diff(np.asarray(tr.s), axis=1) >= -1e-4)
    # exact tracking: the simulator drove the plan made at step 0 for its first three steps
    c = EgoState(tr.x[:, 1:4], tr.y[:, 1:4], tr.theta[:, 1:4], tr.v[:, 1:4]).box_centre(planner.vehicle)
    assert np.allclose(np.asarray(log.x[:, 1:4]), np.asarray(c[..., 0]), atol=1e-3)
    # the batched and the single-scene programs round the smoothing QP differently (float32)
    assert np.allclose(np.asarray(log.v[:, 1:4]), np.asarray(tr.v[:, 1:4]), atol=5e-3)
    assert set(out.info) >= {"dp_feasible", "qp_ok", "no_bypass", "blocking", "behind", "path_bounds"}


def test_cycle_picture_names_the_decision_and_the_obstacle_classes(tmp_path):
    """The picture of a computed cycle: the map, the SL view titled with the lane decision, the ST
    graph titled with the obstacles' classes, every axis labelled; ``plot_cycle`` writes it."""
    import matplotlib
    import matplotlib.pyplot as plt

    from jaxplan.speed.plot import draw_cycle, plot_cycle

    matplotlib.use("Agg")
    planner, scenes, egos, _, c, _ = _plans()
    one = lambda tree: jax.tree_util.tree_map(lambda x: np.asarray(x[0]), tree)
    fig = draw_cycle(planner, one(scenes), one(egos), 0, KINDS[0], planned=one(c))
    titles = [ax.get_title() for ax in fig.axes]
    assert any("decision: keep the lane" in t or "decision: change" in t for t in titles), titles
    assert any(t.startswith("ST graph:") and "blocking" in t and "blind zones" in t for t in titles), titles
    assert all(ax.get_xlabel() and ax.get_ylabel() for ax in fig.axes[:3])
    plt.close(fig)
    out = plot_cycle(str(tmp_path / "cycle.png"), planner, one(scenes), one(egos), 0, KINDS[0], planned=one(c))
    assert os.path.getsize(out) > 10_000


def test_trajectory_runs_along_the_bounds_path():
    """Where the bounds path is used the composed trajectory's points lie on its polyline
    (shapely distance) over its length, and it starts at the car."""
    _, _, ego, out, c, tr = _plans()
    use = np.asarray(c["use_bounds"])
    assert use[:len(KINDS)].sum() >= 3  # the bounds path on the passable scenes
    pp = jax.tree_util.tree_map(np.asarray, c["bounds"])
    for i in np.nonzero(use)[0]:
        line = sg.LineString(pp.xy[i][pp.valid[i]])
        length = float(line.length)
        pts = np.stack([np.asarray(tr.x[i]), np.asarray(tr.y[i])], -1)
        on = np.asarray(tr.s[i]) < length - 0.5
        d = [line.distance(sg.Point(p)) for p in pts[on]]
        assert on.sum() >= 10 and max(d) < 0.02, (i, max(d))
        assert np.hypot(pts[0, 0] - float(ego.x[i]), pts[0, 1] - float(ego.y[i])) < 1e-3


def test_blocked_road_falls_back_to_the_route_path_and_stops_before_the_blockage():
    planner, scenes, _, out, c, tr = _plans()
    b = len(KINDS)  # the impassable scene
    info = jax.tree_util.tree_map(lambda x: np.asarray(x[b]), out.info)
    assert bool(info["path_blocked"]) and not bool(info["path_bounds"])
    pp = jax.tree_util.tree_map(lambda x: np.asarray(x[b]), c["bounds"])
    path = jax.tree_util.tree_map(lambda x: np.asarray(x[b]), c["path"])
    # the route path (the lane's centre line joined from the car) ...
    sc = jax.tree_util.tree_map(lambda x: x[b], scenes)
    far = path.s > 70.0
    assert np.all(np.abs(path.l[far]) < 1e-4)
    # ... with the stop at the route station of the bounds path's blockage
    stop_route = float(np.interp(pp.blocked_s, pp.s, pp.route_s))
    ctx_s = float(np.asarray(c["ctx"].s[b]))
    assert float(info["path_stop_s"]) == pytest.approx(stop_route - ctx_s, abs=1e-3)
    # the ST wall for the reference point sits at that stop less the buffer, and the plan keeps before it
    lo, _, hit, _ = (np.asarray(a) for a in jax.tree_util.tree_map(lambda x: x[b], c["plan"].scene).blocking())
    s0 = float(np.asarray(c["s0"][b]))
    wall = lo[-1][hit[-1]]
    assert wall.size and np.allclose(wall, stop_route - ctx_s - planner.speed.buffer, atol=0.05)
    assert float(np.asarray(tr.s[b]).max()) <= stop_route - ctx_s - planner.speed.buffer + 0.05
    assert float(s0) >= 0.0 and bool(np.asarray(out.ok[b]))


@functools.partial(jax.jit, static_argnums=2)
def _path_at_jit(sc, ego, planner):
    ctx = road_context(sc, ego, 0, planner.horizon_steps, planner.vehicle)
    return ctx, route_path(sc, ctx, ego)


def _path_at(sc, ego, planner):
    """``(ctx, route path)`` of the car ``ego`` at step 0 (its fields as float32 arrays: one program)."""
    return _path_at_jit(sc, jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), ego), planner)


def test_route_path_joins_the_route_from_the_car():
    planner, batch, _, _ = _drives()
    sc = jax.tree_util.tree_map(lambda x: x[2], batch)
    e0 = EgoState.from_box_centre(sc.start, planner.vehicle)
    ego = EgoState(e0.x - 0.8 * jnp.sin(e0.heading), e0.y + 0.8 * jnp.cos(e0.heading), e0.heading + 0.05, e0.v)
    ctx, path = _path_at(sc, ego, planner)
    i0 = int(np.argmin(np.abs(np.asarray(path.s))))
    assert float(path.s[i0]) == 0.0
    assert np.allclose(np.asarray(path.xy[i0]), [float(ego.x), float(ego.y)], atol=1e-3)
    assert float(path.theta[i0]) == pytest.approx(float(ego.heading), abs=1e-4)
    assert float(path.l[i0]) == pytest.approx(float(ctx.l), abs=1e-6)
    far = np.asarray(path.s) > 70.0
    assert np.all(np.abs(np.asarray(path.l)[far]) < 1e-4)  # on the route's centre line


def test_speed_limit_is_raised_only_to_a_higher_set_speed():
    """``speed_road`` reads the lane's limit along the path; a set speed above it (a goal that the
    limit cannot meet in time, ``set_speed``) raises it to that speed, one below leaves it."""
    from jaxplan.speed.planner import speed_road

    planner, batch, _, _ = _drives()
    sc = jax.tree_util.tree_map(lambda x: x[2], batch)
    ego = EgoState.from_box_centre(sc.start, planner.vehicle)
    ctx, path = _path_at(sc, ego, planner)
    lane = np.asarray(speed_road(sc, ctx, path, 30.0, planner.vehicle).limit_v)
    assert np.all(lane > 0.0) and np.all(lane < 30.0)
    hi = float(lane.max()) + 2.0
    raised = np.asarray(speed_road(sc, ctx, path, 30.0, planner.vehicle, hi).limit_v)
    low = np.asarray(speed_road(sc, ctx, path, 30.0, planner.vehicle, float(lane.min()) - 1.0).limit_v)
    assert np.allclose(raised, hi) and np.allclose(low, lane)


def test_route_path_join_from_a_turning_car_stays_between_the_car_and_the_route():
    """A car 0.8 m left of the route, heading 0.05 rad away from it and turning further away
    (curvature 0.02): the join starts with the car's offset, heading and curvature and comes back
    to the route without swinging across it (an earlier closed form missed the end conditions
    and swung metres into the next lane whenever the car started with a slope or curvature)."""
    planner, batch, _, _ = _drives()
    sc = jax.tree_util.tree_map(lambda x: x[2], batch)
    e0 = EgoState.from_box_centre(sc.start, planner.vehicle)
    ego = EgoState(e0.x - 0.8 * jnp.sin(e0.heading), e0.y + 0.8 * jnp.cos(e0.heading), e0.heading + 0.05, e0.v,
                   kappa=jnp.float32(0.02))
    ctx, path = _path_at(sc, ego, planner)
    s, l = np.asarray(path.s), np.asarray(path.l)
    i0 = int(np.argmin(np.abs(s)))
    assert float(path.kappa[i0]) == pytest.approx(0.02, abs=2e-3)
    ahead = s >= 0
    # the car's pull away from the route peaks and decays: the offset stays within a few metres
    # on the car's side of the route and never crosses to the other lane
    assert np.all(l[ahead] < 0.8 + 0.05 * 60.0 + 0.5 * 0.02 * 20.0 ** 2)
    assert np.all(l[ahead] > -0.5)
    assert np.all(np.abs(l[s > 70.0]) < 1e-4)


def test_config_checks_and_nonblocking_switch():
    with pytest.raises(ValueError, match="horizon"):
        PathSpeedPlanner(horizon=5.0)
    with pytest.raises(ValueError, match="w_blind"):
        PathSpeedPlanner().init_params({"w_blind": -1.0})
    with pytest.raises(TypeError, match="w_blinds"):
        PathSpeedPlanner().init_params({"w_blinds": 1.0})
    with pytest.raises(ValueError, match="qp_dt"):
        PathSpeedPlanner(speed=SpeedConfig(qp_dt=0.3))
    from jaxplan.bounds.path_planner import PathConfig
    with pytest.raises(ValueError, match="a_lat_max"):
        PathSpeedPlanner(path=PathConfig(a_lat_max=0.0))
    for name in ("lat_decel", "nudge_buffer", "nudge_window"):
        with pytest.raises(ValueError, match=f"PathConfig.{name} must be >= 0"):
            PathConfig(**{name: -0.1})
    p = PathSpeedPlanner(nonblocking=False)
    w = p.cost_weights(p.init_params(), jnp.float32(10.0))
    assert float(w.w_blind) == 0.0 and float(w.w_no_bypass) == 0.0 and float(w.v_cruise) == 10.0
    w = PathSpeedPlanner().cost_weights(p.init_params(), jnp.float32(10.0))
    assert float(w.w_blind) > 0.0 and float(w.w_no_bypass) > 0.0


def _lateral(log, rec, n):
    """The car's offset from its start lane's centre line at the first ``n`` steps (the road is straight)."""
    th = rec.scenario.ego.heading
    dx, dy = log.x[:n] - log.x[0], log.y[:n] - log.y[0]
    return -np.sin(th) * dx + np.cos(th) * dy


def _ahead_of(log, rec, k, n):
    """Station of obstacle ``k`` minus the car's at the first ``n`` steps."""
    th = rec.scenario.ego.heading
    b = np.asarray(rec.scene.obstacles.boxes[k, :n])
    return np.cos(th) * (b[:, 0] - log.x[:n]) + np.sin(th) * (b[:, 1] - log.y[:n])


@pytest.mark.parametrize("name", ["SLOW", "STOPPED"])
def test_passes_through_the_free_next_lane(name):
    log, m, rec = _synthetic_drive(name)
    n = int(log.end_step) + 1
    assert not m["overlap.collided"] and not m["offroad.offroad"], name
    assert _ahead_of(log, rec, 0, n)[-1] < -5.0  # ended ahead of the obstacle, not behind it
    assert np.max(_lateral(log, rec, n)) > 0.5 * builtin.LANE  # the car's centre over the lane line
    assert m["comfort.max_abs_lat_accel"] <= 4.0 and m["goal.reached"], name


def test_does_not_move_over_in_front_of_a_faster_car():
    """Whenever the car is over the lane line, the faster car is ahead of it or far enough behind to
    slow down to the car's speed at no more than 3 m/s^2."""
    log, m, rec = _synthetic_drive("FASTER")
    n = int(log.end_step) + 1
    assert not m["overlap.collided"]
    over = _lateral(log, rec, n) > 0.5 * builtin.LANE
    ahead = _ahead_of(log, rec, 1, n)
    gap = -ahead - 0.5 * 4.6 - 0.5 * PathSpeedPlanner().vehicle.length  # its front to the car's rear
    need = np.where(gap > 0, np.maximum(20.0 - log.v[:n], 0.0) ** 2 / (2.0 * np.maximum(gap, 1e-3)), np.inf)
    bad = over & (ahead < 0) & (need > 3.0)
    assert not bad.any(), np.nonzero(bad)[0]


def test_the_lane_decision_does_not_flip_between_cycles():
    """The lane change past the slow car, once taken, is kept for at least a second; in a scene that
    does not change it is taken and left at most once each (the stopped car is passed on the bounds
    path, with or without it)."""
    for name in ("SLOW",):
        log, _, _ = _synthetic_drive(name)
        cycles = int(log.end_step) // 3 + 1  # one plan every 3 steps
        change = np.asarray(log.info["lane_change"][:cycles], bool)
        flips = np.nonzero(np.diff(change.astype(int)))[0]
        assert change.any() and len(flips) <= 2, (name, change.astype(int))
        assert np.all(np.diff(flips) >= 4), (name, change.astype(int))  # 4 cycles = 1.2 s


def test_leaves_room_to_a_car_closing_in_from_behind():
    log, m, _ = _synthetic_drive("BEHIND")
    assert not m["overlap.collided"] and not m["offroad.offroad"]
    assert log.v[5] >= log.v[0]  # it does not brake in front of it


def test_passes_an_oncoming_car_inside_the_buffer_rather_than_be_hit_from_behind():
    """SQUEEZE: the speed plan with the 0.3 m buffer stops for the oncoming car that passes 0.15 m
    clear, and the car behind would hit it; the plan without the buffer (``tight``) is taken and
    the car drives on."""
    log, m, _ = _synthetic_drive("SQUEEZE")
    assert not m["overlap.collided"] and not m["offroad.offroad"]
    assert np.asarray(log.info["tight"]).any()
    assert log.v[: int(m["goal.step"]) + 1].min() > 5.0


def test_with_nobody_behind_the_oncoming_car_is_not_passed_inside_the_buffer():
    """ALONE: SQUEEZE without the car behind. Stopping is safe, so the plan without the buffer is
    never taken (it was wherever the buffered plan collided, follower or not)."""
    log, m, _ = _synthetic_drive("ALONE")
    assert not m["overlap.collided"] and not m["offroad.offroad"]
    assert not np.asarray(log.info["tight"]).any()


def test_the_drive_report_names_the_paths_taken_and_what_blocked():
    """``describe`` (the report's words for a drive's last plans): the lane change past the slow car,
    the plan without clearances past the oncoming car, and in hand-made ``info`` the plans with no
    collision-free profile and the blocking obstacles and stop lines of the last plan."""
    planner = PathSpeedPlanner()
    for name, word in (("SLOW", "lane change"), ("SQUEEZE", "no clearance")):
        log, _, _ = _synthetic_drive(name)
        c = int(log.end_step) // 3 + 1
        text = planner.describe({k: np.asarray(v)[:c] for k, v in log.info.items()})
        assert text.startswith(f"paths of the last {c} plans: ") and f"{word} x" in text, text
        counted = sum(int(x) for x in re.findall(r" x(\d+)", text))
        assert counted == c, text
    C = 3
    info = {"lane_change": np.zeros(C, bool), "tight": np.zeros(C, bool), "path_bounds": np.array([True, True, False]),
            "dp_feasible": np.array([True, False, False]), "n_obstacles": np.full(C, 2),
            "blocking": np.array([[False] * 3, [True, False, False], [False, True, True]])}
    assert planner.describe(info) == ("paths of the last 3 plans: bounds path x2, route path x1; 2 with no "
                                      "collision-free speed profile; blocking the last: obstacle 1, a stop line")
    info["dp_feasible"][:] = True
    info["blocking"][-1] = False
    assert planner.describe(info) == "paths of the last 3 plans: bounds path x2, route path x1"


def test_a_goal_before_the_end_of_the_map_is_met_at_speed():
    """The end of the mapped road beyond the goal region is no stop: the car meets the goal's speed
    range there (it slowed to stop before the map's end and entered the region too slow)."""
    log, m, _ = _synthetic_drive("MAPEND")
    assert m["goal.reached"] and not m["overlap.collided"] and not m["offroad.offroad"], m
    assert log.v[int(log.end_step)] >= 13.0


def test_a_dead_end_is_approached_as_gently_as_the_set_speed_slows():
    """DEADEND: the car stands before the end of the road without braking harder than the set
    speed's CURVE_DECEL (the DP kept the speed and braked late at its own limits, and a car
    following close behind hit it)."""
    log, m, rec = _synthetic_drive("DEADEND")
    n = int(log.end_step) + 1
    assert m["goal.reached"] and not m["overlap.collided"] and not m["offroad.offroad"], m
    assert log.v[n - 1] < 0.5  # it stands ...
    ahead = np.cos(rec.scenario.ego.heading) * (log.x[n - 1] - log.x[0]) + np.sin(rec.scenario.ego.heading) * (
        log.y[n - 1] - log.y[0]
    )
    assert 60.0 < ahead < 100.0 - 0.5 * PathSpeedPlanner().vehicle.length  # ... before the end
    assert np.diff(log.v[:n]).min() / 0.1 >= -(CURVE_DECEL + 0.5), np.diff(log.v[:n]).min() / 0.1


def test_a_dead_end_beyond_the_drive_is_no_reason_to_brake():
    """FAREND: the car cannot reach the end of the road before the goal's window closes (the drive
    ends then), so it keeps its speed (it braked to stand there, for a stop it would never reach)."""
    log, m, _ = _synthetic_drive("FAREND")
    n = int(log.end_step) + 1
    assert m["goal.reached"] and not m["overlap.collided"] and not m["offroad.offroad"], m
    assert np.diff(log.v[:n]).min() / 0.1 > -0.5 and log.v[n - 1] > 14.5, (np.diff(log.v[:n]).min() / 0.1, log.v[n - 1])


def _numpy_quintic(l0, m, k, d, length, n=2001):
    """``(l, d2l/ds2)`` of the quintic from ``(l0, m, k)`` to ``(d, 0, 0)`` over ``length``,
    solved here with numpy (independent of ``jaxplan.geometry.quintic``)."""
    L = length
    A = np.array([[L**3, L**4, L**5], [3 * L**2, 4 * L**3, 5 * L**4], [6 * L, 12 * L**2, 20 * L**3]])
    c3, c4, c5 = np.linalg.solve(A, [d - l0 - m * L - k * L * L / 2, -m - k * L, -k])
    x = np.linspace(0.0, L, n)
    return l0 + m * x + k * x**2 / 2 + c3 * x**3 + c4 * x**4 + c5 * x**5, k + 6 * c3 * x + 12 * c4 * x**2 + 20 * c5 * x**3


@pytest.mark.parametrize("slope", [0.344, 0.05])
def test_a_join_begun_while_moving_over_fast_stays_in_the_target_lane(slope):
    """A car 1.08 m short of its target lane's centre, moving over toward it at ``slope``
    (17 degrees: a lane change under way) at 7.16 m/s: the usual join (27.9 m) swings 1.05 m past
    the centre, out of a 3.5 m lane for a 1.8 m car; the join taken is shorter and stays within
    the room (0.65 m) at a comfortable lateral acceleration. A car moving over slowly keeps the
    usual length."""
    from jaxplan.speed.paths import join_length

    v, room, a_lat, start = 7.16, 0.65, 3.0, (2.417, slope, -0.00275)
    longest = float(np.clip(10.0 + 2.5 * v, 15.0, 60.0))
    got = float(join_length(tuple(jnp.float32(x) for x in start), jnp.float32(3.5), jnp.float32(v), a_lat, room))
    l, ddl = _numpy_quintic(*start, 3.5, got)
    assert l.max() - 3.5 <= room + 1e-3 and v * v * np.abs(ddl).max() <= a_lat + 1e-2, (got, l.max(), np.abs(ddl).max())
    if slope > 0.3:
        assert _numpy_quintic(*start, 3.5, longest)[0].max() - 3.5 > room  # the usual join would leave the lane
        assert got < longest
    else:
        assert got == pytest.approx(longest)


@pytest.mark.parametrize("kappa", [0.0, 1.0 / 250.0])
def test_the_lane_the_car_is_in_is_followed_where_the_route_changes_lanes(kappa):
    """Three lanes, the car in the right one, the goal in the middle one: the route changes lanes
    ahead of the car. ``car_lane`` follows the car's lane across the change: every point at its
    offset lies on the right lane's centre line (the road's own geometry, within 5 cm), while the
    route's own line ends a lane to the left; the route path joined to it stays in that lane too."""
    from test_sim import _record, _road_dict

    from jaxplan.geometry.frenet import to_cartesian
    from jaxplan.speed.paths import car_lane, path_stations

    far = ((builtin.START_S - 80.0, 2 * builtin.LANE, "static"),)  # one obstacle, well behind
    rec = _record(_road_dict(far, n_lanes=3, start_lane=0, kappa=kappa, v0=15.0))
    sc, planner = rec.scene, PathSpeedPlanner()
    ego = EgoState.from_box_centre(jnp.asarray(sc.start), planner.vehicle)
    ego = dataclasses.replace(ego, kappa=jnp.float32(kappa))  # driving along its lane
    ctx = road_context(sc, ego, 0, planner.horizon_steps, planner.vehicle)
    u = path_stations(120, 20.0, planner.path_ahead, jnp.float32)  # the stations of planner.route_path
    l_car, near = car_lane(sc, ctx, ctx.s + u)
    assert bool(jnp.all(near))
    with pytest.raises(ValueError, match="n must be at least 3"):
        path_stations(2, 20.0, 100.0, jnp.float32)
    assert float(l_car[-1]) == pytest.approx(-builtin.LANE, abs=0.05)  # the route ends in the middle lane
    assert float(jnp.max(jnp.abs(l_car[u <= 0]))) < 0.05  # where the car is, the route is in its lane
    lane0 = sg.LineString([builtin.SyntheticRoad(kappa, 0.3).pose(s, 0.0)[0] for s in np.linspace(0.0, 400.0, 801)])
    # the scene's coordinates are relative to the car's start (the loader's origin)
    origin = np.asarray(builtin.SyntheticRoad(kappa, 0.3).pose(builtin.START_S, 0.0)[0])
    xy = np.asarray(to_cartesian(sc.route, ctx.s + u, l_car)) + origin
    gap = max(lane0.distance(sg.Point(p)) for p in xy)
    assert gap < 0.05, gap
    # the path joins it from the car's own heading and curvature (lane offsets are stored at route
    # points, to a centimetre or two): ahead of the car within 10 cm of the lane's centre
    path = planner.route_path(sc, ctx, ego, 120, l_car)
    gap = max(lane0.distance(sg.Point(p)) for p in np.asarray(path.xy)[np.asarray(path.s) >= 0] + origin)
    assert gap < 0.1, gap
