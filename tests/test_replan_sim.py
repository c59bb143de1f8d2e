"""Closed loop: the three strategies share one compiled simulator and one safety layer; each
re-plans when it should; signed speed stops at every change of gear; plans arrive after the
latency; counters agree with the logs. One compiled simulator for all tests."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

from jaxplan.replan import (GOAL, IMMEDIATE, LAZY, OBSTACLE, PERIOD, PERIODIC, ManeuverSimConfig, run_summary,
                            sample_scenarios, simulate, simulate_host)
from jaxplan.replan import simulator as S

CFG = ManeuverSimConfig(steps=300)
BUSY = 4  # per kind, with many obstacles; then 2 per kind with none and no noise


def _batch():
    kw = dict(p_real=0.7, p_phantom=0.8, p_dyn=0.6)
    clean = dict(p_real=0.0, p_phantom=0.0, p_dyn=0.0, max_bias=0.0, goal_sigma=0.0, yaw_sigma=0.0)
    parts = [sample_scenarios(3, BUSY, "park", **kw), sample_scenarios(4, BUSY, "drive", **kw),
             sample_scenarios(5, 2, "park", **clean), sample_scenarios(6, 2, "drive", **clean)]
    return jax.tree.map(lambda *a: jnp.concatenate(a), *parts)


@pytest.fixture(scope="module")
def runs():
    sc = _batch()
    out = {}
    for s in (LAZY, PERIODIC, IMMEDIATE):
        final, logs = simulate(sc, s, CFG)
        out[s] = (run_summary(final), jax.tree.map(np.asarray, logs))
    return sc, out


def test_strategies_share_one_compiled_loop_and_agree_without_obstacles(runs):
    _, out = runs
    assert S.simulate_batch._cache_size() == 1  # the strategy is a traced int: one program for all three
    ref = out[LAZY][1]
    for s in (PERIODIC, IMMEDIATE):
        L = out[s][1]
        # Without obstacles and noise the stitched re-plans keep to the plan: nearly the same path
        # (a re-plan may pick an equally short Dubins word) and the same end; the car may wait a
        # latency at a gear shift while a re-plan is in the making.
        for i in range(2 * BUSY, L.x.shape[0]):
            path = shapely.LineString(np.stack([ref.x[i], ref.y[i]], -1))
            d = shapely.distance(path, shapely.points(np.stack([L.x[i], L.y[i]], -1)))
            assert d.max() < 0.2, (s, i, d.max())
            assert np.hypot(L.x[i, -1] - ref.x[i, -1], L.y[i, -1] - ref.y[i, -1]) < 0.05
    assert out[PERIODIC][0]["replans"][2 * BUSY:].min() >= 5
    for s in out:
        assert out[s][0]["success"][2 * BUSY:].all()


def test_counters_match_logs_and_runs_finish(runs):
    _, out = runs
    for s, (m, L) in out.items():
        np.testing.assert_array_equal(m["replans"], L.replan.sum(1))
        np.testing.assert_array_equal(m["rejected"].sum(-1), L.rejected.sum(1))
        for r in (GOAL, OBSTACLE, PERIOD):
            np.testing.assert_array_equal(m["reasons"][:, r], (L.replan & (L.reason == r)).sum(1))
        assert np.all(np.isfinite(L.v))
        assert m["done"].mean() >= 0.9, (s, m["done"])


def test_lazy_replans_only_when_stopped_at_an_intermediate_destination(runs):
    _, out = runs
    m, L = out[LAZY]
    sup = CFG.supervisor
    assert m["replans"].sum() > 0
    assert m["replans_moving"].sum() == 0
    rows, cols = np.nonzero(L.replan)
    for i, j in zip(rows, cols):
        assert abs(L.v[i, j - 1]) < sup.v_stopped  # stopped when the decision was taken
        assert L.reason[i, j] in (GOAL, OBSTACLE)
        if L.reason[i, j] == OBSTACLE and np.isfinite(L.brake_dist[i, j - 1]):
            assert L.brake_dist[i, j - 1] < sup.at_point_tol  # at the brake-stop point
    # Goal re-plans only at a gear shift: parking runs only.
    assert not np.any(L.replan[BUSY:2 * BUSY] & (L.reason[BUSY:2 * BUSY] == GOAL))


def test_baselines_trigger_as_specified(runs):
    _, out = runs
    sup = CFG.supervisor
    m, L = out[PERIODIC]
    for i in range(L.t.shape[0]):
        t = L.t[i][L.replan[i]]
        np.testing.assert_allclose(np.diff(t), 1.0 / sup.periodic_hz, atol=0.051)
    assert m["replans_moving"].sum() > 0.5 * m["replans"].sum()  # the baseline re-plans while moving
    m, L = out[IMMEDIATE]
    assert set(np.unique(L.reason[L.replan]).tolist()) <= {GOAL, OBSTACLE}
    assert m["reasons"][:, OBSTACLE].sum() > 0
    for i in range(L.t.shape[0]):
        assert np.all(np.diff(L.t[i][L.replan[i]]) >= sup.debounce_s - 1e-4)  # debounced


def test_signed_speed_stops_at_every_gear_change_and_plans_arrive_after_the_latency(runs):
    _, out = runs
    sup = CFG.supervisor
    lat = int(round(sup.latency_s / sup.dt))
    for s, (m, L) in out.items():
        v, g = L.v, L.gear
        assert np.all(np.sign(v) * g >= 0)  # the speed's sign is the gear's
        change = g[:, 1:] != g[:, :-1]
        assert np.all(np.abs(v[:, :-1][change]) < sup.v_stopped)  # changes of gear only standing still
        # Never from forward to reverse without a stop: the step before a flip of sign ends at the
        # stop point (its mean speed below v_stopped).
        flip = np.sign(v[:, 1:]) * np.sign(v[:, :-1]) < 0
        assert np.all(np.abs(v[:, :-1][flip]) < sup.v_stopped)
        assert np.all(np.abs(np.diff(v, axis=1)) <= sup.limits.emergency * sup.dt + 1e-4)
        # Every arrived plan (installed or refused) was asked for exactly `lat` ticks before.
        arrived = L.installed | L.rejected
        asked = np.zeros_like(arrived)
        asked[:, lat:] = L.replan[:, :-lat]
        first = np.zeros_like(arrived)
        first[:, lat] = True  # the first plan (not counted as a re-plan)
        assert np.all(arrived <= (asked | first))
        assert (L.replan.sum() - arrived[:, lat + 1:].sum()) <= L.replan[:, -lat:].sum()


def test_host_loop_matches_scan(runs):
    """The host loop (one step per call) drives as the scanned simulator: the same speeds (two
    compiled programs, compiled with different options: float32 rounding drifts apart by up to
    1e-3 m/s over 24 s) and re-plans."""
    sc, out = runs
    one = jax.tree.map(lambda a: a[0], sc)
    final, logs = simulate_host(one, LAZY, CFG)
    m, L = out[LAZY]
    n = len(logs)
    np.testing.assert_allclose([float(lg.v) for lg in logs], L.v[0, :n], atol=5e-3)
    assert int(final.sup.n_replan) == int(m["replans"][0])
