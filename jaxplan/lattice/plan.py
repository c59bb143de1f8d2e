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
                      "min_sep", "chosen", "mode", "obstacles", "finite", "ok"))
class LatticeResult:
    """Everything one plan computed (``N`` candidates, ``T`` steps, any leading batch dims).

    Attributes:
        candidates: ``Candidates`` (trajectories ``(..., N, T)``: x, y, theta, kappa, v, a, t, s).
        features: ``(..., N, F)`` (see ``cost.FEATURES``).
        cost: ``(..., N)`` linear cost ``features @ weights`` (the smooth form's score).
        selection_cost: ``(..., N)`` the exact rule's cost (inf = excluded).
        collided: ``(..., N)``: the candidate hits an obstacle, or cannot be judged (not
            ``finite``: a NaN is never reported as free). first_t, ttc: ``(..., N)``;
            min_sep: ``(..., N, T)``.
        chosen: ``(...)`` index of the chosen candidate; mode: FREE / ESCALATED / RISK, or
            INVALID when no candidate is finite.
        obstacles: the obstacles checked (read at the candidates' times, virtual stop box last).
        finite: ``(..., N)`` the candidate's trajectory, separations and features hold no
            NaN / inf (only those are chosen).
        ok: ``(...)`` the chosen trajectory is finite: False means the plan must not be used
            (for example a reference line with repeated points built inside jit).
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
    finite: Any
    ok: Any

    def chosen_trajectory(self):
        """The chosen ``Trajectory`` ``(..., T)``."""
        i = self.chosen[..., None, None]
        return jax.tree_util.tree_map(lambda f: jnp.take_along_axis(f, i, axis=-2)[..., 0, :],
                                      self.candidates.traj)


def _finite(cand: Candidates, sep, feats):
    """``(N,)`` True where a candidate's trajectory, separations and features hold no NaN / inf."""
    tr = cand.traj
    rows = jnp.stack([tr.x, tr.y, tr.theta, tr.kappa, tr.v, tr.a, tr.s, sep], -1)  # (N, T, 8)
    return jnp.all(jnp.isfinite(rows), axis=(-2, -1)) & jnp.all(jnp.isfinite(feats), axis=-1)


def _plan(state: PlanState, ref: ReferenceLine, obstacles: Obstacles, config: LatticeConfig,
          weights: CostWeights) -> LatticeResult:
    cand: Candidates = generate(state, ref, config)
    obs = align_obstacles(obstacles, cand.traj.t[0])
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
    finite = _finite(cand, sep, feats)
    collided = risk.collided | ~finite
    idx, mode, sel = select(weights, feats, collided, cand.level, valid=finite)
    ok = jnp.take(finite, idx)
    return LatticeResult(cand, feats, costs(weights, feats), sel, collided, risk.first_t, risk.ttc,
                         sep, idx, mode, obs, finite, ok)


_plan_jit = jax.jit(_plan, static_argnames=("config",))


@functools.partial(jax.jit, static_argnames=("config",))
def _plan_batch_jit(state, reference_line, obstacles, config, weights):
    return jax.vmap(lambda s, r, o: _plan(s, r, o, config, weights))(state, reference_line, obstacles)


def _check_shapes(where: str, state: PlanState, ref: ReferenceLine, obstacles: Obstacles, batch: int):
    """Refuse arguments whose batch dimensions do not fit ``plan`` (0) / ``plan_batch`` (1)."""
    got = (jnp.ndim(state.x), jnp.ndim(ref.xy) - 2, jnp.ndim(obstacles.boxes) - 3)
    if got == (batch,) * 3:
        return
    if batch == 0:
        raise ValueError(f"{where}: plans one state at a time, got batch dimensions (state {got[0]}, reference line "
                         f"{got[1]}, obstacles {got[2]}); use jaxplan.lattice.plan_batch or jax.vmap(plan) for batches")
    raise ValueError(f"{where}: needs one leading batch dimension on the state, the reference line and the obstacles, "
                     f"got (state {got[0]}, reference line {got[1]}, obstacles {got[2]}); use jaxplan.lattice.plan "
                     f"for one state")


def _validate(state, reference_line, obstacles, config, weights):
    """Host-side checks of concrete inputs (skipped under jit)."""
    config.validate()
    if is_concrete(state, reference_line, obstacles, weights):
        state.validate()
        reference_line.validate()
        obstacles.validate()
        weights.validate()


def plan(state: PlanState, reference_line: ReferenceLine, obstacles: Obstacles,
         config: LatticeConfig = LatticeConfig(), weights: CostWeights | None = None) -> LatticeResult:
    """Plan once: every candidate of the lattice, its risk and cost, and the choice.

    Host-side checks run on concrete inputs (under jit they are skipped; then check
    ``LatticeResult.ok``: a NaN / inf in the chosen trajectory makes it False).

    Args:
        state: ``PlanState`` with scalar fields (``plan_batch`` or ``jax.vmap`` for batches).
        reference_line: the current lane's centre line ``(P, 2)``.
        obstacles: boxes ``(K, T_obs, 5)`` stamped at ``obstacles.t`` ``(T_obs,)`` (seconds
            from now, any step: they are interpolated to the candidates' times ``k *
            config.dt``; dynamic obstacles are invalid outside their stamps, static ones held);
            ``K = 0`` means nothing in the way.
        config: static settings (hashable).
        weights: ``CostWeights`` (default weights if None).

    Returns:
        ``LatticeResult``.
    """
    weights = CostWeights() if weights is None else weights
    _check_shapes("plan", state, reference_line, obstacles, 0)
    _validate(state, reference_line, obstacles, config, weights)
    return _plan_jit(state, reference_line, obstacles, config, weights)


def plan_batch(state: PlanState, reference_line: ReferenceLine, obstacles: Obstacles,
               config: LatticeConfig = LatticeConfig(), weights: CostWeights | None = None) -> LatticeResult:
    """``plan`` over a leading batch dimension ``B`` of the state, the reference line and the
    obstacles (``config`` and ``weights`` are shared; default weights if None)."""
    weights = CostWeights() if weights is None else weights
    _check_shapes("plan_batch", state, reference_line, obstacles, 1)
    sizes = {"state": jnp.shape(state.x)[0], "reference line": jnp.shape(reference_line.xy)[0],
             "obstacles": jnp.shape(obstacles.boxes)[0]}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"plan_batch: batch sizes differ ({', '.join(f'{k} {v}' for k, v in sizes.items())})")
    # scalar state fields (PlanState.make's defaults) are shared by the batch
    state = jax.tree_util.tree_map(lambda f: jnp.broadcast_to(f, (sizes["state"],) + jnp.shape(f)[1:])
                                   if jnp.ndim(f) == 0 else f, state)
    _validate(state, reference_line, obstacles, config, weights)
    return _plan_batch_jit(state, reference_line, obstacles, config, weights)
