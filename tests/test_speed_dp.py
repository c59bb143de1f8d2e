"""Speed DP: optimum vs exhaustive search, cost tables vs a direct formula, kinematics and
limits of the plans, decisions, speed limits, the goal window, soft-min, batching, gradients."""
import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.speed import (
    CostWeights,
    DPCosts,
    SpeedConfig,
    SpeedRoad,
    dp_from_costs,
    expected_speed_profile,
    make_scene,
    plan_speed,
    profile_cost,
    soft_value,
    stage_costs,
)
from jaxplan.speed.costs import REAR_CONTACT, table_origin, table_size, unreach
from jaxplan.speed.problem import band_widths, profile_at
from jaxplan.types import Obstacles, VehicleParams

SMALL = SpeedConfig(dt=1.0, n_t=4, ds=0.5, v_max=6.0, a_min=-2.0, a_max=1.0, n_sub=2, qp_dt=0.5)
CFG = SpeedConfig(dt=1.0, n_t=5, ds=1.0, v_max=16.0, a_min=-4.0, a_max=2.0)
N_REF = 80  # every path of these tests has this many points (one compiled plan)
REF = ReferenceLine.from_polyline(np.stack([np.linspace(-10.0, 300.0, N_REF), np.zeros(N_REF)], -1))
W = CostWeights.default()
CAR = VehicleParams()
FRONT = CAR.center_offset + 0.5 * CAR.length  # 3.85

_dp = jax.jit(dp_from_costs, static_argnums=1)
_soft = jax.jit(soft_value, static_argnums=1)


@jax.jit
def _small_costs(obs, v0, a0, w):
    _, scene = make_scene(REF, obs, SMALL, s0=10.0, v0=v0)
    return stage_costs(scene, SMALL, w, v0, a0), scene


def _exhaustive(d, cfg):
    best, arg = np.inf, None
    for seq in itertools.product(range(cfg.n_v), repeat=cfg.n_t):
        c = profile_cost(d, cfg, seq)
        if c < best:
            best, arg = c, seq
    return best, arg


def _lead_scene(rng, T=9, dt=0.5, behind=False):
    t = np.arange(T) * dt
    K = 4 if behind else 3
    b = np.zeros((K, T, 5), np.float32)
    b[..., 2], b[..., 3] = 4.5, 1.8
    b[0, :, 0] = rng.uniform(8, 20) + rng.uniform(0, 3) * t
    b[1, :, 0], b[1, :, 1] = rng.uniform(5, 25), rng.uniform(-4, 4)
    b[2, :, 0], b[2, :, 1] = rng.uniform(0, 15) + 4 * t, 3.5  # a neighbour on the left
    if behind:  # a vehicle closing in from behind in the car's lane (the car is at x = 0)
        b[3, :, 0] = -rng.uniform(5, 7) + rng.uniform(7, 9) * t
    return Obstacles(jnp.asarray(b), jnp.ones((K, T), bool), jnp.asarray(t, jnp.float32))


def test_dp_matches_exhaustive_search_on_scene_costs(rng):
    """Obstacles, speed, acceleration, first-segment jerk, terminal and goal costs of real
    scenes: the band DP's optimum and its backtracked profile equal the best of every
    knot-speed sequence (host enumeration, no band, no windows)."""
    for trial in range(4):
        obs = _lead_scene(rng)
        v0, a0 = float(rng.uniform(0, 6)), float(rng.uniform(-2, 1))
        w = W if trial % 2 else dataclasses.replace(W, w_goal=jnp.float32(3.0))
        d, _ = _small_costs(obs, v0, a0, w)
        ii, jj, cost = _dp(d, SMALL)
        best, arg = _exhaustive(d, SMALL)
        assert float(cost) == pytest.approx(best, rel=1e-5, abs=1e-3)
        assert profile_cost(d, SMALL, np.asarray(jj)) == pytest.approx(best, rel=1e-5, abs=1e-3)
        # stations follow from the speeds: s_{k+1} - s_k = (v_k + v_{k+1}) dt / 2
        assert np.array_equal(np.diff(np.concatenate([[0], np.asarray(jj)])) + 0, np.diff(np.concatenate([[0], np.asarray(jj)])))
        i_exp = np.cumsum(np.asarray(jj) + np.concatenate([[0], np.asarray(jj)[:-1]]))
        assert np.array_equal(np.asarray(ii), i_exp)


def test_dp_matches_exhaustive_search_on_random_costs(rng):
    """Random cost tensors (with blocked cells) in the DP's layout."""
    d0, _ = _small_costs(_lead_scene(rng), 3.0, 0.0, W)
    X, V = table_size(SMALL), SMALL.n_v
    for _ in range(4):
        table = rng.uniform(0, 5, d0.table.shape).astype(np.float32)
        table[rng.uniform(size=table.shape) < 0.2] = SMALL.big
        first = np.where(np.asarray(d0.first) < unreach(SMALL), rng.uniform(0, 5, V), unreach(SMALL)).astype(np.float32)
        d = DPCosts(jnp.asarray(table), jnp.asarray(rng.uniform(0, 5, (X, V)), jnp.float32),
                    jnp.asarray(rng.uniform(0, 3, V), jnp.float32), jnp.asarray(rng.uniform(size=SMALL.n_t) < 0.5),
                    jnp.asarray(rng.uniform(0, 3, len(SMALL.accel_offsets)), jnp.float32), jnp.asarray(first),
                    jnp.asarray(rng.uniform(0, 5, (X, V)), jnp.float32), d0.ilo, d0.jlo, d0.c0)
        ii, jj, cost = _dp(d, SMALL)
        best, _ = _exhaustive(d, SMALL)
        assert float(cost) == pytest.approx(best, rel=1e-5)
        # soft-min: a lower bound that converges to the optimum as the temperature -> 0
        soft = [float(_soft(d, SMALL, tau)) for tau in (1.0, 0.1, 0.01)]
        assert soft[0] <= soft[1] + 1e-3 <= soft[2] + 2e-3 <= best + 3e-3
        assert soft[2] == pytest.approx(best, abs=0.2)


def test_band_covers_every_reachable_state(rng):
    """Every station / speed reachable from v0 under the acceleration limits lies inside the
    band at every knot (else the DP would miss profiles)."""
    from jaxplan.speed import band_offsets

    bw = band_widths(CFG)
    offs = CFG.accel_offsets
    for v0 in rng.uniform(0, CFG.v_max, 6):
        ilo, jlo = (np.asarray(a) for a in band_offsets(jnp.float32(v0), CFG))
        a_lo, a_hi = CFG.first_accel_range
        j1 = [j for j in range(CFG.n_v) if a_lo - 1e-4 <= (j * CFG.dv - v0) / CFG.dt <= a_hi + 1e-4]
        states = {(j, j) for j in j1}
        for k in range(CFG.n_t):
            S, V = bw[k]
            for i, j in states:
                assert ilo[k] <= i < ilo[k] + S and jlo[k] <= j < jlo[k] + V, (v0, k, i, j)
            states = {(i + j + j + o, j + o) for i, j in states for o in offs if 0 <= j + o < CFG.n_v}


def _direct_table(scene, cfg, w, v0):
    """The obstacle cost table from its definition (numpy double loop over obstacles and
    stations; independent of the scan)."""
    X, U0 = table_size(cfg), table_origin(cfg)
    c0 = v0 * cfg.dt / 2
    xs = c0 + (np.arange(X) - U0) * cfg.ds
    lo, hi, hit, vob = (np.asarray(a, np.float64) for a in scene.blocking())
    cl = scene.classified
    mult = (np.asarray(cl.size, np.float64) / 8.0) ** float(w.size_exp)
    F = lo.shape[1]
    rate, col = np.zeros((F, X)), np.zeros((F, X), bool)
    front, rear = float(scene.front), float(scene.rear)
    for f in range(F):
        for u, x in enumerate(xs):
            e, g = np.inf, -np.inf
            for k in range(lo.shape[0]):
                if not hit[k, f]:
                    continue
                if lo[k, f] - cfg.ds / 2 <= x <= hi[k, f] + cfg.ds / 2:
                    col[f, u] = True
                elif x < lo[k, f]:
                    e = min(e, lo[k, f] - float(w.follow_dist) - float(w.follow_headway) * max(vob[k, f], 0.0))
                else:
                    g = max(g, hi[k, f] + float(w.overtake_dist))
            r = float(w.w_block) * (max(x - e, 0.0) ** 2 + max(g - x, 0.0) ** 2)
            for k in range(lo.shape[0] - 1):
                if not bool(cl.side.hit[k, f]):
                    continue
                rk = float(cl.side.lower[k, f])
                if bool(cl.no_bypass[k]):
                    r += float(w.w_no_bypass) * mult[k] * max(x + front - rk, 0.0) ** 2
                if bool(cl.blind_zone[k]) and rk - cfg.blind_back <= x + front and x + rear <= rk + cfg.blind_front:
                    r += float(w.w_blind) * mult[k]
            # behind: room ahead of the nearest one, and a contact while the car is not ahead of one
            rb = cl.rear
            ups = [float(rb.upper[k, f]) for k in range(rb.hit.shape[0]) if bool(rb.hit[k, f])]
            if ups:
                r += float(w.w_rear) * max(max(ups) + float(w.rear_gap) - x, 0.0) ** 2
                if any(x <= q + cfg.ds / 2 for q in ups):
                    r += REAR_CONTACT * cfg.big
            rate[f, u] = r
    h = cfg.dt / cfg.n_sub
    return rate * h + np.where(col, cfg.big, 0.0)


def test_cost_table_matches_direct_formula(rng):
    for trial in range(4):
        obs = _lead_scene(rng, behind=trial >= 2)
        v0 = float(rng.uniform(1, 6))
        d, scene = _small_costs(obs, v0, 0.0, W)
        assert bool(np.asarray(scene.classified.no_bypass).any() or np.asarray(scene.classified.blind_zone).any())
        assert bool(np.asarray(scene.classified.rear.hit).any()) == (trial >= 2)
        ref = _direct_table(scene, SMALL, W, v0)
        got = np.asarray(d.table[0], np.float64)
        near = np.abs(got - ref) > 1e-3 * np.maximum(1.0, np.abs(ref))
        assert near.mean() < 0.002  # a station exactly on a boundary's edge may round either way
        assert np.allclose(got[~near], ref[~near], rtol=1e-4, atol=1e-3)


NO_KC = (jnp.zeros((1, 4, 2)), jnp.ones((1, 4), bool), jnp.zeros((1,), bool))


INF = np.inf


def _road(limit_s=(0.0, 1.0, 2.0, 3.0), limit_v=(INF,) * 4, stop=INF, goal_s=(-INF, INF), goal_t=(INF, INF),
          goal_v=(-INF, INF)):
    f = lambda x: jnp.asarray(x, jnp.float32)
    return SpeedRoad(f(limit_s), f(limit_v), f(stop), f(goal_s), f(goal_t), f(goal_v))


def _plan(obs, v0, w=W, keep_clear=NO_KC, a0=0.0, road=None, ref=REF, s0=10.0):
    return plan_speed(ref, obs, CFG, w, v0=v0, a0=a0, s0=s0, keep_clear=keep_clear, vehicle=CAR,
                      road=_road() if road is None else road)


K_OBS, T_OBS = 2, 15


def _moving(start, vel, T=T_OBS, dt=0.5):
    """Boxes moving along x (padded with a far static one to ``K_OBS`` obstacles)."""
    start = list(start) + [[250.0, 40.0, 1.0, 1.0, 0.0]] * (K_OBS - len(start))
    vel = list(vel) + [0.0] * (K_OBS - len(vel))
    t = np.arange(T) * dt
    b = np.repeat(np.asarray(start, np.float32)[:, None], T, 1)
    b[..., 0] += np.asarray(vel)[:, None] * t
    return Obstacles(jnp.asarray(b), jnp.ones(b.shape[:2], bool), jnp.asarray(t, jnp.float32))


def _kinematics_ok(p, v0):
    s, v, a = np.asarray(p.s), np.asarray(p.v), np.asarray(p.a)
    assert v[0] == pytest.approx(min(v0, CFG.v_max), abs=1e-5)
    assert np.allclose(np.diff(s), 0.5 * (v[1:] + v[:-1]) * CFG.dt, atol=1e-4)  # exact constant-acceleration segments
    assert np.allclose(a, np.diff(v) / CFG.dt, atol=1e-5)
    assert np.all(a[1:] >= CFG.a_min - 1e-4) and np.all(a[1:] <= CFG.a_max + 1e-4)
    a_lo, a_hi = CFG.first_accel_range  # the first segment: the grid speed nearest to the limits'
    assert a_lo - 1e-4 <= a[0] <= a_hi + 1e-4
    assert np.all(v >= 0) and np.all(v <= CFG.v_max + 1e-5)


def test_stops_behind_static_obstacle_and_follows_lead_with_headway():
    p = _plan(_moving([[40.0, 0.0, 4.5, 1.8, 0.0]], [0.0]), v0=10.3)
    assert bool(p.feasible)
    _kinematics_ok(p, 10.3)
    # at the end of the horizon it can still stop at b_comfort with the follow distance left
    stop = float(p.s[-1]) + float(p.v[-1]) ** 2 / (2 * CFG.b_comfort) + float(W.follow_dist)
    assert stop + FRONT <= 40 - 2.25 - CFG.buffer + 1e-3
    lead = _plan(_moving([[35.0, 0.0, 4.5, 1.8, 0.0]], [8.0]), v0=12.0)
    _kinematics_ok(lead, 12.0)
    gap = 35 + 8 * np.asarray(lead.t) - 2.25 - (np.asarray(lead.s) + FRONT)
    assert np.all(gap > CFG.buffer)
    # the time-headway follow distance: a longer headway keeps a longer gap
    far = _plan(_moving([[35.0, 0.0, 4.5, 1.8, 0.0]], [8.0]), v0=12.0,
                w=dataclasses.replace(W, follow_headway=jnp.float32(2.5)))
    gap_far = 35 + 8 * np.asarray(far.t) - 2.25 - (np.asarray(far.s) + FRONT)
    assert gap_far[-1] > gap[-1] + 4.0


def test_first_segment_starts_from_v0_and_a0():
    """An off-grid start speed is kept exactly; the jerk from a0 shapes the first segment."""
    free = _moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0])
    for v0 in (0.0, 3.3, 9.7, 15.9):
        _kinematics_ok(_plan(free, v0), v0)
    w = dataclasses.replace(W, w_jerk=jnp.float32(20.0))
    hard = _plan(free, 8.0, w=dataclasses.replace(w, v_cruise=jnp.float32(8.0)), a0=-3.0)
    soft = _plan(free, 8.0, w=dataclasses.replace(w, v_cruise=jnp.float32(8.0)), a0=0.0)
    assert float(hard.a[0]) < float(soft.a[0])


def test_obstacles_behind_do_not_block():
    """A faster car behind in the lane (it would drive into the car) is ignored as blocking;
    a slow car ahead is not."""
    behind = _moving([[-12.0, 0.0, 4.5, 1.8, 0.0]], [15.0])
    p = _plan(behind, 10.0, w=dataclasses.replace(W, v_cruise=jnp.float32(10.0)))
    assert bool(p.feasible) and not bool(p.scene.classified.is_blocking[0]) and bool(p.scene.classified.behind[0])
    assert float(p.v[-1]) >= 9.9  # keeps its speed: no braking for a follower
    ahead = _plan(_moving([[30.0, 0.0, 4.5, 1.8, 0.0]], [2.0]), 10.0)
    assert bool(ahead.scene.classified.is_blocking[0])


def test_speeds_up_hard_only_to_get_away_from_a_car_closing_in():
    """With the default limits (``a_max`` 4 m/s^2, ``a_comfort`` 2) and no reason to speed up
    (cruise = the car's speed), a car closing in at 6 m/s from 5 m behind is outrun by speeding up
    harder than comfortable, and the car stays ahead of it (a contact is not ended by letting the
    recording drive through); without it the car never speeds up harder than comfortable."""
    cfg = SpeedConfig()
    w = dataclasses.replace(W, v_cruise=jnp.float32(10.0))
    rear_bumper = FRONT - CAR.length  # x of the car's rear bumper now (its reference point at x = 0)

    def plan(obs):
        return plan_speed(REF, obs, cfg, w, v0=10.0, s0=10.0, vehicle=CAR, road=_road())

    follower_x = rear_bumper - 5.0 - 2.25  # the follower's centre: its front 5 m behind the car
    chased = plan(_moving([[follower_x, 0.0, 4.5, 1.8, 0.0]], [16.0]))
    a = np.asarray(chased.a)
    assert a[0] > float(w.a_comfort) + 0.5, a
    t = np.asarray(chased.t)
    car_rear = rear_bumper + np.asarray(chased.s)
    assert np.all(car_rear > follower_x + 2.25 + 16.0 * t), (car_rear, t)
    alone = plan(_moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0]))
    assert np.all(np.asarray(alone.a) <= float(w.a_comfort) + 1e-4)


def test_yields_to_and_passes_crossing_obstacles():
    """A pedestrian crossing far ahead late: the car passes first; crossing close and early:
    it yields (the DP's decision is which side of the boundary the profile takes)."""
    t = np.arange(15) * 0.5

    def ped(x, y0):
        b = np.array(_moving([], []).boxes)
        b[0, :, 0], b[0, :, 1], b[0, :, 2:4], b[0, :, 4] = x, y0 + 1.4 * t, 0.6, np.pi / 2
        return Obstacles(jnp.asarray(b), jnp.ones((K_OBS, T_OBS), bool), jnp.asarray(t, jnp.float32))

    w = dataclasses.replace(W, v_cruise=jnp.float32(12.0))
    early = _plan(ped(30.0, -3.0), 12.0, w=w)  # in the lane from t = 1.4 s
    late = _plan(ped(30.0, -9.0), 12.0, w=w)  # in the lane from t = 5.7 s
    b_e, b_l = early.scene.classified.blocking, late.scene.classified.blocking
    first = lambda b: int(np.argmax(np.asarray(b.hit[0])))
    s_e, _, _ = early.at(jnp.asarray(first(b_e) * CFG.dt / CFG.n_sub))
    s_l, _, _ = late.at(jnp.asarray(first(b_l) * CFG.dt / CFG.n_sub))
    assert float(s_e) < float(b_e.lower[0, first(b_e)])  # yields
    assert float(s_l) > float(b_l.upper[0, first(b_l)])  # passes before it arrives
    assert bool(early.feasible) and bool(late.feasible)


def test_neighbour_decisions_change_the_plan():
    # a slower neighbour ahead on the left: no bypass keeps the car behind its rear
    obs = _moving([[20.0, 3.5, 4.5, 1.8, 0.0]], [5.0])
    w = dataclasses.replace(W, v_cruise=jnp.float32(12.0))
    free = _plan(obs, 10.0, w=dataclasses.replace(w, w_no_bypass=jnp.float32(0), w_blind=jnp.float32(0)))
    kept = _plan(obs, 10.0, w=w)
    rear = 20 - 2.25 + 5 * np.asarray(kept.t)
    assert float(free.s[-1]) + FRONT > rear[-1] + 4.5  # overtakes without the decision
    assert np.all(np.asarray(kept.s) + FRONT <= rear + 1.0)  # stays behind with it
    # keep-clear region right before a stopped car: do not stop inside it
    stop = _moving([[46.0, 0.0, 4.5, 1.8, 0.0]], [0.0])
    box = jnp.array([[[32.0, -3], [38, -3], [38, 3], [32, 3]]])
    kc = (box, jnp.ones((1, 4), bool), jnp.ones((1,), bool))
    inside = lambda p: 32 - FRONT - 10 < float(p.s[-1]) + 0 < 38 + 0.95 - 10 + 10  # the car's footprint on [32, 38]
    no_kc, with_kc = _plan(stop, 6.0), _plan(stop, 6.0, keep_clear=kc)
    foot = lambda p: (float(p.s[-1]) - 10 + 10 - 0.95, float(p.s[-1]) + FRONT)
    lo, hi = foot(no_kc)
    assert hi > 32 and lo < 38  # without the region the car stops over it
    lo, hi = foot(with_kc)
    assert not (hi > 32 and lo < 38)
    del inside


def test_lane_and_curvature_speed_limits():
    free = _moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0])
    w = dataclasses.replace(W, v_cruise=jnp.float32(15.0))
    p = _plan(free, 14.0, w=w, road=_road((0.0, 20.0, 21.0, 300.0), (15.0, 15.0, 8.0, 8.0)))
    s, v = np.asarray(p.s), np.asarray(p.v)
    assert np.all(v[s > 25.0] <= 8.0 + CFG.dv)  # slowed down for the lower limit ahead
    assert float(p.v[-1]) == pytest.approx(8.0, abs=CFG.dv)
    # a curve of radius 30 m from 40 m on: sqrt(3 * 30) = 9.5 m/s there
    x = np.linspace(0, 40, 21)
    ang = np.linspace(0, 2.0, N_REF - 20)
    arc = np.stack([40 + 30 * np.sin(ang), 30 - 30 * np.cos(ang)], -1)
    ref = ReferenceLine.from_polyline(np.concatenate([np.stack([x, 0 * x], -1)[:-1], arc]))
    p = _plan(free, 14.0, w=w, ref=ref, s0=0.0)
    s, v = np.asarray(p.s), np.asarray(p.v)
    assert np.all(v[s > 45.0] <= np.sqrt(CFG.a_lat_max * 30) + CFG.dv)
    assert np.any(s > 45.0)


@pytest.mark.parametrize("v, t0", [(14.0, 3.0), (15.0, 4.0)])
def test_short_goal_window_is_met_inside_the_region(v, t0):
    """A window of 0.1 s asks as much as a long one: cruising at ``v`` would put the box centre
    past the region's far end (40 m) when the window opens; the plan is inside it then."""
    free = _moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0])
    w = dataclasses.replace(W, v_cruise=jnp.float32(v))
    p = _plan(free, v, w=w, road=_road(goal_s=(30.0, 40.0), goal_t=(t0, t0 + 0.1)))
    s, _, _ = p.at(jnp.float32(t0))
    assert v * t0 + CAR.center_offset > 40.0 + 3.0
    assert 30.0 <= float(s) + CAR.center_offset <= 40.0


def test_goal_window_is_met():
    """A goal region 60-70 m ahead (box centre), to be met by 6 s: the car arrives in time
    although its cruise speed alone would be too slow."""
    free = _moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0])
    w = dataclasses.replace(W, v_cruise=jnp.float32(6.0), w_goal=jnp.float32(20.0))
    p = _plan(free, 8.0, w=w, road=_road(goal_s=(60.0, 70.0), goal_t=(0.0, 6.0)))
    s6, _, _ = p.at(jnp.float32(6.0))
    assert 60.0 - 1.0 <= float(s6) + CAR.center_offset <= 70.0 + 1.0
    slow = _plan(free, 8.0, w=w)
    assert float(slow.at(jnp.float32(6.0))[0]) < 50.0


def test_batched_equals_single_and_no_recompile():
    scenes = [_moving([[20.0 + 5 * k, 0.0, 4.5, 1.8, 0.0]], [2.0 * k]) for k in range(3)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *scenes)
    stack = lambda tree: jax.tree_util.tree_map(lambda x: jnp.stack([x] * 3), tree)
    v0 = jnp.array([5.0, 3.0, 6.0])
    one = lambda obs, v: plan_speed(REF, obs, SMALL, W, v0=v, s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=_road())
    pb = plan_speed(stack(REF), batch, SMALL, W, v0=v0, s0=10.0, keep_clear=stack(NO_KC), vehicle=CAR,
                    road=stack(_road()))
    for k in range(3):
        p1 = one(scenes[k], float(v0[k]))
        assert np.allclose(pb.s[k], p1.s) and np.allclose(pb.v[k], p1.v)
    from jaxplan.speed.dp import plan_speed_kernel
    n = plan_speed_kernel._cache_size()
    one(scenes[1], 4.0)
    assert plan_speed_kernel._cache_size() == n


def test_expected_profile_converges_and_is_differentiable():
    obs = _moving([[24.0, 0.0, 4.5, 1.8, 0.0]], [2.0])
    exact = plan_speed(REF, obs, SMALL, W, v0=5.0, s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=_road())

    def expected(w_speed, tau):
        w = dataclasses.replace(W, w_speed=w_speed)
        return expected_speed_profile(REF, obs, SMALL, w, tau, v0=5.0, s0=10.0, keep_clear=NO_KC, vehicle=CAR,
                                      road=_road())

    cold = expected(jnp.float32(1.0), 0.01)
    assert np.allclose(cold.s, exact.s, atol=0.05) and np.allclose(cold.v, exact.v, atol=0.05)
    loss = lambda ws: jnp.sum(expected(ws, 2.0).s)
    g = jax.grad(loss)(jnp.float32(1.0))
    h = 0.05
    fd = (loss(jnp.float32(1.0 + h)) - loss(jnp.float32(1.0 - h))) / (2 * h)
    assert np.isfinite(float(g)) and abs(float(g)) > 1e-3
    assert float(g) == pytest.approx(float(fd), rel=0.1, abs=0.05)


def test_bad_input_is_refused():
    obs = _moving([[30.0, 0.0, 4.5, 1.8, 0.0]], [0.0])
    with pytest.raises(ValueError, match="v_max"):
        plan_speed(REF, obs, SpeedConfig(v_max=0.5), W, v0=1.0)
    with pytest.raises(ValueError, match="v0"):
        plan_speed(REF, obs, CFG, W, v0=-1.0)
    with pytest.raises(ValueError, match="qp_dt"):
        plan_speed(REF, obs, SpeedConfig(qp_dt=0.15), W, v0=1.0)
    with pytest.raises(ValueError, match="pass_margin"):
        plan_speed(REF, obs, SpeedConfig(pass_margin=-0.5), W, v0=1.0)
    bad = Obstacles(obs.boxes.at[0, 0, 0].set(jnp.nan), obs.valid, obs.t)
    with pytest.raises(ValueError, match="NaN"):
        plan_speed(REF, bad, CFG, W, v0=1.0)


def test_hopeless_scene_still_gives_a_valid_profile():
    # a car appears right in front: every profile collides; the least-bad one is kinematically
    # valid and hits at the lowest speed: it brakes as hard as it can until the contact
    p = _plan(_moving([[16.0, 0.0, 4.5, 1.8, 0.0]], [0.0]), 12.0)
    assert not bool(p.feasible)
    _kinematics_ok(p, 12.0)
    assert float(p.a[0]) <= CFG.a_min + 1e-4


def test_speed_envelope_matches_brute_force(rng):
    from jaxplan.speed.st_graph import speed_envelope

    env = jax.jit(speed_envelope)  # one compile per length
    for _ in range(300):
        n = int(rng.choice([2, 7, 80]))
        v = rng.uniform(0.0, 30.0, n)
        v[rng.random(n) < 0.1] = 0.0
        ds, b, a = rng.uniform(0.3, 2.0), rng.uniform(0.5, 4.0), rng.uniform(0.5, 4.0)
        got = np.asarray(env(jnp.asarray(v, jnp.float32), jnp.float32(ds), jnp.float32(b), jnp.float32(a)), np.float64)
        d = (np.arange(n)[None, :] - np.arange(n)[:, None]) * ds  # s' - s
        want = np.min(np.where(d >= 0, v[None] ** 2 + 2 * b * d, v[None] ** 2 - 2 * a * d), axis=1)
        np.testing.assert_allclose(got ** 2, want, atol=2e-2, rtol=1e-4)


def test_a_corner_shorter_than_a_segment_is_slowed_for():
    """A sharp corner (radius 6 m over 6 m of arc) that the 1 s knots would step over: the
    knots keep to the braking envelope of its limit sqrt(3 * 6) = 4.2 m/s."""
    free = _moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0])
    w = dataclasses.replace(W, v_cruise=jnp.float32(12.0))
    x = np.linspace(0, 30, 31)
    ang = np.linspace(0, 1.0, 8)
    arc = np.stack([30 + 6 * np.sin(ang), 6 - 6 * np.cos(ang)], -1)
    tail = arc[-1] + np.outer(np.linspace(0, 1, N_REF - 37)[1:] * 150.0, [np.cos(1.0), np.sin(1.0)])
    ref = ReferenceLine.from_polyline(np.concatenate([np.stack([x, 0 * x], -1)[:-1], arc, tail]))
    p = _plan(free, 12.0, w=w, ref=ref, s0=0.0)
    s, v = np.asarray(p.s), np.asarray(p.v)
    env = np.asarray(p.scene.v_limit)
    assert env.min() < 5.0
    lim = np.interp(s, CFG.ds * np.arange(env.shape[0]), env)
    assert np.all(v <= lim + CFG.dv)
    assert np.all(v[(s > 20.0) & (s < 45.0)] <= 9.0)  # slowed before and through the corner


def test_time_margin_matches_brute_force(rng):
    from jaxplan.speed.st_boundary import STBoundary
    from jaxplan.speed.st_graph import time_margin

    K, F = 4, 23
    lo = rng.uniform(0, 50, (K, F))
    hi = lo + rng.uniform(0, 10, (K, F))
    hit = rng.random((K, F)) < 0.5
    which = np.array([True, False, True, False])  # the obstacles widened (the others kept as they are)
    for m, only in itertools.product((0, 1, 3), (None, which)):
        b = time_margin(STBoundary(jnp.asarray(lo), jnp.asarray(hi), jnp.asarray(hit)), m,
                        None if only is None else jnp.asarray(only))
        for k in range(K):
            for f in range(F):
                mk = m if only is None or only[k] else 0
                w = [g for g in range(f, min(F, f + mk + 1)) if hit[k, g]]
                assert bool(b.hit[k, f]) == bool(w)
                if w:
                    assert float(b.lower[k, f]) == pytest.approx(min(lo[k, g] for g in w))
                    assert float(b.upper[k, f]) == pytest.approx(max(hi[k, g] for g in w))


def test_crossing_is_passed_only_with_the_time_margin():
    """A pedestrian crossing ahead at 1.4 m/s from several distances: with the 0.6 s margin the
    car passes ahead in a subset of the cases it passes without one, and not in all of them."""
    t = np.arange(15) * 0.5
    w = dataclasses.replace(W, v_cruise=jnp.float32(12.0))

    def passes(y0, cfg):
        b = np.array(_moving([], []).boxes)
        b[0, :, 0], b[0, :, 1], b[0, :, 2:4], b[0, :, 4] = 30.0, y0 + 1.4 * t, 0.6, np.pi / 2
        obs = Obstacles(jnp.asarray(b), jnp.ones((K_OBS, T_OBS), bool), jnp.asarray(t, jnp.float32))
        p = plan_speed(REF, obs, cfg, w, v0=12.0, a0=0.0, s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=_road())
        assert bool(p.feasible)
        # ahead of the pedestrian's crossing point when it reaches the car's lane
        t_in = (-1.2 - y0) / 1.4
        s, _, _ = p.at(jnp.asarray(t_in))
        return float(s) > 30.0 - 10.0

    starts = np.linspace(-9.0, -3.0, 7)
    without = [passes(y, dataclasses.replace(CFG, pass_margin=0.0)) for y in starts]
    with_m = [passes(y, CFG) for y in starts]
    assert all(a or not b for a, b in zip(without, with_m))  # never passes where it would not without
    assert sum(with_m) < sum(without)


def _dense_dp(d, cfg):
    """The DP's optimum over every (station, speed) state (host numpy, float64, no band):
    the reference of the band DP on grids too large for ``_exhaustive``."""
    from jaxplan.speed.costs import COLLISION_V
    from jaxplan.speed.dp import substep_tables

    table, node, terminal = (np.asarray(a, np.float64) for a in (d.table, d.node, d.terminal))
    first, accel, gv, gk = (np.asarray(a, np.float64) for a in (d.first, d.accel, d.goal_v, d.goal_k))
    R, SLOW, VQ = substep_tables(cfg)
    U0, X, ns, V = table_origin(cfg), table.shape[-1], cfg.n_sub, cfg.n_v
    n_i = cfg.n_s + 2 * V
    i = np.arange(n_i)
    val = np.full((n_i, V), np.inf)
    for j in range(V):
        if first[j] < unreach(cfg):
            val[j, j] = first[j] + node[U0 + j, j] + (gv[j] if gk[0] else 0.0)
    for k in range(1, cfg.n_t):
        new = np.full((n_i, V), np.inf)
        for j in range(V):
            for mi, om in enumerate(cfg.accel_offsets):
                j2 = j + om
                if not 0 <= j2 < V:
                    continue
                cost = np.zeros(n_i)
                prev = None
                for q in range(ns + 1):
                    g = table[SLOW[j, mi, q], k * ns + q, np.clip(U0 + i + R[j, mi, q], 0, X - 1)]
                    inside = g >= 0.5 * cfg.big
                    if q > 0:
                        enter = np.where(inside & ~prev, cfg.big * (1 + VQ[j, mi, q] / COLLISION_V), 0.0)
                        cost += np.where(inside, g - cfg.big, g) + enter
                    prev = inside
                tot = val[:, j] + cost + accel[mi]
                i2 = i + j + j2
                ok = i2 < n_i
                np.minimum.at(new[:, j2], i2[ok], tot[ok])
        u = np.clip(U0 + i, 0, X - 1)
        val = new + node[u] + np.where(gk[k], gv, 0.0)[None]
    return np.min(val + terminal[np.clip(U0 + i, 0, X - 1)])


def test_dp_matches_dense_reference_at_every_start_speed(rng):
    """CFG (9 speeds, 5 knots, band offsets that move with v0 and stop at the largest
    reachable station): for start speeds from standstill to v_max (10 and 12 m/s: the widest
    bands), random cost tables (3 % of the cells in collision) tilted towards the least or
    the most distance, so optima lie at the band's edges: the DP's optimum equals a DP over
    every state, and its profile costs that much (``profile_cost``)."""
    from jaxplan.speed import band_offsets

    X, V, F = table_size(CFG), CFG.n_v, CFG.n_t * CFG.n_sub + 1
    dp = jax.jit(dp_from_costs, static_argnums=1)
    for trial, v0 in enumerate((0.0, 0.7, 10.0, 10.0, 12.0, 12.0, 13.9, 16.0)):
        vj = np.arange(V) * CFG.dv
        a1 = (vj - v0) / CFG.dt
        ok = (a1 >= CFG.first_accel_range[0] - 1e-4) & (a1 <= CFG.first_accel_range[1] + 1e-4)
        table = rng.uniform(0, 5, (2, F, X))
        table[rng.uniform(size=table.shape) < 0.03] = CFG.big
        tilt = (1 if trial % 2 else -1) * rng.uniform(3.0, 6.0) * np.arange(X)[:, None]
        node = rng.uniform(0, 5, (X, V)) + tilt - tilt.min()
        ilo, jlo = band_offsets(jnp.float32(v0), CFG)
        d = DPCosts(jnp.asarray(table, jnp.float32), jnp.asarray(node, jnp.float32),
                    jnp.asarray(rng.uniform(0, 3, V), jnp.float32), jnp.asarray(rng.uniform(size=CFG.n_t) < 0.5),
                    jnp.asarray(rng.uniform(0, 3, len(CFG.accel_offsets)), jnp.float32),
                    jnp.asarray(np.where(ok, rng.uniform(0, 5, V), unreach(CFG)), jnp.float32),
                    jnp.asarray(rng.uniform(0, 5, (X, V)), jnp.float32), ilo, jlo, jnp.float32(v0 * CFG.dt / 2))
        ii, jj, cost = dp(d, CFG)
        best = _dense_dp(d, CFG)
        assert float(cost) == pytest.approx(best, rel=1e-5), (v0, float(cost), best)
        assert profile_cost(d, CFG, np.asarray(jj)) == pytest.approx(best, rel=1e-5)
        assert np.array_equal(np.asarray(ii), np.cumsum(np.asarray(jj) + np.concatenate([[0], np.asarray(jj)[:-1]])))


def test_large_batches_run_in_chunks_with_the_same_plans(monkeypatch):
    """A batch larger than ``BATCH_CHUNK`` runs as a loop over vmapped chunks (and a
    remainder): the same plans as one at a time."""
    import jaxplan.speed.dp as dp_mod

    monkeypatch.setattr(dp_mod, "BATCH_CHUNK", 2)
    scenes = [_moving([[18.0 + 4 * k, 0.0, 4.5, 1.8, 0.0]], [1.5 * k]) for k in range(5)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *scenes)
    stack = lambda tree: jax.tree_util.tree_map(lambda x: jnp.stack([x] * 5), tree)
    v0 = jnp.array([5.0, 3.0, 6.0, 0.5, 4.0])
    pb = plan_speed(stack(REF), batch, SMALL, W, v0=v0, s0=10.0, keep_clear=stack(NO_KC), vehicle=CAR,
                    road=stack(_road()))
    for k in range(5):
        p1 = plan_speed(REF, scenes[k], SMALL, W, v0=float(v0[k]), s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=_road())
        assert np.allclose(pb.s[k], p1.s) and np.allclose(pb.v[k], p1.v) and np.allclose(pb.cost[k], p1.cost)


def test_a_stop_the_car_already_stands_past_does_not_hold_it():
    """The path's stop 0.2 m inside the car's buffer (a blockage at the car itself): the DP
    drives off (it charges entering a boundary, not staying inside one), and the smoothing QP
    follows it instead of holding the car at the stop for ever; a stop 20 m ahead holds both."""
    from jaxplan.speed.smooth import smooth_plan_jit

    free = _moving([[250.0, 30.0, 1.0, 1.0, 0.0]], [0.0])
    w = dataclasses.replace(W, v_cruise=jnp.float32(8.0))
    past = _plan(free, 0.0, w=w, road=_road(stop=FRONT + CFG.buffer - 0.2))
    prof = smooth_plan_jit(past, jnp.float32(0.0), jnp.float32(0.0), config=CFG)
    assert float(past.s[-1]) > 10.0 and float(prof.s[-1]) > 10.0
    ahead = _plan(free, 0.0, w=w, road=_road(stop=FRONT + 20.0))
    prof = smooth_plan_jit(ahead, jnp.float32(0.0), jnp.float32(0.0), config=CFG)
    assert float(ahead.s[-1]) <= 20.0 - CFG.buffer + 0.05
    assert 10.0 < float(prof.s[-1]) <= 20.0 - CFG.buffer + 0.05


def test_a_vehicle_closing_in_from_behind_is_escaped_at_the_limits():
    """The car at 13.5 m/s on an empty road, a car 11 m behind it at 21 m/s (recorded traffic:
    it will not brake). The DP's first second accelerates at the limit (its first knot speed is
    the grid speed nearest to what ``a_max`` reaches, 18 m/s, not 16 m/s only because 18 is a
    little beyond), the smoothing QP's corridor has that car as its lower side wherever the DP
    stays ahead of it, and the executed profile keeps it as far as the limits allow."""
    from jaxplan.speed import smooth
    from jaxplan.speed.smooth import LOWER_MARGIN, hardest_acceleration

    corridor = jax.jit(smooth.corridor, static_argnums=1)  # one program each, not one per operation
    smooth_plan = jax.jit(smooth.smooth_plan, static_argnums=3)

    cfg = SpeedConfig()
    obs = _moving([[-11.0, 0.0, 4.5, 1.8, 0.0]], [21.0])
    p = plan_speed(REF, obs, cfg, W, v0=13.5, a0=0.0, s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=_road())
    assert float(p.a[0]) >= 4.0, np.asarray(p.a)
    h = cfg.qp_dt
    t = jnp.arange(1, int(round(cfg.horizon / h)) + 1, dtype=jnp.float32) * h
    rear = p.scene.classified.rear
    assert bool(jnp.any(rear.hit)), "the car behind is not classified as behind"
    lower, _ = corridor(p, cfg, t)
    s_dp = np.asarray(jax.jit(profile_at)(p, t)[0])
    # the car behind at the checks on both sides of each QP time (the farther counts)
    fc = np.asarray(t) / (cfg.dt / cfg.n_sub)
    hit, up = np.asarray(rear.hit), np.asarray(rear.upper)
    r_up = np.maximum(*(np.where(hit[:, f], up[:, f], -np.inf).max(0)
                        for f in (np.floor(fc + 1e-6).astype(int), np.ceil(fc - 1e-6).astype(int))))
    ahead = s_dp >= r_up
    assert ahead.sum() > 10
    assert np.all(np.asarray(lower)[ahead] >= r_up[ahead] - 1e-4)
    # the executed profile keeps that side as far as the limits allow (at a_max here: the car
    # behind is escaped only just)
    prof = smooth_plan(p, 13.5, 0.0, cfg)
    s_qp = np.asarray(prof.s)[1:]
    # the most the limits reach (independent of the module): the acceleration rising from 0 at
    # jerk_max to a_max, easing off at jerk_max to meet v_max with no acceleration left,
    # integrated finely
    dt = 1e-4
    tf = np.arange(0.0, float(t[-1]) + 1e-9, dt)
    v_f, s_f, a, v, x = np.empty_like(tf), np.empty_like(tf), 0.0, 13.5, 0.0
    for i, ti in enumerate(tf):
        v_f[i], s_f[i] = v, x
        a = min(cfg.a_max, a + cfg.jerk_max * dt, np.sqrt(2.0 * cfg.jerk_max * max(cfg.v_max - v, 0.0)))
        x += v * dt + 0.5 * a * dt * dt
        v += a * dt
    s_a = np.interp(np.asarray(t), tf, s_f)
    assert np.allclose(s_a, np.asarray(hardest_acceleration(0.0, 13.5, jnp.full(t.shape, cfg.v_max), t.shape[0], h, cfg)),
                       atol=0.05)
    keep = np.minimum(r_up, s_a - LOWER_MARGIN)
    assert np.all(s_qp[ahead] >= keep[ahead] - 0.05), (s_qp - keep)[ahead].min()


def test_a_vehicle_behind_and_a_lower_limit_ahead_still_give_an_executable_profile():
    """The car at 13.5 m/s, a car 11 m behind it at 21 m/s (it will not brake), and a speed
    limit of 11 m/s from 20 m ahead (a bend). The DP weighs the limit against the car behind
    and runs above the limit. The smoothing QP's corridor (ahead of the car behind) and the
    limit leave no profile together; the QP runs above the limit as the DP does, up to the
    limit at the emergency lateral acceleration, and no further: the executed profile
    converges, keeps the acceleration and jerk limits, and runs at that stretched limit past
    the limit's start (as far ahead of the car behind as it may)."""
    from jaxplan.planner import EMERGENCY_LAT_ACCEL
    from jaxplan.speed.smooth import LAT_TRACKING_MARGIN, smooth_plan

    cfg = SpeedConfig()
    obs = _moving([[-11.0, 0.0, 4.5, 1.8, 0.0]], [21.0])
    road = _road(limit_s=(0.0, 19.9, 20.0, 300.0), limit_v=(INF, INF, 11.0, 11.0))
    p = plan_speed(REF, obs, cfg, W, v0=13.5, a0=0.0, s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=road)
    h = cfg.qp_dt
    t = jnp.arange(1, int(round(cfg.horizon / h)) + 1, dtype=jnp.float32) * h
    s_dp, v_dp, _ = (np.asarray(x) for x in profile_at(p, t))
    assert np.any((s_dp > 20.0) & (v_dp > 11.5)), "the DP keeps the limit: nothing to test"
    prof = smooth_plan(p, 13.5, 0.0, cfg)
    assert bool(prof.ok), (float(prof.r_prim), float(prof.r_dual))
    a, v, s = np.asarray(prof.a), np.asarray(prof.v), np.asarray(prof.s)
    assert np.all(a >= cfg.a_brake - 1e-3) and np.all(a <= cfg.a_max + 1e-3)
    assert np.all(np.abs(np.asarray(prof.jerk)) <= cfg.jerk_max + 1e-2)
    stretched = 11.0 * np.sqrt((EMERGENCY_LAT_ACCEL - LAT_TRACKING_MARGIN) / cfg.a_lat_max)
    past = s > 20.5
    assert past.sum() > 40
    assert np.all(v[past] <= stretched + 0.05), v[past].max()
    # the car behind is closing in: the profile holds the stretched limit once it has met it
    held = past & (np.asarray(prof.t) > 2.0)
    assert np.all(v[held] >= stretched - 0.1), v[held].min()


@pytest.mark.parametrize("v0, a0, start, end", [(13.0, 0.0, 12.0, 18.0), (10.7, -3.4, 4.0, 10.0)])
def test_a_bend_the_executed_profile_reaches_after_the_dp_still_limits_it(v0, a0, start, end):
    """A car closing in from behind at 16.1 m/s and a short bend ahead (limit 5.5 m/s between
    ``start`` and ``end``): the DP weighs the bend against the car behind and runs through it
    above the limit; the executed profile cannot follow the DP (it starts slower, or braking),
    so it reaches the bend later than the DP does. At the stations it reaches, its speed stays
    within the limit stretched to the emergency lateral acceleration (taken at the DP's
    stations alone, the limit had left the bend behind: 9.1 and 8.9 m/s here)."""
    from jaxplan.planner import EMERGENCY_LAT_ACCEL
    from jaxplan.speed.smooth import LAT_TRACKING_MARGIN, smooth_plan

    cfg = SpeedConfig()
    obs = _moving([[-17.5, 0.0, 4.5, 1.8, 0.0]], [16.1])
    road = _road(limit_s=(0.0, start - 0.1, start, end, end + 0.1, 300.0), limit_v=(INF, INF, 5.5, 5.5, INF, INF))
    p = plan_speed(REF, obs, cfg, W, v0=v0, a0=a0, s0=10.0, keep_clear=NO_KC, vehicle=CAR, road=road)
    stretched = 5.5 * np.sqrt((EMERGENCY_LAT_ACCEL - LAT_TRACKING_MARGIN) / cfg.a_lat_max)
    t = jnp.arange(1, int(round(cfg.horizon / cfg.qp_dt)) + 1, dtype=jnp.float32) * cfg.qp_dt
    s_dp, v_dp, _ = (np.asarray(x) for x in profile_at(p, t))
    bend = (s_dp >= start) & (s_dp <= end)
    assert v_dp[bend].max() > stretched + 1.0, "the DP keeps the limit: nothing to test"
    prof = smooth_plan(p, v0, a0, cfg)
    assert bool(prof.ok), (float(prof.r_prim), float(prof.r_dual))
    s, v = np.asarray(prof.s), np.asarray(prof.v)
    bend = (s >= start) & (s <= end)
    assert bend.sum() >= 5
    assert v[bend].max() <= stretched + 0.05, v[bend].max()
