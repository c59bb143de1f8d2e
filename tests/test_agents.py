"""Reactive traffic and predictions: IDM agents (``jaxplan.sim.agents``), what the planner sees
(``jaxplan.sim.prediction``), the traffic as driven (``DriveLog.traffic``, ``driven_scene``)."""
import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.baselines import BrakePlanner
from jaxplan.geometry.boxes import box_separation
from jaxplan.plan_context import road_context
from jaxplan.planner import PlanOutput
from jaxplan.scenarios import builtin
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.scenarios.build import build_scene
from jaxplan.scenarios.loader import parse_scenario
from jaxplan.scenarios.scene import SceneRecord
from jaxplan.sim import SimConfig, driven_scene, evaluate_batch, rollout
from jaxplan.sim.agents import AgentParams
from test_sim import _road_dict

T = np.arange(251) * 0.1
STEPS = 80
STILL = BrakePlanner(decel=5.0)  # the car starts at rest and stays there


def _scene(d):
    sc = parse_scenario(d, d["id"])
    return SceneRecord(d["id"], build_scene(sc)[0], sc, None)


def _late_car(oid, road, s, l, t_on, t_off):
    """A car recorded only from ``t_on`` to ``t_off`` (s)."""
    car = builtin.road_obstacle(oid, road, s, l)
    car["states"] = [[round(st[0] + t_on, 4)] + st[1:] for st in car["states"] if st[0] + t_on <= t_off + 1e-9]
    return car


@functools.lru_cache(maxsize=1)
def _follow_case():
    """Two scenes driven with the car at rest, by recorded and by IDM traffic (one compiled drive each):
    ``through``: a car recorded to drive through the car's position at 10 m/s; ``free``, on a curve: a
    car accelerating past in the next lane and a car recorded from 2 s to 6 s, ahead in the car's lane."""
    through = _road_dict(obstacles=[(builtin.START_S - 40.0 + 10.0 * T, np.zeros(251))], v0=0.0)
    v = np.minimum(6.0 + 2.0 * T, 14.0)
    free = _road_dict(obstacles=[(builtin.START_S - 10.0 + np.cumsum(v) * 0.1, np.full(251, 3.5))], v0=0.0,
                      kappa=1 / 150.0)
    road = builtin.SyntheticRoad(1 / 150.0, 0.3)
    free["obstacles"].append(_late_car(2, road, builtin.START_S + 30.0 + 8.0 * T, np.zeros(251), 2.0, 6.0))
    recs = [_scene(through), _scene(free)]
    batch = stack_scenes([r.scene for r in recs], min_steps=STEPS + 1)
    logs = {a: rollout(STILL, batch, SimConfig(n_steps=STEPS, stop_at_goal=False, agents=a)) for a in ("log", "idm")}
    return batch, logs


def _car_boxes(log, i):
    car = STILL.vehicle
    n = log.x.shape[1]
    return np.stack([log.x[i], log.y[i], np.full(n, car.length), np.full(n, car.width), log.heading[i]], -1)


def test_idm_follower_stops_behind_the_car_that_the_recording_drives_through():
    batch, logs = _follow_case()
    ego = _car_boxes(logs["idm"], 0)
    tr = logs["idm"].traffic
    agent, there = np.asarray(tr.boxes[0, 0]), np.asarray(tr.valid[0, 0])
    assert there.all() and tr.boxes.shape[1:] == (batch.obstacles.boxes.shape[1], STEPS + 1, 5)
    sep = np.asarray(box_separation(jnp.asarray(ego), jnp.asarray(agent)))
    assert sep.min() > 0.3  # never touches the car
    u = np.array([math.cos(ego[0, 4]), math.sin(ego[0, 4])])
    gap = (ego[-1, :2] - agent[-1, :2]) @ u - 0.5 * (ego[-1, 2] + agent[-1, 2])  # bumper to bumper, behind it
    assert 0.5 < gap < 2.0 and np.hypot(*(agent[-1, :2] - agent[-5, :2])) < 0.01  # stopped behind it
    # the metrics judge the traffic as driven: IDM traffic never touches the car, the recording drives through it
    m = {a: evaluate_batch(logs[a], driven_scene(logs[a], batch), STILL.vehicle) for a in ("log", "idm")}
    assert bool(m["log"]["overlap.collided"][0]) and not bool(m["idm"]["overlap.collided"][0])
    assert bool(evaluate_batch(logs["idm"], batch, STILL.vehicle)["overlap.collided"][0])  # judged on the recording
    assert float(m["idm"]["overlap.min_separation"][0]) == pytest.approx(sep.min(), abs=1e-3)


def test_unobstructed_idm_agents_keep_their_recorded_paths_times_and_presence():
    batch, logs = _follow_case()
    tr, rec = logs["idm"].traffic, batch.obstacles.window(0, STEPS + 1)
    np.testing.assert_array_equal(np.asarray(tr.valid[1]), np.asarray(rec.valid[1]))
    late = np.asarray(tr.valid[1, 1])
    assert not late[:20].any() and late[20:61].all() and not late[61:].any()  # there from 2 s to 6 s
    ok = np.asarray(rec.valid[1])
    err = np.hypot(*(np.asarray(tr.boxes[1, ..., :2]) - np.asarray(rec.boxes[1, ..., :2])).transpose(2, 0, 1))
    assert err[ok].max() < 0.05  # the accelerating car passing in the next lane and the late one: their logs
    dh = np.angle(np.exp(1j * (np.asarray(tr.boxes[1, ..., 4]) - np.asarray(rec.boxes[1, ..., 4]))))
    assert np.abs(dh[ok]).max() < 0.01
    # with recorded traffic the log's traffic is the recording itself
    np.testing.assert_array_equal(np.asarray(logs["log"].traffic.boxes), np.asarray(rec.boxes))


R_CURVE = 60.0


@dataclasses.dataclass(frozen=True)
class _Spy(BrakePlanner):
    """Brakes; its info is what it saw of the traffic (``road_context``)."""

    def plan(self, params, scene, ego, step):
        out = super().plan(params, scene, ego, step)
        ctx = road_context(scene, ego, step, self.horizon_steps, self.vehicle)
        return PlanOutput(out.trajectory, out.ok, {"boxes": ctx.obstacles.boxes, "valid": ctx.obstacles.valid,
                                                   "s": ctx.obstacle_s, "l": ctx.obstacle_l})


def _curve_scene():
    """A curve of radius 60 m: a car 20 m ahead in the left lane at 10 m/s that brakes hard
    (8 m/s^2) from 2 s on, and a pedestrian walking along that lane further ahead."""
    v = np.where(T < 2.0, 10.0, np.maximum(10.0 - 8.0 * (T - 2.0), 0.0))
    d = _road_dict(obstacles=[(builtin.START_S + 20.0 + np.cumsum(v) * 0.1, np.full(251, 3.5))], v0=0.0,
                   kappa=1 / R_CURVE)
    road = builtin.SyntheticRoad(1 / R_CURVE, 0.3)
    d["obstacles"].append(builtin.road_obstacle(2, road, builtin.START_S + 70.0 + 1.5 * T, np.full(251, 3.5), length=0.6,
                                       width=0.6, kind="pedestrian"))
    return _scene(d), road


def test_cv_predictions_follow_the_lane_and_the_planner_sees_no_recorded_future():
    rec, road = _curve_scene()
    assert rec.scene.lane_paths.shape[1:] == (64, 2) and rec.scene.lane_path_valid.all()
    batch = stack_scenes([rec.scene], min_steps=STEPS + 1)
    log = rollout(_Spy(decel=5.0), batch, SimConfig(n_steps=30, stop_at_goal=False, prediction="cv"))
    seen = jax.tree_util.tree_map(lambda a: np.asarray(a[0]), log.info)
    org = np.asarray(rec.scenario.origin)
    pts, _ = road.pose(np.array([0.0, 50.0, 100.0]), np.zeros(3))  # the circle the road's lanes are arcs of
    A = 2 * (pts[1:] - pts[0])
    centre = np.linalg.solve(A, (pts[1:] ** 2).sum(1) - (pts[0] ** 2).sum())
    recorded = np.asarray(batch.obstacles.boxes[0, 0, :, :2])
    for c, step in ((0, 0), (5, 15)):
        b, ok = seen["boxes"][c], seen["valid"][c]  # (K, H, 5) from this cycle's step on
        H = b.shape[1]
        assert ok[:2].all()
        radius = np.hypot(*(b[0, :, :2] + org - centre).T)
        np.testing.assert_allclose(radius, R_CURVE - 3.5, atol=0.05)  # along its lane, the left one
        chord = b[0, -1, :2] - b[0, 0, :2]
        u = np.array([math.cos(b[0, 0, 4]), math.sin(b[0, 0, 4])])
        assert abs(u[0] * chord[1] - u[1] * chord[0]) > 5.0  # far from the straight line along its heading
        speed = np.hypot(*np.diff(b[0, :, :2], axis=0).T) / 0.1
        np.testing.assert_allclose(speed, 10.0 * (R_CURVE - 3.5) / R_CURVE, rtol=0.01)  # constant: no braking
        ahead = (np.hypot(*(b[0, -1, :2] - b[0, 0, :2])) - np.hypot(*(recorded[step + H - 1] - recorded[step])))
        assert ahead > 15.0  # the recording stops by 3.25 s; the prediction does not know
        # the pedestrian goes straight along its heading
        p = b[1, :, :2] - b[1, 0, :2]
        w = np.array([math.cos(b[1, 0, 4]), math.sin(b[1, 0, 4])])
        np.testing.assert_allclose(p[:, 0] * w[1] - p[:, 1] * w[0], 0.0, atol=1e-3)
        assert np.hypot(*p[-1]) == pytest.approx(1.5 * (R_CURVE - 3.5) / R_CURVE * (H - 1) * 0.1, rel=0.02)
        # the Frenet coordinates the planner reads are those of the predicted boxes
        from jaxplan.geometry.frenet import to_frenet

        s, l = to_frenet(jax.tree_util.tree_map(lambda a: a[0], batch.route), jnp.asarray(b[..., :2]))
        np.testing.assert_allclose(seen["s"][c], np.asarray(s), atol=2e-3)
        np.testing.assert_allclose(seen["l"][c], np.asarray(l), atol=2e-3)


def test_the_planners_view_holds_only_the_predictions():
    from jaxplan.sim.prediction import lane_cache, planner_view

    rec, _ = _curve_scene()
    scene = jax.tree_util.tree_map(lambda a: a[0], stack_scenes([rec.scene], min_steps=101))
    view = jax.jit(lambda st: planner_view(scene, st, 51, 120, "cv", lanes=lane_cache(scene)))(jnp.asarray(30))
    valid = np.asarray(view.obstacles.valid)
    assert not valid[:, :30].any() and not valid[:, 81:].any() and valid[:, 30:81].all()
    boxes = np.asarray(view.obstacles.boxes)
    assert (boxes[:, :30, :2] == 0).all() and (boxes[:, 81:, :2] == 0).all()
    assert view.obstacles.boxes.shape == (2, 120, 5) and view.obstacle_sl.shape == (2, 120, 2)
    assert planner_view(scene, 30, 51, 120, "oracle") is scene  # recorded traffic, oracle: the scene itself


def test_log_agents_with_oracle_predictions_drive_as_before():
    """With recorded traffic and its recorded future the drive is the one this simulator drove before
    the reactive agents existed (these figures were computed by it), periodic and lazy."""
    from jaxplan.baselines import IDMPlanner

    rec = _scene(_road_dict(obstacles=[(builtin.START_S + 25.0 + 6.0 * T, np.zeros(251)),
                                       (builtin.START_S + 60.0, 3.5, "static")], v0=12.0, kappa=1 / 200.0))
    batch = stack_scenes([rec.scene], min_steps=61)
    before = {"periodic": ([0.0, 12.9174, 22.573, 30.8063, 38.2653], [0.0, 6.795, 12.734, 18.4233, 24.1311], 20),
              "lazy": ([0.0, 12.9118, 22.5613, 30.7937, 38.2519], [0.0, 6.8048, 12.7521, 18.4409, 24.148], 2)}
    v_before = [12.0, 8.286, 7.002, 6.414, 6.1442]
    k = [0, 15, 30, 45, 60]
    for replan, (x, y, n) in before.items():
        log = rollout(IDMPlanner(), batch, SimConfig(n_steps=60, replan=replan, stop_at_goal=False))
        np.testing.assert_allclose(np.asarray(log.x[0, k]), x, atol=2e-3)
        np.testing.assert_allclose(np.asarray(log.y[0, k]), y, atol=2e-3)
        np.testing.assert_allclose(np.asarray(log.v[0, k]), v_before, atol=2e-3)
        assert int(log.replanned[0].sum()) == n
        w = batch.obstacles.window(0, 61)
        np.testing.assert_array_equal(np.asarray(log.traffic.boxes[0]), np.asarray(w.boxes[0]))
        np.testing.assert_array_equal(np.asarray(log.traffic.valid[0]), np.asarray(w.valid[0]))


def test_lattice_drives_among_idm_agents_with_cv_predictions():
    from jaxplan.lattice.planner import LatticePlanner

    rng = np.random.default_rng(3)
    recs = [_scene(builtin.scene_dict(kind, rng, 0)) for kind in ("slow_leader", "dense_next_lane")]
    batch = stack_scenes([r.scene for r in recs], min_steps=61)
    planner = LatticePlanner()
    log = rollout(planner, batch, SimConfig(n_steps=60, stop_at_goal=False, agents="idm", prediction="cv"))
    assert np.isfinite(np.asarray(log.x)).all() and not np.asarray(log.fallback).any()
    assert log.traffic.boxes.shape == (2, batch.obstacles.boxes.shape[1], 61, 5)
    m = evaluate_batch(log, driven_scene(log, batch), planner.vehicle)
    assert not np.asarray(m["overlap.collided"]).any()
    rec_valid = jax.vmap(lambda o: o.window(0, 61))(batch.obstacles).valid
    np.testing.assert_array_equal(np.asarray(log.traffic.valid), np.asarray(rec_valid))


def test_bad_traffic_settings_one_line():
    for cfg, msg in ((SimConfig(agents="reactive"), "SimConfig.agents must be one of log, idm"),
                     (SimConfig(prediction="future"), "SimConfig.prediction must be one of oracle, cv"),
                     (SimConfig(agents="idm", agent_params=AgentParams(a_max=-1.0)), "AgentParams.a_max"),
                     (SimConfig(agent_params=AgentParams(look_ahead_points=1)), "look_ahead_points")):
        with pytest.raises(ValueError, match=msg) as e:
            cfg.validate()
        assert "\n" not in str(e.value)
    hash(SimConfig(agents="idm", prediction="cv"))  # static under jit
    batch = stack_scenes([_scene(_road_dict()).scene])
    with pytest.raises(ValueError, match="SimConfig.agents must be one of log, idm"):  # before anything compiles
        rollout(STILL, batch, SimConfig(n_steps=5, agents="reactive"))


def test_lane_paths_padded_and_checked():
    d = _road_dict(n_lanes=3)
    one = _scene(d).scene  # 3 lanelets of 450 m: a path from every 50 m of each
    assert one.lane_paths.shape == (27, 64, 2)
    length = np.hypot(*np.diff(one.lane_paths, axis=1).transpose(2, 0, 1)).sum(1)
    np.testing.assert_allclose(length, np.tile([150.0] * 7 + [100.0, 50.0], 3), rtol=1e-3)  # to the road's end
    two = _scene(_road_dict(n_lanes=2)).scene
    batch = stack_scenes([one, two])
    assert batch.lane_paths.shape == (2, 27, 64, 2) and not np.asarray(batch.lane_path_valid[1, 18:]).any()
    bad = dataclasses.replace(one, lane_path_valid=one.lane_path_valid[:, :10])
    with pytest.raises(ValueError, match="Scene.lane_paths"):
        bad.validate()


def test_one_idm_formula():
    """The baseline planner and the tuning suite's IDM are the model's formula with their own parameters."""
    from jaxplan.baselines.idm import IDMParams as PlannerIDM, idm_accel as planner_accel
    from jaxplan.models import idm_accel
    from jaxplan.tuning.traffic import IDMParams as TuningIDM, idm_accel as tuning_accel
    from idm_oracle import idm_step

    v, v_des, gap, v_lead = 12.0, 15.0, 20.0, 9.0
    p = PlannerIDM()
    a = float(idm_accel(v, v_des, gap, v - v_lead, a_max=p.a_max, b_comf=p.b_comf, time_gap=p.time_gap,
                        min_gap=p.min_gap, delta=p.delta))
    assert float(planner_accel(v, v_des, gap, v - v_lead, p)) == pytest.approx(max(a, -p.b_max), rel=1e-6)
    q = TuningIDM()
    b = float(tuning_accel(q, v, v_des, gap, v_lead, True))
    s1, v1 = idm_step(0.0, v, v_des, q, 0.1, gap, v_lead)
    assert v1 == pytest.approx(v + 0.1 * b, rel=1e-6)
    assert float(tuning_accel(q, v, v_des, gap, v_lead, False)) == pytest.approx(q.a_max * (1 - (v / v_des) ** 4))


def test_braking_profile_matches_small_step_integration(rng):
    """``braking_profile`` against Euler integration at 1 ms (speed clipped at rest): distance,
    speed and acceleration, for random speeds, decelerations and times, before and after the stop."""
    from jaxplan.models import braking_profile

    for _ in range(20):
        v0, a = rng.uniform(0.0, 30.0), -rng.uniform(0.5, 9.0)
        t = np.sort(rng.uniform(0.0, 2.0 * v0 / -a + 1.0, 8))
        out = braking_profile(jnp.float32(v0), jnp.float32(a), jnp.asarray(t, jnp.float32))
        s, v, acc = (np.asarray(x, np.float64) for x in out)
        h = 1e-3
        n = int(np.ceil(t[-1] / h)) + 1
        vv = np.maximum(v0 + a * h * np.arange(n + 1), 0.0)
        ss = np.concatenate([[0.0], np.cumsum(0.5 * (vv[1:] + vv[:-1]) * h)])
        i = np.round(t / h).astype(int)
        assert np.allclose(s, ss[i], atol=0.02 + 1e-3 * v0) and np.allclose(v, vv[i], atol=0.01 + 1e-3 * v0)
        t_stop = v0 / -a
        assert np.all(acc[t < t_stop - 1e-3] == np.float32(a)) and np.all(acc[t > t_stop + 1e-3] == 0.0)
