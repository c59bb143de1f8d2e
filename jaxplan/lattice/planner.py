"""``lattice``: the quintic candidate lattice as a road ``Planner`` (``jaxplan.planner``).

Each cycle it reads the ``RoadContext`` (predictions from this step, the set speed from
the speed limits ahead, the lanes beside the route, the goal) and plans on the route's
reference line with ``LatticeConfig.road()``: cruising, following, stopping (before a
stopped obstacle or the end of the mapped route) and goal-reaching profiles over several
end times, an emergency and a fallback level, every lane the scene has on either side at
three lateral times (lanes running the other way only borrowed to pass a blockage),
the feasibility filter, safety buffers, the road edges (``Scene.road_left / road_right``)
and the terminal condition (``jaxplan.lattice.plan``).

The set speed is ``jaxplan.plan_context.set_speed``: the speed limit bent towards the goal's
timing and speed range, slowing before the route's curves and, without a goal region ahead,
before a dead end of the road.

``ok`` is False when every candidate collides (mode RISK) or the plan is not finite (INVALID);
``info`` has the mode, the candidates the feasibility filter rejected and the target lane.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import ClassVar

import jax.numpy as jnp

from jaxplan.compile_options import NO_YNN
from jaxplan.lattice.config import LatticeConfig
from jaxplan.lattice.cost import INVALID, MODE_NAMES, RISK, CostWeights
from jaxplan.lattice.plan import LatticeResult, plan_unchecked
from jaxplan.lattice.state import PlanState
from jaxplan.lattice.targets import RoadTargets
from jaxplan.plan_context import road_context, route_sample, set_speed
from jaxplan.planner import SIM_VEHICLE, EgoState, PlanOutput, tally
from jaxplan.types import VehicleParams, weights_from

LANE_LOOKAHEAD = 2.5  # s: the lanes are read this far ahead (15-60 m)


@dataclasses.dataclass(frozen=True)
class LatticePlanner:
    """The lattice planner (static config: ``options`` as a tuple of ``(LatticeConfig field, value)``
    pairs overriding ``LatticeConfig.road()``). Its params are the ``CostWeights`` (``init_params``)."""

    vehicle: VehicleParams = SIM_VEHICLE
    dt: float = 0.1
    horizon: float = 5.0
    options: tuple = ()
    # the simulator compiles a drive with these (not a field: the same for every lattice planner);
    # ``jaxplan.compile_options`` says what they gain in the plan, ``jaxplan.sim.rollout`` in a drive
    compiler_options: ClassVar[dict] = NO_YNN

    @property
    def config(self) -> LatticeConfig:
        return LatticeConfig.road(horizon=self.horizon, dt=self.dt, vehicle=self.vehicle, **dict(self.options))

    @property
    def horizon_steps(self) -> int:
        return self.config.n_steps

    def scene_config(self, n_lanes: int) -> LatticeConfig:
        """The config for a scene with ``n_lanes`` lanes (``Scene.n_lanes``): ``min(n_lanes,
        max_lanes)`` lateral lanes about the car's."""
        m = min(n_lanes, self.config.max_lanes)
        return dataclasses.replace(self.config, lanes=tuple(range(-(m // 2), m - m // 2)), target_lane=0)

    def init_params(self, weights: Mapping | None = None) -> CostWeights:
        """The cost weights as a pytree of float arrays: the defaults, with the values of
        ``weights`` (``{field: value}``, e.g. a ``jaxplan tune`` file's) in their place."""
        return weights_from(CostWeights, weights)

    def plan_result(self, params: CostWeights, scene, ego: EgoState, step) -> LatticeResult:
        """The whole ``LatticeResult`` of one plan (every candidate, why each was rejected, the
        choice): what ``plan`` returns the chosen trajectory of; for plots and diagnostics."""
        return self.plan_in_context(params, scene, ego, step)[0]

    def plan_in_context(self, params: CostWeights, scene, ego: EgoState, step) -> tuple:
        """``(LatticeResult, RoadContext, set speed ())``: the plan and what it was planned from."""
        cfg = self.scene_config(scene.lane_offset.shape[-2])
        ctx = road_context(scene, ego, step, cfg.n_steps, self.vehicle)
        f = scene.route.xy.dtype
        v_set = set_speed(scene, ctx, ego, self.vehicle, self.horizon, cfg.lat_acc_max)
        state = PlanState(ego.x, ego.y, ego.heading, ego.kappa, ego.v, ego.a, v_set, jnp.inf)
        # the max_lanes lanes about the car's current one (every lane on a road up to that wide), read
        # LANE_LOOKAHEAD s ahead, where the lateral manoeuvres end: where the route blends into another
        # lane, the lane the car is in is then still a target (the offsets at the car would not offer it)
        s_ahead = ctx.s + jnp.clip(ego.v * LANE_LOOKAHEAD, 15.0, 60.0)
        lane_offset = route_sample(scene, scene.lane_offset, s_ahead)
        lane_valid = route_sample(scene, scene.lane_valid.astype(f), s_ahead) > 0.5
        lane_ok = lane_valid & (route_sample(scene, scene.lane_same_dir.astype(f), s_ahead) > 0.5)
        L, M = lane_offset.shape[-1], len(cfg.lanes)
        cur = jnp.argmin(jnp.where(lane_ok, jnp.abs(lane_offset - ctx.l), jnp.inf))
        start = jnp.clip(cur - M // 2, 0, L - M)
        idx = start + jnp.arange(M)
        # lanes running the other way are offered for borrowing (LatticeConfig.borrow_gain; inf: never)
        borrow = jnp.isfinite(cfg.borrow_gain) & lane_valid & ~lane_ok
        targets = RoadTargets(
            lane_offset[idx],
            (lane_ok | borrow)[idx],
            jnp.clip(scene.own_lane - start, 0, M - 1),
            ctx.route_end_s,
            ctx.goal_s,
            ctx.goal_l,
            ctx.goal_t,
            ctx.goal_v,
            jnp.stack([ctx.obstacle_s, ctx.obstacle_l], -1),
            borrow[idx],
            jnp.stack([scene.road_left, scene.road_right], -1),
        )
        return plan_unchecked(state, scene.route, ctx.obstacles, cfg, params, targets), ctx, v_set

    def describe(self, info: dict) -> str:
        """Words for the ``info`` of a few consecutive plans (numpy ``(C,)`` each): their modes,
        and the last one's set speed and leader (the nearest vehicle ahead in the car's lane)."""
        names = [MODE_NAMES[int(m)] if 0 <= int(m) < len(MODE_NAMES) else str(int(m)) for m in info["mode"]]
        words = tally("modes", names) + f"; the last: set speed {float(info['v_set'][-1]):.1f} m/s, "
        k = int(info["leader"][-1])
        if k < 0:
            return words + "no leader"
        gap, v = float(info["leader_gap"][-1]), float(info["leader_v"][-1])
        return words + f"leader obstacle {k} {gap:.0f} m ahead at {v:.1f} m/s"

    def plan(self, params: CostWeights, scene, ego: EgoState, step) -> PlanOutput:
        res, ctx, v_set = self.plan_in_context(params, scene, ego, step)
        traj = res.chosen_trajectory()
        rejected = jnp.sum(res.candidates.available & ~res.feasible)
        info = {
            "mode": res.mode,
            "rejected": rejected,
            "l_target": res.l_target,
            "v_set": v_set,
            "leader": ctx.leader_index,
            "leader_gap": ctx.leader_gap,
            "leader_v": ctx.leader_v,
        }
        return PlanOutput(traj, (res.mode != RISK) & (res.mode != INVALID) & res.ok, info)
