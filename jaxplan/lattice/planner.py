"""``lattice``: the quintic candidate lattice as a road ``Planner`` (``jaxplan.planner``).

Each cycle it reads the ``RoadContext`` (predictions from this step, the set speed from
the speed limits ahead), plans on the route's reference line and returns the chosen
candidate. ``ok`` is False when every candidate collides (mode RISK) or the plan is not finite.
"""
from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from jaxplan.baselines.brake import SIM_VEHICLE
from jaxplan.lattice.candidates import LatticeConfig, PlanState
from jaxplan.lattice.cost import RISK, CostWeights
from jaxplan.lattice.plan import _plan
from jaxplan.plan_context import road_context
from jaxplan.planner import EgoState, PlanOutput
from jaxplan.types import VehicleParams


@dataclasses.dataclass(frozen=True)
class LatticePlanner:
    """The lattice planner (static config; ``weights``: ``CostWeights`` values as a hashable tuple of
    ``(name, value)`` pairs, e.g. from ``jaxplan tune``; unnamed fields keep their defaults)."""

    vehicle: VehicleParams = SIM_VEHICLE
    dt: float = 0.1
    horizon: float = 5.0
    weights: tuple | None = None

    @property
    def config(self) -> LatticeConfig:
        return LatticeConfig(horizon=self.horizon, dt=self.dt, vehicle=self.vehicle)

    @property
    def horizon_steps(self) -> int:
        return self.config.n_steps

    def plan(self, scene, ego: EgoState, step) -> PlanOutput:
        cfg = self.config
        ctx = road_context(scene, ego, step, cfg.n_steps, self.vehicle)
        state = PlanState(ego.x, ego.y, ego.heading, ego.kappa, ego.v, ego.a, ctx.v_set, jnp.inf)
        w = CostWeights() if self.weights is None else CostWeights(**dict(self.weights))
        res = _plan(state, scene.route, ctx.obstacles, cfg, w)
        traj = res.chosen_trajectory()
        finite = jnp.all(jnp.isfinite(traj.x)) & jnp.all(jnp.isfinite(traj.y))
        return PlanOutput(traj, (res.mode != RISK) & finite, {"mode": res.mode})
