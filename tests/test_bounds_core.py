"""Contour-corner distance, exact distance, path bounds and the path QP."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.bounds import (CASE_DEEPEST, CASE_NO_CORNER, CASE_NONE, CASE_OFF_EDGE, CASE_ON_EDGE,
                            contour_avoid_distance, exact_avoid_distance, overlap_interval, path_bounds)
from jaxplan.bounds.corners import contour_construction_jit as construct
from jaxplan.bounds.distance import exact_avoid_distance_jit as exact_jit
from jaxplan.bounds.frenet_bounds import path_bounds_jit
from jaxplan.bounds.optimize import optimize_path_jit
from jaxplan.bounds.path_qp import PathQPConfig, PathWeights, state_problem
from jaxplan.geometry import ReferenceLine, box_corners, has_overlap, to_cartesian
from jaxplan.solvers import ADMMSettings
from jaxplan.types import VehicleParams

CAR = box_corners(jnp.array([0.0, 0.0, 4.0, 2.0, 0.0]))  # x in [-2, 2], y in [-1, 1]


def _unit(v):
    v = np.asarray(v, np.float64)
    return jnp.asarray(v / np.linalg.norm(v), jnp.float32)


def _one(obs, u):
    """Run the batched jitted construction on a single case (batch of 1, one compile per M)."""
    out = construct(CAR[None], jnp.asarray(obs, jnp.float32)[None], _unit(u)[None])
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[0], out)


# Single-corner case: car corner inside the obstacle, Pi' on the obstacle's edge.
OBS_TILTED = [(-3.0, 1.3), (4.0, 0.6), (4.3, 3.6), (-2.7, 4.3)]
# Single-corner case: obstacle corner inside the car.
OBS_DIAMOND = [(0.5, 0.7), (1.5, 1.7), (0.5, 2.7), (-0.5, 1.7)]
OBS_DIAMOND_FRONT = [(1.8, 0.9), (2.3, 1.4), (1.8, 1.9), (1.3, 1.4)]


def test_car_corner_in_obstacle_on_edge():
    o = _one(OBS_TILTED, (0.0, -1.0))
    assert o.case == CASE_ON_EDGE and o.primary_is_car
    np.testing.assert_allclose(o.ph, [2.0, 1.0], atol=1e-5)
    np.testing.assert_allclose(sorted(map(tuple, [o.po1, o.po2])), [(0.0, 1.0), (2.0, 0.8)], atol=1e-5)
    np.testing.assert_allclose(o.pi_first, [2.0, 0.8], atol=1e-5)
    np.testing.assert_allclose(o.distance, 0.2, atol=1e-5)
    np.testing.assert_allclose(sorted(map(tuple, [o.pl1, o.pl2])), [(-3.0, 1.3), (4.0, 0.6)], atol=1e-5)


def test_car_corner_in_obstacle_off_edge():
    u = (1.0, -0.15)  # l3 meets l2 beyond the obstacle's corner (4, 0.6): large curvature
    o = _one(OBS_TILTED, u)
    assert o.case == CASE_OFF_EDGE and o.primary_is_car
    tgt_aux = o.po1 if o.target_aux == 1 else o.po2
    tgt_pl = o.pl1 if o.target_contour == 1 else o.pl2
    np.testing.assert_allclose(tgt_aux, [0.0, 1.0], atol=1e-5)  # the trailing edge (car's top edge)
    np.testing.assert_allclose(tgt_pl, [4.0, 0.6], atol=1e-5)  # the obstacle corner it must pass
    expect = (0.4 / 0.15) * np.hypot(1.0, 0.15)
    np.testing.assert_allclose(o.distance, expect, rtol=1e-5)
    np.testing.assert_allclose(o.pi_second, [2 + 0.4 / 0.15, 0.6], atol=1e-4)
    np.testing.assert_allclose(exact_avoid_distance(CAR, jnp.asarray(OBS_TILTED), _unit(u)), expect, rtol=1e-5)


def test_obstacle_corner_in_car_on_edge():
    o = _one(OBS_DIAMOND, (0.0, -1.0))
    assert o.case == CASE_ON_EDGE and not o.primary_is_car
    np.testing.assert_allclose(o.ph, [0.5, 0.7], atol=1e-5)
    np.testing.assert_allclose(o.pi_first, [0.5, 1.0], atol=1e-5)
    np.testing.assert_allclose(o.distance, 0.3, atol=1e-5)
    np.testing.assert_allclose(sorted(map(tuple, [o.pl1, o.pl2])), [(-2.0, 1.0), (2.0, 1.0)], atol=1e-5)


@pytest.mark.parametrize("mirror", [False, True])
def test_obstacle_corner_in_car_off_edge_both_signs(mirror):
    f = np.array([-1.0, 1.0]) if mirror else np.array([1.0, 1.0])
    obs = np.asarray(OBS_DIAMOND_FRONT) * f
    if mirror:
        obs = obs[::-1]  # keep counter-clockwise
    u = -np.array([1.0, 0.2]) * f  # the obstacle moves (relatively) by -u: up and outward
    o = _one(obs, u)
    assert o.case == CASE_OFF_EDGE and not o.primary_is_car
    tgt_aux = o.po1 if o.target_aux == 1 else o.po2
    tgt_pl = o.pl1 if o.target_contour == 1 else o.pl2
    np.testing.assert_allclose(tgt_aux, np.array([1.7, 1.0]) * f, atol=1e-5)
    np.testing.assert_allclose(tgt_pl, np.array([2.0, 1.0]) * f, atol=1e-5)
    np.testing.assert_allclose(o.distance, 0.25 * np.hypot(1, 0.2), rtol=1e-4)
    np.testing.assert_allclose(exact_avoid_distance(CAR, jnp.asarray(obs, jnp.float32), _unit(u)),
                               0.25 * np.hypot(1, 0.2), rtol=1e-4)


def test_several_corners_deepest_is_primary():
    # The car's whole front end inside a big obstacle: two car corners inside.
    obs = [(1.0, -3.0), (5.0, -3.0), (5.0, 1.5), (1.0, 1.5)]
    o = _one(obs, (0.0, 1.0))  # move left: the front-right corner (2, -1) is deepest
    assert o.case == CASE_DEEPEST and o.primary_is_car
    np.testing.assert_allclose(o.ph, [2.0, -1.0], atol=1e-5)
    assert o.depth.max() == pytest.approx(o.depth[np.argmax(o.depth)])
    np.testing.assert_allclose(o.distance, 2.5, atol=1e-5)  # (2, -1) leaves the obstacle at y = 1.5
    np.testing.assert_allclose(o.distance, exact_avoid_distance(CAR, jnp.asarray(obs), jnp.array([0.0, 1.0])),
                               atol=1e-5)


def test_no_corner_uses_exact():
    obs = [(-0.5, -3.0), (0.5, -3.0), (0.5, 3.0), (-0.5, 3.0)]  # a bar across the car: edges only cross
    o = _one(obs, (1.0, 0.0))
    assert o.case == CASE_NO_CORNER
    np.testing.assert_allclose(o.distance, 2.5, atol=1e-5)


def _random_pairs(rng, n):
    a = np.stack([np.zeros(n), np.zeros(n), np.full(n, 4.8), np.full(n, 1.9), rng.uniform(-0.6, 0.6, n)], -1)
    b = np.stack([rng.uniform(-4, 4, n), rng.uniform(-3, 3, n), rng.uniform(0.5, 5, n),
                  rng.uniform(0.4, 2.5, n), rng.uniform(-np.pi, np.pi, n)], -1)
    ang = rng.uniform(-np.pi, np.pi, n)
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    return (np.asarray(box_corners(jnp.asarray(a, jnp.float32))), np.asarray(box_corners(jnp.asarray(b, jnp.float32))),
            u.astype(np.float32))


def _shapely_bisect(A, B, U, hi=20.0, iters=40):
    """Oracle: smallest t >= 0 with A + t U not overlapping B (interiors), by bisection with shapely."""
    shapely = pytest.importorskip("shapely")
    A, B, U = np.asarray(A, np.float64), np.asarray(B, np.float64), np.asarray(U, np.float64)
    Bs = shapely.polygons(B)

    def hits(t):
        return shapely.relate_pattern(shapely.polygons(A + t[:, None, None] * U[:, None, :]), Bs, "T********")

    start = hits(np.zeros(len(A)))
    lo, hi_ = np.zeros(len(A)), np.full(len(A), hi)
    for _ in range(iters):
        mid = 0.5 * (lo + hi_)
        h = hits(mid)
        lo, hi_ = np.where(h, mid, lo), np.where(h, hi_, mid)
    return np.where(start, hi_, 0.0), start


def test_exact_distance_against_shapely_bisection():
    rng = np.random.default_rng(7)
    A, B, U = _random_pairs(rng, 1500)
    ours = np.asarray(exact_jit(A, B, U))
    ref, start = _shapely_bisect(A, B, U)
    assert start.sum() > 300  # many overlapping cases
    assert np.all(np.abs(ours - ref) <= 2e-4 * (1 + ref))
    # Moved by the distance the car no longer overlaps; slightly less it still does.
    moved = A + (ours + 1e-3)[:, None, None] * U[:, None, :]
    assert not np.any(np.asarray(has_overlap(moved, B)) & start)
    back = A + np.maximum(ours - 2e-3, 0)[:, None, None] * U[:, None, :]
    assert np.all(np.asarray(has_overlap(back, B))[start & (ours > 2e-2)])


def test_exact_distance_polygons_and_interval():
    shapely = pytest.importorskip("shapely")
    from jaxplan.scenarios.shapes import random_convex_polygons

    rng = np.random.default_rng(3)
    a, va = random_convex_polygons(rng, 300, max_vertices=6, spread=1.5)
    b, vb = random_convex_polygons(rng, 300, max_vertices=6, spread=1.5)
    ang = rng.uniform(-np.pi, np.pi, 300)
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    t_lo, t_hi, hit = (np.asarray(x) for x in overlap_interval(a, b, u, va, vb))
    # Oracle on the interval: shift to its middle overlaps, just outside its ends does not.
    A = [shapely.Polygon(p[k]) for p, k in zip(a, va)]
    B = [shapely.Polygon(p[k]) for p, k in zip(b, vb)]
    for i in range(300):
        if not hit[i]:
            continue
        for t, want in ((0.5 * (t_lo[i] + t_hi[i]), True), (t_lo[i] - 1e-3, False), (t_hi[i] + 1e-3, False)):
            moved = shapely.affinity.translate(A[i], *(t * u[i]))
            assert moved.relate_pattern(B[i], "T********") == want, (i, t, want)
    assert hit.mean() > 0.5


def test_contour_distance_random_cases():
    rng = np.random.default_rng(11)
    A, B, U = _random_pairs(rng, 3000)
    o = construct(A, B, U)
    d, case = np.asarray(o.distance), np.asarray(o.case)
    ex = np.asarray(exact_jit(A, B, U))
    hit = np.asarray(has_overlap(A, B))
    assert np.all(d[~hit] == 0) and np.all(case[~hit] == CASE_NONE)  # never reported without overlap
    assert np.all(d[hit] > 0)
    single = (case == CASE_ON_EDGE) | (case == CASE_OFF_EDGE)
    assert single.sum() > 200 and (case == CASE_OFF_EDGE).sum() > 10
    # In the single-corner case (one corner inside, both neighbours on one edge) the construction is exact.
    np.testing.assert_allclose(d[single], ex[single], atol=1e-4)
    # Several corners: the deepest corner's exit can only under-estimate the exact distance.
    deep = case == CASE_DEEPEST
    assert np.all(d[deep] <= ex[deep] + 1e-4)


def test_contour_batched_matches_single_and_jit():
    rng = np.random.default_rng(5)
    A, B, U = _random_pairs(rng, 6)
    A = np.broadcast_to(np.asarray(CAR), A.shape)  # the batch-of-one helper uses CAR
    batched = np.asarray(construct(A.reshape(2, 3, 4, 2), B.reshape(2, 3, 4, 2), U.reshape(2, 3, 2)).distance)
    single = [float(_one(B[i], U[i]).distance) for i in range(6)]
    np.testing.assert_allclose(batched.ravel(), single, atol=1e-6)


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        contour_avoid_distance(np.zeros((4, 2)), np.asarray(OBS_TILTED), np.array([0.0, 1.0]))
    with pytest.raises(ValueError):
        exact_avoid_distance(CAR, np.asarray(OBS_TILTED)[::-1], np.array([0.0, 1.0]))
    with pytest.raises(ValueError):
        path_bounds(None, jnp.zeros(3), jnp.zeros(3), VehicleParams(), jnp.zeros((1, 3, 4, 2)), method="nope")


# --------------------------------------------------------------------------- path bounds
R = 8.0
_ang = np.linspace(-4 / R, 30 / R, 120)
REF = ReferenceLine.from_polyline(np.stack([R * np.sin(_ang), R - R * np.cos(_ang)], -1))
T = 20
S = jnp.linspace(2.0, 18.0, T, dtype=jnp.float32)


def _frame_obstacles(rng, n):
    s_o = rng.uniform(6, 14, n)
    l_o = rng.choice([-1, 1], n) * rng.uniform(1.0, 2.2, n)
    xy = np.asarray(to_cartesian(REF, jnp.asarray(s_o, jnp.float32), jnp.asarray(l_o, jnp.float32)))
    boxes = np.stack([xy[:, 0], xy[:, 1], rng.uniform(1.0, 4.0, n), rng.uniform(0.6, 2.0, n),
                      s_o / R + rng.uniform(-0.4, 0.4, n)], -1)
    c = np.asarray(box_corners(jnp.asarray(boxes, jnp.float32)))
    return jnp.asarray(np.broadcast_to(c[:, None], (n, T, 4, 2)))


def test_path_bounds_exact_is_tight_and_sides():
    rng = np.random.default_rng(0)
    obs = jnp.stack([_frame_obstacles(rng, 3) for _ in range(2)])  # 2 frames
    l = jnp.zeros((2, T), jnp.float32)
    car = VehicleParams()
    b = path_bounds_jit(REF, jnp.broadcast_to(S, (2, T)), l, car, obs, method="exact")
    up, lo = np.asarray(b.obstacle_upper), np.asarray(b.obstacle_lower)
    left = np.asarray(b.left)
    assert np.all(np.isinf(up[~left])) and np.all(np.isinf(lo[left]))
    from jaxplan.geometry import ref_state, vehicle_corners

    # Car moved along the reference normal to each finite bound: touching, not overlapping;
    # 2 cm further it overlaps.
    _, th, _, _ = ref_state(REF, S)
    n_ref = np.stack([-np.sin(th), np.cos(th)], -1)
    xy, hd = np.asarray(b.xy), np.asarray(b.heading)
    checked = 0
    for f in range(2):
        for i in range(T):
            for k in range(3):
                bound = up[f, i, k] if left[f, i, k] else lo[f, i, k]
                if not np.isfinite(bound):
                    continue
                sign = 1.0 if left[f, i, k] else -1.0
                for extra, want in ((-0.02 * sign, False), (0.02 * sign, True)):
                    p = xy[f, i] + (bound + extra) * n_ref[i]
                    c = vehicle_corners(jnp.asarray(p[None], jnp.float32), car, jnp.asarray(hd[f, i:i + 1]))
                    assert bool(has_overlap(c[0], obs[f, k, i])) == want
                checked += 1
    assert checked > 10
    assert np.all(np.asarray(b.upper) <= np.min(np.where(left, up, np.inf), -1) + 1e-6)


def test_path_bounds_contour_vs_exact_and_centerline_runs():
    rng = np.random.default_rng(1)
    obs = _frame_obstacles(rng, 4)
    l = jnp.zeros(T, jnp.float32)
    car = VehicleParams()
    ex = path_bounds_jit(REF, S, l, car, obs, method="exact")
    co = path_bounds_jit(REF, S, l, car, obs, method="contour", normal="frenet")
    ce = path_bounds_jit(REF, S, l, car, obs, method="centerline", lane_lower=-4.0, lane_upper=4.0)
    ov = np.asarray(co.overlap)
    assert ov.sum() > 5
    single = np.isin(np.asarray(co.case), [CASE_ON_EDGE, CASE_OFF_EDGE])
    # Along the Frenet normal the contour-corner construction is exact, so the bounds agree there.
    for a, b_ in ((co.obstacle_upper, ex.obstacle_upper), (co.obstacle_lower, ex.obstacle_lower)):
        a, b_ = np.asarray(a)[single], np.asarray(b_)[single]
        fin = np.isfinite(b_)
        np.testing.assert_allclose(a[fin], b_[fin], atol=1e-3)
    assert np.all(np.asarray(ce.upper) <= 4.0) and np.all(np.asarray(ce.lower) >= -4.0)
    # Without overlap the contour method uses the exact free distance.
    nov = ~ov & np.isfinite(np.asarray(ex.obstacle_upper))
    np.testing.assert_allclose(np.asarray(co.obstacle_upper)[nov], np.asarray(ex.obstacle_upper)[nov], atol=1e-5)


# --------------------------------------------------------------------------- path QP
CFG = PathQPConfig()


def _scipy_qp(lo, up, ds, l_ref, init):
    opt = pytest.importorskip("scipy.optimize")
    T_ = len(lo)
    P, q, A, l_, u_ = (np.asarray(x, np.float64) for x in state_problem(
        ds, jnp.asarray(l_ref, jnp.float32), jnp.asarray(lo), jnp.asarray(up), jnp.full(T_, -CFG.dl_max),
        jnp.full(T_, CFG.dl_max), jnp.full(T_, -CFG.ddl_max), jnp.full(T_, CFG.ddl_max), CFG.jerk_max,
        jnp.asarray(init), PathWeights()))
    eq = u_ - l_ <= 1e-9
    res = opt.minimize(lambda x: 0.5 * x @ P @ x + q @ x, np.zeros(len(q)), jac=lambda x: P @ x + q,
                       constraints=[{"type": "eq", "fun": lambda x: A[eq] @ x - l_[eq], "jac": lambda x: A[eq]},
                                    {"type": "ineq", "fun": lambda x: np.concatenate([u_ - A @ x, A @ x - l_])[
                                        np.concatenate([~eq, ~eq])],
                                     "jac": lambda x: np.concatenate([-A, A])[np.concatenate([~eq, ~eq])]}],
                       method="SLSQP", options={"maxiter": 500, "ftol": 1e-12})
    assert res.success
    return res.x[:T_]


def test_path_qp_against_scipy_and_flags():
    lo = np.full((3, T), -3.0, np.float32)
    up = np.full((3, T), 3.0, np.float32)
    up[0, 8:12] = -1.0
    lo[1, 4:9] = 0.8
    up[2, 6] = -2.0
    lo[2, 6] = -1.0  # lower > upper: infeasible
    l_ref = np.zeros((3, T), np.float32)
    l_ref[1] = 0.3
    init = np.zeros((3, 3), np.float32)
    r = optimize_path_jit(lo, up, 1.0, l_ref, init)
    ok = np.asarray(r.ok)
    assert ok[0] and ok[1] and not ok[2]
    assert not np.asarray(r.feasible)[2] and np.all(np.isnan(np.asarray(r.l)[2]))
    for f in range(2):
        np.testing.assert_allclose(np.asarray(r.l)[f], _scipy_qp(lo[f], up[f], 1.0, l_ref[f], init[f]), atol=1e-3)
    assert np.all(np.asarray(r.max_violation)[:2] <= 1e-3)


def test_jerk_map_matches_equality_constraints():
    from jaxplan.bounds.path_qp import jerk_map

    M, H = jerk_map(T, 0.7)
    x0 = np.array([0.3, -0.1, 0.05])
    _, _, A, lo, hi = state_problem(0.7, jnp.zeros(T), jnp.zeros(T), jnp.zeros(T), jnp.zeros(T), jnp.zeros(T),
                                    jnp.zeros(T), jnp.zeros(T), 1.0, jnp.asarray(x0), PathWeights())
    j = np.random.default_rng(0).normal(size=T - 1)
    x = np.asarray(M) @ j + np.asarray(H) @ x0
    rows = 4 * T - 1  # boxes (3T) and jerks (T-1) come first, then the integration equalities
    np.testing.assert_allclose(np.asarray(A)[rows:] @ x, 0.0, atol=1e-4)
    np.testing.assert_allclose(np.asarray(A)[3 * T:rows] @ x, j, atol=1e-4)  # the jerk rows give the jerks back


def test_path_qp_gradient_finite_difference():
    lo = np.full((3, T), -3.0, np.float32)
    up = np.full((3, T), 3.0, np.float32)

    cfg = PathQPConfig(admm=ADMMSettings(early_exit=False, max_iter=400, rho_updates=1))

    def f(bound):
        r = optimize_path_jit(jnp.asarray(lo), jnp.asarray(up).at[0, 8:12].set(bound), 1.0,
                              jnp.zeros((3, T)), jnp.zeros((3, 3)), config=cfg)
        return jnp.sum(r.l[0])

    g = jax.grad(f)(jnp.float32(-1.0))
    h = 1e-2
    fd = (f(jnp.float32(-1.0 + h)) - f(jnp.float32(-1.0 - h))) / (2 * h)
    assert np.isfinite(g) and abs(g - fd) <= 0.05 * abs(fd) + 0.05
