"""The road lattice: longitudinal modes, feasibility filter, harm selection (open loop, against
brute force and shapely), and closed-loop drives of the ``lattice`` planner on small scenes
(one shared jitted rollout)."""
import dataclasses
import functools
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry import ReferenceLine, box_corners
from jaxplan.lattice import CostWeights, LatticeConfig, PlanState, plan
from jaxplan.lattice.cost import FREE, RISK, choose
from jaxplan.lattice.feasibility import REASONS
from jaxplan.lattice.longitudinal import FALLBACK, FOLLOW, GOAL, STOP, quintic_profile
from jaxplan.lattice.risk import trajectory_boxes
from jaxplan.lattice.targets import GOAL_LANE, RoadTargets
from jaxplan.types import Obstacles

# a small road lattice: 3 lanes, every mode; 5 s at 0.1 s
CFG = LatticeConfig.road(lanes=(-1, 0, 1), escalation=(1.0, 2.0))
T = CFG.n_steps
TT = np.arange(T) * CFG.dt
K = 3


def straight_ref():
    return ReferenceLine.from_polyline(np.stack([np.linspace(-40, 400, 120), np.zeros(120)], 1))


def car(x0, y0, vx, length=4.5, width=1.8, vy=0.0):
    return np.stack([x0 + vx * TT, y0 + vy * TT, np.full(T, length), np.full(T, width),
                     np.full(T, math.atan2(vy, vx) if vx or vy else 0.0)], 1)


def obstacles(boxes):
    boxes = np.asarray(boxes, np.float32).reshape(-1, T, 5)
    k = len(boxes)
    pad = np.tile(np.array([500, 500, 1, 1, 0], np.float32), (K - k, T, 1))
    v = np.concatenate([np.ones((k, T), bool), np.zeros((K - k, T), bool)])
    st = np.zeros(K, bool)
    st[:k] = [np.allclose(b[0, :2], b[-1, :2]) for b in boxes]
    return Obstacles(jnp.asarray(np.concatenate([boxes, pad])), jnp.asarray(v), jnp.asarray(TT, jnp.float32),
                     jnp.asarray(st))


def targets(**kw):
    t = RoadTargets.from_config(CFG)
    return dataclasses.replace(t, **{k: jnp.asarray(v, jnp.float32) for k, v in kw.items()})


plan_jit = jax.jit(plan, static_argnames=("config",))
plan_slim_jit = jax.jit(functools.partial(plan, keep_candidates=False), static_argnames=("config",))


def plan_cfg(st, ref, obs, **targets_kw):
    """``plan`` with ``CFG`` and explicit ``RoadTargets`` (the defaults ``plan`` would take), so
    that every open-loop test shares one compiled plan."""
    return plan_jit(st, ref, obs, CFG, targets=targets(**targets_kw))


def choose_from(res, rule="harm", feasible=None):
    """The exact rule (``cost.choose``) re-run on a result's own arrays (no new compile):
    ``feasible=None`` keeps the filter's verdicts; ``rule`` as ``LatticeConfig.all_collide``."""
    w = CostWeights()
    feas = res.feasible if feasible is None else feasible
    return int(choose(w, res.features, res.candidates.level, res.candidates.available & res.finite, feas,
                      ~res.collided_margin, ~res.collided, res.terminal_ok, res.impact, res.first_t,
                      w.gamma * res.features[:, 2], len(CFG.escalation), rule)[0])


# ---------------------------------------------------------------- longitudinal profiles


def test_quintic_profile_boundary_conditions(rng):
    with jax.enable_x64(True):
        n = 100
        v0, a0 = rng.uniform(0, 25, n), rng.uniform(-3, 2, n)
        s1, v1 = rng.uniform(5, 120, n), rng.uniform(0, 25, n)
        t = np.linspace(0, 10, 1001)
        Te = t[rng.integers(100, 800, n)]  # end times on the grid
        s, v, a = (np.asarray(x) for x in quintic_profile(v0, a0, s1, v1, Te, jnp.asarray(t)))
        for i in range(n):
            k = int(np.argmin(np.abs(t - Te[i])))
            assert s[i, 0] == 0 and v[i, 0] == pytest.approx(v0[i]) and a[i, 0] == pytest.approx(a0[i])
            # the end state is reached at T, then v1 is held
            np.testing.assert_allclose([s[i, k], v[i, k], a[i, k]], [s1[i], v1[i], 0.0], atol=1e-8)
            np.testing.assert_allclose(v[i, k + 1:], v1[i], atol=1e-9)
            np.testing.assert_allclose(s[i, -1], s1[i] + v1[i] * (t[-1] - Te[i]), atol=1e-8)
        # v and a are the derivatives of s (finite differences)
        np.testing.assert_allclose(np.gradient(s, t, axis=1)[:, 1:-1], v[:, 1:-1], atol=0.05)
        away = (np.abs(t[None] - Te[:, None]) > 0.015)[:, 1:-1]  # a has a kink at T (the jerk jumps to 0)
        np.testing.assert_allclose(np.gradient(v, t, axis=1)[:, 1:-1][away], a[:, 1:-1][away], atol=0.3)


def test_stop_follow_goal_modes_reach_their_targets():
    ref = straight_ref()
    st = PlanState.make(0.0, 0.0, 0.0, 12.0, v_set=15.0)
    # a leader at 8 m/s 30 m ahead, a goal 80-90 m ahead in 6-8 s at 8-12 m/s
    lead = car(30 + CFG.vehicle.length, 0.0, 8.0)
    res = plan_cfg(st, ref, obstacles([lead]), goal_s=[80.0, 90.0], goal_l=[-2.0, 2.0], goal_t=[6.0, 8.0],
                   goal_v=[8.0, 12.0])
    kind, avail = np.asarray(res.candidates.kind), np.asarray(res.candidates.available)
    end_t = np.asarray(res.candidates.end_time)
    s_rel, v = np.asarray(res.candidates.s_rel), np.asarray(res.candidates.traj.v)
    front = CFG.vehicle.length - CFG.vehicle.rear_overhang
    for m in (FOLLOW, GOAL, FALLBACK):
        assert avail[kind == m].all()
    assert not avail[kind == STOP].any()  # nothing stopped ahead, no route end
    # following: at each end time inside the horizon, follow_gap + time gap * 8 m/s behind the leader's rear
    for T_end in CFG.end_times:
        i = np.nonzero((kind == FOLLOW) & np.isclose(end_t, T_end))[0][0]
        if T_end <= CFG.horizon:
            k = int(round(T_end / CFG.dt))
            rear = lead[k, 0] - 0.5 * lead[k, 2]
            gap = rear - (s_rel[i, k] + front)
            assert gap == pytest.approx(CFG.follow_gap + CFG.follow_time_gap * 8.0, abs=0.05)
            assert v[i, k] == pytest.approx(8.0, abs=0.05)
    # the fallback brakes to a stop within the horizon at the fallback deceleration
    i = np.nonzero((kind == FALLBACK) & (np.asarray(res.candidates.lane) == 0)
                   & np.isclose(np.asarray(res.candidates.offset), 0.0))[0][0]
    assert v[i, -1] == pytest.approx(0.0, abs=1e-3)
    assert np.asarray(res.candidates.traj.a)[i].min() == pytest.approx(-CFG.fallback_decel, abs=1e-3)
    # a stopped car ahead gives the stop mode: rest a stop gap before it
    res = plan_cfg(st, ref, obstacles([car(45.0, 0.0, 0.0)]))
    kind, avail = np.asarray(res.candidates.kind), np.asarray(res.candidates.available)
    assert avail[(kind == STOP) & (np.asarray(res.candidates.lane) != GOAL_LANE)].all()  # no goal: no goal offset
    i = np.nonzero((kind == STOP) & np.asarray(res.feasible))[0]
    assert len(i)
    stop_front = np.asarray(res.candidates.s_rel)[i, -1] + front
    np.testing.assert_allclose(stop_front[np.asarray(res.candidates.traj.v)[i, -1] < 1e-3],
                               45.0 - 2.25 - CFG.buffer_lon - CFG.stop_gap, atol=0.05)


# ---------------------------------------------------------------- feasibility filter


def _oracle_infeasible(tr, level, cfg):
    """Numpy, from the trajectory samples: curvature, lateral and longitudinal acceleration (and
    speed change per step), jerk."""
    v, a = np.asarray(tr.v, np.float64), np.asarray(tr.a, np.float64)
    kap = np.abs(np.asarray(tr.kappa, np.float64)).max(-1)
    em = level >= len(cfg.escalation)
    lat = np.abs(v ** 2 * np.asarray(tr.kappa)).max(-1)
    jerk = np.abs(np.diff(a) / cfg.dt).max(-1)
    lo = np.where(em, cfg.emergency_a_min, cfg.lon_acc_limits[0])
    hi = np.where(em, max(cfg.emergency_a_max, cfg.lon_acc_limits[1]), cfg.lon_acc_limits[1])
    fd = np.diff(v) / cfg.dt  # the speed change over each step, as a drive's metric measures it
    lon = (np.minimum(a.min(-1), fd.min(-1)) < lo) | (np.maximum(a.max(-1), fd.max(-1)) > hi)
    return kap, lat, lon, jerk, v.min(-1) < 0


def test_feasibility_flags_match_an_oracle_and_nothing_infeasible_is_chosen(rng):
    ref = straight_ref()
    lim = CFG.curvature_limit
    assert lim == pytest.approx(np.tan(CFG.vehicle.max_steer) / CFG.vehicle.wheelbase)
    seen_infeasible_best = 0
    for _ in range(12):
        v = rng.uniform(0.5, 25)
        st = PlanState.make(0.0, rng.uniform(-1, 1), rng.uniform(-0.1, 0.1), v, a=rng.uniform(-2, 1.5),
                            kappa=rng.uniform(-0.02, 0.02), v_set=rng.uniform(5, 30))
        boxes = [car(rng.uniform(10, 60), rng.choice([-3.5, 0, 3.5]), rng.uniform(0, 10)) for _ in range(2)]
        res = plan_cfg(st, ref, obstacles(boxes))
        feas, avail = np.asarray(res.feasible), np.asarray(res.candidates.available)
        r = np.asarray(res.reasons)
        level = np.asarray(res.candidates.level)
        kap, lat, lon, jerk, rev = _oracle_infeasible(res.candidates.traj, level, CFG)
        em = level >= len(CFG.escalation)
        # far from the limits the oracle and the filter agree on every reason
        clear = np.abs(kap - lim) > 0.02 * lim
        assert (r[clear, 0] == (kap[clear] > lim)).all()
        lat_max = np.where(em, CFG.emergency_lat_acc_max, CFG.lat_acc_max)
        clear = np.abs(lat - lat_max) > 0.05
        assert (r[clear, 1] == (lat[clear] > lat_max[clear])).all()
        lo = np.where(em, CFG.emergency_a_min, CFG.lon_acc_limits[0])
        hi = np.where(em, max(CFG.emergency_a_max, CFG.lon_acc_limits[1]), CFG.lon_acc_limits[1])
        a = np.asarray(res.candidates.traj.a)
        clear = (np.abs(a.min(-1) - lo) > 0.01) & (np.abs(a.max(-1) - hi) > 0.01)
        assert (r[clear, 2] == lon[clear]).all()
        vmin = np.asarray(res.candidates.traj.v).min(-1)
        clear = np.abs(vmin) > 0.01
        assert (r[clear, 4] == rev[clear]).all()
        j_max = np.where(em, CFG.emergency_jerk_max, CFG.lon_jerk_max)
        clear = np.abs(jerk - j_max) > 0.05
        assert (r[clear, 3] == (jerk[clear] > j_max[clear])).all()
        assert (feas == ~r.any(-1)).all()
        i = int(res.chosen)
        if (feas & avail).any():
            assert feas[i] and avail[i]
        # without the filter the cheapest candidate is often an infeasible one
        loose = choose_from(res, feasible=jnp.ones_like(res.feasible))  # the choice without the filter
        seen_infeasible_best += int(not feas[loose])
        counts = res.rejected()
        assert counts["rejected"] == int((~feas & avail).sum())
        assert set(REASONS) <= set(counts)
    assert seen_infeasible_best > 0  # the filter changed the choice somewhere


def test_figures_from_the_generator_loop_and_a_plan_without_candidates():
    """The per-candidate figures computed inside the generator's loop agree with the written-out
    trajectories (numpy oracle), the chosen trajectory built alone is the chosen candidate's, and
    ``keep_candidates=False`` gives the same choice and figures without the trajectories."""
    from jaxplan.lattice.cost import FEATURES, goal_error

    ref = straight_ref()
    st = PlanState.make(0.0, 0.3, 0.02, 11.0, a=0.5, kappa=0.004, v_set=14.0)
    obs = obstacles([car(40.0, 0.0, 0.0), car(20.0, 3.5, 12.0)])
    tk = dict(goal_s=[90.0, 100.0], goal_l=[-2.0, 2.0], goal_t=[5.0, 9.0], goal_v=[6.0, 12.0])
    full = plan_cfg(st, ref, obs, **tk)
    tr, c = full.candidates.traj, full.candidates
    f = np.asarray(full.features, np.float64)
    col = FEATURES.index
    np.testing.assert_allclose(f[:, col("rho_max")], np.abs(np.asarray(tr.kappa)).max(-1), rtol=1e-5, atol=1e-7)
    a, v, kap = (np.asarray(x, np.float64) for x in (tr.a, tr.v, tr.kappa))
    np.testing.assert_allclose(f[:, col("jerk_lon")], np.mean((np.diff(a) / CFG.dt) ** 2, -1), rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(f[:, col("jerk_lat")], np.mean((np.diff(v ** 2 * kap) / CFG.dt) ** 2, -1), rtol=1e-3,
                               atol=1e-3)
    np.testing.assert_allclose(f[:, col("v_offset")], np.mean(np.abs(v - 14.0), -1), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(f[:, col("d_lrp")], np.mean(np.abs(np.asarray(c.l) - float(full.l_target)), -1),
                               rtol=1e-5, atol=1e-5)
    tg = targets(**tk)
    goal = goal_error(c.s, c.l, tr.v, jnp.asarray(TT, jnp.float32), tg.goal_s, tg.goal_l, tg.goal_t, tg.goal_v,
                      CFG.vehicle.center_offset, CFG.goal_weight_time)
    assert np.asarray(goal).max() > 0  # the goal term is exercised
    np.testing.assert_allclose(f[:, col("goal")], goal, rtol=1e-5, atol=1e-5)
    i = int(full.chosen)
    for name in ("x", "y", "theta", "kappa", "v", "a", "s", "t"):
        np.testing.assert_allclose(getattr(full.chosen_trajectory(), name), np.asarray(getattr(tr, name))[i],
                                   rtol=1e-5, atol=1e-4, err_msg=name)
    slim = plan_slim_jit(st, ref, obs, CFG, targets=tg)
    assert slim.candidates.traj is None and slim.min_sep is None
    assert int(slim.chosen) == i and int(slim.mode) == int(full.mode)
    for name in ("feasible", "collided", "collided_margin", "terminal_ok", "finite"):
        np.testing.assert_array_equal(getattr(slim, name), getattr(full, name), err_msg=name)
    np.testing.assert_allclose(slim.features, full.features, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(slim.trajectory.x, full.trajectory.x, atol=1e-5)
    assert slim.rejected() == full.rejected()


# ---------------------------------------------------------------- harm when everything collides


def test_all_collide_minimises_harm_against_brute_force(rng):
    shapely = pytest.importorskip("shapely")
    ref = straight_ref()
    cfg = CFG
    for trial in range(4):
        v = rng.uniform(14, 22)
        # a wall across the road close ahead and a car coming the other way: nothing avoids both
        wall = car(rng.uniform(9, 14) + 3.5, 0.0, 0.0, length=1.0, width=30.0)
        oncoming = car(rng.uniform(40, 60), rng.uniform(-1, 1), -rng.uniform(0, 8))
        obs = obstacles([wall, oncoming])
        res = plan_cfg(PlanState.make(0.0, 0.0, 0.0, v), ref, obs)
        assert int(res.mode) == RISK
        tr = res.candidates.traj
        cb = np.asarray(box_corners(trajectory_boxes(tr, cfg.vehicle)), np.float64)  # (N, T, 4, 2)
        ob = np.asarray(box_corners(obs.boxes), np.float64)  # (K, T, 4, 2)
        Pc = shapely.polygons(cb)
        N = cb.shape[0]
        first = np.full(N, np.inf)
        impact = np.zeros(N)
        vx, vy = np.asarray(tr.v) * np.cos(np.asarray(tr.theta)), np.asarray(tr.v) * np.sin(np.asarray(tr.theta))
        ovel = np.gradient(np.asarray(obs.boxes)[..., :2], cfg.dt, axis=1)
        valid = np.asarray(obs.valid)
        hits = np.zeros((N, T, K), bool)
        for k in range(K):
            Po = shapely.polygons(ob[k])
            hits[..., k] = shapely.intersects(Pc, Po[None]) & ~shapely.touches(Pc, Po[None]) & valid[k][None]
        any_hit = hits.any(-1)
        for n in range(N):
            if any_hit[n].any():
                j = int(np.argmax(any_hit[n]))
                first[n] = TT[j]
                # the obstacle touched first: the deepest overlap (shapely intersection area) at that step
                k = max(range(K), key=lambda q: shapely.intersection(Pc[n, j], shapely.polygons(ob[q, j])).area
                        if hits[n, j, q] else -1)
                impact[n] = np.hypot(vx[n, j] - ovel[k, j, 0], vy[n, j] - ovel[k, j, 1])
        pool = np.asarray(res.candidates.available) & np.asarray(res.feasible)
        if not pool.any():
            pool = np.asarray(res.candidates.available)
        assert any_hit.any(-1)[pool].all()  # RISK: every candidate the rule may take collides
        m = impact[pool].min()
        best = pool & (impact <= m + 0.05)
        late = first[best].max()
        best &= first >= late - 1e-6
        i = int(res.chosen)
        assert best[i], (trial, impact[i], m, first[i], late)
        np.testing.assert_allclose(np.asarray(res.impact)[pool], impact[pool], atol=0.05)
        # the risk rule picks by lambda + gamma / TTC and hits harder here
        by_risk = choose_from(res, rule="risk")
        assert impact[by_risk] >= impact[i] - 1e-6


def test_margins_a_car_closing_in_from_behind_and_terminal_condition():
    ref = straight_ref()
    st = PlanState.make(0.0, 0.0, 0.0, 15.0, v_set=15.0)
    # a car 0.2 m beside the corridor of the straight candidates: free, but inside the lateral buffer
    side = car(20.0, 0.5 * CFG.vehicle.width + 0.9 + 0.2, 0.0)
    res = plan_cfg(st, ref, obstacles([side]))
    straight = np.asarray(res.candidates.lane == 0) & np.isclose(np.asarray(res.candidates.offset), 0.0)
    straight &= np.asarray(res.candidates.kind) == 0
    assert not np.asarray(res.collided)[straight].any() and np.asarray(res.collided_margin)[straight].all()
    assert not bool(res.collided_margin[int(res.chosen)])
    # a faster car closing in from behind in the same lane (at 20 m/s, 7.5 m behind): keeping 15 m/s
    # runs into it in 1.5 s; the chosen plan leaves it room (speeds up or changes lane)
    behind = car(-12.0, 0.0, 20.0)
    res = plan_cfg(st, ref, obstacles([behind]))
    keep = np.asarray(res.candidates.kind == 0) & (np.abs(np.asarray(res.candidates.traj.v)[:, -1] - 15.0) < 0.5) \
        & (np.abs(np.asarray(res.candidates.l)[:, -1]) < 0.5)
    assert keep.any() and np.asarray(res.collided)[keep].all()
    i = int(res.chosen)
    assert not bool(res.collided[i]) and int(res.mode) != RISK
    assert float(res.candidates.traj.v[i, 10]) > 15.5 or abs(float(res.candidates.l[i, -1])) > 2.0
    # terminal condition: a stopped car 150 m ahead is free for the fast candidates but they cannot stop after
    # the horizon any more; the chosen plan can
    stopped = car(150.0, 0.0, 0.0)
    res = plan_cfg(PlanState.make(0.0, 0.0, 0.0, 25.0, v_set=25.0), ref, obstacles([stopped]))
    tok = np.asarray(res.terminal_ok)
    free = ~np.asarray(res.collided_margin)
    fast = np.asarray(res.candidates.traj.v)[:, -1] > 20
    lane0 = np.abs(np.asarray(res.candidates.l)[:, -1]) < 1.0
    assert (free & fast & lane0 & ~tok).any()
    i = int(res.chosen)
    assert tok[i] and free[i]
    end = np.asarray(res.candidates.s)[i, -1] + CFG.vehicle.length - CFG.vehicle.rear_overhang
    v_end = float(res.candidates.traj.v[i, -1])
    same_lane = abs(float(res.candidates.l[i, -1])) < 2.0
    if same_lane:
        assert 150 - 2.25 - CFG.buffer_lon - end >= v_end ** 2 / (2 * CFG.terminal_decel) + CFG.terminal_gap - 1e-3


def test_a_plan_keeps_its_margin_from_the_road_edge():
    """A left road edge that leaves the car's box 0.15 m at its lane's centre (inside
    ``edge_margin``, still on the road) and the car 0.3 m right of that centre: candidates that
    go to the centre count as touching a buffer, and the chosen plan keeps the margin; a car
    already inside the margin may stay there (the candidates that hold its offset do not count)."""
    ref = straight_ref()
    R = ref.s.shape[0]
    half = 0.5 * CFG.vehicle.width
    edge = half + 0.15
    edges = np.stack([np.full(R, edge), np.full(R, -5.0)], -1)
    assert 0.15 < CFG.edge_margin
    res = plan_cfg(PlanState.make(0.0, -0.3, 0.0, 15.0, v_set=15.0), ref, obstacles([]), road_edges=edges)
    l_end = np.asarray(res.candidates.l)[:, -1]
    centre = np.abs(l_end) < 1e-3
    assert centre.any() and np.asarray(res.collided_margin)[centre].all()
    assert not np.asarray(res.off_road)[centre].any()  # on the road, only inside the margin
    i = int(res.chosen)
    assert not bool(res.collided_margin[i]) and int(res.mode) == FREE
    assert float(np.max(np.asarray(res.candidates.l)[i])) < edge - half - CFG.edge_margin + 1e-3
    # already inside the margin (at the centre): holding the lane is no violation
    res = plan_cfg(PlanState.make(0.0, 0.0, 0.0, 15.0, v_set=15.0), ref, obstacles([]), road_edges=edges)
    straight = np.asarray(res.candidates.kind == 0) & (np.abs(np.asarray(res.candidates.l)).max(-1) < 1e-3)
    assert straight.any() and not np.asarray(res.collided_margin)[straight].any()
    assert int(res.mode) == FREE


def test_target_speed_reaches_what_a_tight_curve_allows():
    """A car at 3.4 m/s in a left arc of radius 6.5 m, set speed 11 m/s. The level-0 grid steps
    from 3.4 to 6.2 m/s, past the arc's limit ``sqrt(lat_acc_max / kappa)`` (5.1 m/s): none of its
    faster candidates is feasible. ``target_speed`` (the road lattice) adds a cruise profile to the
    set speed capped at ``TARGET_LAT_SHARE`` of that limit (checked against the formula), and the
    plan speeds up to it within the lateral acceleration limit."""
    from jaxplan.geometry.frenet import ref_state
    from jaxplan.lattice.longitudinal import CRUISE, TARGET_LAT_SHARE, target_speed

    R = 6.5
    u = np.linspace(0.0, 1.7 * np.pi * R, straight_ref().s.shape[0])  # as many points: plan_cfg's program
    ref = ReferenceLine.from_polyline(R * np.stack([np.sin(u / R), 1 - np.cos(u / R)], -1))
    x, y = R * np.sin(0.5), R * (1 - np.cos(0.5))
    st = PlanState.make(x, y, 0.5, 3.4, kappa=1.0 / R, v_set=11.0)
    cap = np.sqrt(TARGET_LAT_SHARE * CFG.lat_acc_max * R)
    _, _, k_ahead, _ = ref_state(ref, jnp.linspace(5.0, 30.0, 16))
    assert float(target_speed(k_ahead, 11.0, CFG.lat_acc_max)) == pytest.approx(cap, rel=0.03)
    assert float(target_speed(jnp.zeros(16), 11.0, CFG.lat_acc_max)) == 11.0  # straight: the set speed
    assert CFG.target_speed
    tg = dataclasses.replace(targets(), lane_ok=jnp.asarray([False, True, False]))  # the inner lane is too tight
    res = plan_jit(st, ref, obstacles([]), CFG, targets=tg)
    c = res.candidates
    kind, level, v_end = np.asarray(c.kind), np.asarray(c.level), np.asarray(c.v_end)
    feasible, avail = np.asarray(res.feasible), np.asarray(c.available)
    grid = (kind == CRUISE) & (level == 0) & (np.abs(v_end - cap) > 0.05) & avail
    assert grid.any() and not (feasible & grid & (v_end > 3.5)).any()  # the grid alone holds 3.4 m/s
    i = int(res.chosen)
    v = np.asarray(res.trajectory.v)
    assert int(res.mode) == FREE and bool(feasible[i])
    assert int(kind[i]) == CRUISE and v_end[i] == pytest.approx(cap, rel=0.03) and v[-1] > 4.5, (kind[i], v_end[i])
    assert np.abs(v**2 * np.asarray(res.trajectory.kappa)).max() <= CFG.lat_acc_max + 1e-3


@pytest.mark.parametrize("margin", [False, True], ids=["edge", "edge_margin"])
def test_road_edge_check_matches_shapely(rng, margin):
    """``leaves_road`` against shapely on a straight line (where its lateral reach is exact):
    the car's box at random offsets and headings, the corridor's edges random per point; at the
    plain edge (``ROAD_TOL`` past it) and at the road lattice's ``edge_margin`` inside it."""
    from shapely.geometry import Polygon, box as sbox

    from jaxplan.lattice.plan import ROAD_TOL, leaves_road

    tol = -LatticeConfig.road().edge_margin if margin else ROAD_TOL
    assert not margin or tol < 0

    ref = straight_ref()
    veh = CFG.vehicle
    R = ref.s.shape[0]
    n, T_ = 3000, 4
    left = rng.uniform(2.0, 5.0)
    right = -rng.uniform(2.0, 5.0)
    edges = jnp.asarray(np.stack([np.full(R, left), np.full(R, right)], -1), jnp.float32)
    s = rng.uniform(10.0, 300.0, (n, T_)).astype(np.float32)
    l = (rng.uniform(right, left, (n, 1)) + rng.uniform(-0.3, 0.3, (n, T_))).astype(np.float32)
    dl = np.tan(rng.uniform(-0.3, 0.3, (n, T_))).astype(np.float32)

    class Cand:  # the fields leaves_road reads
        pass

    c = Cand()
    c.s, c.l, c.dl = jnp.asarray(s), jnp.asarray(l), jnp.asarray(dl)
    got = np.asarray(leaves_road(ref, c, edges, veh, tol))
    strip = sbox(-1e4, right - tol, 1e4, left + tol).buffer(1e-4)
    d = np.arctan(dl)
    cy = l + veh.center_offset * np.sin(d)
    boxes = np.stack([s + veh.center_offset * np.cos(d), cy, np.full_like(s, veh.length), np.full_like(s, veh.width), d], -1)
    corners = np.asarray(box_corners(jnp.asarray(boxes)))  # (n, T, 4, 2)
    want = np.array([any(not strip.contains(Polygon(corners[i, k])) for k in range(T_)) for i in range(n)])
    # poses within 1 mm of an edge: float32 may go either way
    reach = 0.5 * veh.width * np.abs(np.cos(d)) + 0.5 * veh.length * np.abs(np.sin(d))
    near = (np.minimum(np.abs(cy + reach - left - tol), np.abs(cy - reach - right + tol)) < 1e-3).any(-1)
    assert 0.2 < want.mean() < 0.9  # both outcomes are well represented
    assert np.all(got[~near] == want[~near])


def test_borrow_gain_is_validated():
    with pytest.raises(ValueError, match="borrow_gain"):
        LatticeConfig.road(borrow_gain=-1.0).validate()
    assert LatticeConfig.road(borrow_gain=float("inf")).validate().borrow_gain == float("inf")


def test_goal_timing_aims_inside_the_region():
    """Arriving when the window opens means arriving ``GOAL_INSIDE`` (2 m; a quarter of a short
    region) before its far end, and by its close that far past its near end: the set speed is
    (aim - s) / t, worked by hand here."""
    from jaxplan.plan_context import goal_speed

    inf = jnp.inf
    early = goal_speed(25.0, 100.0, jnp.asarray([150.0, 160.0]), jnp.asarray([10.0, 10.1]))
    short = goal_speed(25.0, 100.0, jnp.asarray([150.0, 154.0]), jnp.asarray([10.0, 10.1]))
    late = goal_speed(5.0, 100.0, jnp.asarray([150.0, 160.0]), jnp.asarray([0.0, 8.0]))
    assert float(early) == pytest.approx((158.0 - 100.0) / 10.0)
    assert float(short) == pytest.approx((153.0 - 100.0) / 10.0)
    assert float(late) == pytest.approx(min((152.0 - 100.0) / 8.0, 1.2 * 5.0))
    assert float(goal_speed(25.0, 100.0, jnp.asarray([inf, inf]), jnp.asarray([10.0, 10.1]))) == 25.0


def test_set_speed_follows_the_goal_range_and_the_curves():
    """``goal_speed`` aims inside the goal's speed range only once the goal is within reach;
    ``curve_speed`` is ``min sqrt(a_lat / kappa + 2 b d)`` (a straight, then an arc of radius 50 m)."""
    from types import SimpleNamespace

    from jaxplan.geometry.frenet import reference_line
    from jaxplan.plan_context import goal_speed
    from jaxplan.plan_context import curve_speed

    inf = jnp.inf
    gv = jnp.asarray([12.3, 18.3])
    near = goal_speed(25.0, 100.0, jnp.asarray([150.0, 160.0]), jnp.asarray([0.0, inf]), gv, 100.0)
    far = goal_speed(25.0, 100.0, jnp.asarray([250.0, 260.0]), jnp.asarray([0.0, inf]), gv, 100.0)
    passed = goal_speed(25.0, 300.0, jnp.asarray([250.0, 260.0]), jnp.asarray([0.0, inf]), gv, 100.0)
    assert float(near) == pytest.approx(18.3 - 0.6) and float(far) == 25.0 and float(passed) == 25.0
    slow = goal_speed(5.0, 100.0, jnp.asarray([150.0, 160.0]), jnp.asarray([0.0, inf]), gv, 100.0)
    assert float(slow) == pytest.approx(12.3 + 0.6)
    R, d0 = 50.0, 40.0
    u = np.arange(0.0, 150.0, 0.5)
    straight = np.stack([u - d0, np.zeros_like(u)], -1)[u < d0]
    arc = R * np.stack([np.sin(u / R), 1 - np.cos(u / R)], -1)
    scene = SimpleNamespace(route=reference_line(jnp.asarray(np.concatenate([straight, arc]))))
    a_lat, b = 3.2, 2.0
    got = float(curve_speed(scene, 0.0, 120.0, a_lat, b, n=241))
    want = np.sqrt(a_lat * R + 2 * b * d0)  # the arc's curvature settles within a point or two
    assert got == pytest.approx(want, rel=0.03)
    assert float(curve_speed(scene, 0.0, 30.0, a_lat, b, n=61)) > 1e2  # the arc is beyond the reach


# ---------------------------------------------------------------- closed loop


def _scene(kind):
    """Scenario objects of the shared JSON format, on the built-in scenes' road."""
    from jaxplan.scenarios import builtin as b

    road = b.SyntheticRoad(0.0, 0.3)
    t = np.arange(b.RECORD_STEPS) * b.DT
    v0 = 12.0
    if kind == "stop":  # one lane, a stopped car 45 m ahead: the only way out is to stop
        n_lanes, obs = 1, [b.road_obstacle(1, road, b.START_S + 45.0, 0.0, role="static")]
    elif kind == "pass":  # two lanes, a stopped car ahead in the ego lane, the left lane free
        n_lanes, obs = 2, [b.road_obstacle(1, road, b.START_S + 40.0, 0.0, role="static")]
    elif kind == "borrow":  # one lane each way, a stopped car ahead, an oncoming car that has passed by t = 3 s
        n_lanes = 1
        obs = [b.road_obstacle(1, road, b.START_S + 45.0, 0.0, role="static"),
               b.road_obstacle(2, road, b.START_S + 80.0 - 15.0 * t, np.full_like(t, b.LANE), length=4.5)]
    else:  # cut-in from the left, 3 m/s slower, 14 m ahead
        n_lanes = 2
        u = np.clip((t - 0.8) / 2.0, 0.0, 1.0)
        obs = [b.road_obstacle(1, road, b.START_S + 14.0 + (v0 - 3.0) * t, b.LANE * (1.0 - (3 * u ** 2 - 2 * u ** 3)))]
    start, th0 = road.pose(b.START_S, 0.0)
    gc, gth = road.pose(b.START_S + 110.0, 0.5 * (n_lanes - 1) * b.LANE)
    lanelets = b.road_lanelets(road, n_lanes, 15.0)
    if kind == "borrow":  # the lane on the left runs the other way (its points in its own direction)
        ss = np.arange(0.0, b.ROAD_LENGTH + 1e-6, 2.0)[::-1]
        lanelets[0]["adjacentLeft"] = {"ref": 200, "drivingDir": "opposite"}
        lanelets.append({"id": 200, "left": road.pose(ss, 0.5 * b.LANE)[0].round(4).tolist(),
                         "right": road.pose(ss, 1.5 * b.LANE)[0].round(4).tolist(), "predecessors": [],
                         "successors": [], "speed_limit": 15.0,
                         "adjacentLeft": {"ref": lanelets[0]["id"], "drivingDir": "opposite"}})
    return {"id": f"TEST_{kind}", "dt": b.DT, "lanelets": lanelets, "obstacles": obs,
            "planning_problems": [{"id": 1, "initial_state": {"t": 0.0, "position": start.tolist(),
                                                             "orientation": float(th0), "velocity": v0,
                                                             "acceleration": 0.0},
                                   "goals": [{"rectangle": {"center": gc.tolist(), "length": 30.0,
                                                            "width": n_lanes * b.LANE, "orientation": float(gth)},
                                              "time": [0.0, 20.0]}]}]}


@functools.lru_cache(maxsize=1)
def _drives():
    from jaxplan.lattice.planner import LatticePlanner
    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.builtin import survivable
    from jaxplan.scenarios.loader import parse_scenario
    from jaxplan.scenarios.scene import SceneRecord
    from jaxplan.sim.metrics.registry import evaluate_batch
    from jaxplan.sim.rollout import SimConfig, rollout

    recs = []
    for kind in ("stop", "pass", "cut_in", "borrow"):
        d = _scene(kind)
        sc = parse_scenario(d, d["id"])
        scene, route = build_scene(sc)
        recs.append(SceneRecord(d["id"], scene, sc, route))
    surv = survivable(recs)
    planner = LatticePlanner()
    cfg = SimConfig(n_steps=90, stop_at_goal=False)
    batch = stack_scenes([r.scene for r in recs], min_steps=cfg.n_steps + 1)
    log = rollout(planner, batch, cfg)
    m = {k: np.asarray(v) for k, v in evaluate_batch(log, batch, planner.vehicle).items()}
    return recs, surv, jax.tree_util.tree_map(np.asarray, log), m, planner


def test_lattice_drive_compiles_with_the_planners_xla_options():
    """The lattice planner names its XLA options (``NO_YNN``, measured faster for its plan and its
    drives); the drive above ran in the program compiled with them."""
    from jaxplan.compile_options import NO_YNN, options_supported, options_key
    from jaxplan.sim.rollout import compiled_with

    planner = _drives()[-1]
    assert planner.compiler_options == NO_YNN
    key = options_key(NO_YNN)
    assert compiled_with(key)._cache_size() >= 1
    assert compiled_with(key).applied == (NO_YNN if options_supported(key) else {})


def test_the_drive_report_names_the_modes_the_set_speed_and_the_leader():
    """``describe``: the modes of the plans, and the last plan's set speed and leader; behind the
    stopped car (obstacle 0 of TEST_stop) it names that car, standing, at its gap."""
    from jaxplan.sim.drive import describe_last_plans

    recs, _, log, _, planner = _drives()
    i = [r.name for r in recs].index("TEST_stop")
    words = describe_last_plans(planner, {k: np.asarray(v)[i] for k, v in log.info.items()}, int(log.end_step[i]), 3)
    gap = re.search(r"leader obstacle 0 (\d+) m ahead at 0.0 m/s$", words)
    assert words.startswith("modes of the last 7 plans: ") and "set speed" in words and gap, words
    assert 0 < int(gap.group(1)) < 10, words
    hand = {"mode": np.array([0, 0, 2]), "v_set": np.array([10.0, 10.0, 13.94]), "leader": np.array([1, 1, -1]),
            "leader_gap": np.array([5.0, 5.0, 1e4]), "leader_v": np.array([1.0, 1.0, 0.0])}
    assert planner.describe(hand) == "modes of the last 3 plans: free x2, risk x1; the last: set speed 13.9 m/s, no leader"
    hand["leader"][-1], hand["leader_gap"][-1], hand["leader_v"][-1] = 4, 12.4, 2.04
    assert planner.describe(hand).endswith("set speed 13.9 m/s, leader obstacle 4 12 m ahead at 2.0 m/s")


def test_closed_loop_stops_passes_borrows_and_survives_the_cut_in():
    recs, surv, log, m, planner = _drives()
    assert surv.all()  # in-lane braking survives all three: a collision would be the planner's fault
    assert not m["overlap.collided"].any()
    kap_lim = np.tan(planner.vehicle.max_steer) / planner.vehicle.wheelbase
    assert (m["comfort.max_abs_accel"] <= 8.0 + 1e-3).all() and (m["comfort.max_abs_curvature"] <= kap_lim).all()
    from jaxplan.geometry.frenet import to_frenet

    for i, r in enumerate(recs):
        ref = jax.tree_util.tree_map(jnp.asarray, r.scene.route)
        s, l = (np.asarray(a) for a in to_frenet(ref, jnp.stack([log.x[i], log.y[i]], -1)))
        s_obs = float(np.asarray(r.scene.obstacle_sl)[0, 0, 0])
        if r.name == "TEST_stop":  # (nearly) stopped before the car, within a few metres of the stop gap
            front = s[-1] + 0.5 * planner.vehicle.length
            assert log.v[i, -1] < 0.5 and s_obs - 2.3 - 6.0 < front < s_obs - 2.3
        if r.name == "TEST_pass":  # changed lanes, drove past the stopped car, came back towards the route lane
            assert s[-1] > s_obs + 10 and np.abs(l).max() > 1.75  # its centre crossed into the left lane
        if r.name == "TEST_cut_in":
            assert log.v[i].min() > 0.5  # it did not need to stop
        if r.name == "TEST_borrow":  # borrowed the oncoming lane once it was free, passed, came back
            assert not np.asarray(r.scene.lane_same_dir)[r.scene.lane_offset.shape[0] // 2 + 1].any()
            assert s[-1] > s_obs + 10 and np.abs(l).max() > 1.75 and abs(l[-1]) < 0.5
    assert (log.plan_ok.all(axis=-1)).all()
