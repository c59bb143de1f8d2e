"""Learning the lattice's cost weights from human demonstrations.

The lattice is planned once per demonstration (its features do not depend on the
weights); training then only re-weights the features ``(B, N, F)``, so each step is
a small jitted softmin over candidates. Evaluation uses the planner's exact selection
rule (``jaxplan.lattice.select``) with the learned weights.
"""
from __future__ import annotations

import dataclasses
import types

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import reference_line
from jaxplan.lattice import CostWeights, LatticeConfig, PlanState, plan_batch, select
from jaxplan.lattice.cost import FEATURES, rule_cost
from jaxplan.lattice.cost import eligible as rule_eligible
from jaxplan.tuning.demos import Demo
from jaxplan.tuning.train import choice_nll, from_log, target_distribution
from jaxplan.types import Obstacles, VehicleParams

# The lattice used for imitation: three lanes (right, current, left), five offsets
# each, five end speeds; positions at the car's centre, as the recordings give them.
TUNING_CONFIG = LatticeConfig(lanes=(-1, 0, 1), target_lane=0, escalation=(1.0,),
                              vehicle=VehicleParams(reference="center"))
WEIGHT_NAMES = ("alpha", "beta", "gamma", "delta", "collision", "level")
# The weights the exact selection rule uses (the others only shape the smooth cost).
LEARNED = ("alpha", "beta", "gamma", "delta")


def default_weights() -> dict:
    """The planner's default ``CostWeights`` as ``{name: value}``."""
    w = CostWeights()
    return {k: float(getattr(w, k)) for k in WEIGHT_NAMES}


def weights_pytree(weights: dict) -> CostWeights:
    return CostWeights(**{k: weights[k] for k in WEIGHT_NAMES})


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class LatticeData:
    """Per-demonstration lattice outcome, each field with a leading demo axis ``B``.

    Attributes:
        features: ``(B, N, F)``; collided: ``(B, N)``; level: ``(B, N)``.
        ade3, fde3, ade5, fde5: ``(B, N)`` average / final displacement (m) of each
            candidate from the human trajectory at 3 s and 5 s.
        xy: ``(B, N, T, 2)`` candidate positions (for plots).
    """

    features: jax.Array
    collided: jax.Array
    level: jax.Array
    ade3: jax.Array
    fde3: jax.Array
    ade5: jax.Array
    fde5: jax.Array
    xy: jax.Array


def _states(demos: Demo) -> PlanState:
    """The demonstrations' start states; recorded accelerations clipped to the lattice's limits."""
    return PlanState.from_rows(demos.ego.at[:, 4].set(jnp.clip(demos.ego[:, 4], -4.0, 2.5)))


def _chunk_data(demos: Demo, config: LatticeConfig) -> LatticeData:
    refs = jax.vmap(reference_line)(demos.ref_xy)
    obs = Obstacles(demos.obstacles, demos.obstacle_valid, demos.t, demos.obstacle_static)
    res = plan_batch(_states(demos), refs, obs, config, CostWeights())
    xy = jnp.stack([res.candidates.traj.x, res.candidates.traj.y], -1)      # (B, N, T, 2)
    T = min(xy.shape[-2], demos.human_xy.shape[-2])
    err = jnp.linalg.norm(xy[..., :T, :] - demos.human_xy[:, None, :T], axis=-1)  # (B, N, T)
    k3, k5 = min(30, T - 1), min(50, T - 1)
    return LatticeData(res.features, res.collided, res.candidates.level,
                       err[..., 1:k3 + 1].mean(-1), err[..., k3], err[..., 1:k5 + 1].mean(-1), err[..., k5], xy)


def lattice_data(demos: Demo, config: LatticeConfig = TUNING_CONFIG, chunk: int = 64) -> LatticeData:
    """Plan the lattice for every demonstration (in chunks, to bound memory)."""
    B = demos.ego.shape[0]
    parts = []
    for i in range(0, B, chunk):
        part = jax.tree_util.tree_map(lambda x: x[i:i + chunk], demos)
        n = part.ego.shape[0]
        if n < chunk and B > chunk:  # pad the last chunk: one compiled shape
            part = jax.tree_util.tree_map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], chunk - n, 0)]), part)
        out = _chunk_data(part, config)
        parts.append(jax.tree_util.tree_map(lambda x: np.asarray(x)[:n], out))
    return jax.tree_util.tree_map(lambda *xs: jnp.asarray(np.concatenate(xs)), *parts)


def eligible(data: LatticeData):
    """``(B, N)`` the candidates the exact rule chooses among (``jaxplan.lattice.cost.eligible``)."""
    return rule_eligible(data.collided, data.level)[0]


def selection_cost(weights: dict, data: LatticeData):
    """``(B, N)`` the exact rule's cost (``jaxplan.lattice.cost.rule_cost``) for weights
    ``{alpha, beta, gamma, delta, ...}``."""
    return rule_cost(types.SimpleNamespace(**weights), data.features, data.collided)


def lattice_loss(params: dict, data: LatticeData, sigma: float | None = 0.5, temperature: float = 1.0):
    """Mean cross entropy of the softmin form of the exact selection rule (softmin of
    ``selection_cost`` over the ``eligible`` candidates) to the human-nearest target
    (5 s average displacement; one-hot for ``sigma=None``, else ``softmax(-ade / sigma)``)."""
    ok = eligible(data)
    target = target_distribution(data.ade5, ok, sigma)
    return jnp.mean(choice_nll(selection_cost(from_log(params), data), target, ok, temperature))


@jax.jit
def _chosen(weights: CostWeights, data: LatticeData):
    idx, _, _ = select(weights, data.features, data.collided, data.level)
    return idx


def imitation_metrics(weights: dict, data: LatticeData) -> dict:
    """Top-1 agreement, ADE/FDE at 3 s and 5 s of the selected candidate, collision share."""
    idx = _chosen(weights_pytree(weights), data)
    take = lambda a: np.asarray(jnp.take_along_axis(a, idx[:, None], axis=1)[:, 0])
    nearest = np.asarray(jnp.argmin(data.ade5, axis=1))
    return {"top1": float(np.mean(np.asarray(idx) == nearest)),
            "ade3": float(take(data.ade3).mean()), "fde3": float(take(data.fde3).mean()),
            "ade5": float(take(data.ade5).mean()), "fde5": float(take(data.fde5).mean()),
            "collision_share": float(take(data.collided.astype(jnp.float32)).mean()),
            "oracle_ade3": float(np.asarray(jnp.min(data.ade3, axis=1)).mean())}


def synthetic_choices(data: LatticeData, weights: dict, temperature: float, seed: int = 0) -> LatticeData:
    """Replace the human distances by choices sampled from the softmin model with ``weights``.

    The sampled candidate gets distance 0 and every other candidate 1, so the
    one-hot target is the sampled choice (for weight-recovery tests).
    """
    ok = eligible(data)
    logits = jnp.where(ok, -selection_cost(weights, data) / temperature, -jnp.inf)
    pick = jax.random.categorical(jax.random.PRNGKey(seed), logits, axis=-1)
    d = 1.0 - jax.nn.one_hot(pick, logits.shape[-1])
    return dataclasses.replace(data, ade3=d, ade5=d, fde3=d, fde5=d)


__all__ = ["TUNING_CONFIG", "WEIGHT_NAMES", "FEATURES", "LatticeData", "default_weights", "weights_pytree",
           "lattice_data", "eligible", "selection_cost", "lattice_loss", "LEARNED", "imitation_metrics", "synthetic_choices"]
