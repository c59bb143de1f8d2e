"""The path half of the path-speed planner: box intervals, corridor decision,
the path QP against OSQP, and planned paths against shapely."""
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.bounds.decision import LEFT, NONE, RIGHT, decide_corridor, obstacle_intervals
from jaxplan.bounds.distance import box_overlap_interval, overlap_interval
from jaxplan.bounds.optimize import optimize_path
from jaxplan.bounds.path_qp import PathQPConfig, PathWeights, curvature_bounds, state_problem
from jaxplan.bounds.path_planner import PathConfig, plan_path
from jaxplan.geometry import box_corners, has_overlap
from jaxplan.types import VehicleParams

CAR = VehicleParams()


def _unit(h):
    return np.stack([np.cos(h), np.sin(h)], -1)


def test_box_interval_matches_polygon_interval():
    rng = np.random.default_rng(0)
    n = 1000
    a = np.stack([rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(3, 5, n), rng.uniform(1.5, 2, n),
                  rng.uniform(-0.6, 0.6, n)], -1)
    b = np.stack([rng.uniform(-5, 5, n), rng.uniform(-4, 4, n), rng.uniform(0.5, 5, n), rng.uniform(0.4, 2.5, n),
                  rng.uniform(-np.pi, np.pi, n)], -1)
    ang = rng.uniform(-np.pi, np.pi, n)
    d = _unit(ang)
    d[:50] = [0.0, 1.0]
    b[:50, 4] = 0.0  # axis-aligned with the direction: the flat-axis branch
    a[:50, 4] = 0.0
    ref = overlap_interval(box_corners(jnp.asarray(a)), box_corners(jnp.asarray(b)), jnp.asarray(d))
    got = box_overlap_interval(a[:, :2], _unit(a[:, 4]), 0.5 * a[:, 2:4], b[:, :2], _unit(b[:, 4]), 0.5 * b[:, 2:4], d)
    hit_r, hit_g = np.asarray(ref[2]), np.asarray(got[2])
    assert hit_r.mean() > 0.3 and np.all(hit_r == hit_g)
    for i in (0, 1):
        np.testing.assert_allclose(np.asarray(got[i])[hit_r], np.asarray(ref[i])[hit_r], atol=2e-4)


# --------------------------------------------------------------------------- corridor decision
def _straight(N, ds):
    s = np.arange(N) * ds
    return np.stack([s, np.zeros(N)], -1), np.zeros(N)


@functools.lru_cache(maxsize=None)
def _decide_jit():
    def f(base, th, boxes, valid, l0):
        lo, hi, hit = obstacle_intervals(base, th, th, CAR, boxes, valid, 0.2, 0.3)
        N = base.shape[0]
        cor = decide_corridor(lo, hi, hit, jnp.full((N,), -5.0), jnp.full((N,), 5.0), l0, jnp.full((N,), 1.0),
                              jnp.zeros(N))
        return cor, lo, hi, hit
    return jax.jit(jax.vmap(f, in_axes=(None, None, 0, 0, 0)))


def _random_obstacles(rng, F, K):
    s = rng.uniform(10, 45, (F, K))
    l = rng.uniform(-4.5, 4.5, (F, K))
    return np.stack([s, l, rng.uniform(1, 5, (F, K)), rng.uniform(0.5, 2.5, (F, K)),
                     rng.uniform(-0.5, 0.5, (F, K))], -1).astype(np.float32)


def test_corridor_against_brute_force():
    """Every offset inside the corridor is clear of every (buffered) obstacle (brute force over
    a fine grid, with the SAT overlap of the car's box), the car's offset is in it at the start,
    sides are kept along s, and at a blockage no reachable offset is clear."""
    rng = np.random.default_rng(3)
    F, K, N, ds = 60, 6, 50, 1.0
    base, th = _straight(N, ds)
    boxes = _random_obstacles(rng, F, K)
    l0 = rng.uniform(-0.5, 0.5, F).astype(np.float32)
    cor, lo, hi, hit = (jax.tree_util.tree_map(np.asarray, x) for x in
                        _decide_jit()(jnp.asarray(base, jnp.float32), jnp.asarray(th, jnp.float32), boxes,
                                      np.ones((F, K), bool), l0))
    grid = np.linspace(-5, 5, 401)
    blocked = 0
    # brute force: which offsets overlap an obstacle (boxes grown by the longitudinal buffer), SAT
    grown = boxes.copy()
    grown[..., 2] += 0.6
    cars = np.stack(np.broadcast_arrays(base[:, None, 0] + CAR.center_offset, grid[None, :],
                                        np.float32(CAR.length), np.float32(CAR.width), 0.0), -1)
    occ_all = np.asarray(jax.jit(lambda c, o: jnp.any(has_overlap(c[None, :, :, None], o[:, None, None]), -1))(
        box_corners(jnp.asarray(cars, jnp.float32)), box_corners(jnp.asarray(grown))))  # (F, N, G)
    for f in range(F):
        occ = occ_all[f]
        # the lateral buffer: an offset within 0.2 m of an occupied one is occupied
        pad = np.zeros((occ.shape[0], 8), bool)
        occ = occ | np.concatenate([pad, occ[:, :-8]], 1) | np.concatenate([occ[:, 8:], pad], 1)
        v = cor.valid[f]
        for i in np.nonzero(v)[0]:
            inside = (grid > cor.lower[f, i] + 0.02) & (grid < cor.upper[f, i] - 0.02)
            assert not np.any(occ[i][inside]), (f, i)
        assert cor.lower[f, 0] - 1e-3 <= l0[f] <= cor.upper[f, 0] + 1e-3 or not v[0]
        # sides kept: an obstacle decided LEFT is above the corridor wherever it is present
        for k in range(K):
            pres = hit[f, :, k] & v & (hi[f, :, k] > -5) & (lo[f, :, k] < 5)
            if cor.side[f, k] == LEFT:
                assert np.all(lo[f, pres, k] >= cor.upper[f, pres] - 1e-4)
            elif cor.side[f, k] == RIGHT:
                assert np.all(hi[f, pres, k] <= cor.lower[f, pres] + 1e-4)
            else:
                assert not np.any(pres)
        b = int(cor.blocked_index[f])
        if b < N:
            blocked += 1
            # no offset reachable from the last reachable set is clear
            if b > 0:
                reach = (grid >= cor.reach_lo[f, b - 1] - 1.0 + 0.03) & (grid <= cor.reach_hi[f, b - 1] + 1.0 - 0.03)
                lo_ok = np.ones_like(grid, bool)
                for k in range(K):
                    if cor.side[f, k] == LEFT and hit[f, b, k]:
                        lo_ok &= grid < lo[f, b, k]
                    if cor.side[f, k] == RIGHT and hit[f, b, k]:
                        lo_ok &= grid > hi[f, b, k]
                free = ~occ[b] & reach & lo_ok & (np.abs(grid) < 5 - 0.03)
                assert not np.any(free), (f, b)
            assert not np.any(cor.valid[f, b:])
    assert 0 < blocked < F


# --------------------------------------------------------------------------- QP against OSQP
QP_T = 30


@functools.lru_cache(maxsize=None)
def _qp_jit():
    cfg = PathQPConfig(jerk_max=0.3)
    kl, kh = curvature_bounds(jnp.zeros(QP_T), 0.25)
    dl = (jnp.full(QP_T, -1.0), jnp.full(QP_T, 1.0))
    return cfg, dl, (kl, kh), jax.jit(lambda lo, up, r, i: optimize_path(lo, up, 0.8, r, i, None, cfg, dl, (kl, kh)))


def test_path_qp_against_osqp_1000_frames():
    """Against OSQP (float64, eps 1e-8, polished) on 1000 random corridors: a path on every frame
    OSQP solves (99.9 % without the solution polishing: one frame stops at the iteration cap),
    on none that OSQP certifies infeasible; every path returned passes OSQP's convergence test
    again in float64 (bounds met, its multipliers stationary and correctly signed), also on the
    frames OSQP leaves undecided at 50,000 iterations. The path agrees with OSQP's to 5e-5 m
    and its cost (in float64) to 1e-6 relative; without the polishing, 2.5e-3 m and 1.3e-3.
    Float32 with the QP's condition number of about 6e3 resolves the minimiser no finer:
    frame 677 is 1.8e-5 m from OSQP's with costs 2.5e-9 relative apart, and that digit moves
    with how XLA fuses the ADMM loop."""
    osqp = pytest.importorskip("osqp")
    sp = pytest.importorskip("scipy.sparse")
    rng = np.random.default_rng(5)
    F = 1000
    lo = np.full((F, QP_T), -2.0)
    up = np.full((F, QP_T), 3.0)
    for f in range(F):
        for _ in range(rng.integers(1, 3)):
            a = rng.integers(3, QP_T - 3)
            b = a + rng.integers(1, 8)
            if rng.uniform() < 0.5:
                lo[f, a:b] = rng.uniform(-1.5, 2.8)  # some too far to reach: infeasible
            else:
                up[f, a:b] = rng.uniform(-1.8, 1.0)
    l_ref = rng.uniform(-0.5, 0.5, (F, 1)) * np.ones((1, QP_T))
    init = np.stack([rng.uniform(-0.3, 0.3, F), rng.uniform(-0.2, 0.2, F), rng.uniform(-0.1, 0.1, F)], -1)
    cfg, dl, ddl, fn = _qp_jit()
    lo_j, up_j, l_ref_j, init_j = (jnp.asarray(x, jnp.float32) for x in (lo, up, l_ref, init))
    r = jax.tree_util.tree_map(np.asarray, fn(lo_j, up_j, l_ref_j, init_j))
    status = np.full(F, "infeasible (crossing bounds)", dtype=object)
    err, gap, kkt_fail = [], [], []
    problems = jax.jit(jax.vmap(lambda lr, lo_, up_, i: state_problem(
        0.8, lr, lo_, up_, dl[0], dl[1], ddl[0], ddl[1], cfg.jerk_max, i, PathWeights())))
    problems = [np.asarray(x, np.float64) for x in problems(l_ref_j, lo_j, up_j, init_j)]
    for f in range(F):
        P, q, A, l_, u_ = (x[f] for x in problems)
        if r.ok[f]:  # OSQP's test, in float64, on the path and multipliers returned
            x, y = r.z[f].astype(np.float64), r.y[f].astype(np.float64)
            Ax, Px, Aty = A @ x, P @ x, A.T @ y
            prim = np.max(np.abs(Ax - np.clip(Ax, l_, u_)))
            dual = np.max(np.abs(Px + q + Aty))
            d_scale = max(np.max(np.abs(Px)), np.max(np.abs(Aty)), np.max(np.abs(q)))
            ineq = u_ - l_ > 1e-9
            wrong = max(np.max(y[ineq & (Ax < u_ - 1e-4)], initial=0.0),  # a multiplier of the wrong sign
                        -np.min(y[ineq & (Ax > l_ + 1e-4)], initial=0.0))
            if (prim > cfg.admm.eps_abs + cfg.admm.eps_rel * np.max(np.abs(Ax)) or dual > cfg.admm.eps_abs + cfg.admm.eps_rel * d_scale
                    or wrong > 1e-3 * max(1.0, np.max(np.abs(y)))):
                kkt_fail.append(f)
        if np.any(l_ > u_):  # crossing bounds: infeasible on their face (OSQP refuses such data)
            continue
        m = osqp.OSQP()
        m.setup(sp.csc_matrix(np.triu(P)), q, sp.csc_matrix(A), l_, u_, verbose=False, eps_abs=1e-8, eps_rel=1e-8,
                max_iter=50000, polish=True)
        res = m.solve()
        status[f] = res.info.status
        if res.info.status in ("solved", "solved inaccurate") and r.ok[f]:
            err.append(np.max(np.abs(res.x[:QP_T] - r.l[f])))
            cost = lambda x: 0.5 * x @ P @ x + q @ x
            gap.append(abs(cost(r.z[f].astype(np.float64)) - cost(res.x)) / (1.0 + abs(cost(res.x))))
    solved = np.isin(status, ["solved", "solved inaccurate"])
    infeasible = np.array(["infeasible" in s_ for s_ in status])
    assert 0.2 < solved.mean() < 0.95 and infeasible.mean() > 0.05  # both kinds of frames
    assert np.all(r.ok[solved])  # a path wherever OSQP solves
    assert not np.any(r.ok[infeasible])  # never a path where OSQP certifies there is none
    assert np.mean(~r.feasible[infeasible]) >= 0.9  # the certificate (or the input check) says so
    assert np.max(err) <= 5e-5 and np.max(gap) <= 1e-6  # the polished solution is OSQP's
    assert not kkt_fail  # every path returned is the QP's solution by OSQP's test (its own multipliers)


# --------------------------------------------------------------------------- the planner on scenes
def _scene(kind, seed):
    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.builtin import scene_dict
    from jaxplan.scenarios.loader import parse_scenario

    d = scene_dict(kind, np.random.default_rng(seed), 0)
    return d, build_scene(parse_scenario(d, d["id"]))[0]


def _wall_scene():
    """A straight two-lane road with a stopped car in each lane 40 m ahead: no way past."""
    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.builtin import DT, LANE, START_S, road_obstacle, road_lanelets, SyntheticRoad
    from jaxplan.scenarios.loader import parse_scenario

    road = SyntheticRoad(0.0, 0.0)
    obstacles = [road_obstacle(1 + i, road, START_S + 40.0, i * LANE, role="static") for i in range(2)]
    start, th0 = road.pose(START_S, 0.0)
    goal, _ = road.pose(START_S + 120.0, 0.5 * LANE)
    d = {"id": "WALL", "source": "test", "tags": [], "dt": DT, "lanelets": road_lanelets(road, 2, 20.0),
         "obstacles": obstacles,
         "planning_problems": [{"id": 1, "initial_state": {"t": 0.0, "position": start.tolist(),
                                                          "orientation": float(th0), "velocity": 10.0,
                                                          "acceleration": 0.0},
                                "goals": [{"rectangle": {"center": goal.tolist(), "length": 30.0, "width": 2 * LANE,
                                                         "orientation": 0.0}, "time": [0.0, 30.0]}]}]}
    return d, build_scene(parse_scenario(d, d["id"]))[0]


@functools.lru_cache(maxsize=None)
def _plan_fn(nudge: bool = True):
    """``(cfg, jit(vmap(one)))``: the bounds path and the obstacles of a batch of scenes and cars
    (``EgoState`` with ``(B,)`` fields) at step 0. One compiled program for the tests below that
    plan six scenes padded to ``_plan_batch``'s sizes."""
    from jaxplan.plan_context import road_context
    from jaxplan.planner import SIM_VEHICLE

    cfg = PathConfig(vehicle=SIM_VEHICLE, nudge=nudge)

    def one(scene, ego):
        ctx = road_context(scene, ego, 0, 60, SIM_VEHICLE)
        return plan_path(scene, ctx, cfg), ctx.obstacles

    return cfg, jax.jit(jax.vmap(one))


def _plan(scenes, egos=None, nudge=True):
    """``(plan, obstacles)`` (numpy) of ``scenes`` (at most six; padded to ``_plan_batch``'s sizes and
    filled up to six with copies of the first) from ``egos`` (default: each scene's start)."""
    from jaxplan.planner import SIM_VEHICLE, EgoState
    from jaxplan.scenarios.batch import stack_scenes

    n, rows = len(scenes), len(_batch_scenes()[0])
    batch = stack_scenes(list(scenes) + [scenes[0]] * (rows - n), min_sizes=_batch_scenes()[1])
    ego = EgoState.from_box_centre(batch.start, SIM_VEHICLE)
    if egos is not None:
        ego = jax.tree_util.tree_map(lambda a, b: a.at[:n].set(b), ego, egos)
    plan, obs = _plan_fn(nudge)[1](batch, ego)
    return tuple(jax.tree_util.tree_map(lambda x: np.asarray(x)[:n], t) for t in (plan, obs))


@functools.lru_cache(maxsize=None)
def _batch_scenes():
    """The six scenes of ``_plan_batch`` and their padded sizes (``stack_scenes``' ``min_sizes``)."""
    from jaxplan.scenarios.batch import scene_sizes

    kinds = [("stopped_car", 1), ("parked_cars", 2), ("curve_stop", 3), ("slow_leader", 4), ("stopped_car", 6)]
    scenes = [_scene(k, s)[1] for k, s in kinds] + [_wall_scene()[1]]
    return scenes, {k: max(scene_sizes(s)[k] for s in scenes) for k in scene_sizes(scenes[0])}


@functools.lru_cache(maxsize=None)
def _plan_batch():
    """``(plan, obstacles, cfg)`` of the built-in scenes of five kinds and the wall scene."""
    return (*_plan(_batch_scenes()[0]), _plan_fn()[0])


def test_planned_paths_are_clear_by_shapely():
    shapely = pytest.importorskip("shapely")
    from jaxplan.geometry import vehicle_corners

    plan, obs, cfg = _plan_batch()
    n = plan.ok.shape[0]
    assert plan.ok[:5].all()  # every built-in scene has a path
    for i in range(n):
        v = plan.valid[i]
        # resample 4x along the path between the output points
        s_f = np.linspace(0, plan.s[i][v].max(), 4 * v.sum())
        xy = np.stack([np.interp(s_f, plan.s[i], plan.xy[i, :, 0]), np.interp(s_f, plan.s[i], plan.xy[i, :, 1])], -1)
        th = np.interp(s_f, plan.s[i], plan.theta[i])
        cars = np.asarray(vehicle_corners(jnp.asarray(xy, jnp.float32), cfg.vehicle, jnp.asarray(th, jnp.float32)))
        car_polys = shapely.polygons(cars)
        for k in np.nonzero(plan.blocking[i])[0]:
            o = shapely.Polygon(np.asarray(box_corners(jnp.asarray(obs.boxes[i, k, 0]))))
            assert not np.any(shapely.intersects(car_polys, o) & ~shapely.touches(car_polys, o)), (i, k)
        # the path stays on the grid spacing, starts at the car and follows the route's arc length
        np.testing.assert_allclose(np.diff(plan.s[i]), plan.ds[i], rtol=1e-5)
        seg = np.linalg.norm(np.diff(plan.xy[i][v], axis=0), axis=-1)
        assert np.all(np.abs(seg - plan.ds[i]) < 0.05 * plan.ds[i] + 1e-3)
    # parked cars on the right edge: every one of them is passed on the left
    assert np.all(plan.side[1][plan.blocking[1]] == RIGHT)
    # the slow leader moves: not blocking, no decision
    assert not plan.blocking[3].any() and np.all(plan.side[3] == NONE)


def test_blockage_cuts_the_path():
    from jaxplan.geometry import vehicle_corners

    plan, obs, cfg = _plan_batch()
    i = plan.ok.shape[0] - 1  # the wall
    assert plan.blocking[i].sum() >= 2
    assert np.isfinite(plan.blocked_s[i]) and 10.0 < plan.blocked_s[i] < 45.0
    assert not plan.valid[i][plan.s[i] >= plan.blocked_s[i]].any()
    # just past blocked_s along the path the car (its obstacle grown by lon_buffer) overlaps an obstacle
    k = np.searchsorted(plan.s[i], plan.blocked_s[i])
    xy, th = plan.xy[i, k:k + 2], plan.theta[i, k:k + 2]
    car = vehicle_corners(jnp.asarray(xy), cfg.vehicle, jnp.asarray(th))
    grown = obs.boxes[i, :, 0].copy()
    grown[:, 2] += 2 * cfg.lon_buffer + 2 * plan.ds[i]
    hit = np.asarray(has_overlap(car[:, None], box_corners(jnp.asarray(grown))[None]))
    assert hit[:, plan.blocking[i]].any()
    assert np.all(np.isfinite(plan.xy[i]))


def test_spd_inverse_against_numpy_batched():
    """The LAPACK-free Cholesky + triangular inverse (jaxlib's batched LAPACK kernels can hang on CPU)."""
    from jaxplan.solvers import spd_inverse

    rng = np.random.default_rng(3)
    for n in (1, 7, 32, 45):
        A = rng.normal(size=(16, n, n))
        K = A @ np.swapaxes(A, 1, 2) + 0.5 * n * np.eye(n)
        got = np.asarray(jax.jit(jax.vmap(spd_inverse))(jnp.asarray(K, jnp.float32)))
        ref = np.linalg.inv(K)
        assert np.max(np.abs(got - ref)) <= 1e-4 * np.max(np.abs(ref)), n


def test_fast_car_changes_lane_within_the_lateral_acceleration():
    """A lane change asked of a car at 30 m/s: the path's curvature stays under a_lat_max /
    v(s)^2 (the speed falling at lat_decel), and planned for a car at rest (steering limit
    only) it would not."""
    from jaxplan.bounds.path_planner import solve_path, speed_curvature_cap
    from jaxplan.geometry.frenet import ReferenceLine

    N, ds, v0 = 81, 2.5, 30.0
    xy = np.stack([np.arange(200) * 2.0 - 20.0, np.zeros(200)], -1)
    ref = ReferenceLine.from_polyline(xy.astype(np.float32))
    st = jnp.asarray(20.0 + ds * np.arange(N), jnp.float32)
    edge = jnp.full((N,), 5.5, jnp.float32)
    args = (ref, st, jnp.float32(ds), jnp.zeros((1, 5), jnp.float32) + jnp.asarray([-500.0, 0, 1, 1, 0]),
            jnp.zeros((1,), bool), edge, -edge, jnp.full((N,), -3.5, jnp.float32), jnp.zeros(3, jnp.float32), PathConfig(vehicle=CAR))
    solve = jax.jit(lambda v: solve_path(*args, v0=v))
    fast = solve(jnp.float32(v0))
    slow = solve(jnp.float32(0.0))  # a car at rest: the steering limit only
    assert bool(fast["qp"].ok) and bool(slow["qp"].ok)
    cap = np.asarray(speed_curvature_cap(v0, np.asarray(st) - 20.0, PathConfig.a_lat_max, PathConfig.lat_decel))
    k_fast, k_slow = np.abs(np.asarray(fast["kappa"])), np.abs(np.asarray(slow["kappa"]))
    assert np.all(k_fast <= cap * 1.1 + 5e-4)  # the QP meets its bounds to its tolerance
    assert np.any(k_slow > 2 * cap)
    assert np.asarray(fast["l"])[-1] == pytest.approx(-3.5, abs=0.2)  # the lane is still reached



def test_fast_car_in_a_bend_follows_the_road():
    """A car at 15 m/s entering a bend of radius 30 m (the curvature the speed bound allows at
    that speed is 3 / 15^2 = 0.013 1/m, the road's 0.033): the path still follows the lane
    centre (the speed plan is the one to slow); a path bounded below the road's curvature would
    leave it."""
    from jaxplan.bounds.path_planner import solve_path
    from jaxplan.geometry.frenet import ReferenceLine

    N, ds, R = 41, 1.0, 30.0
    a = np.linspace(0.0, 1.8, 200)
    xy = np.concatenate([np.stack([np.linspace(-20.0, -0.5, 40), np.zeros(40)], -1),
                         np.stack([R * np.sin(a), R * (1 - np.cos(a))], -1)])
    ref = ReferenceLine.from_polyline(xy.astype(np.float32))
    st = jnp.asarray(15.0 + ds * np.arange(N), jnp.float32)
    edge = jnp.full((N,), 1.75, jnp.float32)
    far = jnp.zeros((1, 5), jnp.float32) + jnp.asarray([-500.0, 0, 1, 1, 0])
    args = (ref, st, jnp.float32(ds), far, jnp.zeros((1,), bool), edge, -edge, jnp.zeros((N,), jnp.float32),
            jnp.zeros(3, jnp.float32), PathConfig(vehicle=CAR))
    out = jax.jit(lambda v: solve_path(*args, v0=v))(jnp.float32(15.0))
    assert bool(out["qp"].ok)
    assert np.abs(np.asarray(out["l"])).max() < 0.3, np.asarray(out["l"])
    k = np.abs(np.asarray(out["kappa"]))
    assert k[-10:].min() > 0.9 / R  # it turns with the road

@functools.lru_cache(maxsize=None)
def _suite_paths():
    """The planner's paths on the seed-000 suite's frames of radius 12 m and 80 m (``bounds_suite``,
    12 frames per radius, 4 obstacles): ``(pick, boxes (2, F, K, T, 5), out)``, shared by the tests."""
    import jaxplan.eval.bounds_suite as bs
    from jaxplan.geometry import reference_line

    refs, S, L, _, _, BOX = bs.make_scenarios(np.random.default_rng(0), 12, 4)
    pick = [2, 5]  # R 12 m, R 80 m
    one = lambda ref_xy, s, l, b: bs.frame_path(reference_line(ref_xy), s, l, b)
    fn = jax.jit(jax.vmap(jax.vmap(one, (None, 0, 0, 0)), (0, 0, 0, 0)))
    out = fn(*(jnp.asarray(a[pick]) for a in (refs, S, L, BOX)))
    return pick, BOX[pick], jax.tree_util.tree_map(np.asarray, out)


def test_solved_suite_paths_are_clear_by_shapely():
    """The seed-000 suite's frames (curves of radius 12 m and 80 m, where re-bounding at the
    path's heading alone oscillated and left two solved paths overlapping an obstacle): every
    path the QP solves misses every obstacle at every station (shapely, the car's box at the
    path's pose against the obstacle's box at that station's time, up to a blockage)."""
    shapely = pytest.importorskip("shapely")
    import jaxplan.eval.bounds_suite as bs
    from jaxplan.geometry import vehicle_corners

    pick, boxes, out = _suite_paths()
    ok, xy, th, valid = (out[k] for k in ("qp_ok", "xy", "theta", "valid"))
    corridor = out["corridor_ok"]
    assert (ok & corridor).sum() >= 16  # most frames have a path
    dense = np.asarray(jax.vmap(jax.vmap(lambda b: bs.densify(b, 1)))(jnp.asarray(boxes)))  # (R, F, K, N, 5)
    checked = 0
    for r, f in zip(*np.nonzero(ok & corridor)):
        cars = shapely.polygons(np.asarray(vehicle_corners(jnp.asarray(xy[r, f]), bs.CAR, jnp.asarray(th[r, f]))))
        obs = shapely.polygons(np.asarray(box_corners(jnp.asarray(np.swapaxes(dense[r, f], 0, 1)))))  # (N, K)
        hit = shapely.intersects(cars[:, None], obs) & ~shapely.touches(cars[:, None], obs)
        hit &= valid[r, f][:, None]  # up to a blockage (the car stops before it)
        assert not hit.any(), (pick[r], f, np.argwhere(hit)[:3])
        checked += 1
    assert checked == (ok & corridor).sum()


def test_hard_suite_frame_is_solved_like_osqp():
    """The seed-000 suite's first frame of radius 12 m: a path QP the ADMM does not finish
    within the planner's 2,000 iterations (OSQP's own ADMM, in float64, takes thousands more;
    without the solution polishing the QP stopped 1.1 mm outside a bound and the frame had no
    path). With it: a path, clear, and OSQP's solution of the same QP (float64, eps 1e-8,
    polished) to 1e-5 m."""
    osqp = pytest.importorskip("osqp")
    sp = pytest.importorskip("scipy.sparse")
    import jaxplan.eval.bounds_suite as bs

    _, _, out = _suite_paths()
    r, f = 0, 0  # R 12 m, frame 0
    assert out["corridor_ok"][r, f] and out["qp_ok"][r, f] and out["clear"][r, f]
    lo_l, up_l, dlo, dhi, ddlo, ddhi = out["qp_input"][r, f]
    N = lo_l.shape[0]
    j = lambda a: jnp.asarray(a, jnp.float32)
    P, q, A, lo, hi = (np.asarray(x, np.float64) for x in state_problem(
        j(out["ds"][r, f]), jnp.zeros(N, jnp.float32), j(lo_l), j(up_l), j(dlo), j(dhi), j(ddlo), j(ddhi),
        bs.PATH.qp.jerk_max, j(out["init"][r, f]), PathWeights(*bs.PATH.weights)))
    m = osqp.OSQP()
    m.setup(sp.csc_matrix(np.triu(P)), q, sp.csc_matrix(A), lo, hi, verbose=False, eps_abs=1e-8, eps_rel=1e-8,
            max_iter=100000, polish=True)
    res = m.solve()
    assert res.info.status == "solved"
    assert np.max(np.abs(res.x[:N] - out["l"][r, f])) <= 1e-5


def test_path_starts_at_the_cars_pose_heading_and_curvature():
    """On a curved road, from cars off the lane's centre, heading away from it and turning: the
    solved bounds path starts exactly at the car (its Frenet start state is the exact inverse of
    the path's, ``geometry.quintic.cartesian_to_frenet_state``; a first-order start missed the
    curvature by 2e-5)."""
    from jaxplan.planner import SIM_VEHICLE, EgoState

    sc = _batch_scenes()[0][2]  # curve_stop, seed 3
    e0 = EgoState.from_box_centre(sc.start, SIM_VEHICLE)
    cases = [(0.0, 0.0, 0.0), (-0.5, -0.1, 0.04), (0.3, 0.05, -0.02)]
    l_off, dh, k = (jnp.asarray(c, jnp.float32) for c in zip(*cases))
    egos = EgoState(e0.x - l_off * jnp.sin(e0.heading), e0.y + l_off * jnp.cos(e0.heading), e0.heading + dh,
                    jnp.full(3, e0.v), jnp.zeros(3, jnp.float32), k)
    pp, _ = _plan([sc] * 3, egos)
    for i in range(3):
        assert bool(pp.ok[i])
        assert np.allclose(pp.xy[i, 0], [float(egos.x[i]), float(egos.y[i])], atol=1e-5)
        assert float(pp.theta[i, 0]) == pytest.approx(float(egos.heading[i]), abs=1e-5)
        assert float(pp.kappa[i, 0]) == pytest.approx(float(k[i]), abs=1e-6)


def _passing_scene(cars):
    """A straight two-lane road, the car in the right lane at 10 m/s, and ``cars``: ``(s (T,), l (T,),
    role)`` each (stations from the car's, offsets from its lane's centre)."""
    from jaxplan.scenarios.build import build_scene
    from jaxplan.scenarios.builtin import DT, LANE, START_S, road_obstacle, road_lanelets, SyntheticRoad
    from jaxplan.scenarios.loader import parse_scenario

    road = SyntheticRoad(0.0, 0.0)
    start, th0 = road.pose(START_S, 0.0)
    goal, _ = road.pose(START_S + 120.0, 0.5 * LANE)
    d = {"id": "PASS", "source": "test", "tags": [], "dt": DT, "lanelets": road_lanelets(road, 2, 20.0),
         "obstacles": [road_obstacle(i + 1, road, START_S + s, l, role=role) for i, (s, l, role) in enumerate(cars)],
         "planning_problems": [{"id": 1, "initial_state": {"t": 0.0, "position": start.tolist(),
                                                          "orientation": float(th0), "velocity": 10.0,
                                                          "acceleration": 0.0},
                                "goals": [{"rectangle": {"center": goal.tolist(), "length": 30.0, "width": 2 * LANE,
                                                         "orientation": 0.0}, "time": [0.0, 30.0]}]}]}
    return build_scene(parse_scenario(d, d["id"]))[0]


@pytest.mark.parametrize("nudge", [True, False])
def test_path_moves_over_in_its_lane_for_a_moving_car_reaching_in(nudge):
    """A car coming the other way with its near side 0.8 m over the lane line (0.15 m clear of the
    car's body at the lane centre, inside ``nudge_buffer``): with
    ``nudge`` the path keeps ``nudge_buffer`` from it where the two meet (the car's box at the
    path's pose there, against the other car's box then) and is back at the lane centre past it;
    a car crossing the lane centre does not move the path (the speed plan yields to it), nor does
    a car driving inside the next lane when the path passes a stopped car through that lane (the
    speed plan times the pass); without ``nudge`` the path stays at the centre."""
    from jaxplan.planner import SIM_VEHICLE
    from jaxplan.scenarios.builtin import LANE, RECORD_STEPS

    cfg = _plan_fn(nudge)[0]
    near = 0.5 * LANE - 0.8  # the oncoming car's near side, from the car's lane centre
    t = np.arange(RECORD_STEPS) * 0.1
    oncoming = 80.0 - 10.0 * t  # from 80 m ahead at 10 m/s: the two meet about 40 m ahead
    reach_in = (oncoming, np.full(RECORD_STEPS, near + 0.9), "dynamic")
    crossing = (oncoming, np.linspace(-6.0, 8.0, RECORD_STEPS), "dynamic")  # over the road within the horizon
    stopped = (np.full(1, 30.0), np.zeros(1), "static")
    next_lane = (-10.0 + 14.0 * t, np.full(RECORD_STEPS, LANE), "dynamic")  # passes the car, 0.85 m inside its lane
    pp, _ = _plan([_passing_scene([reach_in]), _passing_scene([crossing]), _passing_scene([stopped, next_lane])],
                  nudge=nudge)
    assert pp.ok.all()
    s, l = pp.s[0], pp.l[0]
    meet = np.abs(s - 40.0) < 3.0
    half = 0.5 * SIM_VEHICLE.width
    if nudge:
        # the body's left side (the path is straight there: its heading is the road's) and the buffer
        assert np.all(l[meet] + half <= near - cfg.nudge_buffer + 0.02), l[meet]
        assert np.abs(l[-5:]).max() < 0.05  # back at the lane centre well past the other car
    else:
        assert np.abs(l).max() < 0.05
        assert np.any(l[meet] + half > near - cfg.nudge_buffer)
    assert np.abs(pp.l[1]).max() < 0.05  # the crossing car: no nudge
    assert not np.isfinite(pp.blocked_s[2]) and pp.l[2].max() > 2.0  # around the stopped car, through the next lane
