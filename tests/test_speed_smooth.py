"""The smoothing QP: its exact piecewise-jerk integration, the ADMM solver against OSQP, the
executed profile's limits, and the slack when the corridor cannot be kept."""
import jax
import jax.numpy as jnp
import numpy as np
import osqp
import pytest
import scipy.sparse as sps

from jaxplan.solvers import admm_prefactored
from jaxplan.speed import SpeedConfig
from jaxplan.speed.smooth import SmoothWeights, integration_maps, hardest_braking, leavable_a0, qp_matrices, qp_problem

CFG = SpeedConfig()
W = SmoothWeights()
N, H = int(round(CFG.horizon / CFG.qp_dt)), CFG.qp_dt


@jax.jit
def _solve(s_ref, v_ref, lower, upper, v_lim, a0, v0):
    q, l, u, slack = qp_problem(s_ref, v_ref, lower, upper, v_lim, a0, v0, CFG, W)
    x, rp, rd = admm_prefactored(qp_matrices(N, H, W)["fixed"], q, l, u)
    return q, l, u, x, rp, rd, slack


_solve_batch = jax.jit(jax.vmap(_solve))


def _problems(rng, B):
    """Random references (piecewise-constant accelerations), corridors (a lead vehicle
    ahead that sometimes brakes hard), speed limits and start states."""
    t = np.arange(1, N + 1) * H
    v0 = rng.uniform(0, 20, B)
    a0 = np.asarray(leavable_a0(rng.uniform(-3, 1.5, B), v0, CFG))
    acc = np.repeat(rng.uniform(-4, 2, (B, 7)), 10, 1)
    v = np.maximum(v0[:, None] + np.cumsum(acc * H, 1), 0.0)
    s = np.cumsum(v * H, 1)
    lead0 = rng.uniform(5, 80, B)
    lead_v = np.maximum(rng.uniform(0, 20, B)[:, None] + rng.uniform(-6, 0, B)[:, None] * t, 0.0)
    upper = np.where(rng.uniform(size=B)[:, None] < 0.7, lead0[:, None] + np.cumsum(lead_v * H, 1), 1e20)
    lower = np.full((B, N), -1e20)
    v_lim = np.where(rng.uniform(size=B)[:, None] < 0.3, rng.uniform(5, 15, B)[:, None], 30.0) + 0 * t
    f = lambda x: jnp.asarray(x, jnp.float32)
    return tuple(f(x) for x in (s, v, lower, upper, v_lim, a0, v0))


def test_piecewise_jerk_maps_integrate_exactly(rng):
    """v and s from the maps equal a fine Euler integration of the linear acceleration."""
    Va, Vy, Sa, Sy = integration_maps(N, H)
    for _ in range(3):
        a = rng.uniform(-5, 2, N)
        a0, v0 = rng.uniform(-2, 2), rng.uniform(0, 15)
        full = np.concatenate([[a0], a])
        fine = 200
        tt = np.linspace(0, N * H, N * fine + 1)
        af = np.interp(tt, np.arange(N + 1) * H, full)
        vf = v0 + np.concatenate([[0], np.cumsum(0.5 * (af[1:] + af[:-1]) * np.diff(tt))])
        sf = np.concatenate([[0], np.cumsum(0.5 * (vf[1:] + vf[:-1]) * np.diff(tt))])
        y = np.array([a0, v0])
        assert np.allclose(Va @ a + Vy @ y, vf[fine::fine], atol=1e-9)
        assert np.allclose(Sa @ a + Sy @ y, sf[fine::fine], atol=1e-6)


def test_admm_matches_osqp(rng):
    """110 QPs: at least 85 % converge, and the converged ADMM solutions equal OSQP's (run to
    1e-6, polished): speeds within 0.05 m/s, stations within 3 cm (plus 0.1 % of the farthest),
    accelerations within 0.05 m/s^2 RMS (plus 2 % of the largest), the same objective. The
    acceptance bounds the ADMM's residuals, not each acceleration: at XLA's default options one
    accepted solution (residuals 7.5e-3 / 4.8e-3) differs from OSQP's by 0.165 m/s^2 in one braking
    acceleration, by 0.037 m/s in speed and 3.8 cm in station."""
    B = 110
    probs = _problems(rng, B)
    q, l, u, x, rp, rd, _ = (np.asarray(a, np.float64) for a in _solve_batch(*probs))
    m = qp_matrices(N, H, W)
    P, A = sps.csc_matrix(m["P"]), sps.csc_matrix(m["A"])
    ok = (rp < 1e-2) & (rd < 5e-3)
    assert ok.mean() >= 0.9
    Sa, Sy = m["Sa"], m["Sy"]
    compared = 0
    for b in range(B):
        solver = osqp.OSQP()
        solver.setup(P, q[b], A, np.where(l[b] < -1e19, -np.inf, l[b]), np.where(u[b] > 1e19, np.inf, u[b]),
                     verbose=False, eps_abs=1e-6, eps_rel=1e-6, max_iter=20000, polish=True)
        res = solver.solve()
        assert res.info.status in ("solved", "solved inaccurate")
        if not ok[b] or res.info.status != "solved":
            continue
        compared += 1
        ref = res.x
        assert np.sqrt(np.mean((x[b, :N] - ref[:N]) ** 2)) < 0.05 + 0.02 * np.abs(ref[:N]).max()
        assert np.abs(m["Va"] @ (x[b, :N] - ref[:N])).max() < 0.05
        y = np.array([probs[5][b], probs[6][b]], np.float64)
        assert np.abs(Sa @ x[b, :N] - Sa @ ref[:N]).max() < 0.03 + 1e-3 * np.abs(Sa @ ref[:N] + Sy @ y).max()
        obj = lambda z: 0.5 * z @ m["P"] @ z + q[b] @ z
        assert obj(x[b]) == pytest.approx(obj(ref), rel=3e-3, abs=0.2)
    assert compared >= 85


def test_executed_profile_meets_the_limits(rng):
    """Clipped to its bounds, the solution is an exact profile whose sampled accelerations,
    finite-difference accelerations of the speeds (what a drive's metric sees), jerk and
    speeds are within the limits, from the car's speed and acceleration."""
    probs = _problems(rng, 40)
    *_, x, rp, rd, _ = _solve_batch(*probs)
    m = qp_matrices(N, H, W)
    for b in range(40):
        a0, v0 = float(probs[5][b]), float(probs[6][b])
        a = np.clip(np.asarray(x[b, :N], np.float64), CFG.a_brake, CFG.a_max)
        v = m["Va"] @ a + m["Vy"] @ np.array([a0, v0])
        s = m["Sa"] @ a + m["Sy"] @ np.array([a0, v0])
        full_v = np.concatenate([[v0], v])
        fd = np.diff(full_v) / H
        assert np.all(fd >= CFG.a_brake - 1e-4) and np.all(fd <= CFG.a_max + 1e-4)
        if rp[b] < 0.05:
            j = np.diff(np.concatenate([[a0], a])) / H
            assert np.all(np.abs(j) <= CFG.jerk_max + 0.6)
            assert np.all(v >= -0.05)
            assert np.all(np.diff(np.concatenate([[0.0], s])) >= -5e-3)


def test_hardest_braking_is_the_least_station(rng):
    """The jerk-limited hardest braking stops without reversing, keeps the limits, and no
    admissible profile (random ones, clipped to the limits) ends up behind it."""
    for _ in range(3):
        a0, v0 = rng.uniform(-3, 2), rng.uniform(0, 20)
        s_b, v_b, _ = (np.asarray(x, np.float64) for x in hardest_braking(jnp.float32(a0), jnp.float32(v0), N, H, CFG))
        assert np.all(v_b >= 0) and np.all(np.diff(s_b) >= -1e-6) and v_b[-1] <= 0.5  # stopped or creeping
        full = np.concatenate([[v0], v_b])
        assert np.all(np.diff(full) / H >= CFG.a_brake - 1e-3)
        m = qp_matrices(N, H, W)
        for _ in range(20):
            a = np.clip(np.cumsum(rng.uniform(-1, 1, N)) * CFG.jerk_max * H + a0, CFG.a_brake, CFG.a_max)
            j = np.diff(np.concatenate([[a0], a])) / H
            if np.any(np.abs(j) > CFG.jerk_max):
                continue
            v = m["Va"] @ a + m["Vy"] @ np.array([a0, v0])
            if np.any(v < 0):
                continue
            s = m["Sa"] @ a + m["Sy"] @ np.array([a0, v0])
            assert np.all(s >= s_b - 0.05)


def test_slack_when_the_corridor_cannot_be_kept():
    """A wall 10 m ahead at 15 m/s: no braking within the limits stops in time; the QP
    brakes as hard as it may (the hardest braking) and reports how far it passes the wall."""
    t = np.arange(1, N + 1) * H
    f = lambda x: jnp.asarray(x, jnp.float32)
    s_ref = f(np.minimum(15 * t, 40.0))
    q, l, u, x, rp, rd, slack = _solve(s_ref, f(np.full(N, 15.0)), f(np.full(N, -1e20)), f(np.full(N, 10.0)),
                                       f(np.full(N, 30.0)), f(0.0), f(15.0))
    # the feasible set is (almost) the one hardest-braking profile: slow for ADMM, but its
    # iterate is that profile within decimetres
    assert float(rp) < 0.5
    s_b, _, _ = hardest_braking(f(0.0), f(15.0), N, H, CFG)
    m = qp_matrices(N, H, W)
    a = np.clip(np.asarray(x, np.float64), CFG.a_brake, CFG.a_max)
    s = m["Sa"] @ a + m["Sy"] @ np.array([0.0, 15.0])
    assert float(slack) == pytest.approx(float(s_b[-1]) - 10.0, abs=1e-3) and float(slack) > 5.0
    assert np.abs(s - np.asarray(s_b)).max() < 0.5
    # and without the wall: no slack, the (consistent) reference is tracked
    q, l, u, x, rp, rd, slack = _solve(f(15 * t), f(np.full(N, 15.0)), f(np.full(N, -1e20)), f(np.full(N, 1e20)),
                                       f(np.full(N, 30.0)), f(0.0), f(15.0))
    assert float(slack) == 0.0
    s = m["Sa"] @ np.asarray(x, np.float64) + m["Sy"] @ np.array([0.0, 15.0])
    assert np.abs(s - 15 * t).max() < 0.05
