"""Speed DP: optimum vs exhaustive search, soft-min limit, decisions, batching, gradients."""
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.speed import (CostWeights, SpeedConfig, dp_from_costs, expected_speed_profile, make_scene,
                           plan_speed, soft_value, stage_costs)
from jaxplan.types import Obstacles

SMALL = SpeedConfig(dt=1.0, n_t=4, ds=1.0, v_max=4.0, a_min=-2.0, a_max=1.0, n_sub=2)
CFG = SpeedConfig(dt=1.0, n_t=5, ds=1.0, v_max=12.0, a_min=-4.0, a_max=2.0, n_sub=4)
REF = ReferenceLine.from_polyline(np.array([[-10.0, 0.0], [200.0, 0.0]]))
W = CostWeights.default()

_dp = jax.jit(dp_from_costs, static_argnums=6)
_soft = jax.jit(soft_value, static_argnums=6)


def _exhaustive(node, accel, jerk, terminal, j0, m0, cfg):
    offs = cfg.accel_offsets
    best = np.inf
    for seq in itertools.product(range(len(offs)), repeat=cfg.n_t):
        i, j, m, c = 0, j0, m0, 0.0
        for k, mk in enumerate(seq):
            j = j + offs[mk]
            if not 0 <= j < cfg.n_v:
                break
            i = i + j
            c += node[k, i, j] + accel[mk] + jerk[mk, m]
            m = mk
        else:
            best = min(best, c + terminal[i, j])
    return best


def _path_cost(ii, jj, aa, node, accel, jerk, terminal, j0, m0, cfg):
    offs = list(cfg.accel_offsets)
    c, m = 0.0, m0
    for k in range(cfg.n_t):
        mk = offs.index(int(aa[k]))
        c += node[k, ii[k], jj[k]] + accel[mk] + jerk[mk, m]
        m = mk
    return c + terminal[ii[-1], jj[-1]]


def test_dp_matches_exhaustive_search(rng):
    cfg = SMALL
    M = len(cfg.accel_offsets)
    for _ in range(6):
        node = rng.uniform(0, 10, (cfg.n_t, cfg.n_s, cfg.n_v)).astype(np.float32)
        node[rng.uniform(size=node.shape) < 0.3] = cfg.big  # blocked cells
        accel = rng.uniform(0, 3, M).astype(np.float32)
        jerk = rng.uniform(0, 3, (M, M)).astype(np.float32)
        terminal = rng.uniform(0, 5, (cfg.n_s, cfg.n_v)).astype(np.float32)
        j0, m0 = int(rng.integers(0, cfg.n_v)), int(rng.integers(0, M))
        ii, jj, aa, cost = _dp(node, accel, jerk, terminal, j0, m0, cfg)
        ref = _exhaustive(node, accel, jerk, terminal, j0, m0, cfg)
        assert float(cost) == pytest.approx(ref, rel=1e-5)
        # the backtracked profile is consistent and has exactly that cost
        ii, jj, aa = np.asarray(ii), np.asarray(jj), np.asarray(aa)
        assert np.array_equal(np.diff(np.concatenate([[0], ii])), jj)
        assert np.array_equal(np.diff(np.concatenate([[j0], jj])), aa)
        assert _path_cost(ii, jj, aa, node, accel, jerk, terminal, j0, m0, cfg) == pytest.approx(ref, rel=1e-5)
        # soft-min: a lower bound that converges to the optimum as the temperature -> 0
        soft = [float(_soft(node, accel, jerk, terminal, j0, m0, cfg, tau)) for tau in (1.0, 0.1, 0.01)]
        assert soft[0] <= soft[1] + 1e-3 <= soft[2] + 2e-3 <= ref + 3e-3
        assert soft[2] == pytest.approx(ref, abs=0.2)


@jax.jit
def _small_costs(obs, v0):
    _, scene = make_scene(REF, obs, SMALL, s0=10.0)
    return stage_costs(scene, SMALL, W, v0, 0.0)


def test_dp_on_scene_costs_matches_exhaustive():
    obs = Obstacles.held(jnp.array([[22.0, 0.0, 4.5, 1.8, 0.0]]), jnp.arange(5) * 1.0)
    costs = [np.asarray(c) for c in _small_costs(obs, 3.0)]
    assert costs[0].max() >= SMALL.big  # the obstacle is within reach
    ii, jj, aa, cost = _dp(*costs, SMALL)
    assert float(cost) == pytest.approx(_exhaustive(*costs, SMALL), rel=1e-5)


NO_KC = (jnp.zeros((1, 4, 2)), jnp.ones((1, 4), bool), jnp.zeros((1,), bool))


def _plan(obs, v0, w=W, keep_clear=NO_KC):
    return plan_speed(REF, obs, CFG, w, v0=v0, s0=10.0, keep_clear=keep_clear)


def _static(boxes):
    return _moving(boxes, [0.0] * len(boxes))


def _moving(start, vel, T=11, dt=0.5):
    t = np.arange(T) * dt
    b = np.repeat(np.asarray(start, np.float32)[:, None], T, 1)
    b[..., 0] += np.asarray(vel)[:, None] * t
    return Obstacles(jnp.asarray(b), jnp.ones(b.shape[:2], bool), jnp.asarray(t, jnp.float32))


def _front_xy(plan):
    return np.asarray(plan.s) + 3.85  # car front x (path starts at x = -10, s0 = 10)


def test_stops_behind_static_obstacle_and_follows_lead():
    p = _plan(_static([[30.0, 0.0, 4.5, 1.8, 0.0]]), v0=10.0)
    assert bool(p.feasible)
    assert _front_xy(p)[-1] < 30 - 2.25 - CFG.buffer
    assert float(p.v[-1]) <= 1.0
    assert np.all(np.diff(np.asarray(p.s)) >= 0) and np.all(np.asarray(p.v) <= CFG.v_max)
    assert np.all(np.asarray(p.a) >= CFG.a_min) and np.all(np.asarray(p.a) <= CFG.a_max)
    lead = _plan(_moving([[25.0, 0.0, 4.5, 1.8, 0.0]], [6.0]), v0=10.0)
    t = np.asarray(lead.t)
    assert np.all(_front_xy(lead) < 25 + 6 * t - 2.25 - CFG.buffer)


def test_decisions_change_the_plan():
    # neighbour on the left, slower, just ahead: no bypass keeps the car behind its rear
    obs = _moving([[14.0, 3.5, 4.5, 1.8, 0.0]], [5.0])
    free = _plan(obs, 10.0, w=CostWeights(**{**W.__dict__, "w_no_bypass": jnp.float32(0), "w_blind": jnp.float32(0)}))
    kept = _plan(obs, 10.0)
    rear = 14 - 2.25 + 5 * np.asarray(kept.t)
    assert _front_xy(free)[-1] > rear[-1] + 4.5  # overtakes without the decision
    assert np.all(_front_xy(kept) <= rear + 0.5)  # stays behind with it
    # keep-clear region right before a stopped car: do not stop inside it
    # (the car overlaps the region [22, 28] for s in (18.15, 28.95); the stopped car needs s < 29.6)
    stop = _static([[36.0, 0.0, 4.5, 1.8, 0.0]])
    box = jnp.array([[[22.0, -3], [28, -3], [28, 3], [22, 3]]])
    kc = (box, jnp.ones((1, 4), bool), jnp.ones((1,), bool))
    no_kc = _plan(stop, 5.0)
    with_kc = _plan(stop, 5.0, keep_clear=kc)
    inside = lambda p: 18.15 < float(p.s[-1]) < 28.95
    assert inside(no_kc) and not inside(with_kc)
    assert float(with_kc.v[-1]) <= 2.0


def test_batched_equals_single_and_no_recompile():
    scenes = [_moving([[30.0 + 5 * k, 0.0, 4.5, 1.8, 0.0]], [3.0 * k]) for k in range(3)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *scenes)
    refs = jax.tree_util.tree_map(lambda x: jnp.stack([x] * 3), REF)
    v0 = jnp.array([8.0, 10.0, 6.0])
    kc = jax.tree_util.tree_map(lambda x: jnp.stack([x] * 3), NO_KC)
    pb = plan_speed(refs, batch, CFG, W, v0=v0, s0=10.0, keep_clear=kc)
    for k in range(3):
        p1 = _plan(scenes[k], float(v0[k]))
        assert np.allclose(pb.s[k], p1.s) and np.allclose(pb.v[k], p1.v)
    from jaxplan.speed.dp import _plan_jit
    n = _plan_jit._cache_size()
    _plan(scenes[1], 7.0)
    assert _plan_jit._cache_size() == n


def test_expected_profile_converges_and_is_differentiable():
    obs = _moving([[30.0, 0.0, 4.5, 1.8, 0.0]], [4.0])
    exact = _plan(obs, 9.0)
    def expected(w_speed, tau):
        w = CostWeights(**{**W.__dict__, "w_speed": w_speed})
        return expected_speed_profile(REF, obs, CFG, w, tau, v0=9.0, s0=10.0, keep_clear=NO_KC)

    cold = expected(jnp.float32(1.0), 0.02)
    assert np.allclose(cold.s, exact.s, atol=0.05) and np.allclose(cold.v, exact.v, atol=0.05)
    loss = lambda ws: jnp.sum(expected(ws, 2.0).s)
    g = jax.grad(loss)(jnp.float32(1.0))
    h = 0.05
    fd = (loss(jnp.float32(1.0 + h)) - loss(jnp.float32(1.0 - h))) / (2 * h)
    assert np.isfinite(float(g)) and abs(float(g)) > 1e-3
    assert float(g) == pytest.approx(float(fd), rel=0.1, abs=0.05)


def test_bad_input_is_refused():
    obs = _static([[30.0, 0.0, 4.5, 1.8, 0.0]])
    with pytest.raises(ValueError):
        plan_speed(REF, obs, SpeedConfig(v_max=0.5), W, v0=1.0)
    with pytest.raises(ValueError):
        plan_speed(REF, obs, CFG, W, v0=-1.0)
    bad = Obstacles(obs.boxes.at[0, 0, 0].set(jnp.nan), obs.valid, obs.t)
    with pytest.raises(ValueError):
        plan_speed(REF, bad, CFG, W, v0=1.0)


def test_smoothing_qp_matches_scipy_and_reduces_jerk():
    from scipy.optimize import minimize

    from jaxplan.speed.compose import speed_profile_at
    from jaxplan.speed.smooth import TRUST, SmoothWeights, corridor, smooth_plan_jit, smoothing_qp

    obs = _moving([[25.0, 0.0, 4.5, 1.8, 0.0]], [4.0])
    p = _plan(obs, 10.0)
    t, s, v, a, ok = smooth_plan_jit(p, 10.0, CFG)
    assert bool(ok)
    h = CFG.dt / CFG.n_sub
    s_ref, v_ref, a_ref = speed_profile_at(p.t, p.s, 10.0, t)
    lo, up = corridor(p, CFG, s_ref)
    assert float(up.min()) < 1e3  # the lead vehicle bounds the corridor
    assert np.all(np.asarray(s) <= np.asarray(up) + 1e-2)
    lo = np.maximum(np.asarray(lo), np.asarray(s_ref) - TRUST)
    up = np.maximum(np.minimum(np.asarray(up), np.asarray(s_ref) + TRUST), lo)
    Q, q, A, b, G, g = (np.asarray(m, np.float64) for m in smoothing_qp(
        s_ref, v_ref, 10.0, jnp.asarray(lo), jnp.asarray(up), CFG, h, SmoothWeights()))
    res = minimize(lambda x: 0.5 * x @ Q @ x + q @ x, np.asarray(s_ref, np.float64), jac=lambda x: Q @ x + q,
                   method="SLSQP", constraints=[{"type": "eq", "fun": lambda x: A @ x - b, "jac": lambda x: A},
                                                {"type": "ineq", "fun": lambda x: g - G @ x, "jac": lambda x: -G}],
                   options={"maxiter": 500, "ftol": 1e-12})
    assert res.success
    assert np.allclose(np.asarray(s), res.x, atol=0.03)
    jerk_dp = np.abs(np.diff(np.asarray(a_ref))).max() / h
    jerk_qp = np.abs(np.diff(np.asarray(a))).max() / h
    assert jerk_qp < 0.5 * jerk_dp


def test_hopeless_scene_still_gives_a_valid_profile():
    # a car appears right in front: every profile collides; the least-bad one must still be kinematically valid
    obs = _static([[12.0, 0.0, 4.5, 1.8, 0.0]])
    p = _plan(obs, 12.0)
    assert not bool(p.feasible)
    s, v, a = np.asarray(p.s), np.asarray(p.v), np.asarray(p.a)
    assert np.all(np.diff(s) >= 0) and np.all(v >= 0) and np.all(v <= CFG.v_max)
    assert np.allclose(np.diff(s), v * CFG.dt) and np.all(a >= CFG.a_min) and np.all(a <= CFG.a_max)
