"""``brake``: stay in lane and brake at a constant deceleration from the first step.

A scene is *survivable* when this planner, braking at ``-5 m/s^2`` from ``t = 0``, avoids
every obstacle (``jaxplan.scenarios.builtin`` keeps only such scenes): a collision of
another planner in it is then that planner's fault.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax.numpy as jnp

from jaxplan.baselines.route_follow import follow_route
from jaxplan.models.braking import braking_profile
from jaxplan.planner import SIM_VEHICLE, EgoState, PlanOutput
from jaxplan.types import VehicleParams


@dataclasses.dataclass(frozen=True)
class BrakePlanner:
    """Brake at ``decel`` (m/s^2, > 0) along the route at the car's current lateral offset.

    ``from_start``: the plan made at step 0 is kept (each later plan continues the same
    stop: it brakes at ``decel`` from the current speed, which is the same profile).
    """

    vehicle: VehicleParams = SIM_VEHICLE
    dt: float = 0.1
    horizon: float = 5.0
    decel: float = 5.0

    @property
    def horizon_steps(self) -> int:
        return int(round(self.horizon / self.dt)) + 1

    def init_params(self, values: Mapping | None = None) -> dict:
        """No tunable params (an empty pytree); ``values`` must be empty."""
        if values:
            raise ValueError(f"BrakePlanner has no params, got {sorted(values)}")
        return {}

    def plan(self, params: dict, scene, ego: EgoState, step) -> PlanOutput:
        f = scene.route.xy.dtype
        t = jnp.arange(self.horizon_steps, dtype=f) * self.dt
        ds, v, a = braking_profile(ego.v, -self.decel, t)
        traj = follow_route(scene.route, ego, ds, v, a, t)
        return PlanOutput(traj, jnp.asarray(True), {})
