"""The lattice planned once per demonstration: candidates, their features and their
distance to the human's future.

The candidates do not depend on the weights, so the lattice is planned once per
demonstration (``lattice_data``); training then only re-weights the features
``(B, N, F)``. Two costs read them:

- the lattice's own selection rule (``jaxplan.lattice.select``) with its
  ``CostWeights``, positive weights of ``alpha d_lrp + beta rho_max + delta |v_end - v0|``
  (the default-weights baseline, the grid over its ratios, and the weight-recovery
  tests on synthetic demonstrations);
- the imitation model (``jaxplan.tuning.imitation``) over the scene-by-candidate
  features of ``jaxplan.tuning.features``.

The candidate set is a tuple of ``LatticeConfig``s whose candidates are
concatenated (``TUNING_CONFIGS``: 17 end speeds, the jerk-limited profile the
planner uses and a constant-acceleration one, offsets reached at the horizon or
after 3 s, three lanes). When the lattice offers end times and lateral times
itself, one config does it.
"""

from __future__ import annotations

import dataclasses
import types
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.compile_options import NO_YNN, jit
from jaxplan.geometry.frenet import reference_line
from jaxplan.lattice import CostWeights, LatticeConfig, PlanState, plan_batch, select
from jaxplan.lattice.cost import FEATURES as RULE_FEATURES
from jaxplan.lattice.cost import eligible as rule_eligible
from jaxplan.lattice.cost import rule_cost
from jaxplan.tuning.baselines import CHUNK, chunks
from jaxplan.tuning.demos import Demo
from jaxplan.tuning.features import FeatureConfig, candidate_features
from jaxplan.tuning.metrics import displacement
from jaxplan.tuning.traffic import IDMParams, frenet_traffic
from jaxplan.tuning.train import choice_nll, from_log, target_distribution
from jaxplan.types import Obstacles, VehicleParams

# 17 end speeds (km/h from the start speed), finer near zero where most humans end.
SPEEDS_17 = (-40.0, -30.0, -22.0, -16.0, -12.0, -9.0, -6.0, -3.0, 0.0, 3.0, 6.0, 9.0, 12.0, 16.0, 22.0, 30.0, 40.0)
# The lattice of the planner as it is (five end speeds), positions at the car's centre as the recordings give them.
TUNING_CONFIG = LatticeConfig(
    lanes=(-1, 0, 1), target_lane=0, escalation=(1.0,), vehicle=VehicleParams(reference="center")
)
RICH = dataclasses.replace(TUNING_CONFIG, speed_deltas_kmh=SPEEDS_17)
TUNING_CONFIGS = (
    RICH,
    dataclasses.replace(RICH, lateral_time=3.0),
    dataclasses.replace(RICH, profile="accel"),
    dataclasses.replace(RICH, profile="accel", lateral_time=3.0),
)
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
        features: ``(B, N, F)`` scene-by-candidate features (``features.FEATURES``).
        rule: ``(B, N, 6)`` the lattice's own cost features (``lattice.cost.FEATURES``).
        collided: ``(B, N)``; level: ``(B, N)`` escalation level.
        ade3, fde3, ade5, fde5: ``(B, N)`` average / final displacement (m) of each
            candidate from the human trajectory at 3 s and 5 s.
        valid5: ``(B,)`` the recording reaches 5 s (ADE5 / FDE5 defined).
    """

    features: jax.Array
    rule: jax.Array
    collided: jax.Array
    level: jax.Array
    ade3: jax.Array
    fde3: jax.Array
    ade5: jax.Array
    fde5: jax.Array
    valid5: jax.Array

    @property
    def n(self) -> int:
        return int(self.ade3.shape[0])

    def take(self, idx) -> LatticeData:
        idx = np.asarray(idx)
        if idx.dtype == bool:
            idx = np.nonzero(idx)[0]
        return jax.tree_util.tree_map(lambda x: x[idx], self)


def start_states(demos: Demo, start_accel: str = "zero") -> PlanState:
    """The demonstrations' start states for the lattice.

    ``start_accel="zero"`` plans from zero acceleration: the acceleration fitted on
    the past does not predict the next second on NGSIM (see ``demos.fit_start_state``)
    and candidates that start from it imitate worse (best-in-lattice ADE3 0.69 m
    against 0.45 m). ``"fit"``: the fitted one, clipped to the lattice's limits.
    """
    if start_accel not in ("zero", "fit"):
        raise ValueError(f"start_accel must be 'zero' or 'fit', got {start_accel!r}")
    a = jnp.zeros_like(demos.ego[..., 4]) if start_accel == "zero" else jnp.clip(demos.ego[..., 4], -4.0, 2.5)
    return PlanState.from_rows(jnp.asarray(demos.ego).at[..., 4].set(a))


def _obstacles(demos: Demo) -> Obstacles:
    return Obstacles(demos.obstacles, demos.obstacle_valid, demos.t, demos.obstacle_static)


# the lattice's XLA options (jaxplan.compile_options): 128 synthetic demonstrations took 1.44-1.71 s
# with them against 2.34-2.69 s without (three alternations in one process)
@jit(options=NO_YNN, static_argnames=("configs", "fcfg", "start_accel"))
def chunk_data(demos: Demo, idm: IDMParams, configs: tuple, fcfg: FeatureConfig, start_accel: str):
    """The lattice's candidate data of a chunk of demonstrations (one compiled program per chunk
    shape and configs)."""
    state = start_states(demos, start_accel)
    refs = jax.vmap(reference_line)(demos.ref_xy)
    obs = _obstacles(demos)
    T = configs[0].n_steps
    traffic = jax.vmap(lambda r, o: frenet_traffic(r, o.aligned(T), configs[0].dt))(refs, obs)
    parts: list[tuple[Any, ...]] = []
    for cfg in configs:
        res = plan_batch(state, refs, obs, cfg, CostWeights())
        feats = jax.vmap(candidate_features, in_axes=(0, 0, 0, 0, None, None, None))(
            res.candidates, res.ttc, traffic, state.v, cfg, idm, fcfg
        )
        xy = jnp.stack([res.candidates.traj.x, res.candidates.traj.y], -1)  # (B, N, T, 2)
        e = displacement(xy, demos.human_xy[:, None], demos.human_valid[:, None])
        c = res.candidates
        raw = {
            "x": c.traj.x,
            "y": c.traj.y,
            "s": c.s,
            "l": c.l,
            "v": c.traj.v,
            "a": c.traj.a,
            "lane": c.lane,
            "offset": c.offset,
            "v_end": c.v_end,
        }
        parts.append((feats, res.features, res.collided, c.level, e["ade3"], e["fde3"], e["ade5"], e["fde5"], raw))
    cat = [jnp.concatenate([p[i] for p in parts], axis=1) for i in range(8)]
    raw = {k: jnp.concatenate([p[8][k] for p in parts], axis=1) for k in parts[0][8]}
    valid5 = displacement(demos.human_xy, demos.human_xy, demos.human_valid)["valid5"]
    return LatticeData(*(cat + [valid5])), raw


def lattice_data(
    demos: Demo,
    configs: tuple = TUNING_CONFIGS,
    idm: IDMParams = IDMParams(),
    fcfg: FeatureConfig = FeatureConfig(),
    chunk: int = CHUNK,
    start_accel: str = "zero",
    keep: tuple = (),
):
    """Plan every config of the candidate set for every demonstration (in chunks, to bound memory).

    Args:
        demos: batched ``Demo`` (leading axis ``B``).
        configs: ``LatticeConfig``s with the same horizon and dt; their candidates are concatenated.
        idm: parameters of the desired-progress model of the features.
        chunk: demonstrations per compiled call (every call is padded to it: one compiled shape
            whatever the number of demonstrations).
        keep: names of candidate fields to return as well, ``{name: (B, N, ...)}`` numpy, from
            ``x, y, s, l, v, a`` (``(B, N, T)``) and ``lane, offset, v_end`` (``(B, N)``); for a few
            demonstrations (they are large).

    Returns:
        ``LatticeData`` (numpy-backed jax arrays), and the kept fields when ``keep`` is given.
    """
    if isinstance(configs, LatticeConfig):
        configs = (configs,)
    configs = tuple(c.validate() for c in configs)
    if len({(c.n_steps, c.dt) for c in configs}) != 1:
        raise ValueError("lattice_data: every config of the candidate set needs the same horizon and dt")
    B = demos.ego.shape[0]
    if B == 0:
        raise ValueError("lattice_data: no demonstrations")
    parts, kept = [], []
    for part, n in chunks(demos, chunk):
        out, raw = chunk_data(part, idm, configs, fcfg, start_accel)
        parts.append(jax.tree_util.tree_map(lambda x: np.asarray(x)[:n], out))
        kept.append({k: np.asarray(raw[k])[:n] for k in keep})
    data = jax.tree_util.tree_map(lambda *xs: jnp.asarray(np.concatenate(xs)), *parts)
    if not keep:
        return data
    return data, {k: np.concatenate([p[k] for p in kept]) for k in keep}


def candidate_xy(demos: Demo, configs: tuple = TUNING_CONFIGS, start_accel: str = "zero") -> np.ndarray:
    """``(B, N, T, 2)`` candidate positions of the candidate set (for plots; the order of
    ``lattice_data``, whose compiled call it reuses)."""
    raw = lattice_data(demos, configs, start_accel=start_accel, keep=("x", "y"))[1]
    return np.stack([raw["x"], raw["y"]], -1)


def eligible(data: LatticeData):
    """``(B, N)`` the candidates a planner can choose: the collision-free ones (of the lowest
    level that has one), or every candidate when all collide (``lattice.cost.eligible``)."""
    return rule_eligible(data.collided, data.level)[0]


def selection_cost(weights: dict, data: LatticeData):
    """``(B, N)`` the exact rule's cost (``jaxplan.lattice.cost.rule_cost``) for weights
    ``{alpha, beta, gamma, delta, ...}``."""
    return rule_cost(types.SimpleNamespace(**weights), data.rule, data.collided)


def lattice_loss(params: dict, data: LatticeData, sigma: float | None = 0.5, temperature: float = 1.0):
    """Mean cross entropy of the softmin form of the exact selection rule (softmin of
    ``selection_cost`` over the ``eligible`` candidates, log-parametrised weights) to the
    human-nearest target (5 s average displacement; one-hot for ``sigma=None``, else
    ``softmax(-ade / sigma)``)."""
    ok = eligible(data)
    target = target_distribution(data.ade5, ok, sigma)
    return jnp.mean(choice_nll(selection_cost(from_log(params), data), target, ok, temperature))


@jax.jit
def _rule_choice(weights: CostWeights, data: LatticeData):
    idx, _, _ = select(weights, data.rule, data.collided, data.level)
    return idx


def rule_choice(weights: dict, data: LatticeData) -> np.ndarray:
    """``(B,)`` the candidate the lattice's exact rule chooses with ``weights``."""
    return np.asarray(_rule_choice(weights_pytree({**default_weights(), **weights}), data))


def nearest_eligible(data: LatticeData) -> np.ndarray:
    """``(B,)`` the eligible candidate nearest the human (ADE3): the best the planner could choose."""
    return np.asarray(jnp.argmin(jnp.where(eligible(data), data.ade3, jnp.inf), axis=1))


def choice_errors(idx, data: LatticeData) -> dict:
    """Per-demonstration errors ``(B,)`` of chosen candidates ``idx (B,)`` in the form of
    ``metrics.displacement`` (``ade3``, ``valid3``, ...), plus ``collided`` and ``top1``
    (the choice is the nearest eligible candidate; colliding ones never count)."""
    idx = np.asarray(idx)
    take = lambda a: np.take_along_axis(np.asarray(a), idx[:, None], axis=1)[:, 0]
    out = {k: take(getattr(data, k)) for k in ("ade3", "fde3", "ade5", "fde5")}
    out.update(
        valid3=np.ones(len(idx), bool),
        valid5=np.asarray(data.valid5),
        collided=take(data.collided),
        top1=(idx == nearest_eligible(data)),
    )
    return out


def imitation_metrics(weights: dict, data: LatticeData) -> dict:
    """Top-1 agreement, ADE/FDE at 3 s and 5 s of the candidate the exact rule chooses with
    ``weights``, collision share, and the best eligible candidate's ADE3 (``oracle_ade3``)."""
    e = choice_errors(rule_choice(weights, data), data)
    return {
        "top1": float(e["top1"].mean()),
        "ade3": float(e["ade3"].mean()),
        "fde3": float(e["fde3"].mean()),
        "ade5": float(e["ade5"][e["valid5"]].mean()) if e["valid5"].any() else float("nan"),
        "fde5": float(e["fde5"][e["valid5"]].mean()) if e["valid5"].any() else float("nan"),
        "collision_share": float(e["collided"].mean()),
        "oracle_ade3": oracle_ade3(data),
    }


def oracle_ade3(data: LatticeData) -> float:
    """Mean ADE3 of the best eligible candidate (best in lattice)."""
    return float(np.mean(np.asarray(jnp.min(jnp.where(eligible(data), data.ade3, jnp.inf), axis=1))))


def synthetic_choices(data: LatticeData, weights: dict, temperature: float, seed: int = 0) -> LatticeData:
    """Replace the human distances by choices sampled from the softmin of the exact rule with ``weights``.

    The sampled candidate gets distance 0 and every other candidate 1, so the
    one-hot target is the sampled choice (for weight-recovery tests).
    """
    ok = eligible(data)
    logits = jnp.where(ok, -selection_cost(weights, data) / temperature, -jnp.inf)
    pick = jax.random.categorical(jax.random.PRNGKey(seed), logits, axis=-1)
    d = 1.0 - jax.nn.one_hot(pick, logits.shape[-1])
    return dataclasses.replace(data, ade3=d, ade5=d, fde3=d, fde5=d)


__all__ = [
    "TUNING_CONFIG",
    "TUNING_CONFIGS",
    "SPEEDS_17",
    "WEIGHT_NAMES",
    "RULE_FEATURES",
    "LatticeData",
    "default_weights",
    "weights_pytree",
    "lattice_data",
    "candidate_xy",
    "eligible",
    "selection_cost",
    "lattice_loss",
    "LEARNED",
    "rule_choice",
    "choice_errors",
    "imitation_metrics",
    "oracle_ade3",
    "nearest_eligible",
    "synthetic_choices",
    "start_states",
]
