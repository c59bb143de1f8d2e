"""``idm``: lane keeping with the Intelligent Driver Model (Treiber et al. 2000).

Along the route at the car's lateral offset, the speed follows IDM towards the set speed
(the speed limit ahead) behind the nearest predicted obstacle in the car's corridor at
each future step, and stops before the end of the mapped road. The IDM law is the library's
one (``jaxplan.models.idm``) with this planner's parameters (``IDMParams``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax.numpy as jnp
from jax import lax

from jaxplan.baselines.route_follow import follow_route
from jaxplan.geometry.boxes import box_half_extents
from jaxplan.geometry.frenet import ref_state
from jaxplan.models.idm import idm_accel as idm_model
from jaxplan.plan_context import NO_LEADER, road_context
from jaxplan.planner import SIM_VEHICLE, EgoState, PlanOutput
from jaxplan.types import VehicleParams, pytree_dataclass, weights_from


@pytree_dataclass(data_fields=("time_gap", "min_gap", "a_max", "b_comf", "delta", "b_max"))
class IDMParams:
    """IDM parameters (a pytree; each ``()``): desired time gap (s), minimum gap (m), maximum
    acceleration and comfortable deceleration (m/s^2), acceleration exponent, and the braking
    limit (m/s^2)."""

    time_gap: Any = 1.5
    min_gap: Any = 2.0
    a_max: Any = 1.5
    b_comf: Any = 2.0
    delta: Any = 4.0
    b_max: Any = 8.0


def idm_accel(v, v_set, gap, dv, p: IDMParams = IDMParams()):
    """IDM acceleration ``(...)`` (``jaxplan.models.idm.idm_accel`` with this planner's parameters)
    for speed ``v``, desired speed ``v_set``, bumper gap ``gap`` (m, > 0 or large without a leader)
    and approach rate ``dv = v - v_leader``; clipped to ``[-b_max, a_max]``. Finite gradients (the
    gap is floored at 0.1 m)."""
    a = idm_model(
        v, v_set, gap, dv, a_max=p.a_max, b_comf=p.b_comf, time_gap=p.time_gap, min_gap=p.min_gap, delta=p.delta
    )
    return jnp.clip(a, -p.b_max, p.a_max)


@dataclasses.dataclass(frozen=True)
class IDMPlanner:
    """Lane-keeping IDM over ``horizon`` seconds (see the module docstring); its params are the
    ``IDMParams``."""

    vehicle: VehicleParams = SIM_VEHICLE
    dt: float = 0.1
    horizon: float = 5.0

    @property
    def horizon_steps(self) -> int:
        return int(round(self.horizon / self.dt)) + 1

    def init_params(self, values: Mapping | None = None) -> IDMParams:
        """``IDMParams`` as float arrays: the defaults, with ``values`` (``{field: value}``) in their
        place (``jaxplan.types.weights_from``)."""
        return weights_from(IDMParams, values)

    def plan(self, params: IDMParams, scene, ego: EgoState, step) -> PlanOutput:
        H = self.horizon_steps
        ctx = road_context(scene, ego, step, H, self.vehicle)
        f = scene.route.xy.dtype
        veh = self.vehicle
        front = jnp.asarray(veh.front_offset, f)
        half_w = 0.5 * jnp.asarray(veh.width, f)
        obs = ctx.obstacles
        hdg = ref_state(scene.route, ctx.obstacle_s)[1]
        ext = box_half_extents(obs.boxes, hdg)  # (K, H, 2)
        dt = self.dt
        # obstacle speed along the route, from consecutive predicted positions
        ds_obs = jnp.diff(ctx.obstacle_s, axis=1) / dt
        v_obs = jnp.concatenate([ds_obs, ds_obs[:, -1:]], axis=1)
        ok_v = obs.valid & jnp.concatenate([obs.valid[:, 1:], obs.valid[:, -1:]], axis=1)
        v_obs = jnp.where(ok_v, v_obs, 0.0)

        def step_fn(carry, k):
            s, v = carry
            in_lane = jnp.abs(ctx.obstacle_l[:, k] - ctx.l) < ext[:, k, 1] + half_w
            gap = ctx.obstacle_s[:, k] - ext[:, k, 0] - (s + front)
            cand = obs.valid[:, k] & in_lane & (ctx.obstacle_s[:, k] + ext[:, k, 0] > s)
            gap = jnp.where(cand, gap, NO_LEADER)
            j = jnp.argmin(gap)
            g, vl = gap[j], v_obs[j, k]
            end_gap = ctx.route_end_s - (s + front)  # the road's end: a stopped leader
            use_end = end_gap < g
            g, vl = jnp.where(use_end, end_gap, g), jnp.where(use_end, 0.0, vl)
            a = idm_accel(v, ctx.v_set, g, v - vl, params)
            a = jnp.maximum(a, -v / dt)  # stop, never reverse
            v1 = v + a * dt
            s1 = s + 0.5 * (v + v1) * dt
            return (s1, v1), (s, v, a)

        _, (s, v, a) = lax.scan(step_fn, (ctx.s, jnp.asarray(ego.v, f)), jnp.arange(H))
        t = jnp.arange(H, dtype=f) * dt
        traj = follow_route(scene.route, ego, s - ctx.s, v, a, t)
        return PlanOutput(traj, jnp.asarray(True), {})
