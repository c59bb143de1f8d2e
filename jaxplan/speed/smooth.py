"""Optional smoothing QP after the DP (piecewise-jerk style, solved with qpax).

Variables: the stations ``s_0..s_{n-1}`` every ``h = dt / n_sub`` (the DP's
sub-steps). Speed, acceleration and jerk are finite differences. Minimise

    w_ref |s - s_dp|^2 + w_vref |v - v_dp|^2 + w_acc |a|^2 + w_jerk |jerk|^2

subject to ``s_0 = 0``, ``v_0 = v0``, ``0 <= v <= v_max``, ``a_min <= a <= a_max``
and the station corridor the DP chose: behind every blocking boundary the DP
stayed behind (``s <= lower - ds``) and ahead of every one it passed
(``s >= upper + ds``). ``s_dp``, ``v_dp`` are the DP's monotone cubic.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import qpax

from jaxplan.speed.compose import speed_profile_at
from jaxplan.speed.dp import SpeedConfig


# Half-width (m) of the trust region around the DP profile.
TRUST = 30.0


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SmoothWeights:
    w_ref: Any = 1.0
    w_vref: Any = 0.5
    w_acc: Any = 1.0
    w_jerk: Any = 0.2


def _diff_ops(n, h):
    """Finite-difference matrices: velocity ``(n-1, n)``, acceleration ``(n-2, n)``, jerk ``(n-3, n)``."""
    d1 = (np.eye(n, k=1) - np.eye(n))[:-1] / h
    d2 = (np.diff(np.eye(n), 2, axis=0)) / h ** 2
    d3 = (np.diff(np.eye(n), 3, axis=0)) / h ** 3
    return d1, d2, d3


def corridor(plan, config: SpeedConfig, s_ref):
    """Station bounds ``(F,)`` from the DP's side of each blocking boundary.

    Args:
        plan: ``SpeedPlan`` of one scene (with its ``scene``); s_ref: ``(F,)`` DP stations
            at the fine times.
    """
    b = plan.scene.classified.blocking
    lo, hi, hit = b.lower, b.upper, b.hit  # (K, F)
    behind = hit & (s_ref <= lo - config.ds + 1e-3)
    ahead = hit & (s_ref >= hi + config.ds - 1e-3)
    upper = jnp.min(jnp.where(behind, lo - config.ds, 1e4), 0)
    lower = jnp.max(jnp.where(ahead, hi + config.ds, -1e4), 0)
    return jnp.maximum(lower, -1e4), jnp.maximum(upper, jnp.maximum(lower, -1e4))


def smoothing_qp(s_ref, v_ref, v0, lower, upper, config: SpeedConfig, h: float, w: SmoothWeights):
    """QP matrices ``(Q, q, A, b, G, g)`` for one scene; ``s_ref, v_ref, lower, upper`` ``(n,)``."""
    n = s_ref.shape[-1]
    d1, d2, d3 = (jnp.asarray(m, s_ref.dtype) for m in _diff_ops(n, h))
    eye = jnp.eye(n, dtype=s_ref.dtype)
    Q = 2 * (w.w_ref * eye + w.w_vref * d1.T @ d1 + w.w_acc * d2.T @ d2 + w.w_jerk * d3.T @ d3)
    q = -2 * (w.w_ref * s_ref + w.w_vref * d1.T @ v_ref[:-1])
    A = jnp.stack([eye[0], d1[0]])
    b = jnp.stack([jnp.zeros((), s_ref.dtype), jnp.asarray(v0, s_ref.dtype)])
    G = jnp.concatenate([eye, -eye, d1, -d1, d2, -d2])
    g = jnp.concatenate([upper, -lower, jnp.full((n - 1,), config.v_max), jnp.zeros((n - 1,)),
                         jnp.full((n - 2,), config.a_max), jnp.full((n - 2,), -config.a_min)]).astype(s_ref.dtype)
    return Q, q, A, b, G, g


def smooth_plan(plan, v0, config: SpeedConfig, w: SmoothWeights | None = None):
    """Smoothed station profile of one scene's DP plan at the fine times.

    Returns:
        (t ``(F,)``, s ``(F,)``, v ``(F-1,)``, a ``(F-2,)``, feasible bool: the
        solution meets the constraints within 1 cm / 0.05 m/s / 0.1 m/s^2).
    """
    w = SmoothWeights() if w is None else w
    h = config.dt / config.n_sub
    t = jnp.asarray(config.fine_times(), plan.s.dtype)
    s_ref, v_ref, _ = speed_profile_at(plan.t, plan.s, v0, t)
    lower, upper = corridor(plan, config, s_ref)
    # a trust region around the DP profile keeps the interior point well scaled
    lower = jnp.maximum(lower, s_ref - TRUST)
    upper = jnp.maximum(jnp.minimum(upper, s_ref + TRUST), lower)
    Q, q, A, b, G, g = smoothing_qp(s_ref, v_ref, v0, lower, upper, config, h, w)
    x, _, _, _, _, _ = qpax.solve_qp(Q, q, A, b, G, g, solver_tol=1e-5, max_iter=40)
    # qpax's own convergence flag stays False in float32 even at mm accuracy: check the
    # constraints instead (1 cm, 0.05 m/s, 0.1 m/s^2 of slack)
    slack = jnp.concatenate([jnp.full((2 * t.shape[0],), 1e-2), jnp.full((2 * (t.shape[0] - 1),), 5e-2),
                             jnp.full((2 * (t.shape[0] - 2),), 1e-1)]).astype(x.dtype)
    feasible = jnp.all(G @ x <= g + slack) & jnp.all(jnp.abs(A @ x - b) <= 5e-2) & jnp.all(jnp.isfinite(x))
    d1, d2, _ = _diff_ops(t.shape[0], h)
    return t, x, jnp.asarray(d1, x.dtype) @ x, jnp.asarray(d2, x.dtype) @ x, feasible


smooth_plan_jit = jax.jit(smooth_plan, static_argnames=("config",))
