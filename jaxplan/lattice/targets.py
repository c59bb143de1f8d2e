"""What the lattice aims at besides end speeds: lanes, a stop point, a goal (``RoadTargets``).

``RoadTargets`` is optional input of ``plan``: without it the lattice has only the config's lanes
(``config.lanes * config.lane_width``, no goal, stop points only from the crossroad target
and stopped obstacles). The road planner (``jaxplan.lattice.planner``) fills it from the
``Scene`` each cycle: the lanes beside the route and which exist, the end of the mapped
route, the goal's route ranges and time window, and the obstacles' Frenet coordinates
(projected once by the ``Scene``).

Leader and stopped obstacle (``lane_leader``): among the obstacles valid now whose lateral
extent overlaps the car's corridor (``|l_o - l| < ext_l + width / 2``) and whose centre is
ahead, the nearest rear bumper; it is the leader, and a stop point when it moves slower
than ``STOPPED_SPEED``.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from jaxplan.geometry.boxes import box_half_extents
from jaxplan.geometry.frenet import ref_state, to_frenet
from jaxplan.types import pytree_dataclass

STOPPED_SPEED = 0.5  # m/s: slower obstacles ahead are stopped for
HOLD_LANE, GOAL_LANE = 100, 101  # lane ids of the "hold the current offset" and "goal offset" lateral targets


@pytree_dataclass(
    data_fields=(
        "lane_centres",
        "lane_ok",
        "route_lane",
        "stop_s",
        "goal_s",
        "goal_l",
        "goal_t",
        "goal_v",
        "obstacle_sl",
        "lane_borrow",
        "road_edges",
    )
)
class RoadTargets:
    """Per-plan targets (each field unbatched; add leading axes for ``plan_batch``).

    Attributes:
        lane_centres: ``(Ln,)`` Frenet offsets of the lanes' centres at the car (m).
        lane_ok: ``(Ln,)`` bool, the lane exists (and runs the car's way).
        route_lane: ``()`` int, index of the route's lane (the local reference path).
        stop_s: ``()`` arc length on the line where the car's front must stop (inf: none),
            e.g. the end of the mapped route.
        goal_s, goal_l: ``(2,)`` the goal region's range in route coordinates (inf: none).
        goal_t: ``(2,)`` the goal's time window from now (s); goal_v: ``(2,)`` its speeds.
        obstacle_sl: ``(K, T, 2)`` the obstacles' centres in Frenet coordinates on the line
            (aligned with the obstacles), or None: then ``plan`` projects them.
        lane_borrow: ``(Ln,)`` bool, the lane (``lane_ok`` too) runs the other way: a target only
            by ``LatticeConfig.borrow_gain`` more progress (None: no such lane).
        road_edges: ``(R, 2)`` the drivable corridor's left and right edges (Frenet ``l``, m) at
            the reference line's points, or None: no road-edge check.
    """

    lane_centres: Any
    lane_ok: Any
    route_lane: Any
    stop_s: Any = float("inf")
    goal_s: Any = (float("inf"), float("inf"))
    goal_l: Any = (-float("inf"), float("inf"))
    goal_t: Any = (0.0, float("inf"))
    goal_v: Any = (-float("inf"), float("inf"))
    obstacle_sl: Any = None
    lane_borrow: Any = None
    road_edges: Any = None

    @classmethod
    def from_config(cls, config, dtype=None) -> RoadTargets:
        """The config's lanes (``config.lanes * config.lane_width``), nothing else."""
        f = dtype or jnp.result_type(float)
        lanes = jnp.asarray(config.lanes, f) * config.lane_width
        inf = jnp.asarray(jnp.inf, f)
        return cls(
            lanes,
            jnp.ones(lanes.shape, bool),
            jnp.asarray(list(config.lanes).index(config.target_lane)),
            inf,
            jnp.stack([inf, inf]),
            jnp.stack([-inf, inf]),
            jnp.stack([jnp.zeros_like(inf), inf]),
            jnp.stack([-inf, inf]),
            None,
        )


def obstacle_frenet(ref, obstacles):
    """``(K, T, 2)`` Frenet ``(s, l)`` of the obstacles' centres (geometry core's ``to_frenet``)."""
    s, l = to_frenet(ref, obstacles.boxes[..., :2])
    return jnp.stack([s, l], -1)


def extents(ref, boxes, s):
    """Half extents along and across the line ``(..., 2)`` of boxes ``(..., 5)`` centred at arc lengths ``s``."""
    return box_half_extents(boxes, ref_state(ref, s)[1])


def speed_along(sl, valid, dt):
    """``(K, T)`` obstacle speeds along the line from consecutive Frenet stations (0 where unknown)."""
    ds = jnp.diff(sl[..., 0], axis=-1) / dt
    v = jnp.concatenate([ds, ds[..., -1:]], axis=-1)
    ok = valid & jnp.concatenate([valid[..., 1:], valid[..., -1:]], axis=-1)
    return jnp.where(ok, v, 0.0)


def lane_leader(s_car, l_car, half_width, front, sl, ext, valid, v_along):
    """The leader in the car's corridor (see the module docstring).

    Args:
        s_car, l_car: ``()`` the car's reference point; half_width, front: ``()`` car half width
            and reference-point-to-front length.
        sl: ``(K, T, 2)``; ext: ``(K, T, 2)``; valid: ``(K, T)``; v_along: ``(K, T)``.

    Returns:
        (index ``()`` (-1: none), rear ``(T,)`` of the leader minus the car's front, relative to
        ``s_car``, speed ``(T,)``, found ``()``, stopped ``()``).
    """
    in_lane = jnp.abs(sl[:, 0, 1] - l_car) < ext[:, 0, 1] + half_width
    ahead = sl[:, 0, 0] > s_car
    gap = sl[:, 0, 0] - ext[:, 0, 0] - (s_car + front)
    cand = valid[:, 0] & in_lane & ahead
    gap = jnp.where(cand, gap, jnp.inf)
    k = jnp.argmin(gap)
    found = jnp.isfinite(gap[k])
    rear = sl[k, :, 0] - ext[k, :, 0] - front - s_car
    # past the end of its prediction it keeps its last valid state
    last = jnp.max(jnp.where(valid[k], jnp.arange(valid.shape[1]), 0))
    rear = jnp.where(valid[k], rear, rear[last])
    v = jnp.where(valid[k], v_along[k], v_along[k, last])
    stopped = found & (jnp.abs(v_along[k, 0]) < STOPPED_SPEED)
    return jnp.where(found, k, -1), rear, v, found, stopped
