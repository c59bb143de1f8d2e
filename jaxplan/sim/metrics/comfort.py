"""``comfort``: what the car did, from the driven states (finite differences, not the plans'
claims): longitudinal acceleration ``dv/dt``, jerk ``d^2 v / dt^2``, lateral acceleration
``v dtheta/dt`` and curvature ``dtheta/ds`` (over steps that move at least ``MIN_STEP`` m); and what
the road asks: ``lat_accel_floor``, the largest ``v^2 |kappa|`` along the route's centre line
ahead of the first state when the car brakes at ``EMERGENCY_DECEL`` from there (a drive whose
floor is above a lateral limit cannot keep that limit on the centre line)."""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.frenet import to_frenet
from jaxplan.planner import EMERGENCY_DECEL
from jaxplan.sim.metrics.registry import register_metric

MIN_STEP = 0.05


@register_metric("comfort")
def comfort(log, scene, vehicle):
    dt = scene.dt
    ok2 = log.valid[1:] & log.valid[:-1]
    acc = jnp.diff(log.v) / dt
    jerk = jnp.diff(acc) / dt
    dth = jnp.diff(jnp.unwrap(log.heading))
    ds = jnp.sqrt(jnp.diff(log.x) ** 2 + jnp.diff(log.y) ** 2)
    vm = 0.5 * (log.v[1:] + log.v[:-1])
    lat = vm * dth / dt
    moving = ok2 & (ds > MIN_STEP)
    kappa = jnp.where(moving, dth / jnp.maximum(ds, MIN_STEP), 0.0)
    mx = lambda a, m: jnp.max(jnp.where(m, jnp.abs(a), 0.0), initial=0.0)
    s0, _ = to_frenet(scene.route, jnp.stack([log.x[0], log.y[0]]))
    ahead = scene.route.s - s0
    v2 = jnp.maximum(log.v[0] ** 2 - 2.0 * EMERGENCY_DECEL * ahead, 0.0)
    here = log.v[0] ** 2 * jnp.abs(jnp.interp(s0, scene.route.s, scene.route.kappa))
    return {
        "max_abs_accel": mx(acc, ok2),
        "min_accel": jnp.min(jnp.where(ok2, acc, 0.0), initial=0.0),
        "max_abs_jerk": mx(jerk, ok2[1:] & ok2[:-1]),
        "max_abs_lat_accel": mx(lat, ok2),
        "max_abs_curvature": mx(kappa, moving),
        "lat_accel_floor": jnp.maximum(mx(v2 * scene.route.kappa, ahead >= 0.0), here),
    }
