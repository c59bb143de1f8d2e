"""Lattice: profiles, quintic paths, candidate layout, collision risk vs shapely, selection rules."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry import ReferenceLine, box_corners, frenet_to_cartesian_state
from jaxplan.lattice import (trajectory_boxes, ESCALATED, FREE, KMH, RISK, CostWeights, LatticeConfig, PlanState, generate,
                             jerk_profile, jerk_profile_params, accel_profile, min_separation, plan,
                             quintic_coeffs, cartesian_to_frenet_state, risk_from_separation, select,
                             soft_select, costs)
from jaxplan.lattice.profiles import eval_segments
from jaxplan.types import Obstacles

CFG = LatticeConfig(n_offsets=3)  # 3 levels x 5 speeds x 1 lane x 3 offsets = 45 candidates, 51 steps
T = CFG.n_steps
TT = np.arange(T) * CFG.dt
K = 3
generate_jit = jax.jit(generate, static_argnames="config")
profile_jit = jax.jit(jerk_profile)
accel_jit = jax.jit(accel_profile)


def straight_ref():
    return ReferenceLine.from_polyline(np.stack([np.linspace(-30, 400, 100), np.zeros(100)], 1))


def curved_ref(R=120.0, n=300):
    th = np.linspace(-0.2, 2.0, n)
    return ReferenceLine.from_polyline(np.stack([R * np.sin(th), R - R * np.cos(th)], 1))


def obstacles(boxes, valid=None):
    """Boxes (k, T, 5) padded to K obstacles."""
    boxes = np.asarray(boxes, np.float32).reshape(-1, T, 5)
    k = len(boxes)
    pad = np.tile(np.array([0, 0, 1, 1, 0], np.float32), (K - k, T, 1))
    b = np.concatenate([boxes, pad], 0)
    v = np.concatenate([np.ones((k, T), bool) if valid is None else valid, np.zeros((K - k, T), bool)], 0)
    return Obstacles(jnp.asarray(b), jnp.asarray(v), jnp.asarray(TT, jnp.float32))


def moving(x0, y0, vx, vy, length=4.5, width=1.8, heading=0.0):
    return np.stack([x0 + vx * TT, y0 + vy * TT, np.full(T, length), np.full(T, width), np.full(T, heading)], 1)


# ---------------------------------------------------------------- quintic


def test_quintic_boundary_conditions(rng):
    with jax.enable_x64(True):
        n = 200
        l0, dl0, ddl0 = rng.normal(0, 1, n), rng.normal(0, 0.2, n), rng.normal(0, 0.02, n)
        l1, S, dl1 = rng.uniform(-5, 5, n), rng.uniform(5, 80, n), rng.normal(0, 0.3, n)
        c = np.asarray(quintic_coeffs(l0, dl0, ddl0, l1, S))
        c_slope = np.asarray(quintic_coeffs(l0, dl0, ddl0, l1, S, dl1=dl1))  # an end slope (s(t) at a speed)
        assert c.dtype == np.float64
        for i in range(n):
            for cc, end in ((c[i], 0.0), (c_slope[i], dl1[i])):
                p = np.polynomial.Polynomial(cc)
                for x, want in ((0.0, (l0[i], dl0[i], ddl0[i])), (S[i], (l1[i], end, 0.0))):
                    got = (p(x), p.deriv(1)(x), p.deriv(2)(x))
                    np.testing.assert_allclose(got, want, atol=1e-6, rtol=0)


def test_frenet_state_round_trip(rng):
    ref = curved_ref()
    s = rng.uniform(20, 200, 50)
    l, dl, ddl = rng.uniform(-3, 3, 50), rng.normal(0, 0.1, 50), rng.normal(0, 0.005, 50)
    xy, th, k = frenet_to_cartesian_state(ref, s, l, dl, ddl)
    got = cartesian_to_frenet_state(ref, xy, th, k)
    for g, w in zip(got, (s, l, dl, ddl)):
        np.testing.assert_allclose(np.asarray(g), w, atol=2e-3)


# ---------------------------------------------------------------- profiles


def test_jerk_profile_properties(rng):
    n = 300
    v0 = rng.uniform(0, 30, n)
    v0[:20] = rng.uniform(0, 1, 20)  # near a standstill
    a0 = rng.uniform(-3.5, 2.0, n)  # inside [a_min, a_max] = [-4, 2.5]
    v_end = np.clip(v0 + rng.uniform(-15, 15, n), 0, None)
    t = np.linspace(0, 20, 4001)
    J, amin, amax = 2.0, -4.0, 2.5
    s, v, a = (np.asarray(x, np.float64) for x in profile_jit(v0, a0, v_end, t, J, amin, amax))
    p = {k: np.asarray(x) for k, x in jerk_profile_params(v0, a0, v_end, J, amin, amax).items()}
    # a(0) = a0, continuity of v, acceleration inside limits and jerk bounded by J
    raised = a0 ** 2 / (2 * J) > v0  # braking at a0 would reverse the car: a0 is raised
    assert 5 < raised.sum() < n // 2
    np.testing.assert_allclose(a[:, 0], np.where(raised, -np.sqrt(2 * J * v0), a0), atol=1e-5)
    np.testing.assert_allclose(p["a0"], a[:, 0], atol=1e-5)
    assert v.min() >= 0
    assert np.abs(np.diff(v, axis=1)).max() <= (amax - amin) * 0.005 + 1e-3
    assert a.max() <= amax + 1e-4 and a.min() >= amin - 1e-4
    moving_ = v > 1e-3
    jerk = np.diff(a, axis=1) / 0.005
    assert np.abs(jerk[moving_[:, 1:] & moving_[:, :-1]]).max() <= J * 1.01 + 1e-2
    # s is the integral of v
    s_trap = np.concatenate([np.zeros((n, 1)), np.cumsum(0.5 * (v[:, 1:] + v[:, :-1]) * 0.005, axis=1)], 1)
    assert np.all(np.abs(s - s_trap) <= 1e-3 * (1 + s_trap))
    # feasible (never needs to reverse, reached in the window): v(t_end) = v_end and a(t_end) = 0
    ok = p["t_end"] < 19.0
    assert ok.sum() > 200
    k = np.searchsorted(t, p["t_end"])
    rows = np.nonzero(ok)[0]
    np.testing.assert_allclose(v[rows, k[rows]], v_end[rows], atol=1e-3)
    np.testing.assert_allclose(a[rows, k[rows]], 0, atol=2.5e-2)  # one sample past t_end
    np.testing.assert_allclose(v[rows, -1], v_end[rows], atol=1e-3)


def test_jerk_profile_infeasible_cases():
    t = np.linspace(0, 10, 1001)
    # a0 = 3 beyond a_max = 2.5 and a tiny speed gain: ramping back alone overshoots v_end
    s, v, a = (np.asarray(x) for x in profile_jit(10.0, 3.0, 10.5, t, 0.5, -4.0, 2.5))
    assert a[0] == pytest.approx(3.0)
    assert np.isfinite(v).all() and abs(v[-1] - 10.5) < 1e-3 or v[-1] > 10.5
    # braking hard near a standstill: a0 is raised so that the car stops without reversing
    s, v, a = (np.asarray(x) for x in profile_jit(2.0, -3.0, 0.0, t, 2.0, -4.0, 2.5))
    assert a[0] == pytest.approx(-np.sqrt(2 * 2.0 * 2.0), abs=1e-5)
    assert v.min() >= 0 and np.all(np.diff(s) >= -1e-6) and v[-1] == pytest.approx(0, abs=1e-5)


def test_accel_profile_three_cases():
    t = np.arange(51) * 0.1
    for v0, ve, want_a in ((10.0, 15.0, 1.0), (10.0, 0.0, -2.0), (10.0, 10.0, 0.0), (5.0, 40.0, 2.5)):
        s, v, a = (np.asarray(x) for x in accel_jit(v0, ve, t, -4.0, 2.5))
        assert a[0] == pytest.approx(want_a, abs=1e-5)
        np.testing.assert_allclose(s[-1], v0 * 5 + 0.5 * want_a * 25, rtol=1e-5)
        if want_a != 2.5:
            assert v[-1] == pytest.approx(ve, abs=1e-4)
        else:  # clipped: not reached
            assert v[-1] == pytest.approx(v0 + 2.5 * 5, abs=1e-4)


def test_eval_segments_matches_dense_integration():
    t = np.linspace(0, 6, 6001)
    s, v, a = (np.asarray(x) for x in eval_segments(jnp.asarray(t), [jnp.asarray(3.0), jnp.asarray(5.0)],
                                                    [jnp.asarray(1.0), jnp.asarray(2.0)],
                                                    [jnp.asarray(0.5), jnp.asarray(-1.0)],
                                                    [jnp.asarray(2.0), jnp.asarray(2.0)], jnp.asarray(7.0)))
    assert v[1999] == pytest.approx(3 + 2 + 1, abs=1e-2)
    np.testing.assert_allclose(s[1:], np.cumsum(0.5 * (v[1:] + v[:-1]) * 1e-3), atol=2e-3)


# ---------------------------------------------------------------- lattice


def test_lattice_shape_order_and_start():
    cfg = LatticeConfig(lanes=(0, 1), target_lane=1, n_offsets=3, escalation=(1.0, 2.0))
    ref = curved_ref()
    st = PlanState.make(0.5, -0.4, 0.03, 12.0, a=0.3, kappa=1 / 150)
    c = generate_jit(st, ref, cfg)
    E, V, Ln, O = cfg.grid
    N = E * V * Ln * O
    assert c.traj.x.shape == (N, cfg.n_steps) == (60, 51)
    np.testing.assert_allclose(np.asarray(c.traj.t[0]), np.arange(51) * 0.1, atol=1e-6)
    lvl, spd, lane, off = (np.asarray(x).reshape(E, V, Ln, O) for x in (c.level, c.speed_index, c.lane, c.offset))
    assert (lvl == np.arange(E)[:, None, None, None]).all() and (spd == np.arange(V)[None, :, None, None]).all()
    assert (lane == np.array([0, 1])[None, None, :, None]).all()
    np.testing.assert_allclose(off[0, 0], [[-1, 0, 1], [2.5, 3.5, 4.5]], atol=1e-6)
    ve = np.asarray(c.v_end).reshape(E, V, Ln, O)[:, :, 0, 0]
    np.testing.assert_allclose(ve[0], 12 + np.array([-20, -10, 0, 10, 20]) * KMH, atol=1e-5)
    np.testing.assert_allclose(ve[1], np.clip(12 + np.array([-40, -20, 0, 20, 40]) * KMH, 0, None), atol=1e-5)
    # every candidate starts at the car's pose and speed
    np.testing.assert_allclose(np.asarray(c.traj.x[:, 0]), 0.5, atol=2e-3)
    np.testing.assert_allclose(np.asarray(c.traj.y[:, 0]), -0.4, atol=2e-3)
    np.testing.assert_allclose(np.asarray(c.traj.theta[:, 0]), 0.03, atol=1e-4)
    np.testing.assert_allclose(np.asarray(c.traj.kappa[:, 0]), 1 / 150, atol=2e-4)
    np.testing.assert_allclose(np.asarray(c.traj.v[:, 0]), 12.0, atol=2e-2)
    # end offsets reached where the manoeuvre length was travelled; headings follow the path
    l = np.asarray(c.l)
    np.testing.assert_allclose(l[:, -1], np.asarray(c.offset), atol=1e-3)
    x, y, th = (np.asarray(z, np.float64) for z in (c.traj.x, c.traj.y, c.traj.theta))
    mv = np.hypot(np.diff(x), np.diff(y)) > 0.3
    chord = np.arctan2(np.diff(y), np.diff(x))
    mid = 0.5 * (th[:, 1:] + th[:, :-1])
    assert np.abs(np.angle(np.exp(1j * (chord - mid))))[mv].max() < 0.02
    # the Cartesian speed matches the travelled distance
    vv = np.asarray(c.traj.v, np.float64)
    np.testing.assert_allclose(np.hypot(np.diff(x), np.diff(y)), 0.05 * (vv[:, 1:] + vv[:, :-1]), atol=0.03)


def test_stations_finite_flags_every_candidate_of_a_bad_profile():
    """The plan's finiteness check leaves out x and y (finite where l and the profile's points on the
    line are): ``stations_finite`` must flag exactly the candidates of a profile with a bad point."""
    from jaxplan.lattice.parts import LatticeParts, stations_finite

    G, P, T = 6, 4, 9
    rows = lambda *shape: jnp.asarray(np.random.default_rng(0).normal(size=(G, T) + shape), jnp.float32)
    ref_at = (rows(2), rows(), rows(), rows(), rows(), rows())  # pos, cos, sin, theta, kappa, dkappa
    parts = lambda at: LatticeParts((rows(),) * 3, at, None, jnp.zeros((P,)), *([None] * 8))  # what it reads
    assert np.asarray(stations_finite(parts(ref_at))).all()
    for field in range(len(ref_at)):  # a NaN in any of the line's quantities, at one profile's sample
        for bad_value in (jnp.nan, jnp.inf):
            bad = list(ref_at)
            bad[field] = bad[field].at[4, 7].set(bad_value)
            ok = np.asarray(stations_finite(parts(tuple(bad))))
            assert ok.shape == (G * P,)
            assert not ok[4 * P:5 * P].any() and ok[:4 * P].all() and ok[5 * P:].all()



def test_generator_chunks_divide_the_profiles_and_do_not_change_the_candidates(monkeypatch):
    """``candidates.chunk_profiles``: a divisor of the profile count below it (a loop, no remainder), the
    largest that fits ``CHUNK_POINTS`` (brute force); the candidates are the same in any chunking."""
    from jaxplan.lattice import candidates as C

    for G in range(1, 41):
        for points in (1, 100, 255, 2201, 5000):
            c = C.chunk_profiles(G, points)
            fits = [d for d in range(1, G) if G % d == 0 and d * points <= C.CHUNK_POINTS]
            assert c == (max(fits) if fits else 1)
            assert G % c == 0 and (c < G or G == 1)
    st, ref = PlanState.make(0.5, -0.4, 0.03, 12.0, a=0.3, kappa=1 / 150), curved_ref()
    G = CFG.n_profiles
    assert 1 < C.chunk_profiles(G, CFG.n_lateral * T) < G  # this config is cut into several chunks
    got = generate(st, ref, CFG)
    monkeypatch.setattr(C, "chunk_profiles", lambda G, points: 1)  # one profile per chunk
    one = generate(st, ref, CFG)
    for a, b in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(one)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-6)

# ---------------------------------------------------------------- collision risk


def test_collision_flags_match_shapely(rng):
    shapely = pytest.importorskip("shapely")
    ref = curved_ref(n=len(straight_ref().s))  # straight_ref's shape: the plan compiled once for both
    agree = checked = 0
    for scene in range(6):
        st = PlanState.make(0.0, rng.uniform(-0.5, 0.5), rng.uniform(-0.05, 0.05), rng.uniform(5, 20))
        boxes = []
        for _ in range(K):
            s0 = rng.uniform(10, 80)
            x0, y0 = 120 * np.sin(s0 / 120), 120 - 120 * np.cos(s0 / 120)
            h = rng.uniform(-np.pi, np.pi)
            sp = rng.uniform(0, 10)
            boxes.append(moving(x0, y0 + rng.uniform(-4, 4), sp * np.cos(h), sp * np.sin(h),
                                rng.uniform(2, 6), rng.uniform(1, 2.5), h))
        valid = rng.uniform(size=(K, T)) > 0.1
        res = plan(st, ref, obstacles(boxes, valid), CFG)
        cb = np.asarray(box_corners(trajectory_boxes(res.candidates.traj, CFG.vehicle)), np.float64)  # (N,T,4,2)
        ob = np.asarray(box_corners(jnp.asarray(np.asarray(boxes, np.float32))), np.float64)  # (K,T,4,2)
        Pc = shapely.polygons(cb)  # (N, T)
        hit = np.zeros(cb.shape[:2], bool)
        for k in range(K):
            Po = shapely.polygons(ob[k])  # (T,)
            inter = shapely.intersects(Pc, Po[None]) & ~shapely.touches(Pc, Po[None])
            hit |= inter & valid[k][None]
        ms = np.asarray(res.min_sep)
        clear = np.abs(ms) > 1e-3
        assert (hit == (ms < 0))[clear].all()
        flags = hit.any(1)
        safe = clear.all(1) | (hit == (ms < 0)).all(1)
        assert (np.asarray(res.collided) == flags)[safe].all()
        agree += int((np.asarray(res.collided) == flags).sum())
        checked += flags.size
        # first collision time
        ft = np.where(flags, TT[np.argmax(hit, 1)], np.inf)
        np.testing.assert_allclose(np.asarray(res.first_t)[safe], ft[safe], atol=1e-5)
    assert agree == checked


def test_ttc_head_on_matches_analytic(rng):
    for _ in range(20):
        v1, v2 = rng.uniform(2, 20), rng.uniform(0, 20)
        x0 = rng.uniform(20, 100)
        L1, L2, W = rng.uniform(3, 6), rng.uniform(3, 6), rng.uniform(1.5, 2.2)
        h = rng.uniform(-np.pi, np.pi)
        u = np.array([np.cos(h), np.sin(h)])
        car = np.stack([v1 * TT * u[0], v1 * TT * u[1], np.full(T, L1), np.full(T, W), np.full(T, h)], 1)
        pos = x0 - v2 * TT
        obs = np.stack([pos * u[0], pos * u[1], np.full(T, L2), np.full(T, W), np.full(T, h + np.pi)], 1)
        o = Obstacles(jnp.asarray(obs[None], jnp.float32), jnp.ones((1, T), bool), jnp.asarray(TT))
        sep = min_separation(jnp.asarray(car[None], jnp.float32), o)
        r = risk_from_separation(sep, jnp.asarray(TT, jnp.float32))
        want = (x0 - 0.5 * (L1 + L2)) / (v1 + v2)
        if want < TT[-1] - 0.1:
            assert bool(r.collided[0])
            assert float(r.ttc[0]) == pytest.approx(want, abs=2e-3 * max(1, want))
            assert float(r.first_t[0]) == pytest.approx(np.ceil(want / 0.1 - 1e-6) * 0.1, abs=1e-4)
        elif want > TT[-1] + 0.1:
            assert not bool(r.collided[0]) and np.isinf(float(r.ttc[0]))


# ---------------------------------------------------------------- selection


def _lam(res, w=CostWeights()):
    f = np.asarray(res.features)
    return float(w.alpha) * f[:, 0] + float(w.beta) * f[:, 1] + float(w.delta) * f[:, 3]


def test_select_free_candidates_exist():
    ref = straight_ref()
    st = PlanState.make(0.0, 0.0, 0.0, 15.0)
    res = plan(st, ref, obstacles([moving(35, 0, 12, 0)]), CFG)
    col, lvl = np.asarray(res.collided), np.asarray(res.level if hasattr(res, "level") else res.candidates.level)
    assert col.any() and (~col[lvl == 0]).any()
    assert int(res.mode) == FREE
    lam = np.where(~col & (lvl == 0), _lam(res), np.inf)
    assert int(res.chosen) == int(np.argmin(lam))
    assert not col[int(res.chosen)]


def _profile_end_s(v0, v_end):
    t = np.arange(T) * CFG.dt
    s, _, _ = jerk_profile(v0, 0.0, v_end, t, CFG.jerk, CFG.a_min, CFG.a_max)
    return float(s[-1])


def test_select_escalation_finds_free_candidate():
    v0 = 15.0
    front = CFG.vehicle.length - CFG.vehicle.rear_overhang
    s0 = _profile_end_s(v0, v0 - 20 * KMH) + front
    s1 = _profile_end_s(v0, v0 - 40 * KMH) + front
    rear = 0.5 * (s0 + s1)  # stopped car: every level-0 candidate reaches it, the slowest level-1 ones do not
    res = plan(PlanState.make(0.0, 0.0, 0.0, v0), straight_ref(), obstacles([moving(rear + 2.25, 0, 0, 0)]), CFG)
    col, lvl = np.asarray(res.collided), np.asarray(res.candidates.level)
    assert col[lvl == 0].all() and not col[lvl == 1].all()
    assert int(res.mode) == ESCALATED
    i = int(res.chosen)
    assert not col[i] and lvl[i] == 1
    assert i == int(np.argmin(np.where(~col & (lvl == 1), _lam(res), np.inf)))


def test_select_all_collide_risk_rule_uses_risk():
    # a wall across the road 12 m ahead: no candidate can stop in time; the risk rule
    import dataclasses
    res = plan(PlanState.make(0.0, 0.0, 0.0, 20.0), straight_ref(),
               obstacles([moving(12 + 3.85 + 0.5, 0, 0, 0, 1.0, 20.0)]), dataclasses.replace(CFG, all_collide="risk"))
    assert np.asarray(res.collided).all() and int(res.mode) == RISK
    ttc = np.asarray(res.ttc)
    want = _lam(res) + float(CostWeights().gamma) / np.maximum(ttc, CFG.ttc_min)
    assert int(res.chosen) == int(np.argmin(want))


def test_crossroad_virtual_stop():
    ref, none = straight_ref(), obstacles([moving(-100, 50, 0, 0)])
    far = plan(PlanState.make(0.0, 0.0, 0.0, 8.0, d_crossroad=np.inf), ref, none, CFG)
    near = plan(PlanState.make(0.0, 0.0, 0.0, 8.0, d_crossroad=30.0), ref, none, CFG)
    assert int(far.mode) == FREE and not np.asarray(far.collided).any()
    assert bool(near.obstacles.valid[-1, 0]) and not bool(far.obstacles.valid[-1, 0])
    tr = near.chosen_trajectory()
    front = np.asarray(tr.x) + (CFG.vehicle.length - CFG.vehicle.rear_overhang)
    assert front.max() <= 30.0 + CFG.d_margin + 1e-3
    assert not bool(near.collided[int(near.chosen)])
    assert float(tr.v[-1]) < float(far.chosen_trajectory().v[-1])


def test_soft_select_tends_to_exact(rng):
    import dataclasses
    ref = straight_ref()
    cfg = dataclasses.replace(CFG, all_collide="risk")  # the smooth form scores the risk rule
    w = CostWeights()
    for obs in ([moving(35, 0, 12, 0)], [moving(60, 0, 0, 0)], [moving(12 + 4.35, 0, 0, 0, 1.0, 20.0)]):
        res = plan(PlanState.make(0.0, 0.0, 0.0, 15.0), ref, obstacles(obs), cfg)
        f = np.asarray(res.features).copy()
        f[:, 4] = np.asarray(res.collided)  # sep_eps -> 0
        f[:, 5] = np.asarray(res.candidates.level) * (1 - f[:, 4])
        f = jnp.asarray(f)
        p = np.asarray(soft_select(w, f, 1e-4))
        idx, _, _ = select(w, f, res.collided, res.candidates.level)
        assert int(idx) == int(res.chosen)
        c = np.asarray(costs(w, f))
        tie = np.isclose(c, c[int(idx)], rtol=0, atol=1e-4)  # e.g. the v0 candidate repeated at every level
        assert tie[int(np.argmax(p))] and p[tie].sum() > 0.99
        p_hot = np.asarray(soft_select(w, f, 1e3))
        assert p_hot.max() < 0.5  # a high temperature spreads the choice
        g = jax.grad(lambda a: soft_select(CostWeights(alpha=a), f, 1.0)[0])(1.0)
        assert np.isfinite(g)


def test_batched_plan_matches_single_and_does_not_recompile():
    from jaxplan.lattice import plan_batch
    from jaxplan.lattice.plan import plan_kernel
    ref = straight_ref()
    states = [PlanState.make(0.0, y, 0.0, v) for y, v in ((0.0, 10.0), (0.3, 15.0))]
    obs = [obstacles([moving(40, 0, 5, 0)]), obstacles([moving(30, 0, 0, 0)])]
    singles = [plan(s, ref, o, CFG) for s, o in zip(states, obs)]
    n0 = plan_kernel._cache_size()
    plan(states[0], ref, obs[1], CFG)
    assert plan_kernel._cache_size() == n0
    stack = lambda xs: jax.tree_util.tree_map(lambda *a: jnp.stack(a), *xs)
    refs = stack([ref, ref])
    b = plan_batch(stack(states), refs, stack(obs), CFG)  # weights default like plan's
    for i, r in enumerate(singles):
        assert int(b.chosen[i]) == int(r.chosen)
        np.testing.assert_allclose(np.asarray(b.cost[i]), np.asarray(r.cost), rtol=1e-5, atol=1e-5)
        np.testing.assert_array_equal(np.asarray(b.collided[i]), np.asarray(r.collided))


def test_fast_atan2_and_box_separation_axes(rng):
    from jaxplan.geometry import box_separation
    from jaxplan.geometry.boxes import box_separation_axes
    from jaxplan.lattice.lateral import atan2
    y, x = rng.normal(size=5000), rng.normal(size=5000)
    x[:10] = 0.0
    np.testing.assert_allclose(np.asarray(atan2(jnp.asarray(y, jnp.float32), jnp.asarray(x, jnp.float32))),
                               np.arctan2(y, x), atol=1e-6)
    a = np.column_stack([rng.uniform(-5, 5, (2000, 2)), rng.uniform(0.5, 5, (2000, 2)), rng.uniform(-4, 4, 2000)])
    b = np.column_stack([rng.uniform(-5, 5, (2000, 2)), rng.uniform(0.5, 5, (2000, 2)), rng.uniform(-4, 4, 2000)])
    a, b = jnp.asarray(a, jnp.float32), jnp.asarray(b, jnp.float32)
    ax = lambda q: jnp.stack([jnp.cos(q[:, 4]), jnp.sin(q[:, 4])], -1)
    got = box_separation_axes(a[:, :2], ax(a), 0.5 * a[:, 2:4], b[:, :2], ax(b), 0.5 * b[:, 2:4])
    np.testing.assert_allclose(np.asarray(got), np.asarray(box_separation(a, b)), atol=1e-5)


def test_broad_phase_matches_dense(rng):
    from jaxplan.lattice.risk import car_parts, min_separation_axes, min_separation_broad
    c = generate_jit(PlanState.make(0.0, 0.2, 0.0, 12.0), straight_ref(), CFG)
    center, half = car_parts(jnp.stack([c.traj.x, c.traj.y], -1), c.axis, CFG.vehicle)
    boxes = [moving(rng.uniform(5, 60), rng.uniform(-3, 3), rng.uniform(-5, 10), rng.uniform(-1, 1),
                    heading=rng.uniform(-1, 1)) for _ in range(K)]
    o = obstacles(boxes)
    dense = np.asarray(min_separation_axes(center, c.axis, half, o))
    G, P = CFG.grid[0] * CFG.grid[1], CFG.grid[2] * CFG.grid[3]
    for budget in (1, G * K * T):  # 1: too small, falls back to the dense check
        got = np.asarray(min_separation_broad(center, c.axis, half, o, P, budget, 1.0))
        assert ((got < 0) == (dense < 0)).all()
        close = dense < 1.0
        assert close.any()
        np.testing.assert_allclose(got[close], dense[close], atol=1e-5)
        assert (got[~close] > 1.0 - 1e-5).all()


def test_lateral_time_reaches_the_offset_early():
    cfg = LatticeConfig(n_offsets=3, escalation=(1.0,), lateral_time=2.0)
    st = PlanState.make(0.0, 0.0, 0.0, 20.0)
    c = generate_jit(st, curved_ref(), cfg)
    l, off = np.asarray(c.l), np.asarray(c.offset)
    s = np.asarray(c.s) - np.asarray(c.s)[:, :1]
    k = 20  # t = 2 s: the offset is reached where the car is then (s > s_min at 20 m/s), and held
    np.testing.assert_allclose(l[:, k:], np.broadcast_to(off[:, None], l[:, k:].shape), atol=2e-3)
    assert np.all(s[:, k] > cfg.s_min)
    slow = generate_jit(st, curved_ref(), LatticeConfig(n_offsets=3, escalation=(1.0,)))
    assert np.abs(np.asarray(slow.l)[:, k] - off).max() > 0.1  # the default spreads it over the horizon
    with pytest.raises(ValueError, match="lateral_time"):
        LatticeConfig(lateral_time=9.0).validate()


def test_a_collision_is_avoided_at_the_emergency_limits_before_a_comfortable_plan_takes_it():
    """``cost.choose``: when every comfortable (feasible) candidate collides, a collision-free one within
    the emergency limits is taken (mode EMERGENCY); without that option, or when a comfortable
    collision-free candidate exists, the rule is as before."""
    from jaxplan.lattice.cost import EMERGENCY, FEATURES, choose

    w = CostWeights()
    feats = jnp.zeros((4, len(FEATURES))).at[:, 0].set(jnp.asarray([0.0, 1.0, 2.0, 3.0]))
    level = jnp.zeros(4, jnp.int32)
    avail = jnp.ones(4, bool)
    comfort = jnp.asarray([True, True, False, False])  # 2 and 3 exceed the comfortable limits
    free = jnp.asarray([False, False, True, True])  # 0 and 1 collide
    emergency = jnp.asarray([True, True, False, True])  # 3 is within the emergency limits
    args = (w, feats, level, avail, comfort, free, free, jnp.ones(4, bool), jnp.ones(4), jnp.ones(4))
    idx, mode, _ = choose(*args, n_comfort=3, emergency_ok=emergency)
    assert int(idx) == 3 and int(mode) == EMERGENCY
    idx, mode, _ = choose(*args, n_comfort=3)
    assert int(mode) == RISK and int(idx) in (0, 1)
    idx, mode, _ = choose(*args, n_comfort=3, emergency_ok=jnp.asarray([True, True, False, False]))
    assert int(mode) == RISK  # nothing collision-free within any limits
    free2 = jnp.asarray([False, True, True, True])  # 1: comfortable and free
    idx, mode, _ = choose(w, feats, level, avail, comfort, free2, free2, jnp.ones(4, bool), jnp.ones(4), jnp.ones(4),
                          n_comfort=3, emergency_ok=emergency)
    assert int(idx) == 1 and int(mode) == FREE


def test_a_free_plan_on_the_road_is_taken_before_a_free_plan_off_it():
    """``cost.choose``: when no candidate keeps the buffers, a collision-free candidate on the road
    (``on_road``) is taken before a cheaper collision-free one that leaves it; where every free
    candidate leaves the road, the one that leaves it least counts as on it
    (``plan.least_off_road``)."""
    from jaxplan.lattice.cost import CONSTRAINED, FEATURES, choose
    from jaxplan.lattice.plan import LEAST_OFF_ROAD_TOL, least_off_road

    w = CostWeights()
    feats = jnp.zeros((4, len(FEATURES))).at[:, 0].set(jnp.asarray([0.0, 1.0, 2.0, 3.0]))
    level = jnp.zeros(4, jnp.int32)
    ones = jnp.ones(4, bool)
    no_margin = jnp.zeros(4, bool)  # every candidate touches a buffer or the edge margin
    free = jnp.asarray([False, True, True, True])  # 0 collides
    on_road = jnp.asarray([True, False, False, True])
    args = (w, feats, level, ones, ones, no_margin, free, ones, jnp.ones(4), jnp.ones(4))
    idx, mode, _ = choose(*args, on_road=on_road)
    assert int(idx) == 3 and int(mode) == CONSTRAINED
    idx, _, _ = choose(*args)
    assert int(idx) == 1  # without the road's verdict: the cheapest free candidate
    # every free candidate leaves the road: those within the tolerance of the least excess count as on it
    off = jnp.asarray([False, True, True, True])
    excess = jnp.asarray([0.0, 0.4, 0.1 + 0.5 * LEAST_OFF_ROAD_TOL, 0.1])
    got = np.asarray(least_off_road(off, excess, free))
    assert got.tolist() == [True, False, True, True]
    idx, _, _ = choose(*args, on_road=jnp.asarray(got))
    assert int(idx) == 2
    # nothing free: every candidate counts (the choice then goes by harm)
    assert np.asarray(least_off_road(off, excess, jnp.zeros(4, bool))).all()
