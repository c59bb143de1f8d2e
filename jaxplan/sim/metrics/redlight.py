"""``redlight``: stop lines the car crossed against the light.

The car's front (the middle of its front bumper, from the box centre along its heading) crosses
a stop line between two logged steps when the segment it moves along meets the line (extended by
``LINE_MARGIN`` at both ends: lights govern the whole lane). A crossing counts when the line's
governing light (``Scene.lights``, ``jaxplan.scenarios.lights``) forbids crossing at the step the
front is past it: red or red-yellow. Yellow, green and an inactive light let the car through.

Figures: ``crossings`` (how many stop lines were crossed against the light), ``crossed`` (any),
``first_step`` (the step at which the first such crossing ends, -1 without one).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.scenarios.lights import LINE_MARGIN, colors_at, must_stop
from jaxplan.sim.metrics.registry import register_metric


def line_crossings(a, b, line):
    """``(N, NL)`` bool: the segments ``a -> b`` (``(N, 2)`` each) meet the lines ``(NL, 2, 2)``
    (each extended by ``LINE_MARGIN`` at both ends)."""
    p, q = line[:, 0], line[:, 1]  # (NL, 2)
    u = q - p
    u = u / jnp.maximum(jnp.linalg.norm(u, axis=-1, keepdims=True), 1e-9)
    p, q = p - LINE_MARGIN * u, q + LINE_MARGIN * u

    def side(o, e, x):  # sign of the cross product (e - o) x (x - o)
        return (e[..., 0] - o[..., 0]) * (x[..., 1] - o[..., 1]) - (e[..., 1] - o[..., 1]) * (x[..., 0] - o[..., 0])

    a, b = a[:, None, :], b[:, None, :]
    s1, s2 = side(p, q, a), side(p, q, b)  # the car's path against the line
    s3, s4 = side(a, b, p), side(a, b, q)  # the line against the car's path
    return (s1 * s2 <= 0) & (s3 * s4 <= 0) & ((s1 != 0) | (s2 != 0))


@register_metric("redlight")
def redlight(log, scene, vehicle):
    lights = scene.lights
    f = log.x.dtype
    if lights is None or lights.s.shape[-1] == 0:  # static: no stop lines on the route
        return {
            "crossings": jnp.asarray(0, jnp.int32),
            "crossed": jnp.asarray(False),
            "first_step": jnp.asarray(-1, jnp.int32),
        }
    u = jnp.stack([jnp.cos(log.heading), jnp.sin(log.heading)], -1)
    front = jnp.stack([log.x, log.y], -1) + 0.5 * jnp.asarray(vehicle.length, f) * u  # (N, 2)
    N = front.shape[0]
    hit = line_crossings(front[:-1], front[1:], jnp.asarray(lights.line, f))  # (N - 1, NL)
    red = must_stop(colors_at(lights, jnp.arange(1, N)))  # (N - 1, NL), the step the front is past
    moved = log.valid[1:] & log.valid[:-1]
    bad = hit & red & moved[:, None] & jnp.asarray(lights.valid)[None]
    per_line = jnp.any(bad, axis=0)
    any_step = jnp.any(bad, axis=1)
    crossed = jnp.any(per_line)
    return {
        "crossings": jnp.sum(per_line).astype(jnp.int32),
        "crossed": crossed,
        "first_step": jnp.where(crossed, jnp.argmax(any_step) + 1, -1).astype(jnp.int32),
    }
