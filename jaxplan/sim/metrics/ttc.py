"""``ttc``: the smallest time to collision over the drive. At every step the car (along its
heading at its speed) and every obstacle ahead of it or static (at its velocity from the
recording) are extrapolated at constant velocity; the TTC is the first of the times
``0, TTC_STEP, ..., TTC_MAX`` at which their boxes overlap (``inf`` when none does)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_separation
from jaxplan.sim.metrics.overlap import car_boxes
from jaxplan.sim.metrics.registry import register_metric

TTC_STEP = 0.1
TTC_MAX = 3.0


@register_metric("ttc")
def ttc(log, scene, vehicle):
    N = log.x.shape[0]
    obs = scene.obstacles.window(0, N + 1)
    b = obs.boxes  # (K, N + 1, 5)
    vel = jnp.where((obs.valid[:, 1:] & obs.valid[:, :-1])[..., None], (b[:, 1:, :2] - b[:, :-1, :2]) / scene.dt, 0.0)
    vel = jnp.where(obs.static[:, None, None], 0.0, vel)  # (K, N, 2)
    car = car_boxes(log, vehicle)  # (N, 5)
    u = jnp.stack([jnp.cos(log.heading), jnp.sin(log.heading)], -1)
    taus = jnp.arange(int(round(TTC_MAX / TTC_STEP)) + 1, dtype=log.x.dtype) * TTC_STEP
    rel = b[:, :N, :2] - car[None, :, :2]
    relevant = obs.valid[:, :N] & (obs.static[:, None] | (jnp.sum(rel * u[None], -1) > 0)) & log.valid[None]

    def at(tau):
        c = car.at[:, :2].add(tau * log.v[:, None] * u)
        o = b[:, :N].at[..., :2].add(tau * vel)
        return jnp.any(relevant & (box_separation(c[None], o) < 0), axis=0)  # (N,)

    hit = jax.vmap(at)(taus)  # (S, N)
    first = jnp.where(jnp.any(hit, 0), taus[jnp.argmax(hit, 0)], jnp.inf)
    return {"min_ttc": jnp.min(first)}
