"""Property-based tests (hypothesis) of the geometry core: invariances and robust input handling."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxplan.geometry import (ReferenceLine, box_corners, box_separation, headings_from_path, overlap_area,
                              separation, to_cartesian, to_frenet)

_sep = jax.jit(separation)
_area = jax.jit(overlap_area)
finite = st.floats(-50, 50, allow_nan=False, width=32)
size = st.floats(0.125, 8, allow_nan=False, width=32)
angle = st.floats(-7, 7, allow_nan=False, width=32)
box = st.tuples(finite, finite, size, size, angle)
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(box, box, finite, finite, angle)
def test_rigid_motion_invariance_and_symmetry(a, b, tx, ty, rot):
    a, b = np.array(a, np.float64), np.array(b, np.float64)
    with jax.enable_x64(True):
        ca, cb = box_corners(a), box_corners(b)
        s_ab, s_ba = float(_sep(ca, cb)), float(_sep(cb, ca))
        R = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
        move = lambda c: np.asarray(c) @ R.T + [tx, ty]
        s_moved = float(_sep(move(ca), move(cb)))
        area, area_moved = float(_area(ca, cb)), float(_area(move(ca), move(cb)))
        s_box = float(box_separation(a, b))
    assert s_ab == pytest.approx(s_ba, abs=1e-9)
    assert s_moved == pytest.approx(s_ab, abs=1e-7)
    assert s_box == pytest.approx(s_ab, abs=1e-9)
    assert area_moved == pytest.approx(area, abs=1e-7)
    assert 0 <= area <= min(a[2] * a[3], b[2] * b[3]) + 1e-9
    assert (area > 1e-9) <= (s_ab < 1e-9)  # positive area only when overlapping


@SETTINGS
@given(st.lists(st.tuples(finite, finite), min_size=1, max_size=12))
def test_headings_any_path_finite(points):
    xy = np.array(points, np.float32)
    h = np.asarray(headings_from_path(xy))
    assert h.shape == (len(points),) and np.all(np.isfinite(h)) and np.all(np.abs(h) <= np.pi + 1e-6)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(finite, finite), min_size=2, max_size=6), finite, finite)
def test_reference_line_any_polyline(points, px, py):
    xy = np.array(points, np.float64)
    try:
        ref = ReferenceLine.from_polyline(xy)
    except ValueError as e:  # refused with a reason: repeated points or a cusp
        assert "two distinct" in str(e) or "turns back" in str(e)
        return
    s, l = to_frenet(ref, jnp.array([px, py], jnp.float32))
    assert np.isfinite(float(s)) and np.isfinite(float(l))
    # Points on the line map back to themselves.
    s2, l2 = to_frenet(ref, ref.xy)
    assert np.all(np.abs(np.asarray(l2)) < 1e-3)
    np.testing.assert_allclose(np.asarray(to_cartesian(ref, s2, l2)), np.asarray(ref.xy), atol=1e-3)


def test_reference_line_refuses_cusps():
    with pytest.raises(ValueError, match="turns back"):
        ReferenceLine.from_polyline(np.array([[32.0, 0], [0, 0], [1, 0]]))


@pytest.mark.parametrize("far", [1e6, -2e6])
def test_far_coordinates_error_in_float32_and_work_in_x64(far):
    b = np.array([[far, far, 4.0, 2.0, 0.1], [far + 3.0, far, 4.0, 2.0, 0.1]])
    with pytest.raises(ValueError, match="too far from the origin"):
        box_corners(b)
    with jax.enable_x64(True):
        c = box_corners(b)
        near = box_corners(b - [far, far, 0, 0, 0])  # the same pair at the origin
        assert float(separation(c[0], c[1])) == pytest.approx(float(separation(near[0], near[1])), abs=1e-6)


def test_many_obstacles_one_call():
    rng = np.random.default_rng(3)
    obs = np.column_stack([rng.uniform(-100, 100, (10_000, 2)), np.full(10_000, 4.0), np.full(10_000, 2.0),
                           rng.uniform(-3, 3, 10_000)])
    car = np.array([0.0, 0.0, 4.8, 1.9, 0.0])
    s = np.asarray(jax.jit(box_separation)(car, obs))
    brute = np.asarray(separation(box_corners(car), box_corners(obs)))
    assert s.shape == (10_000,)
    np.testing.assert_allclose(s, brute, atol=1e-4, rtol=1e-5)  # float32 at 100 m
