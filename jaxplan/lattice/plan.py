"""One jitted lattice plan: candidates, collision risk, features, costs, exact and smooth choice."""
from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.lattice.candidates import Candidates, LatticeConfig, PlanState, generate
from jaxplan.lattice.cost import CostWeights, cost_features, costs, select
from jaxplan.lattice.crossroad import with_stop_target
from jaxplan.lattice.risk import (align_obstacles, car_parts, min_separation_axes, min_separation_broad,
                                  risk_from_separation)
from jaxplan.types import Obstacles, _pytree, is_concrete


@_pytree(data_fields=("candidates", "features", "cost", "selection_cost", "collided", "first_t", "ttc",
                      "min_sep", "chosen", "mode", "obstacles"))
class LatticeResult:
    """Everything one plan computed (``N`` candidates, ``T`` steps, any leading batch dims).

    Attributes:
        candidates: ``Candidates`` (trajectories ``(..., N, T)``: x, y, theta, kappa, v, a, t, s).
        features: ``(..., N, F)`` (see ``cost.FEATURES``).
        cost: ``(..., N)`` linear cost ``features @ weights`` (the smooth form's score).
        selection_cost: ``(..., N)`` the exact rule's cost (inf = excluded).
        collided, first_t, ttc: ``(..., N)``; min_sep: ``(..., N, T)``.
        chosen: ``(...)`` index of the chosen candidate; mode: FREE / ESCALATED / RISK.
        obstacles: the obstacles checked (aligned to T, virtual stop box last).
    """

    candidates: Any
    features: Any
    cost: Any
    selection_cost: Any
    collided: Any
    first_t: Any
    ttc: Any
    min_sep: Any
    chosen: Any
    mode: Any
    obstacles: Any

    def chosen_trajectory(self):
        """The chosen ``Trajectory`` ``(..., T)``."""
        i = self.chosen[..., None, None]
        return jax.tree_util.tree_map(lambda f: jnp.take_along_axis(f, i, axis=-2)[..., 0, :],
                                      self.candidates.traj)


def _plan(state: PlanState, ref: ReferenceLine, obstacles: Obstacles, config: LatticeConfig,
          weights: CostWeights) -> LatticeResult:
    cand: Candidates = generate(state, ref, config)
    obs = align_obstacles(obstacles, config.n_steps)
    obs = with_stop_target(obs, ref, cand.s[0, 0], state.d_crossroad, config)
    center, half = car_parts(jnp.stack([cand.traj.x, cand.traj.y], -1), cand.axis, config.vehicle)
    if config.near_budget > 0:
        E, V, Ln, O = config.grid
        G, K = E * V, obs.boxes.shape[-3]
        budget = max(1, int(np.ceil(config.near_budget * G * K * config.n_steps)))
        sep = min_separation_broad(center, cand.axis, half, obs, Ln * O, budget, config.broad_margin)
    else:
        sep = min_separation_axes(center, cand.axis, half, obs)
    risk = risk_from_separation(sep, cand.traj.t[0])
    feats = cost_features(cand.l, cand.traj.kappa, cand.l_target, risk.ttc, cand.v_end, state.v_set, sep,
                          cand.level, config.ttc_min, config.sep_eps)
    idx, mode, sel = select(weights, feats, risk.collided, cand.level)
    return LatticeResult(cand, feats, costs(weights, feats), sel, risk.collided, risk.first_t, risk.ttc,
                         sep, idx, mode, obs)


_plan_jit = jax.jit(_plan, static_argnames=("config",))


def plan(state: PlanState, reference_line: ReferenceLine, obstacles: Obstacles,
         config: LatticeConfig = LatticeConfig(), weights: CostWeights | None = None) -> LatticeResult:
    """Plan once: every candidate of the lattice, its risk and cost, and the choice.

    Args:
        state: ``PlanState`` (scalar fields; ``jax.vmap`` ``plan_batch`` for batches).
        reference_line: the current lane's centre line.
        obstacles: boxes ``(K, T_obs, 5)``, step ``k`` at time ``k * config.dt``
            (cut or padded to the horizon); ``K = 0`` means nothing in the way.
        config: static settings (hashable).
        weights: ``CostWeights`` (default weights if None).

    Returns:
        ``LatticeResult``.
    """
    if weights is None:
        weights = CostWeights()
    if is_concrete(state, obstacles):
        config.validate()
        state.validate()
        obstacles.validate()
    return _plan_jit(state, reference_line, obstacles, config, weights)


@functools.partial(jax.jit, static_argnames=("config",))
def plan_batch(state: PlanState, reference_line: ReferenceLine, obstacles: Obstacles,
               config: LatticeConfig, weights: CostWeights) -> LatticeResult:
    """``plan`` over a leading batch dimension of every argument but ``config`` and ``weights``."""
    return jax.vmap(lambda s, r, o: _plan(s, r, o, config, weights))(state, reference_line, obstacles)
