"""Speed planning geometry: projected ST boundaries vs shapely, strip clipping, classification
(blocking, behind, non-blocking with decisions beside and behind the car), resampling,
keep-clear regions, composition."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.speed import (
    LEFT,
    RIGHT,
    SpeedPlan,
    blocking_boundaries,
    classify,
    compose_plan,
    first_trajectory,
    keep_clear_intervals,
    path_profile,
    project_obstacles,
    resample_obstacles,
    side_boundaries,
    strip_boundaries,
    strip_extent,
)
from jaxplan.types import Obstacles, VehicleParams

CAR = VehicleParams()
FRONT = CAR.center_offset + 0.5 * CAR.length  # 3.85
REAR = CAR.center_offset - 0.5 * CAR.length  # -0.95

_project = jax.jit(project_obstacles)
_blocking = jax.jit(blocking_boundaries)
_side = jax.jit(side_boundaries, static_argnums=(3,))
_strip = jax.jit(strip_extent)
_classify = jax.jit(classify)
_profile = jax.jit(path_profile, static_argnums=(2, 3))
_compose = jax.jit(compose_plan, static_argnums=(3, 4))
_kc = jax.jit(keep_clear_intervals)


def _np_box(b):
    x, y, L, W, h = b
    c, s = np.cos(h), np.sin(h)
    pts = [(sx * L / 2, sy * W / 2) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    return shapely.Polygon([(x + c * u - s * v, y + s * u + c * v) for u, v in pts])


def _car_poly(xy, th, grow=0.0):
    off = CAR.center_offset
    return _np_box([xy[0] + off * np.cos(th), xy[1] + off * np.sin(th), CAR.length + 2 * grow, CAR.width + 2 * grow, th])


def _random_obstacles(rng, K, T, dt=0.5, x_max=35.0):
    start = np.column_stack([rng.uniform(0, x_max, K), rng.uniform(-4, 4, K), rng.uniform(1, 6, K),
                             rng.uniform(0.6, 2.5, K), rng.uniform(-np.pi, np.pi, K)])
    vel = rng.uniform(-5, 5, (K, 2))
    t = np.arange(T) * dt
    boxes = np.repeat(start[:, None], T, 1)
    boxes[..., :2] += vel[:, None] * t[None, :, None]
    valid = rng.uniform(size=(K, T)) > 0.15
    return boxes, valid, Obstacles(jnp.asarray(boxes, jnp.float32), jnp.asarray(valid), jnp.asarray(t, jnp.float32))


def _shapely_range(cars, stations, ob):
    inter = np.array([c.intersects(ob) and c.intersection(ob).area > 1e-9 for c in cars])
    return (stations[inter].min(), stations[inter].max()) if inter.any() else None


def test_straight_path_boundaries_match_shapely(rng):
    """On a straight path the projected boundary is the range of car positions (every 5 cm)
    whose footprint (grown by the buffer) overlaps the obstacle: within one station."""
    ref = ReferenceLine.from_polyline(np.array([[-20.0, 0.0], [80.0, 0.0]]))
    st = np.arange(-15.0, 45.0, 0.05)
    buf = 0.3
    checked = 0
    for trial in range(3):
        boxes, valid, obs = _random_obstacles(rng, 6, 4)
        b = _blocking(_project(ref, obs), CAR, buf)
        cars = [_car_poly((s, 0.0), 0.0, buf) for s in st]
        for k in range(6):
            for j in range(4):
                r = _shapely_range(cars, st, _np_box(boxes[k, j])) if valid[k, j] else None
                assert bool(b.hit[k, j]) == (r is not None)
                if r is not None:
                    checked += 1
                    assert float(b.lower[k, j]) == pytest.approx(r[0] + 20.0, abs=0.06)
                    assert float(b.upper[k, j]) == pytest.approx(r[1] + 20.0, abs=0.06)
    assert checked > 10


def test_curved_path_boundaries_are_conservative(rng):
    """On a curved path (radius >= 50 m) every car position whose footprint (on the path,
    at its heading) overlaps the obstacle lies inside the boundary, and the boundary is at
    most a little wider than the exact range."""
    checked = 0
    for trial in range(3):
        x = np.linspace(0, 60, 60)
        k = rng.choice([-1, 1]) / rng.uniform(50, 80)
        ref = ReferenceLine.from_polyline(np.stack([x, 0.5 * k * x ** 2], -1))
        prof = _profile(ref, -15.0, 700, 0.1)
        xy, th, st = (np.asarray(a, float) for a in (prof.xy, prof.theta, prof.s))
        cars = [_car_poly(xy[i], th[i]) for i in range(len(st))]
        boxes, valid, obs = _random_obstacles(rng, 6, 3, x_max=40.0)
        boxes[..., 1] += 0.5 * k * boxes[..., 0] ** 2  # near the curve
        obs = Obstacles(jnp.asarray(boxes, jnp.float32), obs.valid, obs.t)
        b = _blocking(_project(ref, obs), CAR, 0.0)
        for kk in range(6):
            for j in range(3):
                if not valid[kk, j]:
                    continue
                r = _shapely_range(cars, st, _np_box(boxes[kk, j]))
                if r is None:
                    continue
                checked += 1
                assert bool(b.hit[kk, j])
                assert float(b.lower[kk, j]) <= r[0] + 0.1 and float(b.upper[kk, j]) >= r[1] - 0.1
                if st[0] < r[0] and r[1] < st[-1]:  # the exact range is not cut by the stations checked
                    assert float(b.lower[kk, j]) >= r[0] - 1.0 and float(b.upper[kk, j]) <= r[1] + 1.0
    assert checked > 5


@pytest.mark.parametrize("radius", [12.0, 20.0, 30.0])
def test_tight_curve_band_widens_only_on_the_outside(rng, radius):
    """On an arc of ``radius`` (left or right turn) with obstacles beside the path on both sides:
    every obstacle some footprint on the path overlaps (shapely) is hit, its exact range inside
    the boundary; and none is hit that every footprint clears by more than 0.1 m (the band is
    widened for the body's swing on the outside of the curve only, where the body goes)."""
    checked = {"hit": 0, "clear": 0}
    for turn in (1.0, -1.0):
        k = turn / radius
        ang = np.linspace(-0.6, 2.4, 400) * 20.0 / radius
        ref = ReferenceLine.from_polyline(np.stack([np.sin(ang) / abs(k), turn * (1 - np.cos(ang)) / abs(k)], -1))
        prof = _profile(ref, 0.0, 300, 0.1)
        xy, th, st = (np.asarray(a, float) for a in (prof.xy, prof.theta, prof.s))
        cars = [_car_poly(xy[i], th[i]) for i in range(len(st))]
        swept = shapely.union_all(cars)
        K = 40
        u = rng.uniform(8.0, 22.0, K)  # station of the obstacle's centre
        side = rng.choice([-1.0, 1.0], K)
        off = side * rng.uniform(1.0, 2.4, K)
        L, W = rng.uniform(1.0, 4.5, K), rng.uniform(0.8, 2.0, K)
        p_xy, p_th, _, _ = (np.asarray(a, float) for a in ref_state(ref, jnp.asarray(u, jnp.float32)))
        nrm = np.stack([-np.sin(p_th), np.cos(p_th)], -1)
        c = p_xy + off[:, None] * nrm
        boxes = np.column_stack([c, L, W, p_th + rng.uniform(-0.2, 0.2, K)])[:, None].astype(np.float32)
        obs = Obstacles(jnp.asarray(boxes), jnp.ones((K, 1), bool), jnp.zeros((1,), jnp.float32))
        b = _blocking(_project(ref, obs), CAR, 0.0)
        for kk in range(K):
            poly = _np_box(boxes[kk, 0])
            r = _shapely_range(cars, st, poly)
            if r is not None:
                checked["hit"] += 1
                assert bool(b.hit[kk, 0])
                # the ends of the range are approximate on a tight curve (the body's swing is taken
                # at its front for the whole band): short by at most a few centimetres per 1/R
                tol = 0.05 + 2.0 / radius
                assert float(b.lower[kk, 0]) <= r[0] + tol and float(b.upper[kk, 0]) >= r[1] - tol
            elif swept.distance(poly) > 0.1:
                checked["clear"] += 1
                assert not bool(b.hit[kk, 0]), (radius, turn, off[kk], swept.distance(poly))
    assert checked["hit"] >= 10 and checked["clear"] >= 10


def test_strip_extent_matches_shapely(rng):
    for _ in range(200):
        b = [rng.uniform(-5, 5), rng.uniform(-4, 4), rng.uniform(0.5, 6), rng.uniform(0.5, 3), rng.uniform(-4, 4)]
        lo, hi = sorted(rng.uniform(-3, 3, 2))
        poly = _np_box(b)
        corners = np.asarray(poly.exterior.coords)[:4]
        s_min, s_max, hit = (float(a) for a in _strip(jnp.asarray(corners, jnp.float32), lo, hi))
        clip = poly.intersection(shapely.box(-100, lo, 100, hi))
        assert bool(hit) == (not clip.is_empty)
        if not clip.is_empty:
            x0, _, x1, _ = clip.bounds
            assert s_min == pytest.approx(x0, abs=1e-4) and s_max == pytest.approx(x1, abs=1e-4)


def _scene(boxes_fn, T=36, dt=0.2):
    t = np.arange(T) * dt
    boxes = np.stack([boxes_fn(tt) for tt in t], 1)  # (K, T, 5)
    return Obstacles(jnp.asarray(boxes, jnp.float32), jnp.ones(boxes.shape[:2], bool), jnp.asarray(t, jnp.float32))


def test_classification_hand_built_scenes():
    """The car's reference point at x = 0 going +x at 10 m/s; stations relative to it."""
    ref = ReferenceLine.from_polyline(np.array([[-60.0, 0.0], [200.0, 0.0]]))

    def boxes(t):
        return np.array([
            [30 + 5 * t, 0.0, 4.5, 1.8, 0.0],             # 0 lead vehicle in the lane: blocking
            [14 + 8 * t, 3.5, 4.5, 1.8, 0.0],             # 1 slower neighbour ahead on the left: no bypass + blind zone
            [5 + 8 * t, -3.5, 12.0, 2.5, 0.0],            # 2 truck beside on the right: blind zone only
            [20.0, -3.2, 4.5, 1.8, 0.0],                  # 3 parked car on the right: non-blocking, no decision
            [40.0, 12.0, 4.5, 1.8, 0.0],                  # 4 far away: neither
            [25 + 6 * t, 3.5 - 0.7 * t, 4.5, 1.8, -0.2],  # 5 cut-in from the left ahead: blocking
            [35.0, -6 + 1.2 * t, 0.6, 0.6, np.pi / 2],    # 6 crossing pedestrian ahead: blocking
            [-9 + 14 * t, 0.0, 4.5, 1.8, 0.0],            # 7 faster follower in the lane: behind, ignored
            [-2 + 9 * t, 3.5, 4.5, 1.8, 0.0],             # 8 neighbour beside-behind on the left: blind zone, no no-bypass
            [-25 + 15 * t, -3.5, 4.5, 1.8, 0.0],          # 9 neighbour far behind on the right: side strip behind the car
            [-12 + 9 * t, -3.5 + 1.0 * t, 4.5, 1.8, 0.1],  # 10 merges in behind the car: behind, ignored
            [45 - 8 * t, 3.5, 4.5, 1.8, np.pi],           # 11 oncoming on the left: non-blocking, no decision
        ])

    obs = _scene(boxes)
    osl = _project(ref, obs)
    osl = jax.tree_util.tree_map(lambda a: a, osl)
    osl = type(osl)(osl.corners.at[..., 0].add(-60.0), osl.centre.at[..., 0].add(-60.0), osl.kappa, osl.valid)
    c = _classify(osl, obs, CAR, obs.t, 10.0, -5.0, buffer=0.3)
    assert list(np.asarray(c.is_blocking)) == [True, False, False, False, False, True, True] + [False] * 5
    assert list(np.asarray(c.behind)) == [False] * 7 + [True, False, False, True, False]
    assert list(np.asarray(c.is_nonblocking)) == [False, True, True, True] + [False] * 4 + [True] * 4
    assert list(np.asarray(c.side_of))[:4] == [0, LEFT, RIGHT, RIGHT] and int(c.side_of[8]) == LEFT
    assert int(c.side_of[11]) == LEFT
    assert list(np.asarray(c.no_bypass)) == [False, True] + [False] * 10
    assert list(np.asarray(c.blind_zone)) == [False, True, True] + [False] * 5 + [True, True, True, False]
    # driving the car's way: the moving vehicles but the oncoming one; not the parked car, the far
    # one standing, the crossing pedestrian
    assert list(np.asarray(c.same_way)) == [True, True, True, False, False, True, False] + [True] * 4 + [False]
    assert float(c.size[2]) == pytest.approx(30.0)
    # the side strips reach behind the car: the far neighbour's range at t = 0 is its own extent
    assert float(c.side.lower[9, 0]) == pytest.approx(-25 - 2.25, abs=0.01)
    assert float(c.side.upper[9, 0]) == pytest.approx(-25 + 2.25, abs=0.01)
    assert float(c.side.lower[1, 0]) == pytest.approx(14 - 2.25, abs=0.01)
    # the pedestrian blocks only while it is on the car's band; the lead's boundary is its
    # extent less the car's front / rear and the buffer
    ped_hit = np.asarray(c.blocking.hit[6])
    assert ped_hit.any() and not ped_hit.all()
    assert float(c.blocking.lower[0, 0]) == pytest.approx(30 - 2.25 - FRONT - 0.3, abs=0.01)
    assert float(c.blocking.upper[0, 0]) == pytest.approx(30 + 2.25 - REAR + 0.3, abs=0.01)
    assert float(c.v_along[0, 3]) == pytest.approx(5.0, abs=0.01)
    assert not np.asarray(c.blocking.hit[7]).any()  # ignored as blocking


def test_side_boundaries_mirror():
    ref = ReferenceLine.from_polyline(np.array([[-50.0, 0.0], [50.0, 0.0]]))
    obs = _scene(lambda t: np.array([[10.0, 3.0, 4.0, 1.8, 0.0], [10.0, -3.0, 4.0, 1.8, 0.0]]), T=2)
    osl = _project(ref, obs)
    left, right = _side(osl, CAR, 3.5, LEFT, 0.0), _side(osl, CAR, 3.5, RIGHT, 0.0)
    assert list(np.asarray(left.hit[:, 0])) == [True, False]
    assert list(np.asarray(right.hit[:, 0])) == [False, True]
    assert float(left.lower[0, 0]) == pytest.approx(58.0, abs=1e-4) and float(left.upper[0, 0]) == pytest.approx(62.0, abs=1e-4)


def test_strip_boundaries_agree_with_each_strip_alone(rng):
    """The classifier's one-scan form gives each strip's boundaries as computed alone."""
    x = np.linspace(0, 60, 60)
    ref = ReferenceLine.from_polyline(np.stack([x, 0.5 * x ** 2 / 60.0], -1))
    _, _, obs = _random_obstacles(rng, 12, 4, x_max=40.0)
    osl = _project(ref, obs)
    blk, left, right = jax.jit(strip_boundaries)(osl, CAR, 3.0, 0.3)
    for got, want in ((blk, _blocking(osl, CAR, 0.3)), (left, _side(osl, CAR, 3.0, LEFT, 0.3)),
                      (right, _side(osl, CAR, 3.0, RIGHT, 0.3))):
        assert np.array_equal(np.asarray(got.hit), np.asarray(want.hit)) and np.asarray(want.hit).any()
        h = np.asarray(want.hit)
        np.testing.assert_allclose(np.asarray(got.lower)[h], np.asarray(want.lower)[h], atol=1e-4)
        np.testing.assert_allclose(np.asarray(got.upper)[h], np.asarray(want.upper)[h], atol=1e-4)


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


def test_composed_plan_is_the_exact_profile(rng):
    """A DP plan's trajectory: piecewise-constant acceleration through every knot, s the
    integral of v, v the integral of a, positions on the path."""
    ref = ReferenceLine.from_polyline(np.stack([np.linspace(0, 160, 40), 3 * np.sin(np.linspace(0, 160, 40) / 20)], -1))
    for _ in range(5):
        v = np.concatenate([[rng.uniform(0, 10)], np.clip(rng.uniform(0, 12, 7), 0, None)]).astype(np.float32)
        t = np.arange(8, dtype=np.float32)
        s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))]).astype(np.float32)
        plan = SpeedPlan(jnp.asarray(t), jnp.asarray(s), jnp.asarray(v), jnp.asarray(np.diff(v)), 0.0, True)
        tr = _compose(ref, 2.0, plan, 0.01, 701)
        ts, vs, a_ = (np.asarray(x, float) for x in (tr.t, tr.v, tr.a))
        assert np.allclose(np.asarray(tr.s)[::100], s, atol=1e-3)  # passes every knot
        assert np.allclose(vs[::100], v, atol=1e-4)
        integ = np.concatenate([[0.0], np.cumsum(0.5 * (vs[1:] + vs[:-1]) * np.diff(ts))])
        assert np.allclose(integ, np.asarray(tr.s), atol=2e-3)
        seg = np.minimum((ts // 1).astype(int), 6)
        assert np.allclose(a_, np.diff(v)[seg], atol=1e-5)  # constant within each segment
        xy, _, _, _ = ref_state(ref, 2.0 + tr.s)
        assert np.allclose(tr.xy, xy, atol=1e-4)


def test_frenet_points_invert_to_cartesian(rng):
    """``frenet_points`` (the projection the boundaries and ``to_frenet`` use) inverts
    ``to_cartesian`` and gives ``ref_state``'s heading and curvature there, on a winding path,
    for points beside it and beyond both ends (where the end chords extend the line)."""
    from jaxplan.geometry.frenet import frenet_points, to_cartesian

    u = np.linspace(0.0, 60.0, 41)
    ref = ReferenceLine.from_polyline(np.stack([u, 8.0 * np.sin(u / 9.0)], -1))
    length = float(ref.s[-1])
    s_true = jnp.asarray(np.concatenate([rng.uniform(0.0, length, 300), rng.uniform(-15.0, 0.0, 20),
                                         rng.uniform(length, length + 15.0, 20)]), jnp.float32)
    # |l| well inside the smallest radius of curvature (about 10 m), so the projection is unique
    l_true = jnp.asarray(rng.uniform(-4.0, 4.0, s_true.shape[0]), jnp.float32)
    p = to_cartesian(ref, s_true, l_true)
    s, l, th, kap = jax.jit(frenet_points)(ref, p[:, 0], p[:, 1])
    np.testing.assert_allclose(s, s_true, atol=2e-3)
    np.testing.assert_allclose(l, l_true, atol=2e-3)
    _, th_ref, kap_ref, _ = ref_state(ref, s_true)
    np.testing.assert_allclose(th, th_ref, atol=1e-3)
    np.testing.assert_allclose(kap, kap_ref, atol=1e-3)


def test_a_car_the_path_moves_over_to_from_behind_is_blocking():
    """A path that leaves the car's lane for the left one at once: the faster neighbour coming up
    from behind in the left lane reaches the car's band beside the car (behind its braking station
    where it first grazes the band), so the car would merge in front of it: blocking, as the
    verdict would put such a contact at the car's fault. A follower squarely behind in the car's
    lane is still behind."""
    xs = np.linspace(0.0, 8.0, 17)
    shift = 3.5 * (10 * (xs / 8) ** 3 - 15 * (xs / 8) ** 4 + 6 * (xs / 8) ** 5)
    pts = np.concatenate([[[-60.0, 0.0]], np.column_stack([xs, shift]), [[200.0, 3.5]]])
    ref = ReferenceLine.from_polyline(pts)

    def boxes(t):
        return np.array([[-12 + 16 * t, 3.5, 4.5, 1.8, 0.0],   # 0 faster neighbour in the left lane
                         [-9 + 14 * t, 0.0, 4.5, 1.8, 0.0]])   # 1 faster follower in the car's lane

    obs = _scene(boxes)
    osl = _project(ref, obs)
    osl = type(osl)(osl.corners.at[..., 0].add(-60.0), osl.centre.at[..., 0].add(-60.0), osl.kappa, osl.valid)
    lane_s = float(np.interp(1.0, shift, xs))  # where the path is 1 m over (its station ~ x here)
    c = _classify(osl, obs, CAR, obs.t, 10.0, -5.0, lane_s, buffer=0.3)
    assert list(np.asarray(c.behind)) == [False, True]
    assert list(np.asarray(c.is_blocking)) == [True, False]
    # the same path taken as the car's lane (no lane_s): excused, as before the path was known to move over
    c_lane = _classify(osl, obs, CAR, obs.t, 10.0, -5.0, buffer=0.3)
    assert list(np.asarray(c_lane.behind)) == [True, True]
    # where it first grazes the band its centre is behind the car's braking station: only the
    # squarely-behind test tells it from a follower
    f = int(np.argmax(np.asarray(c.blocking.hit[0])))
    centre = 0.5 * (float(c.blocking.lower[0, f]) + float(c.blocking.upper[0, f]))
    t = float(obs.t[f])
    assert centre < 10.0 * min(t, 2.0) - 2.5 * min(t, 2.0) ** 2


def test_vehicles_moving_over_into_the_cars_lane_are_passed_without_the_crossing_margin():
    """``merging_in`` on a route along the x axis (the car at x = 0 in the lane at l = 0): the
    obstacles whose distance to the car's lane centre shrinks by more than MERGE_SHIFT; in the
    ST graph only those of them that drive the car's way lose the crossing margin. Where the
    route moves over to the next lane (its frame shifts under the lanes), a vehicle keeping its
    lane is not merging."""
    from types import SimpleNamespace

    from jaxplan.speed import SpeedConfig
    from jaxplan.speed import make_scene as make_st_scene
    from jaxplan.speed.paths import merging_in

    def boxes(t):
        return np.array([
            [30 + 5 * t, 0.0, 4.5, 1.8, 0.0],              # 0 leader in the lane
            [10 + 8 * t, 3.5, 4.5, 1.8, 0.0],              # 1 beside in the next lane (the car may move over)
            [25 + 6 * t, 3.5 - 0.7 * t, 4.5, 1.8, -0.2],   # 2 cuts in from the left ahead
            [-2 + 12 * t, -3.5 + 0.6 * t, 4.5, 1.8, 0.05],  # 3 merges in from the right, faster
            [35.0, -6 + 1.2 * t, 0.6, 0.6, np.pi / 2],     # 4 pedestrian crossing ahead
            [20 + 6 * t, 0.3 * t, 4.5, 1.8, 0.05],         # 5 leaves the lane to the left
        ])

    obs = _scene(boxes)
    b = np.asarray(obs.boxes)
    ctx = SimpleNamespace(s=jnp.float32(0.0), obstacles=obs, obstacle_s=jnp.asarray(b[..., 0]),
                          obstacle_l=jnp.asarray(b[..., 1]))
    u = jnp.linspace(-40.0, 120.0, 161)
    lane = jnp.zeros_like(u)
    assert list(np.asarray(merging_in(ctx, u, lane))) == [False, False, True, True, True, False]
    # not valid now: not judged
    late = Obstacles(obs.boxes, obs.valid.at[2, 0].set(False), obs.t)
    assert not bool(merging_in(SimpleNamespace(**{**vars(ctx), "obstacles": late}), u, lane)[2])
    # the route moves over to the left lane from x = 20 to 60: its frame shifts 3.5 m under the
    # lanes, and the car's lane lies at l = -3.5 beyond; the neighbour on the left keeps its lane
    shift = np.clip((b[..., 0] - 20.0) / 40.0, 0.0, 1.0) * 3.5
    moved = SimpleNamespace(**{**vars(ctx), "obstacle_l": jnp.asarray(b[..., 1] - shift)})
    lane_moved = -jnp.clip((u - 20.0) / 40.0, 0.0, 1.0) * 3.5
    assert not bool(merging_in(moved, u, lane_moved)[1])
    assert bool(merging_in(moved, u, jnp.zeros_like(u))[1])  # seen from the route's frame alone it would be

    ref = ReferenceLine.from_polyline(np.array([[-60.0, 0.0], [300.0, 0.0]]))
    cfg = SpeedConfig()
    make_scene = jax.jit(make_st_scene, static_argnames=("config", "vehicle"))  # one program per call's shapes
    moving = merging_in(ctx, u, lane)
    _, plain = make_scene(ref, obs, cfg, CAR, 60.0, v0=10.0)
    _, merge = make_scene(ref, obs, cfg, CAR, 60.0, v0=10.0, merging=moving)
    c = plain.classified
    same = np.asarray(c.same_way)
    assert list(same[[2, 3, 4]]) == [True, True, False]
    without = [k for k in range(6) if not np.array_equal(np.asarray(plain.classified.blocking.upper[k]),
                                                         np.asarray(merge.classified.blocking.upper[k]))]
    # the two blocking vehicles that drive the car's way and move over into its lane lose the
    # margin; the crossing pedestrian and the leader keep it
    assert without == [2, 3]
    up_p, up_m = np.asarray(plain.classified.blocking.upper[2]), np.asarray(merge.classified.blocking.upper[2])
    hit = np.asarray(merge.classified.blocking.hit[2])
    assert np.all(up_m[hit] <= up_p[hit] + 1e-4) and np.any(up_m[hit] < up_p[hit] - 1.0)
    with pytest.raises(ValueError, match="merging has shape"):
        make_scene(ref, obs, cfg, CAR, 60.0, v0=10.0, merging=jnp.zeros(5, bool))
    # margin=False (the plan without the comfort clearances): every boundary is the plain overlap
    # (time_margin's input), the margin is kept otherwise; a car coming towards the car in its lane
    # (its near side sweeps closer) and the crossing pedestrian show the difference
    sweep = _scene(lambda t: np.concatenate([boxes(t), [[70 - 8 * t, 0.2, 4.5, 1.8, np.pi]]]))
    moving6 = jnp.concatenate([moving, jnp.zeros(1, bool)])
    kept, bare = (make_scene(ref, sweep, cfg, CAR, 60.0, v0=10.0, merging=moving6, margin=jnp.asarray(m))[1]
                  for m in (True, False))
    _, overlap = make_scene(ref, sweep, dataclasses.replace(cfg, pass_margin=0.0), CAR, 60.0, v0=10.0)
    _, margined = make_scene(ref, sweep, cfg, CAR, 60.0, v0=10.0, merging=moving6)
    kb, bb, ob = kept.classified.blocking, bare.classified.blocking, overlap.classified.blocking
    for f in ("lower", "upper", "hit"):
        np.testing.assert_array_equal(getattr(bb, f), getattr(ob, f))
        np.testing.assert_array_equal(getattr(kb, f), getattr(margined.classified.blocking, f))
    hit = np.asarray(ob.hit)
    assert np.any(np.asarray(kb.lower[6])[hit[6]] < np.asarray(bb.lower[6])[hit[6]] - 3.0)
    assert np.asarray(kb.hit[4]).sum() > hit[4].sum()
    with pytest.raises(ValueError, match="margin has shape"):
        make_scene(ref, obs, cfg, CAR, 60.0, v0=10.0, margin=jnp.zeros(6, bool))
