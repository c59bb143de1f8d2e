"""Demonstrations: the start state from the past, short recordings, vehicles shared across
files, the split disjoint by vehicle, displacement errors and bootstrap intervals."""
import dataclasses
import glob
import os

import numpy as np
import pytest

from conftest import shared_data_or_skip
from jaxplan.tuning.demos import DemoConfig, DemoIndex, fit_start_state, location_of, scenario_demos
from jaxplan.tuning.metrics import bootstrap_ci, displacement
from jaxplan.tuning.vehicles import disjoint, split_by_vehicle, vehicle_identities, vehicle_links


def test_start_state_is_exact_for_constant_acceleration_and_matches_polyfit(rng):
    dt = 0.1
    for v0, a, th in ((12.0, 1.3, 0.4), (3.0, -2.0, -2.5), (20.0, 0.0, 3.0)):
        t = (np.arange(11) - 10) * dt  # the past second, ending now
        s = v0 * t + 0.5 * a * t * t
        xy = np.column_stack([s * np.cos(th), s * np.sin(th)])
        v, h, acc = fit_start_state(xy, dt, heading_fallback=0.0)
        assert v == pytest.approx(v0, abs=1e-9) and acc == pytest.approx(a, abs=1e-9)
        assert np.cos(h - th) == pytest.approx(1.0, abs=1e-12)
    # noisy curved track: the acceleration is the tangential part of numpy's quadratic fit
    t = (np.arange(16) - 15) * dt
    xy = np.column_stack([10 * t + 0.8 * t * t, 0.3 * t * t]) + rng.normal(0, 0.05, (16, 2))
    _, h, acc = fit_start_state(xy, dt, 0.0)
    c = np.polyfit(t, xy, 2)  # (3, 2), highest power first
    assert acc == pytest.approx(2 * c[0] @ np.array([np.cos(h), np.sin(h)]), abs=1e-9)
    # standing still: the fallback heading
    assert fit_start_state(np.zeros((11, 2)), dt, 1.2)[:2] == (0.0, 1.2)


@pytest.fixture(scope="module")
def us101():
    from jaxplan.scenarios.loader import load_scenario

    d = shared_data_or_skip()
    return {n: load_scenario(os.path.join(d, f"{n}.json")) for n in
            ("USA_US101-15_1_T-1", "USA_US101-5_1_T-1", "USA_Lanker-1_1_T-1", "DEU_A9-2_1_T-1")}


def test_demos_from_recorded_traffic_use_only_the_past_and_fit_short_recordings(us101):
    cfg = DemoConfig(n_obstacles=8, ref_points=48)
    sc = us101["USA_US101-15_1_T-1"]
    demos, index = scenario_demos(sc, cfg)
    assert len(demos) > 20 and len(index) == len(demos)
    for d in demos:
        assert d.human_xy.shape == (51, 2) and d.obstacles.shape == (8, 51, 5) and d.ref_xy.shape == (48, 2)
        np.testing.assert_allclose(d.human_xy[0], 0.0, atol=1e-9)
        assert d.human_valid[:31].all()  # at least min_future = 3 s recorded
        n = int(d.human_valid.sum())
        v = np.linalg.norm(np.diff(d.human_xy[:n], axis=0), axis=1) / 0.1
        np.testing.assert_allclose(v, d.human_v[:n - 1], rtol=1e-9)
        ok = d.obstacle_valid[:, 0]
        r = np.linalg.norm(d.obstacles[ok, 0, :2], axis=1)
        assert np.all(np.diff(r) >= 0) and np.all(r > 0.5)
    # the start state does not see the future: scramble every position after the starts
    boxes = np.asarray(sc.obstacles.boxes).copy()
    k_first = int(round(min(index.start) / sc.dt))
    boxes[:, k_first + 1:, :2] += np.random.default_rng(0).normal(0, 3.0, boxes[:, k_first + 1:, :2].shape)
    scr = dataclasses.replace(sc, obstacles=dataclasses.replace(sc.obstacles, boxes=boxes))
    first = [i for i in range(len(index)) if index.start[i] == min(index.start)]
    d2, ix2 = scenario_demos(scr, cfg)
    same = {(o, s): d for d, o, s in zip(d2, ix2.obstacle_id, ix2.start)}
    for i in first:
        key = (index.obstacle_id[i], index.start[i])
        if key in same:
            np.testing.assert_allclose(same[key].ego, demos[i].ego, atol=1e-6)
    # Lankershim keeps 4 s: 1 s of past and 3 s of future fit, 5 s would not
    lk, lix = scenario_demos(us101["USA_Lanker-1_1_T-1"], cfg)
    assert len(lk) > 5 and set(lix.location) == {"Lankershim"}
    assert all(not d.human_valid[-1] for d in lk)


def test_shared_vehicles_are_found_by_motion_and_the_split_keeps_them_together(us101):
    a, b = us101["USA_US101-15_1_T-1"], us101["USA_US101-5_1_T-1"]
    # give file b new ids: only the recorded motion can tell they are the same cars
    b_new = dataclasses.replace(b, obstacle_ids=np.asarray(b.obstacle_ids) + 100000)
    links = vehicle_links([a, b_new])
    motion = [(x, y) for x, y, why in links if why == "motion"]
    assert len(motion) >= 6 and all(x[0] != y[0] for x, y in motion)
    # each link really is one car: the step vectors agree once the time shift is found
    # and an unrelated location shares nothing
    assert not vehicle_links([a, us101["DEU_A9-2_1_T-1"]])
    assert not [ln for ln in vehicle_links([a, b_new], step_tol=1e-9) if ln[2] == "motion"]  # the break
    ids = vehicle_identities([a, b_new])
    for x, y in motion:
        assert ids[x] == ids[y]
    assert len(set(ids.values())) < len(ids)
    from jaxplan.tuning.demos import demo_set

    ds = demo_set([a, b_new], DemoConfig(n_obstacles=8, ref_points=48), identities=ids)
    val = split_by_vehicle(ds.index)
    assert val.any() and (~val).any()
    assert disjoint(ds.index.take(val), ds.index.take(~val))
    assert np.array_equal(val, split_by_vehicle(ds.index))  # deterministic
    # splitting by the per-file id instead would put shared cars on both sides
    naive = dataclasses.replace(ds.index, vehicle=np.full(len(ds), "", dtype=object))
    nv = split_by_vehicle(naive)
    both = {ids[(s, o)] for s, o in zip(naive.scenario[nv], naive.obstacle_id[nv])} & \
        {ids[(s, o)] for s, o in zip(naive.scenario[~nv], naive.obstacle_id[~nv])}
    assert both


def test_locations():
    assert [location_of(s) for s in ("USA_US101-3_1_T-1", "USA_Lanker-1_2_T-1", "DEU_Muc-1_1_T-1", "ZAM_Over-1_1")] \
        == ["US-101", "Lankershim", "German roads", "other"]


def test_displacement_errors_against_a_loop(rng):
    T = 51
    human = np.cumsum(rng.normal(0, 1, (T, 2)), 0)
    pred = human + rng.normal(0, 0.5, (4, T, 2))
    valid = np.arange(T) < 41  # 4 s recorded
    e = displacement(pred, human, valid)
    for i in range(4):
        d = [np.hypot(*(pred[i, k] - human[k])) for k in range(T)]
        assert float(e["ade3"][i]) == pytest.approx(np.mean(d[1:31]), rel=1e-5)
        assert float(e["fde3"][i]) == pytest.approx(d[30], rel=1e-5)
    assert bool(e["valid3"].all()) and not bool(e["valid5"].any())


def test_bootstrap_resamples_whole_scenarios(rng):
    # two scenarios of very different size and value: the interval is about scenarios, not demos
    v = np.concatenate([np.zeros(200), np.ones(2)])
    cl = np.array(["a"] * 200 + ["b"] * 2)
    est, lo, hi = bootstrap_ci(v, cl, n_boot=2000)
    assert est == pytest.approx(2 / 202)
    # by hand: drawing 2 of 2 scenarios gives {a, a} (mean 0) or {b, b} (mean 1) a quarter
    # of the time each, so the 95 % interval runs from 0 to 1 (a bootstrap over demos would not)
    assert lo == 0.0 and hi == 1.0
    one = bootstrap_ci(rng.normal(size=50), np.full(50, "x"))
    assert one[1] == pytest.approx(one[0]) and one[2] == pytest.approx(one[0])
    r = bootstrap_ci(2 * np.arange(1, 7.0), list("aabbcc"), ratio_to=np.arange(1, 7.0))
    assert r == pytest.approx((2.0, 2.0, 2.0))
    idx = DemoIndex(np.array(["s"]), np.array(["other"]), np.array([1]), np.array([""], dtype=object), np.zeros(1))
    assert len(idx.take([0, 0])) == 2


def test_demo_counts_per_location_of_the_shared_set():
    d = shared_data_or_skip()
    files = sorted(glob.glob(os.path.join(d, "USA_Lanker-1_[123]_T-1.json")))
    from jaxplan.scenarios.loader import load_scenario

    n = sum(len(scenario_demos(load_scenario(f), DemoConfig(n_obstacles=4, ref_points=16))[0]) for f in files)
    assert n >= 40  # the 3 Lankershim files long enough for 1 s past + 3 s future


def test_speed_examples_keep_paths_the_speed_planner_accepts():
    """A recorded path that jitters back and forth (a nearly stopped car) is left out of the
    speed planner's examples; every kept path passes the planner's own input check."""
    import jax.numpy as jnp

    from jaxplan.geometry.frenet import ReferenceLine
    from jaxplan.tuning.demos import synthetic_demos
    from jaxplan.tuning.speed_tuning import speed_data

    d = synthetic_demos(4, seed=0)
    xy = np.array(d.human_xy)
    t = np.arange(xy.shape[1]) * 0.1
    xy[1] = np.stack([2.0 * t + 0.4 * (np.arange(len(t)) % 2), np.zeros_like(t)], -1)  # steps back every other sample
    xy[2] = np.stack([0.05 * np.sin(t), np.zeros_like(t)], -1)                          # never moves 2 m
    data, kept = speed_data(dataclasses.replace(d, human_xy=jnp.asarray(xy, jnp.float32)))
    assert kept.tolist() == [0, 3] and data.path_xy.shape[0] == 2
    for p in np.asarray(data.path_xy, np.float64):
        ReferenceLine.from_polyline(p).validate()
