"""Cost features, weights, exact selection with escalation and its smooth (softmin) form.

Features ``(..., N, F)`` in the order of ``FEATURES``:

- ``d_lrp``: mean over the horizon of ``|l - l_target|`` (m), the distance to the
  local reference path (the target lane's centre).
- ``rho_max``: maximum ``|kappa|`` over the horizon (1/m).
- ``risk``: ``1 / max(TTC, ttc_min)`` (1/s), 0 without collision. The seed writes
  ``gamma * TTC``; a larger TTC is safer, so the risk decreases with TTC.
- ``speed``: ``|v_end - v_set|`` (m/s).
- ``collision``: ``sigmoid(-min_sep / sep_eps)``, the smooth collision indicator from
  the signed separation (``min_sep`` = minimum over steps and obstacles).
- ``level_free``: escalation level times ``(1 - collision)``.

The exact rule (the seed's flow): if some level-0 candidate is collision-free,
take the free one of least ``lambda = alpha d_lrp + beta rho_max + delta speed``;
else the lowest escalation level with a free candidate, likewise; if every
candidate collides, the least ``lambda + gamma risk`` over all of them.

The smooth form scores ``cost = features @ weights`` and takes a softmin with a
temperature. With ``collision`` much larger than ``level`` times the number of levels, and
``level`` much larger than the spread of ``lambda``, its argmin is the exact rule's choice
as the temperature and ``sep_eps`` go to 0.
"""
from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.types import _pytree, check_weights

FEATURES = ("d_lrp", "rho_max", "risk", "speed", "collision", "level_free")
# The exact selection's modes; INVALID: no candidate could be judged (NaN / inf in all of them).
FREE, ESCALATED, RISK, INVALID = 0, 1, 2, 3
MODE_NAMES = ("free", "escalated", "risk", "invalid")


@_pytree(data_fields=("alpha", "beta", "gamma", "delta", "collision", "level"))
class CostWeights:
    """Cost weights (array pytree, differentiable). Each field ``(...)``.

    alpha: D_toLRP; beta: rho_max; gamma: risk (1/TTC); delta: |v_end - v_set|;
    collision: smooth collision indicator; level: escalation level of free candidates.
    """

    alpha: Any = 1.0
    beta: Any = 10.0
    gamma: Any = 10.0
    delta: Any = 0.1
    collision: Any = 1e4
    level: Any = 1e3

    def validate(self) -> "CostWeights":
        """Host-side: every weight finite and >= 0 (a ``ValueError`` names the field)."""
        check_weights(self)
        return self

    def vector(self):
        """``(..., F)`` in the order of ``FEATURES``."""
        f = jnp.result_type(float)
        return jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(getattr(self, k), f) for k in
                                                ("alpha", "beta", "gamma", "delta", "collision", "level"))), -1)


def cost_features(l, kappa, l_target, ttc, v_end, v_set, min_sep, level, ttc_min=0.1, sep_eps=0.05):
    """Per-candidate features ``(..., N, F)``.

    Args:
        l, kappa: ``(..., N, T)`` lateral offset and curvature.
        l_target: ``(...)`` offset of the local reference path.
        ttc: ``(..., N)`` time to collision (inf = none).
        v_end: ``(..., N)``; v_set: ``(...)``.
        min_sep: ``(..., N, T)`` minimum signed separation to the obstacles.
        level: ``(..., N)`` escalation level.
    """
    d_lrp = jnp.mean(jnp.abs(l - jnp.asarray(l_target)[..., None, None]), axis=-1)
    rho = jnp.max(jnp.abs(kappa), axis=-1)
    risk = jnp.where(jnp.isfinite(ttc), 1.0 / jnp.maximum(ttc, ttc_min), 0.0)
    speed = jnp.abs(v_end - jnp.asarray(v_set)[..., None])
    coll = jax.nn.sigmoid(-jnp.min(min_sep, axis=-1) / sep_eps)
    lvl = level.astype(d_lrp.dtype) * (1.0 - coll)
    return jnp.stack([d_lrp, rho, risk, speed, coll, lvl], axis=-1)


def costs(weights: CostWeights, features):
    """Linear cost ``(..., N)`` of features ``(..., N, F)``."""
    return jnp.einsum("...nf,...f->...n", features, weights.vector())


def lam(weights: CostWeights, features):
    """The seed's ``lambda = alpha D_toLRP + beta rho_max (+ delta speed)``, ``(..., N)``."""
    return weights.alpha * features[..., 0] + weights.beta * features[..., 1] + weights.delta * features[..., 3]


def eligible(collided, level):
    """The candidates the exact rule chooses among.

    Args:
        collided: ``(..., N)`` bool; level: ``(..., N)`` int escalation level.

    Returns:
        (eligible ``(..., N)``: the free candidates of the lowest level that has one, or every
        candidate when all collide; any_free ``(...)``; first free level ``(...)``).
    """
    free = ~collided
    big = jnp.iinfo(jnp.int32).max
    first_level = jnp.min(jnp.where(free, level, big), axis=-1)  # (...)
    any_free = first_level < big
    ok = jnp.where(any_free[..., None], free & (level == first_level[..., None]), True)
    return ok, any_free, first_level


def rule_cost(weights, features, collided):
    """The exact rule's cost ``(..., N)``: ``lambda``, plus ``gamma * risk`` when every
    candidate collides. ``weights`` needs ``alpha, beta, gamma, delta`` attributes."""
    all_collide = jnp.all(collided, axis=-1, keepdims=True)
    return lam(weights, features) + jnp.where(all_collide, weights.gamma * features[..., 2], 0.0)


def select(weights: CostWeights, features, collided, level, valid=None):
    """Exact selection (see the module docstring).

    Args:
        features: ``(..., N, F)``; collided: ``(..., N)`` bool; level: ``(..., N)`` int.
        valid: ``(..., N)`` bool or None: candidates that can be judged (finite trajectory,
            separation and features). The others count as colliding and are never chosen;
            when no candidate is valid the mode is ``INVALID``.

    Returns:
        (index ``(...)`` int, mode ``(...)`` in {FREE, ESCALATED, RISK, INVALID}, selection
        cost ``(..., N)`` with ``inf`` for candidates the rule excluded).
    """
    if valid is not None:
        collided = collided | ~valid
    ok, any_free, first_level = eligible(collided, level)
    if valid is not None:
        ok = ok & valid
    c = jnp.where(ok, rule_cost(weights, features, collided), jnp.inf)
    idx = jnp.argmin(c, axis=-1)
    mode = jnp.where(any_free, jnp.where(first_level == 0, FREE, ESCALATED), RISK)
    if valid is not None:
        mode = jnp.where(jnp.any(valid, axis=-1), mode, INVALID)
    return idx, mode, c


def soft_select(weights: CostWeights, features, temperature):
    """Smooth selection: softmin of ``costs(weights, features)`` with a temperature.

    Returns:
        ``(..., N)`` probabilities (differentiable in the weights and the features).
    """
    return jax.nn.softmax(-costs(weights, features) / temperature, axis=-1)
