"""Imitation baselines and the traffic helpers: constant velocity / acceleration in closed
form, the leader and the IDM against plain-Python loops, predicted collisions."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.geometry.frenet import reference_line
from jaxplan.tuning.baselines import CHUNK, chunks, collides, constant_acceleration, constant_velocity, idm, predict
from jaxplan.tuning.demos import Demo
from jaxplan.tuning.traffic import IDMParams, frenet_traffic, leader
from jaxplan.types import Obstacles
from idm_oracle import idm_step

T, K = 51, 4
t = np.arange(T) * 0.1


def _scene(v0, a0, cars, th=0.3, y_ref=0.0):
    """One demo on a straight road of heading ``th``: ``cars`` = [(s0, l, v)] moving along it."""
    u, n = np.array([np.cos(th), np.sin(th)]), np.array([-np.sin(th), np.cos(th)])
    s_ref = np.linspace(-10, 300, 96)
    ref = s_ref[:, None] * u + y_ref * n
    obs = np.tile([0.0, 0.0, 1.0, 1.0, 0.0], (K, T, 1))
    ok = np.zeros((K, T), bool)
    for k, (s0, l, v) in enumerate(cars):
        pos = (s0 + v * t)[:, None] * u + (l + y_ref) * n
        obs[k, :, :2], obs[k, :, 2:4], obs[k, :, 4] = pos, (4.5, 1.8), th
        ok[k] = True
    f = lambda x: jnp.asarray(x, jnp.float32)
    return Demo(f([0.0, 0.0, th, v0, a0]), f(ref), f(obs), jnp.asarray(ok), jnp.zeros(K, bool),
                f(np.zeros((T, 2))), f(np.zeros(T)), jnp.ones(T, bool), f(t))


def _batch(demos):
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *demos)


def test_constant_velocity_and_acceleration_in_closed_form():
    d = _batch([_scene(10.0, 1.0, []), _scene(6.0, -3.0, [])])
    cv, ca = np.asarray(constant_velocity(d)), np.asarray(constant_acceleration(d))
    u = np.array([np.cos(0.3), np.sin(0.3)])
    np.testing.assert_allclose(cv[0], np.outer(10 * t, u), atol=1e-4)
    np.testing.assert_allclose(ca[0], np.outer(10 * t + 0.5 * t * t, u), atol=1e-4)
    stop = 6.0 ** 2 / (2 * 3.0)  # 6 m/s at -3 m/s^2 stops after 2 s and 6 m, then stays
    s = np.where(t < 2.0, 6 * t - 1.5 * t * t, stop)
    np.testing.assert_allclose(ca[1], np.outer(s, u), atol=1e-4)


def _idm_loop(v0, s_lead0, v_lead, p: IDMParams, dt=0.1, length=4.8, lead_len=4.5):
    """Plain-Python IDM behind one car driving at constant speed (the oracle)."""
    s, v, out = 0.0, v0, [0.0]
    v_des = p.v_ratio * v0 + p.v_extra
    for k in range(T - 1):
        gap = s_lead0 + v_lead * k * dt - s - 0.5 * (length + lead_len) if s_lead0 < 1e5 else None
        s, v = idm_step(s, v, v_des, p, dt, gap, v_lead)
        out.append(s)
    return np.array(out)


def test_idm_follows_the_recorded_leader_like_a_loop():
    p = IDMParams(v_ratio=1.1, v_extra=2.0, headway=1.2, s_jam=2.0, a_max=1.0, b_comf=1.5)
    cases = [(12.0, [(25.0, 0.2, 8.0)]),                       # closing on a slower car
             (12.0, [(25.0, 3.5, 2.0), (60.0, -0.3, 14.0)]),    # the car in the next lane is not a leader
             (8.0, [])]                                          # free road
    d = _batch([_scene(v0, 0.0, cars) for v0, cars in cases])
    xy = predict(lambda x: idm(x, p), d)  # padded to the shape every run compiles
    u = np.array([np.cos(0.3), np.sin(0.3)])
    for i, (v0, cars) in enumerate(cases):
        lead = [c for c in cars if abs(c[1]) < 1.75]
        s0, vl = (lead[0][0], lead[0][2]) if lead else (1e9, 0.0)
        ref = _idm_loop(v0, s0, vl, p)
        np.testing.assert_allclose(xy[i] @ u, ref, atol=2e-3 * max(1.0, ref.max()))
    # a slower leader makes it brake; a free road makes it speed up
    assert (xy[0, -1] @ u) < 12.0 * 5 and (xy[2, -1] @ u) > 8.0 * 5


def test_leader_against_brute_force(rng):
    ref = reference_line(jnp.asarray(np.column_stack([np.linspace(-10, 200, 60), 0.02 * np.linspace(-10, 200, 60)])))
    boxes = np.zeros((6, T, 5))
    boxes[..., 0] = rng.uniform(0, 150, (6, 1)) + rng.uniform(0, 15, (6, 1)) * t
    boxes[..., 1] = 0.02 * boxes[..., 0] + rng.choice([-3.5, 0.0, 3.5], (6, 1)) + rng.normal(0, 0.3, (6, 1))
    boxes[..., 2] = rng.uniform(3, 6, (6, 1))
    boxes[..., 3] = 1.8
    valid = rng.uniform(size=(6, T)) < 0.9
    tr = jax.jit(frenet_traffic, static_argnums=2)(ref, Obstacles(jnp.asarray(boxes, jnp.float32), jnp.asarray(valid),
                                                                  jnp.asarray(t)), 0.1)
    s_q = rng.uniform(0, 150, (3, T)).astype(np.float32)
    l_q = rng.uniform(-2, 2, (3, T)).astype(np.float32)
    gap, vl, has = (np.asarray(x) for x in jax.jit(leader, static_argnums=(3, 4))(tr, jnp.asarray(s_q),
                                                                                   jnp.asarray(l_q), 4.8, 1.75))
    ts, tl, tv, tlen = (np.asarray(x) for x in (tr.s, tr.l, tr.v, tr.length))
    for q in range(3):
        for k in range(T):
            best = None
            for j in range(6):
                if valid[j, k] and ts[j, k] > s_q[q, k] and abs(tl[j, k] - l_q[q, k]) < 1.75:
                    g = ts[j, k] - s_q[q, k] - 0.5 * (tlen[j, k] + 4.8)
                    if best is None or g < best[0]:
                        best = (g, tv[j, k])
            assert has[q, k] == (best is not None)
            if best:
                assert gap[q, k] == pytest.approx(best[0], abs=1e-4) and vl[q, k] == pytest.approx(best[1], abs=1e-4)
    # speeds along the line: the cars drive at their recorded speeds (projected on the line)
    inner = valid[:, :-2] & valid[:, 1:-1] & valid[:, 2:]
    speed = np.hypot(np.diff(boxes[..., 0], axis=1), np.diff(boxes[..., 1], axis=1)) / 0.1
    np.testing.assert_allclose(tv[:, 1:-1][inner], speed[:, 1:][inner], rtol=0.01, atol=0.05)


def test_predicted_collisions():
    d = _batch([_scene(15.0, 0.0, [(30.0, 0.0, 0.0)]),   # constant velocity runs into a stopped car
                _scene(15.0, 0.0, [(30.0, 3.5, 0.0)])])  # ... which is in the next lane here
    pad = lambda d: next(chunks(d, CHUNK))[0]  # the compiled shape of every run
    hit = np.asarray(collides(constant_velocity(pad(d)), pad(d)))[:2]
    assert hit.tolist() == [True, False]
    # a static obstacle recorded for one step only is still there later
    d1 = jax.tree_util.tree_map(lambda x: x[:1], d)
    d1 = dataclasses.replace(d1, obstacle_valid=d1.obstacle_valid.at[:, :, 1:].set(False),
                             obstacle_static=d1.obstacle_static.at[:, 0].set(True))
    assert bool(collides(constant_velocity(pad(d1)), pad(d1))[0])
