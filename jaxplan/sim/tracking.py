"""How the simulated car follows a plan between re-plans.

- ``exact``: the car is where the plan says at every step (perfect tracking, as CommonRoad
  benchmarks and the peers' own examples drive).
- ``bicycle``: a kinematic bicycle (rear-axle reference) steered by pure pursuit towards
  the plan's path a look-ahead distance ahead, with the plan's acceleration plus a speed
  feedback; steering clipped to the car's limit, ``substeps`` Euler steps per ``dt``. It
  shows that the plans are trackable by a car.

Both take the state at the plan's start and return the states at the next ``K`` steps.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from jaxplan.planner import EgoState
from jaxplan.types import Trajectory, VehicleParams


def _rear_offset(vehicle: VehicleParams):
    """Distance from the reference point forward to the rear axle."""
    return vehicle.center_offset - (0.5 * vehicle.length - vehicle.rear_overhang)


def track_exact(plan: Trajectory, ego: EgoState, n: int, vehicle: VehicleParams, config) -> EgoState:
    """States ``(n,)`` at plan indices ``1..n``."""
    k = jnp.arange(1, n + 1)
    return EgoState.at(plan, k)


def track_bicycle(plan: Trajectory, ego: EgoState, n: int, vehicle: VehicleParams, config) -> EgoState:
    """States ``(n,)`` of a kinematic bicycle following ``plan`` for ``n`` steps of ``config.dt``."""
    f = plan.x.dtype
    L = jnp.asarray(vehicle.wheelbase, f)
    ro = jnp.asarray(_rear_offset(vehicle), f)
    # the plan's path at the rear axle
    px = plan.x + ro * jnp.cos(plan.theta)
    py = plan.y + ro * jnp.sin(plan.theta)
    seg = jnp.sqrt(jnp.diff(px) ** 2 + jnp.diff(py) ** 2)
    ps = jnp.concatenate([jnp.zeros((1,), f), jnp.cumsum(seg)])
    max_steer = jnp.asarray(vehicle.max_steer, f)
    sub = config.substeps
    h = config.dt / sub

    def control(x, y, th, v, k):
        d2 = (px - x) ** 2 + (py - y) ** 2
        i = jnp.argmin(d2)
        ld = jnp.maximum(config.min_lookahead, config.lookahead_time * v)
        j = jnp.clip(jnp.searchsorted(ps, ps[i] + ld), 0, ps.shape[0] - 1)
        dx, dy = px[j] - x, py[j] - y
        dist = jnp.maximum(jnp.sqrt(dx * dx + dy * dy), 1e-3)
        alpha = jnp.arctan2(dy, dx) - th
        steer = jnp.clip(jnp.arctan2(2.0 * L * jnp.sin(alpha), dist), -max_steer, max_steer)
        kk = jnp.clip(k, 0, plan.v.shape[0] - 1)
        acc = plan.a[kk] + config.speed_gain * (plan.v[kk] - v)
        return steer, acc

    def step(carry, k):
        x, y, th, v = carry

        def substep(c, q):
            x, y, th, v = c
            steer, acc = control(x, y, th, v, k)
            acc = jnp.maximum(acc, -v / h)  # stop, never reverse
            x = x + v * jnp.cos(th) * h
            y = y + v * jnp.sin(th) * h
            th = th + v * jnp.tan(steer) / L * h
            v = v + acc * h
            return (x, y, th, v), (acc, jnp.tan(steer) / L)

        (x, y, th, v), (acc, kap) = lax.scan(substep, (x, y, th, v), jnp.arange(sub))
        return (x, y, th, v), (x, y, th, v, acc[-1], kap[-1])

    x0 = ego.x + ro * jnp.cos(ego.heading)
    y0 = ego.y + ro * jnp.sin(ego.heading)
    _, (x, y, th, v, a, kap) = lax.scan(
        step, (x0, y0, jnp.asarray(ego.heading, f), jnp.asarray(ego.v, f)), jnp.arange(n)
    )
    return EgoState(x - ro * jnp.cos(th), y - ro * jnp.sin(th), th, v, a, kap)


TRACKERS = {"exact": track_exact, "bicycle": track_bicycle}
