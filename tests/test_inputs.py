"""Issue 13, items 1-7: inputs that mean what they say (every test failed on the code before the fix).

1 static obstacles held over any horizon (lattice, suites, tuning data, CommonRoad);
2 reference lines extended backwards; 3 ``Obstacles.t`` honoured by the lattice (the speed
planner already resampled: test_speed_dp plans against 0.5 s predictions); 4 reference lines
checked on the host and NaN plans never reported valid; 5 weights refused when NaN,
negative or misspelled; 6 finite gradients against finite differences; 7 float32 range,
batched states, ``plan_batch`` defaults, negative start speed.
"""
import copy
import functools
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry.frenet import ReferenceLine, reference_line
from jaxplan.lattice import FREE, CostWeights, LatticeConfig, PlanState, plan, plan_batch
from jaxplan.scenarios.loader import ScenarioError, parse_scenario
from jaxplan.types import Obstacles
from test_loader import _minimal

CFG = LatticeConfig(escalation=(1.0,), horizon=3.0)  # shared by the tests below: one compiled plan per shape
T = CFG.n_steps


def _road(n=60, x0=-10.0, x1=150.0):
    x = np.linspace(x0, x1, n)
    return np.column_stack([x, np.zeros(n)])


REF = ReferenceLine.from_polyline(_road())


def _lead(t, x0=15.0, v=10.0):
    """A lead car in the ego lane: boxes ``(1, len(t), 5)``."""
    t = np.asarray(t, float)
    return np.stack([x0 + v * t, 0 * t, 4.5 + 0 * t, 1.8 + 0 * t, 0 * t], -1)[None].astype(np.float32)


def _obs(boxes, t, k=50):
    """``boxes (K0, T, 5)`` padded with invalid entries to ``k`` obstacles (the shapes of
    test_robustness_planners' plans, so the suite compiles one plan for both files)."""
    b = np.concatenate([boxes, np.tile(np.float32([0, 0, 1, 1, 0]), (k - len(boxes), boxes.shape[1], 1))])
    v = np.arange(k)[:, None] < len(boxes)
    return Obstacles(jnp.asarray(b), jnp.asarray(np.broadcast_to(v, b.shape[:2])), jnp.asarray(t, jnp.float32))


def _static_only_scene():
    """A ZAM_Over-1_1-like file: one static box 28 m ahead in the lane, no moving obstacle (1 time step)."""
    d = _minimal()
    d["obstacles"] = [{"id": 8, "role": "static", "type": "parkedVehicle", "length": 4.8, "width": 2.0,
                       "center": [38.0, 0.5], "orientation": 0.0}]
    return d


# ------------------------------------------------------------ static obstacles


def test_static_obstacle_blocks_the_whole_horizon():
    sc = parse_scenario(_static_only_scene(), "static.json")
    assert sc.obstacles.boxes.shape[1] == 1  # one time step, as in ZAM_Over-1_1
    res = plan(PlanState.make(0.0, 0.0, 0.0, 8.0), REF, sc.obstacles, CFG)
    col = np.asarray(res.collided)
    not_slower = np.asarray(res.candidates.v_end) >= 8.0 - 1e-4
    # every candidate that keeps or raises the speed drives into the parked box (after 2 s)
    assert not_slower.sum() == 15 and col[not_slower].all()
    assert np.all(np.asarray(res.first_t)[not_slower] > 1.5)  # not at t = 0: the box is held
    assert not col[int(res.chosen)] and float(res.candidates.v_end[int(res.chosen)]) < 8.0
    assert bool(sc.obstacles.static[0])


def test_suites_and_demonstrations_hold_static_obstacles(tmp_path):
    from jaxplan.eval.lattice_suite import recorded_obstacles
    from jaxplan.eval.speed_suite import recorded_scenes
    from jaxplan.tuning.demos import scenario_demos

    d = _minimal()
    states = [[0.1 * k, 20.0 + 10.0 * 0.1 * k, 0.0, 0.0, 10.0, 0.0] for k in range(60)]  # 6 s recording
    d["obstacles"][0]["states"] = states
    d["obstacles"][1]["center"] = [28.0, 3.5]  # static, beside the lane (role static)
    sc = parse_scenario(d, "s.json")
    assert list(np.asarray(sc.obstacles.static)) == [False, True]
    obs = recorded_obstacles(sc, LatticeConfig(horizon=12.0))  # longer than the 6 s recording
    st = np.asarray(obs.static)
    v = np.asarray(obs.valid)
    assert st.sum() == 1 and v[st].all()  # held to the end of the horizon
    dyn = np.nonzero(v.any(1) & ~st)[0]
    assert len(dyn) == 1 and v[dyn[0], :60].all() and not v[dyn[0], 60:].any()  # gone when its recording ends
    # the speed suite's recorded scenes: the static box valid over any window of the drive
    (tmp_path / "s.json").write_text(json.dumps(d))
    recs, _ = recorded_scenes(str(tmp_path))
    ob = recs[0].scene.obstacles
    st, wv = np.asarray(ob.static), np.asarray(ob.window(100, 71).valid)  # 10 s in: past the 6 s recording
    dyn = ~st & np.asarray(ob.valid).any(-1)
    assert st.sum() == 1 and dyn.sum() == 1 and wv[st].all() and not wv[dyn].any()
    # demonstrations carry the flag to the lattice used for tuning
    demos, _ = scenario_demos(sc)
    assert demos and all(bool(np.any(dm.obstacle_static)) for dm in demos)


def test_commonroad_static_held_dynamic_gone_after_its_recording():
    pytest.importorskip("commonroad", reason="commonroad-io not installed (extra jaxplan[commonroad])")
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.prediction.prediction import TrajectoryPrediction
    from commonroad.scenario.trajectory import Trajectory as CRTrajectory

    from conftest import shared_data_or_skip
    from jaxplan.scenarios.commonroad import commonroad_to_dict, load_commonroad

    folder = shared_data_or_skip("commonroad2020a")
    over = load_commonroad(os.path.join(folder, "ZAM_Over-1_1.xml"))  # only a static obstacle, 1 step
    assert bool(over.obstacles.static[0]) and np.asarray(over.obstacles.aligned(51).valid).all()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cr, pps = CommonRoadFileReader(os.path.join(folder, "DEU_Test-1_1_T-1.xml")).open()
    car = cr.dynamic_obstacles[0]  # cut its recording to 1 s
    tr = car.prediction.trajectory
    car.prediction = TrajectoryPrediction(CRTrajectory(tr.initial_time_step, tr.state_list[:9]), car.obstacle_shape)
    sc = parse_scenario(commonroad_to_dict(cr, pps), "cut.xml")
    assert list(np.asarray(sc.obstacles.static)) == [False, True]
    v = np.asarray(sc.obstacles.aligned(50).valid)
    assert v[1].all() and v[0, :10].all() and not v[0, 10:].any()


# ------------------------------------------------------------------- polylines


def test_polylines_extend_backwards_behind_the_start():
    from jaxplan.scenarios.polylines import resample_polyline

    xy = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    np.testing.assert_allclose(resample_polyline(xy, np.array([0.0, 1, 2]), np.array([-2.0, 3.5])),
                               [[-2.0, 0.0], [3.5, 0.0]])
    # a bent line: behind the start along the first chord, beyond the end along the last
    xy = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 9.0]])
    q = resample_polyline(xy, np.array([0.0, 5.0, 10.0]), np.array([-5.0, 12.0]))
    np.testing.assert_allclose(q, [[-3.0, -4.0], [3.0, 11.0]], atol=1e-12)


# ----------------------------------------------------------------- time stamps


def test_obstacle_time_stamps_are_honoured():
    st = PlanState.make(0.0, 0.0, 0.0, 15.0)
    fine = np.arange(T) * CFG.dt          # 0.1 s, the planner's grid
    coarse = np.arange(T) * 0.2           # the same lead car sampled at 0.2 s (6 s of it)
    a = plan(st, REF, _obs(_lead(fine), fine), CFG)
    b = plan(st, REF, _obs(_lead(coarse), coarse), CFG)
    np.testing.assert_array_equal(np.asarray(a.collided), np.asarray(b.collided))
    np.testing.assert_allclose(np.asarray(a.min_sep), np.asarray(b.min_sep), atol=1e-4)
    assert int(a.chosen) == int(b.chosen)
    keep = np.abs(np.asarray(a.candidates.v_end) - 15.0) < 1e-4
    assert np.asarray(b.collided)[keep].all()  # read as 0.1 s samples, the lead would run away: free
    # a window of a recording is stamped from its first step ("now")
    rec = _obs(_lead(np.arange(80) * 0.1, x0=-15.0), np.arange(80) * 0.1)
    w = rec.window(30, T)  # steps 30 .. 60 of an 8 s recording
    np.testing.assert_allclose(np.asarray(w.t), fine, atol=1e-6)
    c = plan(st, REF, w, CFG)
    np.testing.assert_array_equal(np.asarray(c.collided), np.asarray(a.collided))


# ------------------------------------------------- bad reference lines and NaN


def _dup_xy():
    xy = _road(59)
    return np.insert(xy, 6, xy[6], axis=0).astype(np.float32)  # a repeated point just ahead of the car (60 points)


def test_plan_refuses_a_reference_line_with_repeated_points():
    ref = reference_line(jnp.asarray(_dup_xy()))  # the jittable constructor keeps the repeated point
    with pytest.raises(ValueError, match="reference line: points 6 and 7 coincide"):
        plan(PlanState.make(0.0, 0.0, 0.0, 10.0), ref, Obstacles.empty(jnp.arange(T) * CFG.dt), CFG)


def test_nan_inside_jit_is_never_a_valid_free_plan():
    from jaxplan.lattice.plan import plan_kernel  # the jitted kernel plan dispatches to: no host checks

    st = PlanState.make(0.0, 0.0, 0.0, 8.0)
    obs = parse_scenario(_static_only_scene(), "static.json").obstacles  # the static-obstacle test's shapes: no new compile
    nan_obs = Obstacles(obs.boxes.at[0, 0, 0].set(jnp.nan), obs.valid, obs.t, obs.static)
    # called as plan calls it (jit's cache tells explicit arguments from defaults)
    bad = [plan_kernel(st, ref, o, CFG, CostWeights(), None, True)
           for ref, o in ((reference_line(jnp.asarray(_dup_xy())), obs), (REF, nan_obs))]
    for res in bad:
        assert int(res.mode) != FREE and np.asarray(res.collided).all()  # never a free plan
    from jaxplan.lattice import INVALID

    for res in bad:
        assert not bool(res.ok) and int(res.mode) == INVALID and not np.asarray(res.finite).any()
    good = plan_kernel(st, REF, obs, CFG, CostWeights(), None, True)
    assert bool(good.ok) and int(good.mode) == FREE and np.asarray(good.finite).all()


# --------------------------------------------------------------------- weights


@pytest.mark.parametrize("field,value", [("alpha", float("nan")), ("beta", -1.0), ("gamma", float("inf"))])
def test_bad_weights_are_refused_naming_the_field(field, value):
    w = CostWeights(**{field: value})
    with pytest.raises(ValueError, match=f"CostWeights.{field}"):
        plan(PlanState.make(0.0, 0.0, 0.0, 10.0), REF, Obstacles.empty(jnp.arange(T) * CFG.dt), CFG, w)
    with pytest.raises(ValueError, match=f"CostWeights.{field}"):
        w.validate()


def test_speed_weights_are_refused_naming_the_field():
    from jaxplan.speed import CostWeights as SpeedWeights
    from jaxplan.speed import SpeedConfig, plan_speed

    path = ReferenceLine.from_polyline(_road(20))
    with pytest.raises(ValueError, match="CostWeights.w_jerk"):
        plan_speed(path, Obstacles.empty(jnp.arange(8) * 1.0), SpeedConfig(), SpeedWeights(w_jerk=-0.5), v0=5.0)


def test_weights_file_with_a_misspelled_name(tmp_path):
    from jaxplan.eval.registry import SuiteArgs
    from jaxplan.eval.tune_suite import load_suite_weights

    p = tmp_path / "w.json"
    p.write_text(json.dumps({"weights": {"alhpa": 2.0, "beta": 5.0}, "meta": {"planner": "lattice"}}))
    with pytest.raises(ValueError) as e:
        load_suite_weights(SuiteArgs(out=str(tmp_path), weights=str(p)))
    msg = str(e.value)
    assert str(p) in msg and "'alhpa'" in msg and "alpha, beta, gamma, delta, collision, level" in msg
    p.write_text(json.dumps({"weights": {"w_speed": 2.0}, "meta": {"planner": "speed"}}))
    with pytest.raises(ValueError, match="'speed' planner"):
        load_suite_weights(SuiteArgs(out=str(tmp_path), weights=str(p)))


# ------------------------------------------------------------------- gradients


def test_gradients_wrt_state_and_obstacles_are_finite_and_match_finite_differences():
    from jaxplan.lattice.cost import FEATURES
    from jaxplan.lattice.plan import plan_unchecked

    cfg = LatticeConfig()  # the default config: jerk profile, escalation, broad-phase collision check
    # one weighted sum of every feature of every candidate, and of where the candidates end (x, y, s,
    # v): a NaN / inf in the gradient of any of them shows in its gradient (NaN and inf never cancel)
    feat = dict(zip(("d_lrp", "rho_max", "risk", "speed", "collision", "level_free"), (1.0, 30.0, 0.7, 0.5, 3.0, 0.2)))
    mix = np.array([feat.get(f, 0.1) for f in FEATURES] + [0.01, 0.02, 0.01, 0.1])  # every feature, then the ends
    with jax.enable_x64(True):
        t = jnp.arange(cfg.n_steps) * cfg.dt
        xs = np.linspace(-10, 200, 60)
        straight, curved = (np.column_stack([xs, y]) for y in (0 * xs, 2 * np.sin(xs / 40)))
        valid = jnp.ones((1, cfg.n_steps), bool)

        def score(x, boxes, ref_xy):
            st = PlanState(x[0], x[1], x[2], x[3], x[4], x[5], x[4], jnp.inf)
            r = plan_unchecked(st, reference_line(ref_xy), Obstacles(boxes, valid, t), cfg, CostWeights())
            tr = r.candidates.traj
            parts = jnp.concatenate([r.features.sum(0), jnp.stack([f[:, -1].sum() for f in (tr.x, tr.y, tr.s, tr.v)])])
            return jnp.sum(parts * mix), parts

        # a one-off program: XLA's cheapest optimisation level keeps its compile short
        @functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0,
                                                      "xla_llvm_disable_expensive_passes": True})
        def grad_and_fd(x, boxes, ref_xy, dx, db, eps):
            (gx, gb), parts = jax.grad(score, (0, 1), has_aux=True)(x, boxes, ref_xy)
            sign = jnp.array([1.0, -1.0])  # both sides in one (vmapped) copy of the program
            both = jax.vmap(lambda s: score(x + s * eps * dx, boxes + s * eps * db, ref_xy)[0])(sign)
            return gx, gb, (both[0] - both[1]) / (2 * eps), parts

        lead = jnp.asarray(np.stack([20 + 5 * t, 0.3 + 0 * t, 4.5 + 0 * t, 1.8 + 0 * t, 0.05 + 0 * t], -1)[None])
        rng = np.random.default_rng(0)
        dx = jnp.asarray(rng.normal(size=6) * [0.3, 0.1, 0.01, 1e-4, 0.5, 0.2])
        db = jnp.asarray(rng.normal(size=lead.shape) * [0.3, 0.1, 0.0, 0.0, 0.01])
        # (x, y, heading, kappa, v, a): on a straight line at a = 0 (the defaults) the 0 km/h candidate's
        # peak acceleration is sqrt(0); some candidates stop (zero chord lengths); off the line of a
        # curved road at a = 0.3 every term is smooth: the finite-difference check
        runs = [[np.asarray(a) for a in grad_and_fd(jnp.asarray(x0), lead, jnp.asarray(xy), dx, db, 1e-6)]
                for x0, xy in (([0.0, 0.0, 0.0, 0.0, 8.0, 0.0], straight), ([0.0, 0.1, 0.02, 0.001, 8.0, 0.3], curved))]
    for gx, gb, _, parts in runs:
        assert np.all(np.isfinite(gx)), f"non-finite gradient w.r.t. the start state: {gx}"
        assert np.all(np.isfinite(gb)), "non-finite gradient w.r.t. the obstacles"
        assert parts[FEATURES.index("risk")] > 0 and np.abs(gb).max() > 0  # some candidates collide: not vacuous
    gx, gb, fd, _ = runs[1]
    directional = gx @ np.asarray(dx) + np.sum(gb * np.asarray(db))
    assert directional == pytest.approx(float(fd), rel=1e-4, abs=1e-6)


# ---------------------------------------------------------------- state checks


def test_far_start_state_is_refused_in_float32():
    with pytest.raises(ValueError, match="too far from the origin for float32"):
        PlanState.make(1e6, 0.0, 0.0, 10.0)
    raw = PlanState(jnp.float32(0.0), jnp.float32(-1e6), 0.0, 0.0, 10.0, 0.0, 10.0, jnp.inf)
    with pytest.raises(ValueError, match="PlanState x, y.*local frame"):
        plan(raw, REF, Obstacles.empty(jnp.arange(T) * CFG.dt), CFG)


def test_batched_state_in_plan_says_plan_batch():
    st = PlanState.make(jnp.zeros(2), jnp.array([0.0, 0.3]), jnp.zeros(2), jnp.array([10.0, 12.0]))
    obs = _obs(_lead(np.arange(T) * CFG.dt, 30.0, 5.0), np.arange(T) * CFG.dt)
    with pytest.raises(ValueError) as e:
        plan(st, REF, obs, CFG)
    msg = str(e.value)
    assert "\n" not in msg and "plan_batch" in msg and "jax.vmap" in msg
    with pytest.raises(ValueError, match="use jaxplan.lattice.plan for one state"):
        plan_batch(PlanState.make(0.0, 0.0, 0.0, 10.0), REF, obs, CFG)
    # (plan_batch's default weights: test_lattice_core.test_batched_plan_matches_single_and_does_not_recompile)


def test_loader_refuses_a_negative_start_speed():
    d = copy.deepcopy(_minimal())
    d["planning_problems"][0]["initial_state"]["velocity"] = -3.0
    with pytest.raises(ScenarioError, match=r"neg.json: field planning_problems\[0\].initial_state.velocity"):
        parse_scenario(d, "neg.json")
