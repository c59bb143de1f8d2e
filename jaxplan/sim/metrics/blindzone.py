"""``blindzone``: time the car spends in a moving neighbour's blind zone.

A vehicle's blind zone is the strip beside it that its driver sees in neither the mirror nor
the side window: on either side, from ``ZONE_GAP`` m off its side to ``ZONE_GAP + ZONE_WIDTH``
m, along its heading from ``BLIND_BACK`` m behind its rear bumper to ``BLIND_FRONT`` m ahead
of it (the path-speed planner's non-blocking boundaries keep out of the same zone:
``jaxplan.speed.SpeedConfig.blind_back / blind_front``). The car is in it at a step when its
box overlaps the zone of an obstacle moving faster than ``MOVING`` m/s (from its boxes one
step apart), by the geometry core's SAT test.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxplan.geometry.boxes import box_has_overlap
from jaxplan.sim.metrics.overlap import MOVING, car_boxes
from jaxplan.sim.metrics.registry import register_metric

BLIND_BACK = 4.0  # m behind the neighbour's rear bumper
BLIND_FRONT = 1.0  # m ahead of it
ZONE_GAP = 0.5  # m from the neighbour's side to the zone
ZONE_WIDTH = 3.0  # m


def blind_zone_steps(car, boxes, moving, back: float = BLIND_BACK, front: float = BLIND_FRONT):
    """Whether the car is in a blind zone at each step.

    Args:
        car: ``(N, 5)`` the car's boxes.
        boxes: ``(K, N, 5)`` the obstacles' boxes at the same steps.
        moving: ``(K, N)`` bool, the obstacle is there and moving at that step.
        back, front: the zone's reach behind the obstacle's rear and ahead of it (m).

    Returns:
        ``(N,)`` bool.
    """
    L, W, h = boxes[..., 2], boxes[..., 3], boxes[..., 4]
    c, s = jnp.cos(h), jnp.sin(h)
    lon = -0.5 * L + 0.5 * (front - back)  # the zone's centre along the obstacle, from its centre
    hit = jnp.zeros(boxes.shape[:-1], bool)
    for side in (1.0, -1.0):
        lat = side * (0.5 * W + ZONE_GAP + 0.5 * ZONE_WIDTH)
        zone = jnp.stack(
            [
                boxes[..., 0] + c * lon - s * lat,
                boxes[..., 1] + s * lon + c * lat,
                jnp.full_like(L, back + front),
                jnp.full_like(L, ZONE_WIDTH),
                h,
            ],
            -1,
        )
        hit = hit | box_has_overlap(car[None], zone)
    return jnp.any(hit & moving, axis=0)


@register_metric("blindzone")
def blindzone(log, scene, vehicle):
    N = log.x.shape[0]
    obs = scene.obstacles.window(0, N + 1)
    b = obs.boxes
    speed = jnp.linalg.norm(b[:, 1:, :2] - b[:, :-1, :2], axis=-1) / scene.dt
    moving = obs.valid[:, :N] & obs.valid[:, 1:] & (speed > MOVING) & ~obs.static[:, None]
    inside = blind_zone_steps(car_boxes(log, vehicle), b[:, :N], moving) & log.valid
    return {"time_s": jnp.sum(inside) * jnp.asarray(scene.dt, log.x.dtype)}
