"""The ``pathspeed`` planner in closed loop on built-in scenes that in-lane braking survives:
no collision of its own, the driven accelerations within the limits, the trajectory from the
car's state, parity of the batched plan with the simulator's, and the path stand-in."""
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.plan_context import road_context
from jaxplan.planner import EgoState, make_planner
from jaxplan.speed import SpeedConfig
from jaxplan.speed.planner import PathSpeedPlanner, route_path

KINDS = ("stopped_car", "slow_leader", "cut_in", "dense_next_lane")
STEPS = 90  # 9 s


@functools.lru_cache(maxsize=None)
def _drives():
    """Four survivable built-in scenes (one per kind) and one shared jitted rollout."""
    from jaxplan.scenarios.builtin import builtin_dicts
    from jaxplan.scenarios.loader import parse_scenario
    from jaxplan.scenarios.scene import build_scene, stack_scenes
    from jaxplan.sim.metrics.registry import evaluate_batch
    from jaxplan.sim.rollout import SimConfig, rollout

    dicts = builtin_dicts(1, seed=3, kinds=KINDS)
    scenes = [build_scene(parse_scenario(d, d["id"]))[0] for d in dicts]
    cfg = SimConfig(n_steps=STEPS)
    batch = stack_scenes(scenes, min_steps=STEPS + 80)
    planner = make_planner("pathspeed")
    log = rollout(planner, batch, cfg)
    metrics = {k: np.asarray(v) for k, v in evaluate_batch(log, batch, planner.vehicle).items()}
    return planner, batch, log, metrics


def test_closed_loop_is_safe_and_within_the_limits():
    planner, batch, log, m = _drives()
    assert not m["overlap.at_fault"].any()
    assert not m["overlap.collided"].any()
    # the drive metric differentiates the driven states: the executed profile's limits hold
    cfg = planner.speed
    assert np.all(m["comfort.max_abs_accel"] <= -cfg.a_brake + 0.05)
    assert np.all(m["comfort.max_abs_accel"] <= 8.0)
    assert np.all(m["progress.route_m"] > 10.0)  # it drives (a stopped car ahead stops it later)
    assert np.mean(np.asarray(log.plan_ok)) > 0.8
    assert not np.asarray(log.fallback).any()


def test_plan_starts_at_the_car_and_matches_the_simulator():
    planner, batch, log, _ = _drives()
    ego = jax.vmap(lambda s: EgoState.from_box_centre(s.start, planner.vehicle))(batch)
    out = jax.jit(jax.vmap(lambda s, e: planner.plan(s, e, 0)))(batch, ego)
    tr = out.trajectory
    H = planner.horizon_steps
    assert tr.x.shape == (len(KINDS), H)
    assert np.allclose(tr.t[:, 1] - tr.t[:, 0], planner.dt)
    assert np.allclose(tr.x[:, 0], ego.x, atol=1e-3) and np.allclose(tr.y[:, 0], ego.y, atol=1e-3)
    assert np.allclose(tr.v[:, 0], ego.v, atol=1e-4)
    dh = np.angle(np.exp(1j * (np.asarray(tr.theta[:, 0]) - np.asarray(ego.heading))))
    assert np.all(np.abs(dh) < 1e-3)
    assert np.all(np.asarray(tr.v) >= 0) and np.all(np.diff(np.asarray(tr.s), axis=1) >= -1e-4)
    # exact tracking: the simulator drove the plan made at step 0 for its first three steps
    c = EgoState(tr.x[:, 1:4], tr.y[:, 1:4], tr.theta[:, 1:4], tr.v[:, 1:4]).box_centre(planner.vehicle)
    assert np.allclose(np.asarray(log.x[:, 1:4]), np.asarray(c[..., 0]), atol=1e-3)
    assert np.allclose(np.asarray(log.v[:, 1:4]), np.asarray(tr.v[:, 1:4]), atol=1e-4)
    assert set(out.info) >= {"dp_feasible", "qp_ok", "no_bypass", "blocking", "behind"}


@functools.partial(jax.jit, static_argnums=2)
def _path_at(sc, ego, planner):
    ctx = road_context(sc, ego, 0, planner.horizon_steps, planner.vehicle)
    return ctx, route_path(sc, ctx, ego)


def test_route_path_joins_the_route_from_the_car():
    planner, batch, _, _ = _drives()
    sc = jax.tree_util.tree_map(lambda x: x[2], batch)
    e0 = EgoState.from_box_centre(sc.start, planner.vehicle)
    ego = EgoState(e0.x - 0.8 * jnp.sin(e0.heading), e0.y + 0.8 * jnp.cos(e0.heading), e0.heading + 0.05, e0.v)
    ctx, path = _path_at(sc, ego, planner)
    i0 = int(np.argmin(np.abs(np.asarray(path.s))))
    assert float(path.s[i0]) == 0.0
    assert np.allclose(np.asarray(path.xy[i0]), [float(ego.x), float(ego.y)], atol=1e-3)
    assert float(path.theta[i0]) == pytest.approx(float(ego.heading), abs=1e-4)
    assert float(path.l[i0]) == pytest.approx(float(ctx.l), abs=1e-6)
    far = np.asarray(path.s) > 70.0
    assert np.all(np.abs(np.asarray(path.l)[far]) < 1e-4)  # on the route's centre line


def test_config_checks_and_nonblocking_switch():
    with pytest.raises(ValueError, match="horizon"):
        PathSpeedPlanner(horizon=5.0)
    with pytest.raises(ValueError, match="weights"):
        PathSpeedPlanner(weights=(1.0, 2.0))
    with pytest.raises(ValueError, match="qp_dt"):
        PathSpeedPlanner(speed=SpeedConfig(qp_dt=0.3))
    w = PathSpeedPlanner(nonblocking=False).cost_weights(jnp.float32(10.0))
    assert float(w.w_blind) == 0.0 and float(w.w_no_bypass) == 0.0 and float(w.v_cruise) == 10.0
    w = PathSpeedPlanner().cost_weights(jnp.float32(10.0))
    assert float(w.w_blind) > 0.0 and float(w.w_no_bypass) > 0.0
