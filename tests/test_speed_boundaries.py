"""Speed planning: ST boundaries vs a brute-force shapely check, classification, composition."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.speed import (LEFT, RIGHT, blocking_boundaries, classify, compose_plan, first_trajectory,
                           keep_clear_intervals, path_profile, resample_obstacles, side_probes)
from jaxplan.speed.dp import SpeedPlan
from jaxplan.types import Obstacles, VehicleParams

CAR = VehicleParams()
N, DS = 40, 0.75

_blocking = jax.jit(blocking_boundaries)
_classify = jax.jit(classify)
_profile = jax.jit(path_profile, static_argnums=(2, 3))
_compose = jax.jit(compose_plan, static_argnums=(4, 5))
_kc = jax.jit(keep_clear_intervals)


def _np_box(b):
    x, y, L, W, h = b
    c, s = np.cos(h), np.sin(h)
    pts = [(sx * L / 2, sy * W / 2) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    return shapely.Polygon([(x + c * u - s * v, y + s * u + c * v) for u, v in pts])


def _curved_ref(rng):
    x = np.linspace(0, 40, 30)
    k = rng.uniform(-0.01, 0.01)
    return ReferenceLine.from_polyline(np.stack([x, k * x ** 2], -1))


def _car_poly(xy, th):
    off = CAR.center_offset
    return _np_box([xy[0] + off * np.cos(th), xy[1] + off * np.sin(th), CAR.length, CAR.width, th])


def test_blocking_boundaries_match_brute_force(rng):
    total = 0
    for trial in range(4):
        ref = _curved_ref(rng)
        prof = _profile(ref, 0.0, N, DS)
        K, T = 6, 5
        start = np.column_stack([rng.uniform(0, 35, K), rng.uniform(-4, 4, K), rng.uniform(1, 6, K),
                                 rng.uniform(0.6, 2.5, K), rng.uniform(-np.pi, np.pi, K)])
        vel = rng.uniform(-5, 5, (K, 2))
        t = np.arange(T) * 0.5
        boxes = np.repeat(start[:, None], T, 1)
        boxes[..., :2] += vel[:, None] * t[None, :, None]
        valid = rng.uniform(size=(K, T)) > 0.15
        obs = Obstacles(jnp.asarray(boxes, jnp.float32), jnp.asarray(valid), jnp.asarray(t, jnp.float32))
        b = _blocking(prof, obs, CAR)
        xy, th, s = np.asarray(prof.xy, float), np.asarray(prof.theta, float), np.asarray(prof.s, float)
        cars = [_car_poly(xy[i], th[i]) for i in range(N)]
        for k in range(K):
            for j in range(T):
                ob = _np_box(boxes[k, j])
                inter = np.array([c.intersection(ob).area > 1e-6 for c in cars]) & valid[k, j]
                near = np.array([abs(c.distance(ob)) < 1e-3 or 0 < c.intersection(ob).area <= 1e-6 for c in cars])
                total += 1
                if near.any():
                    continue  # touching: either verdict is fine
                assert bool(b.hit[k, j]) == inter.any()
                if inter.any():
                    assert float(b.lower[k, j]) == pytest.approx(s[inter].min(), abs=1e-4)
                    assert float(b.upper[k, j]) == pytest.approx(s[inter].max(), abs=1e-4)
    assert total == 4 * 30


def test_static_obstacle_spans_all_times():
    ref = ReferenceLine.from_polyline(np.array([[0.0, 0.0], [100.0, 0.0]]))
    prof = _profile(ref, 0.0, N, DS)
    t = jnp.arange(5) * 0.5
    obs = Obstacles.held(jnp.array([[15.0, 0.0, 4.0, 2.0, 0.3]]), t)
    b = _blocking(prof, obs, CAR)
    assert bool(jnp.all(b.hit))
    # car front (3.85 m ahead of the rear axle) reaches the obstacle's rotated rear
    assert np.allclose(b.lower, b.lower[0, 0]) and np.allclose(b.upper, b.upper[0, 0])
    # rear-most obstacle x = 15 - 2 cos .3 - sin .3 = 12.79 -> first station with s + 3.85 > 12.79;
    # front-most 17.21 -> last station with s - 0.95 < 17.21 (stations every 0.75 m)
    assert float(b.lower[0, 0]) == 9.0 and float(b.upper[0, 0]) == 18.0


def test_resample_obstacles_matches_numpy(rng):
    T = 6
    t = np.arange(T) * 0.1
    boxes = rng.uniform(-5, 5, (3, T, 5)).astype(np.float32)
    boxes[..., 2:4] = np.abs(boxes[..., 2:4]) + 0.5
    boxes[..., 4] = np.linspace(3.0, 3.4, T)  # crosses +pi: interpolated along the short turn
    valid = np.ones((3, T), bool)
    valid[1, 3] = False
    obs = Obstacles(jnp.asarray(boxes), jnp.asarray(valid), jnp.asarray(t, jnp.float32))
    tn = np.array([0.0, 0.05, 0.25, 0.3, 0.45, 0.5, 0.7])
    r = resample_obstacles(obs, tn)
    for k in range(3):
        for q in range(2):
            assert np.allclose(r.boxes[k, :6, q], np.interp(tn[:6], t, boxes[k, :, q]), atol=1e-5)
    assert np.allclose(np.unwrap(np.asarray(r.boxes[0, :6, 4])), np.interp(tn[:6], t, boxes[0, :, 4]), atol=1e-5)
    assert not bool(r.valid[0, 6])  # beyond the prediction
    assert list(np.asarray(r.valid[1])) == [True, True, False, False, True, True, False]


def _scene(boxes_fn, T=21, dt=0.25):
    t = np.arange(T) * dt
    boxes = np.stack([boxes_fn(tt) for tt in t], 1)  # (K, T, 5)
    return Obstacles(jnp.asarray(boxes, jnp.float32), jnp.ones(boxes.shape[:2], bool), jnp.asarray(t, jnp.float32))


def test_classification_hand_built_scenes():
    ref = ReferenceLine.from_polyline(np.array([[-10.0, 0.0], [200.0, 0.0]]))
    prof = _profile(ref, 10.0, 60, 1.0)  # car at x = 0

    def boxes(t):
        return np.array([
            [30 + 5 * t, 0.0, 4.5, 1.8, 0.0],          # 0 lead vehicle in the lane: blocking
            [10 + 8 * t, 3.5, 4.5, 1.8, 0.0],          # 1 moving neighbour on the left: no bypass + blind zone
            [5 + 8 * t, -3.5, 12.0, 2.5, 0.0],         # 2 moving truck on the right: blind zone only
            [20.0, -3.2, 4.5, 1.8, 0.0],               # 3 parked car on the right: non-blocking, no decision
            [40.0, 12.0, 4.5, 1.8, 0.0],               # 4 far away: neither
            [25 + 6 * t, 3.5 - 0.7 * t, 4.5, 1.8, -0.2],  # 5 cut-in from the left: blocking
            [35.0, -6 + 1.2 * t, 0.6, 0.6, np.pi / 2],  # 6 crossing pedestrian: blocking
        ])

    c = _classify(prof, _scene(boxes), CAR)
    assert list(np.asarray(c.is_blocking)) == [True, False, False, False, False, True, True]
    assert list(np.asarray(c.is_nonblocking)) == [False, True, True, True, False, False, False]
    assert list(np.asarray(c.side_of)) == [0, LEFT, RIGHT, RIGHT, 0, 0, 0]
    assert list(np.asarray(c.no_bypass)) == [False, True, False, False, False, False, False]
    assert list(np.asarray(c.blind_zone)) == [False, True, True, False, False, False, False]
    assert float(c.size[2]) == pytest.approx(30.0)
    # the neighbour's side range covers its own extent along the road (within a station)
    # (stations start at x = -10; strips are one station long)
    assert float(c.side.lower[1, 0]) == pytest.approx(10 + 7.75, abs=0.51)
    assert float(c.side.upper[1, 0]) == pytest.approx(10 + 12.25, abs=0.51)
    # the pedestrian blocks only while it is on the car's footprint band
    ped_hit = np.asarray(c.blocking.hit[6])
    assert ped_hit.any() and not ped_hit.all()


def test_side_probes_flank_the_footprint():
    ref = ReferenceLine.from_polyline(np.array([[0.0, 0.0], [50.0, 50.0]]))
    prof = _profile(ref, 0.0, 10, 1.0)
    lp, rp = side_probes(prof, CAR, 3.0, LEFT), side_probes(prof, CAR, 3.0, RIGHT)
    n = np.array([-1.0, 1.0]) / np.sqrt(2)
    d = np.asarray(lp[:, :2] - prof.xy) @ n
    assert np.allclose(d, 0.5 * CAR.width + 1.5, atol=1e-5)
    assert np.allclose(np.asarray(rp[:, :2] - prof.xy) @ n, -(0.5 * CAR.width + 1.5), atol=1e-5)


def test_keep_clear_region_projection():
    ref = ReferenceLine.from_polyline(np.array([[0.0, 0.0], [100.0, 0.0]]))
    prof = _profile(ref, 0.0, 60, 1.0)
    box = np.array([[[30.0, -3], [36, -3], [36, 3], [30, 3]], [[30.0, 5], [36, 5], [36, 9], [30, 9]]])
    lo, hi, hit = _kc(prof, CAR, box, jnp.ones((2, 4), bool), jnp.array([True, True]))
    assert list(np.asarray(hit)) == [True, False]
    # car [s - 0.95, s + 3.85] overlaps [30, 36]: s in (26.15, 36.95)
    assert float(lo[0]) == 27.0 and float(hi[0]) == 36.0
    lo, hi, hit = _kc(prof, CAR, box, jnp.ones((2, 4), bool), jnp.array([False, True]))
    assert not bool(hit.any())


def test_first_trajectory_constant_speed():
    ref = ReferenceLine.from_polyline(np.stack([np.linspace(0, 60, 20), 0.01 * np.linspace(0, 60, 20) ** 2], -1))
    prof = _profile(ref, 5.0, 30, 1.0)
    tr = first_trajectory(prof, 4.0, jnp.arange(8) * 0.5)
    xy, _, _, _ = ref_state(ref, 5.0 + 4.0 * jnp.arange(8) * 0.5)
    assert np.allclose(tr.xy, xy, atol=1e-5)
    assert np.allclose(tr.s, 2.0 * np.arange(8), atol=1e-5)


def test_composed_trajectory_consistent(rng):
    ref = ReferenceLine.from_polyline(np.stack([np.linspace(0, 120, 40), 3 * np.sin(np.linspace(0, 120, 40) / 20)], -1))
    for _ in range(5):
        seg = rng.integers(0, 8, 7).astype(np.float32)
        seg[rng.integers(0, 7)] = 0.0
        s = np.concatenate([[0.0], np.cumsum(seg)]).astype(np.float32)
        t = np.arange(8, dtype=np.float32)
        plan = SpeedPlan(jnp.asarray(t), jnp.asarray(s), jnp.asarray(seg), jnp.zeros(7), 0.0, True)
        v0 = float(seg[0]) + 0.3
        tr = _compose(ref, 2.0, plan, v0, 0.01, 701)
        ts, vs = np.asarray(tr.t, float), np.asarray(tr.v, float)
        integ = np.concatenate([[0.0], np.cumsum(0.5 * (vs[1:] + vs[:-1]) * np.diff(ts))])
        assert np.allclose(integ, np.asarray(tr.s), atol=2e-3)          # s = integral of v
        assert np.all(vs >= -1e-4) and np.all(np.diff(np.asarray(tr.s)) >= -1e-5)  # never backwards
        assert np.allclose(np.asarray(tr.s)[::100], s, atol=1e-4)       # passes every DP knot
        xy, th, _, _ = ref_state(ref, 2.0 + tr.s)
        assert np.allclose(tr.xy, xy, atol=1e-4)
        dv = np.gradient(vs, ts)
        inner = np.abs(((ts * 100).round() % 100)) > 1  # away from knots (a jumps there)
        assert np.allclose(dv[inner], np.asarray(tr.a)[inner], atol=0.05)
