"""Boxes, headings, lines, the Frenet frame; parity, gradients, recompiles, bad input."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxplan as jp
from jaxplan.geometry import (ReferenceLine, box_corners, frenet_to_cartesian_state, has_overlap,
                              headings_from_path, line_intersection, point_on_segment, project_point,
                              separation, to_cartesian, to_frenet, vehicle_corners)
from jaxplan.types import Obstacles, Polygon, Trajectory, VehicleParams


def test_box_corners_ccw_from_front_left(rng):
    boxes = np.stack([rng.normal(size=200), rng.normal(size=200), rng.uniform(1, 5, 200),
                      rng.uniform(0.5, 2, 200), rng.uniform(-4, 4, 200)], -1)
    c = np.asarray(box_corners(boxes))
    assert c.shape == (200, 4, 2)
    x, y = c[..., 0], c[..., 1]
    area = 0.5 * np.sum(x * np.roll(y, -1, -1) - np.roll(x, -1, -1) * y, -1)
    np.testing.assert_allclose(area, boxes[:, 2] * boxes[:, 3], rtol=1e-5)
    fwd = np.stack([np.cos(boxes[:, 4]), np.sin(boxes[:, 4])], -1)
    left = np.stack([-fwd[:, 1], fwd[:, 0]], -1)
    rel = c[:, 0] - boxes[:, :2]
    np.testing.assert_allclose(np.sum(rel * fwd, -1), boxes[:, 2] / 2, atol=1e-5)
    np.testing.assert_allclose(np.sum(rel * left, -1), boxes[:, 3] / 2, atol=1e-5)


def _headings_loop(xy):
    out = []
    for i in range(len(xy)):
        j = max(i, 1)
        d = xy[j] - xy[j - 1]
        out.append(np.arctan2(d[1], d[0]))
    return np.array(out)


def test_headings_from_path_matches_loop_and_handles_repeats(rng):
    xy = np.cumsum(rng.normal(size=(5, 20, 2)), axis=1)
    h = np.asarray(headings_from_path(xy))
    for k in range(5):
        np.testing.assert_allclose(h[k], _headings_loop(xy[k]), atol=1e-5)
    rep = np.array([[0, 0], [0, 0], [1, 1], [1, 1], [1, 2.0]])
    np.testing.assert_allclose(headings_from_path(rep), [np.pi / 4] * 4 + [np.pi / 2], atol=1e-6)
    # Reversing along a line: heading follows the direction of travel.
    back = np.array([[3.0, 0], [2, 0], [1, 0]])
    np.testing.assert_allclose(np.abs(headings_from_path(back)), np.pi, atol=1e-6)


@pytest.mark.parametrize("reference", ["rear_axle", "center"])
def test_vehicle_corners_reference_point(reference):
    veh = VehicleParams(length=4.8, width=1.9, wheelbase=2.9, rear_overhang=0.95, reference=reference)
    th = 0.6
    xy = np.array([[1.0, 2.0], [1 + np.cos(th), 2 + np.sin(th)]])
    c = np.asarray(vehicle_corners(xy, veh))[0]
    fwd, left = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
    rear_mid = 0.5 * (c[1] + c[2])
    along = np.dot(rear_mid - xy[0], fwd)
    expect = -0.95 if reference == "rear_axle" else -2.4
    assert abs(along - expect) < 1e-5 and abs(np.dot(rear_mid - xy[0], left)) < 1e-5
    assert abs(np.linalg.norm(c[0] - c[3]) - 1.9) < 1e-5


def test_lines_vertical_parallel_and_segments():
    p, t1, t2, ok = line_intersection(jnp.array([1.0, -5]), jnp.array([0.0, 1]), jnp.array([0.0, 2]),
                                      jnp.array([3.0, 0]))
    assert ok and np.allclose(p, [1, 2]) and np.isclose(t1, 7) and np.isclose(t2, 1 / 3)
    _, _, _, ok = line_intersection(jnp.array([0.0, 0]), jnp.array([1.0, 1]), jnp.array([0.0, 1]),
                                    jnp.array([2.0, 2]))
    assert not ok
    t, foot = project_point(jnp.array([2.0, 3]), jnp.array([0.0, 0]), jnp.array([0.0, 2]))
    assert np.isclose(t, 1.5) and np.allclose(foot, [0, 3])
    assert point_on_segment(jnp.array([0.5, 0.5]), jnp.array([0.0, 0]), jnp.array([1.0, 1]))
    assert not point_on_segment(jnp.array([1.5, 1.5]), jnp.array([0.0, 0]), jnp.array([1.0, 1]))
    assert point_on_segment(jnp.array([1.0, 1]), jnp.array([1.0, 1]), jnp.array([1.0, 1]))  # zero length


def _arc(radius, n=400, span=None):
    span = span or min(2.5, 60.0 / radius)
    th = np.linspace(-np.pi / 2, -np.pi / 2 + span, n)
    return np.stack([radius * np.cos(th), radius + radius * np.sin(th)], -1)


@pytest.mark.parametrize("radius", [5.0, 8.0, 20.0, 80.0])
def test_frenet_round_trip_and_curvature(rng, radius):
    with jax.enable_x64(True):
        ref = ReferenceLine.from_polyline(_arc(radius))
        s = rng.uniform(-3, float(ref.length) + 3, 3000)  # beyond both ends too
        l = rng.uniform(-5, 5, 3000)
        l = np.where(l > 0, np.minimum(l, 0.97 * radius), l)  # stay off the centre of curvature
        xy = to_cartesian(ref, s, l)
        s2, l2 = to_frenet(ref, xy)
        back = np.asarray(to_cartesian(ref, s2, l2))
        assert np.abs(back - np.asarray(xy)).max() < 1e-3
        inside = (s > 0.5) & (s < float(ref.length) - 0.5)
        assert np.abs(np.asarray(s2) - s)[inside].max() < 1e-2
        kappa = np.asarray(ref.kappa)[5:-5]
        assert np.all(np.abs(kappa * radius - 1) < 0.01)


def test_frenet_curve_state_on_offset_circle():
    with jax.enable_x64(True):
        ref = ReferenceLine.from_polyline(_arc(10.0, n=800))
        s = jnp.linspace(2, 14, 20)
        xy, th, k = frenet_to_cartesian_state(ref, s, jnp.full(20, 2.0), jnp.zeros(20), jnp.zeros(20))
        assert np.allclose(np.asarray(k), 1 / 8.0, rtol=1e-2)  # a circle of radius 10 - 2
        assert np.allclose(np.linalg.norm(np.asarray(xy) - [0, 10], axis=-1), 8.0, atol=1e-3)


def test_frenet_of_a_host_side_float64_line_runs_in_jaxs_float_without_a_warning():
    """A scene built on the host has float64 numpy leaves (``build_scene``): ``to_frenet`` on its
    route runs in float32 as JAX does by default (no warning about a float64 request) and gives the
    float32 line's answer; with x64 on it stays float64."""
    import warnings

    ref = ReferenceLine.from_polyline(_arc(10.0, n=200))
    host = ReferenceLine(*(np.asarray(x, np.float64) for x in (ref.xy, ref.s, ref.theta, ref.kappa)))
    pts = np.array([[3.0, 1.0], [5.0, 2.5], [7.0, 4.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s, l = to_frenet(host, pts)
    assert s.dtype == l.dtype == jnp.float32
    s32, l32 = to_frenet(ref, pts)
    np.testing.assert_allclose(np.asarray(s), np.asarray(s32), atol=1e-5)
    np.testing.assert_allclose(np.asarray(l), np.asarray(l32), atol=1e-5)
    with jax.enable_x64(True):
        s64, _ = to_frenet(host, pts)
        assert s64.dtype == jnp.float64


def test_parity_single_vmap_jit(rng):
    a = box_corners(np.asarray(rng.normal(size=(64, 5)) * [2, 2, 0, 0, 2] + [0, 0, 4, 2, 0], np.float32))
    b = box_corners(np.asarray(rng.normal(size=(64, 5)) * [2, 2, 0, 0, 2] + [0, 0, 3, 1.5, 0], np.float32))
    batched = np.asarray(separation(a, b))
    single = np.array([float(separation(a[i], b[i])) for i in range(8)])
    vm = np.asarray(jax.vmap(separation)(a, b))
    jt = np.asarray(jax.jit(separation)(a, b))
    np.testing.assert_allclose(batched[:8], single, atol=1e-6)
    np.testing.assert_allclose(vm, batched, atol=1e-6)
    np.testing.assert_allclose(jt, batched, atol=1e-6)
    # Leading dimensions broadcast: all pairs at once.
    allp = np.asarray(separation(a[:, None], b[None, :]))
    assert allp.shape == (64, 64) and np.allclose(np.diag(allp), batched, atol=1e-6)


def test_gradients_against_finite_differences(rng):
    with jax.enable_x64(True):
        boxes = jnp.array([[0.0, 0.0, 4.0, 2.0, 0.3], [1.5, 0.7, 3.0, 1.6, 1.1], [9.0, 1.0, 3.0, 1.6, 0.2]])
        f = lambda bx, j: separation(box_corners(bx[0]), box_corners(bx[j]))
        for j in (1, 2):  # overlapping and apart
            g = jax.grad(f)(boxes, j)
            for idx in [(0, 0), (0, 1), (0, 4), (j, 0), (j, 4), (j, 2)]:
                e = jnp.zeros_like(boxes).at[idx].set(1e-6)
                fd = (f(boxes + e, j) - f(boxes - e, j)) / 2e-6
                assert abs(fd - g[idx]) < 1e-5, (j, idx, fd, g[idx])
        ref = ReferenceLine.from_polyline(_arc(8.0))
        p = jnp.array([3.0, 1.0])
        J = jax.jacobian(lambda q: jnp.stack(to_frenet(ref, q)))(p)
        for k in range(2):
            e = jnp.zeros(2).at[k].set(1e-6)
            fd = (jnp.stack(to_frenet(ref, p + e)) - jnp.stack(to_frenet(ref, p - e))) / 2e-6
            np.testing.assert_allclose(J[:, k], fd, atol=1e-4)


def test_no_recompile_for_equal_shapes(rng):
    traces = []

    @jax.jit
    def f(a, b):
        traces.append(1)
        return has_overlap(a, b)

    for _ in range(3):
        a = box_corners(rng.normal(size=(10, 5)) * 0.1 + [0, 0, 4, 2, 0])
        f(a, a[::-1])
    assert len(traces) == 1


@pytest.mark.parametrize("bad,msg", [
    (np.array([[0.0, 0, np.nan, 1, 0]]), "NaN"),
    (np.array([[0.0, 0, np.inf, 1, 0]]), "NaN or inf"),
    (np.array([[0.0, 0, -1, 1, 0]]), "positive"),
    (np.array([[0.0, 0, 0, 1, 0]]), "positive"),
    (np.array([[0.0, 0, 1, 1]]), "shape"),
])
def test_bad_boxes_raise(bad, msg):
    with pytest.raises(ValueError, match=msg):
        box_corners(bad)


def test_bad_polygons_raise_or_reorient():
    sq = np.array([[0.0, 0], [1, 0], [1, 1], [0, 1]])
    with pytest.raises(ValueError, match="clockwise"):
        has_overlap(sq[::-1], sq)
    with pytest.raises(ValueError, match="not convex"):
        has_overlap(np.array([[0.0, 0], [2, 0], [0.5, 0.5], [0, 2]]), sq)
    with pytest.raises(ValueError, match="zero area"):
        has_overlap(np.array([[0.0, 0], [1, 0], [2, 0]]), sq)
    with pytest.raises(ValueError, match=r"\(\.\.\., N, 2\)|shape"):
        has_overlap(np.zeros((4, 3)), sq)
    p = Polygon.from_vertices(sq[::-1])  # documented: the constructor re-orients
    assert float(jp.polygon_area(p.vertices, p.valid)) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="NaN"):
        ReferenceLine.from_polyline(np.array([[0.0, 0], [np.nan, 1]]))
    with pytest.raises(ValueError, match="two distinct"):
        ReferenceLine.from_polyline(np.array([[1.0, 1], [1.0, 1]]))
    with pytest.raises(ValueError, match="rear_overhang|length"):
        VehicleParams(length=3.0, wheelbase=2.9, rear_overhang=0.5).validate()


def test_empty_obstacles_mean_nothing_in_the_way():
    t = jnp.linspace(0, 4, 20)
    obs = Obstacles.empty(t).validate()
    car = box_corners(jnp.array([0.0, 0, 4.8, 1.9, 0]))
    obs_c = box_corners(obs.boxes)  # (0, 20, 4, 2)
    hit = has_overlap(car, obs_c, None, None) if obs_c.shape[0] else jnp.zeros((0, 20), bool)
    assert hit.shape == (0, 20) and not bool(jnp.any(hit))
    Trajectory(*(jnp.zeros(5) for _ in range(9))).validate()


def test_box_separation_equals_polygon_separation(rng):
    with jax.enable_x64(True):
        a = np.stack([rng.uniform(-4, 4, 4000), rng.uniform(-4, 4, 4000), rng.uniform(0.5, 5, 4000),
                      rng.uniform(0.3, 3, 4000), rng.uniform(-4, 4, 4000)], -1)
        b = np.stack([rng.uniform(-4, 4, 4000), rng.uniform(-4, 4, 4000), rng.uniform(0.5, 5, 4000),
                      rng.uniform(0.3, 3, 4000), rng.uniform(-4, 4, 4000)], -1)
        fast = np.asarray(jp.geometry.box_separation(a, b))
        poly = np.asarray(separation(box_corners(a), box_corners(b)))
    np.testing.assert_allclose(fast, poly, atol=1e-9)
    assert (fast < 0).sum() > 500 and (fast > 0).sum() > 500
