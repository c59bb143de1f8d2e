"""Planners at their public boundary: bad input gets a clear ValueError; empty and huge
obstacle sets, duplicate points and far-away scenes give correct results."""
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.lattice import LatticeConfig, PlanState, plan
from jaxplan.types import Obstacles

CFG = LatticeConfig(escalation=(1.0,), horizon=3.0)
T = CFG.n_steps


def _ref(n=60, dup=False):
    x = np.linspace(-10, 150, n)
    xy = np.column_stack([x, np.zeros(n)])
    if dup:  # repeated points are dropped by the constructor
        xy = np.repeat(xy, 2, axis=0)
    return ReferenceLine.from_polyline(xy)


def _obstacles(K, rng=None, x0=30.0):
    t = jnp.arange(T) * CFG.dt
    if K == 0:
        return Obstacles.empty(t)
    rng = rng or np.random.default_rng(0)
    b = np.zeros((K, T, 5), np.float32)
    b[..., 0] = x0 + rng.uniform(0, 500, (K, 1))
    b[..., 1] = rng.choice([-3.5, 3.5], (K, 1)) + rng.uniform(-0.3, 0.3, (K, 1))
    b[..., 2:4] = [4.5, 1.8]
    return Obstacles(jnp.asarray(b), jnp.ones((K, T), bool), t)


def test_lattice_rejects_bad_state_and_obstacles():
    with pytest.raises(ValueError, match="PlanState"):
        PlanState.make(0.0, float("nan"), 0.0, 10.0)
    with pytest.raises(ValueError):
        PlanState.make(0.0, 0.0, 0.0, -1.0)
    bad = _obstacles(3)
    bad = Obstacles(bad.boxes.at[0, 0, 2].set(-1.0), bad.valid, bad.t)
    with pytest.raises(ValueError):
        plan(PlanState.make(0.0, 0.0, 0.0, 10.0), _ref(), bad, CFG)
    with pytest.raises(ValueError):
        ReferenceLine.from_polyline(np.zeros((5, 2)))  # zero-length path


def test_lattice_empty_equals_far_obstacles_and_huge_sets_work():
    st = PlanState.make(0.0, 0.0, 0.0, 10.0)
    empty = plan(st, _ref(), _obstacles(0), CFG)
    assert not np.asarray(empty.collided).any()
    # Obstacles far beyond the horizon change nothing.
    far = plan(st, _ref(), _obstacles(50, x0=400.0), CFG)
    assert int(far.chosen) == int(empty.chosen)
    np.testing.assert_array_equal(np.asarray(far.collided), np.asarray(empty.collided))
    # 10,000 obstacles, one of them half in the lane ahead: found, and the chosen candidate avoids it.
    big = _obstacles(10_000, x0=400.0)
    boxes = big.boxes.at[0, :, :].set(jnp.array([25.0, 1.9, 4.5, 1.8, 0.0]))
    res = plan(st, _ref(), Obstacles(boxes, big.valid, big.t), CFG)
    assert np.asarray(res.collided).any() and not bool(res.collided[int(res.chosen)])
    # Duplicate reference points give the same plan.
    dup = plan(st, _ref(dup=True), _obstacles(0), CFG)
    np.testing.assert_allclose(np.asarray(dup.candidates.traj.x), np.asarray(empty.candidates.traj.x), atol=1e-4)


def test_lattice_far_from_origin_needs_a_local_frame():
    xy = np.column_stack([np.linspace(0, 100, 30) + 1e6, np.full(30, 1e6)])
    with pytest.raises(ValueError, match="local frame"):
        ReferenceLine.from_polyline(xy)
