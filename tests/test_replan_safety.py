"""The safety layer every strategy shares, one rule per test, through the real ``supervise`` /
``submit`` path on small hand-made plans (one compiled tick for every test):

* a new plan is checked before it is installed, and the old one kept when the new one collides;
* the collision-point queue and the brake-stop point survive a re-plan (re-anchored on the new plan);
* a re-plan while moving starts ahead on the old plan, and its plan arrives after the latency;
* a plan that would change gear before the moving car can stop is refused;
* collision points are time-aware: a crossing pedestrian counts where it will be.
"""
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.replan import (PERIODIC, REJECT_COLLISION, REJECT_GEAR, CarState, MotionLimits, Perception,
                            SupervisorConfig, finish_plan, submit, supervise)
from jaxplan.replan import supervisor as S
from jaxplan.types import VehicleParams

CFG = SupervisorConfig()
VEH = VehicleParams()
N, K = 40, 2
GOAL = jnp.array([19.5, 0.0, 0.0])


def line(y0=0.0, heading=0.0, gear=1, ds=0.5, v0=0.0, x0=0.0):
    """A straight plan of ``N`` points from ``(x0, y0)`` along ``heading`` (driven in ``gear``)."""
    u = np.arange(N) * ds
    d = np.array([np.cos(heading), np.sin(heading)]) * (1 if gear > 0 else -1)
    xy = np.array([x0, y0]) + u[:, None] * d
    return finish_plan(jnp.asarray(xy, jnp.float32), jnp.full((N,), heading, jnp.float32),
                       jnp.full((N,), gear, jnp.int32), jnp.ones((N,), bool), jnp.asarray(v0, jnp.float32),
                       CFG.limits, True)


@functools.lru_cache(maxsize=None)
def _tick():
    return jax.jit(supervise, static_argnums=(7, 8))


def tick(state, s, v, t, per=None, strategy=PERIODIC):
    plan = state.plan
    p, h, _ = S.interpolate_pose(plan.traj.xy, plan.traj.theta, plan.s_abs, jnp.asarray(s, jnp.float32))
    car = CarState(jnp.concatenate([p, h[None]]), jnp.asarray(v, jnp.float32), jnp.asarray(s, jnp.float32))
    per = empty() if per is None else per
    return _tick()(state, car, per, GOAL, jnp.asarray(t, jnp.float32), jnp.asarray(strategy), jnp.asarray(False),
                   CFG, VEH)


def empty():
    return Perception(jnp.zeros((K, 5)), jnp.zeros((K, 2)), jnp.zeros((K,), bool))


def seen(*boxes, vel=None):
    b = np.zeros((K, 5), np.float32)
    v = np.zeros((K, 2), np.float32)
    m = np.zeros(K, bool)
    for i, x in enumerate(boxes):
        b[i], m[i] = x, True
        if vel is not None:
            v[i] = vel[i]
    return Perception(jnp.asarray(b), jnp.asarray(v), jnp.asarray(m))


@functools.lru_cache(maxsize=None)
def installed_a():
    """State with plan A (straight along y = 0) installed at t = 0.3, the car standing at s = 0."""
    st = S.init(line(), jnp.zeros(3), GOAL, K, CFG, VEH)
    st, dec = tick(st, 0.0, 0.0, 0.1)
    assert bool(dec.replan)
    st = submit(st, line(), dec)
    st, dec = tick(st, 0.0, 0.0, 0.2)
    assert not bool(dec.installed)  # not before the latency
    st, dec = tick(st, 0.0, 0.0, 0.3)
    assert bool(dec.installed)
    return st


def ask_and_deliver(st, plan, s, v, t, per=None, per_at_arrival=None, ds_latency=0.0):
    """A periodic re-plan at ``t`` (the car at ``s`` with speed ``v``), answered with ``plan``;
    the ticks until it arrives. Returns (state, the arrival tick's decision, the request)."""
    st, dec = tick(st, s, v, t, per)
    assert bool(dec.replan)
    req = dec.request
    st = submit(st, plan, dec)
    lat = int(round(CFG.latency_s / CFG.dt))  # the plan arrives this many ticks later, not earlier
    assert lat >= 2
    for j in range(1, lat + 1):
        st, d = tick(st, s + ds_latency * j / lat, v, t + j * CFG.dt, per_at_arrival if j == lat else per)
        assert bool(d.installed | d.rejected.any()) == (j == lat)
    return st, d, req


def test_a_colliding_new_plan_is_refused_and_the_old_one_kept():
    st = installed_a()
    old_end = float(st.plan.traj.y[int(st.plan.valid.sum()) - 1])
    box = seen([6.0, 1.0, 1.0, 1.0, 0.0])  # beside plan A (y = 0), on plan B (heading up-left)
    b = line(heading=0.15)
    st2, d, _ = ask_and_deliver(st, b, 0.0, 0.0, 1.4, per=box, per_at_arrival=box)
    assert bool(d.rejected[REJECT_COLLISION]) and not bool(d.installed)
    assert float(st2.plan.traj.y[int(st2.plan.valid.sum()) - 1]) == pytest.approx(old_end)
    # The same plan is installed when the way is clear.
    st3, d, _ = ask_and_deliver(st, b, 0.0, 0.0, 1.4)
    assert bool(d.installed)
    assert float(st3.plan.traj.y[int(st3.plan.valid.sum()) - 1]) > 2.0


def test_queue_and_brake_stop_survive_a_replan():
    st = installed_a()
    ph = seen([10.0, 0.0, 0.8, 0.8, 0.0])  # a phantom on plan A
    st, dec = tick(st, 0.0, 0.0, 0.4, ph)
    assert bool(dec.new_collision) and bool(st.brake.active)
    brake_a = float(st.brake.s)
    # The phantom is gone; a re-plan brings plan B (the same road, a little to the left).
    b = line(y0=0.0, heading=0.01)
    st, d, _ = ask_and_deliver(st, b, 0.0, 0.0, 1.4)
    assert bool(d.installed)
    assert int(st.queue.valid.sum()) >= 1
    assert bool(st.brake.active)  # re-anchored where the remembered phantom meets plan B
    assert float(st.brake.s) == pytest.approx(brake_a, abs=0.3)
    assert float(d.stop_s) == pytest.approx(float(st.brake.s), abs=1e-5)
    # The entries expire as before: 2 s after they were seen, the brake is released.
    st, d = tick(st, 0.0, 0.0, 2.5)
    assert not bool(st.brake.active) and int(st.queue.valid.sum()) == 0


def _law(s, v, steps, lim: MotionLimits, dt, vmax):
    """The car's law written out: accelerate at ``accel`` up to ``vmax`` (no stop point near)."""
    for _ in range(steps):
        v = min(v + lim.accel * dt, vmax)
        s += v * dt
    return s, v


def test_a_replan_while_moving_starts_ahead_after_the_latency():
    st = installed_a()
    s0, v0 = 3.0, 2.0
    st2, d, req = ask_and_deliver(st, line(x0=3.43, v0=2.2), s0, v0, 1.4, ds_latency=0.43)
    s_ref, v_ref = _law(s0, v0, int(round(CFG.latency_s / CFG.dt)), CFG.limits, CFG.dt, CFG.limits.v_fwd)
    assert float(req.start[0]) == pytest.approx(s_ref, abs=1e-4)  # the point ahead on plan A
    assert float(req.speed) == pytest.approx(v_ref, abs=1e-4)
    assert bool(d.installed)
    # The car keeps its place: the installed plan begins with the stretch it drove meanwhile.
    assert float(st2.plan.traj.x[0]) == pytest.approx(s0, abs=1e-4)
    assert float(d.s_offset) == pytest.approx(s0, abs=1e-4)


def test_a_gear_change_before_the_moving_car_can_stop_is_refused():
    st = installed_a()
    s0, v0 = 3.0, 2.0
    rev = line(x0=3.43, gear=-1)  # reverse right from the stitch point
    st2, d, _ = ask_and_deliver(st, rev, s0, v0, 1.4, ds_latency=0.43)
    assert bool(d.rejected[REJECT_GEAR]) and not bool(d.installed)
    # From a standstill the same change of gear is fine.
    st3, d, _ = ask_and_deliver(st, line(x0=0.0, gear=-1), 0.0, 0.0, 1.4)
    assert bool(d.installed) and int(st3.dirs[st3.k]) in (1, -1)


def test_collision_points_are_time_aware():
    st = installed_a()
    # The car drives at 3 m/s; the pedestrians walk across plan A at x = 15 (car front there in ~3.7 s).
    gone = seen([15.0, -1.0, 0.6, 0.6, np.pi / 2], vel=[[0.0, 1.3]])  # crosses long before the car comes
    st1, d = tick(st, 0.0, 3.0, 0.4, gone)
    assert not bool(d.new_collision)
    meet = seen([15.0, -5.5, 0.6, 0.6, np.pi / 2], vel=[[0.0, 1.3]])  # on the path when the car gets there
    st2, d = tick(st, 0.0, 3.0, 0.4, meet)
    assert bool(d.new_collision) and bool(st2.brake.active)
    still = seen([15.0, -5.5, 0.6, 0.6, np.pi / 2], vel=[[0.0, 0.0]])  # standing off the path
    _, d = tick(st, 0.0, 3.0, 0.4, still)
    assert not bool(d.new_collision)
