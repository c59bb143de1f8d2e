"""A cost that imitates human drivers: linear in scene-by-candidate features, signed
weights where the sign means something, a learned temperature, trained on the metric.

Model: each candidate ``n`` of a scene gets the cost ``c_n = w . f_n / scale`` over the
features of ``jaxplan.tuning.features`` (divided by their spread on the training
set, ``scale``, so the weights compare). Penalties have positive weights
(``w = exp(theta)``); features in ``features.SIGNED`` take either sign
(``w = theta``). Only the direction of ``w`` decides the choice, so ``w`` is
normalised to unit length and the softness of the choice is a separate learned
temperature ``tau``: ``p_n = softmax(-c_n / tau)`` over the candidates the planner can
choose (``lattice_tuning.eligible``: never a colliding one while a free one exists).

The planner's choice is the exact ``argmin`` of ``c`` over the same candidates
(``choose``). Losses:

- ``expected_ade``: ``sum_n p_n ADE3_n``, the metric itself under the softmin
  (as ``tau -> 0`` it is the ADE3 of the planner's choice);
- ``cross_entropy``: to ``softmax(-ADE / sigma)`` over the eligible candidates (the
  maximum-entropy inverse-RL form); ``loss`` mixes both.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.tuning.features import FEATURES, SIGNED, UNITS
from jaxplan.tuning.lattice_tuning import LatticeData, eligible
from jaxplan.tuning.train import target_distribution

MODEL_KIND = "jaxplan.imitation/1"


def feature_scale(data: LatticeData) -> np.ndarray:
    """``(F,)`` the spread of each feature over the eligible candidates (std, 1 where constant)."""
    f = np.asarray(data.features, np.float64)
    ok = np.asarray(eligible(data))
    x = f[ok]
    sd = x.std(0)
    return np.where(sd > 1e-9, sd, 1.0).astype(np.float32)


def init_params(names=FEATURES) -> dict:
    """Trainable parameters: ``theta (F,)`` (0: every weight 1 or 0 before normalising) and ``log_tau``."""
    return {"theta": jnp.zeros(len(names), jnp.float32), "log_tau": jnp.asarray(np.log(0.3), jnp.float32)}


def direction(theta, signed) -> jax.Array:
    """Unit-length weights ``(..., F)`` from ``theta (..., F)``: ``exp`` for penalties, identity where ``signed``."""
    w = jnp.where(signed, theta, jnp.exp(jnp.minimum(theta, 30.0)))
    return w / jnp.maximum(jnp.linalg.norm(w, axis=-1, keepdims=True), 1e-12)


def cost(params: dict, features, scale, signed):
    """``(..., N)`` the model's cost of normalised features ``features / scale``.

    Args:
        features: ``(..., N, F)``; scale: ``(F,)``; signed: ``(F,)`` bool.
    """
    return jnp.einsum("...nf,f->...n", features / scale, direction(params["theta"], signed))


def _logits(params, data: LatticeData, scale, signed):
    c = cost(params, data.features, scale, signed)
    return jnp.where(eligible(data), -c / jnp.exp(params["log_tau"]), -jnp.inf)


def expected_ade(params: dict, data: LatticeData, scale, signed):
    """Mean over demonstrations of the softmin's expected ADE3 (m)."""
    p = jax.nn.softmax(_logits(params, data, scale, signed), axis=-1)
    return jnp.mean(jnp.sum(p * jnp.where(eligible(data), data.ade3, 0.0), axis=-1))


def cross_entropy(params: dict, data: LatticeData, scale, signed, sigma: float = 0.5):
    """Mean cross entropy of the softmin to ``softmax(-ADE3 / sigma)`` over the eligible candidates."""
    ok = eligible(data)
    target = target_distribution(data.ade3, ok, sigma)
    logp = jax.nn.log_softmax(_logits(params, data, scale, signed), axis=-1)
    return -jnp.mean(jnp.sum(jnp.where(target > 0, target * logp, 0.0), axis=-1))


def loss(params: dict, data: LatticeData, scale, signed, ce_weight: float = 0.0, sigma: float = 0.5):
    """``expected_ade + ce_weight * cross_entropy``."""
    out = expected_ade(params, data, scale, signed)
    if ce_weight:
        out = out + ce_weight * cross_entropy(params, data, scale, signed, sigma)
    return out


@jax.jit
def _choose(theta, features, scale, signed, ok):
    c = jnp.einsum("bnf,f->bn", features / scale, direction(theta, signed))
    return jnp.argmin(jnp.where(ok, c, jnp.inf), axis=-1)


@dataclasses.dataclass(frozen=True)
class ImitationModel:
    """A trained imitation cost (host side; ``save`` / ``load`` as JSON).

    Attributes:
        names: the features, in order.
        theta: ``(F,)`` trained parameters; scale: ``(F,)`` feature spreads on the training set.
        temperature: the learned softmin temperature (in units of the normalised cost).
        meta: free-form settings (IDM parameters of the features, candidate set, figures).
    """

    names: tuple
    theta: np.ndarray
    scale: np.ndarray
    temperature: float
    meta: dict = dataclasses.field(default_factory=dict)

    @property
    def signed(self) -> np.ndarray:
        return np.array([n in SIGNED for n in self.names])

    def params(self) -> dict:
        return {
            "theta": jnp.asarray(self.theta, jnp.float32),
            "log_tau": jnp.asarray(np.log(self.temperature), jnp.float32),
        }

    def weights(self) -> dict:
        """``{feature: weight}`` per unit of the normalised feature (unit-length vector)."""
        w = np.asarray(direction(jnp.asarray(self.theta), jnp.asarray(self.signed)))
        return dict(zip(self.names, w.tolist()))

    def physical_weights(self) -> dict:
        """``{feature: weight}`` per unit of the raw feature (``weights / scale``): cost per m, per m/s, ..."""
        w = self.weights()
        return {k: w[k] / float(s) for k, s in zip(self.names, self.scale)}

    def choose(self, data: LatticeData) -> np.ndarray:
        """``(B,)`` the planner's choice: the least cost among the eligible candidates."""
        if data.features.shape[-1] != len(self.names):
            raise ValueError(f"model has {len(self.names)} features, data {data.features.shape[-1]}")
        return np.asarray(
            _choose(
                jnp.asarray(self.theta, jnp.float32),
                data.features,
                jnp.asarray(self.scale),
                jnp.asarray(self.signed),
                eligible(data),
            )
        )

    def save(self, path: str) -> None:
        """Write the model as JSON (atomically)."""
        d = {
            "kind": MODEL_KIND,
            "features": list(self.names),
            "theta": [float(x) for x in self.theta],
            "scale": [float(x) for x in self.scale],
            "temperature": float(self.temperature),
            "weights": self.weights(),
            "physical_weights": self.physical_weights(),
            "units": {k: UNITS.get(k, "") for k in self.names},
            "meta": self.meta,
        }
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path + ".tmp", "w") as f:
            json.dump(d, f, indent=1, sort_keys=True)
        os.replace(path + ".tmp", path)

    @staticmethod
    def load(path: str) -> ImitationModel:
        """Read a model written by ``save``; one clear error names a bad file or field."""
        try:
            with open(path) as f:
                d = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{path}: not a readable model file ({type(e).__name__}: {e})") from None
        if not isinstance(d, dict) or d.get("kind") != MODEL_KIND:
            raise ValueError(f"{path}: not an imitation model (field 'kind' should be {MODEL_KIND!r})")
        try:
            names = tuple(str(n) for n in d["features"])
            theta = np.asarray(d["theta"], np.float32)
            scale = np.asarray(d["scale"], np.float32)
            tau = float(d["temperature"])
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{path}: missing or bad field ({type(e).__name__}: {e})") from None
        unknown = [n for n in names if n not in FEATURES]
        if unknown:
            raise ValueError(f"{path}: unknown features {unknown}; known: {', '.join(FEATURES)}")
        if theta.shape != (len(names),) or scale.shape != (len(names),):
            raise ValueError(f"{path}: 'theta' and 'scale' need one value per feature ({len(names)})")
        if not (
            np.all(np.isfinite(theta))
            and np.all(scale > 0)
            and np.all(np.isfinite(scale))
            and np.isfinite(tau)
            and tau > 0
        ):
            raise ValueError(f"{path}: 'theta' must be finite, 'scale' and 'temperature' positive and finite")
        return ImitationModel(names, theta, scale, tau, d.get("meta") or {})


@functools.cache
def _adam(lr: float, steps: int):
    """Adam with warm-up and cosine decay (one object per setting: the training step compiles once)."""
    return optax.adam(optax.warmup_cosine_decay_schedule(0.0, lr, max(1, steps // 10), steps, lr * 0.05))


@functools.partial(jax.jit, static_argnames=("opt", "ce_weight", "sigma", "l2"))
def _train_step(params, state, data, scale, signed, opt, ce_weight, sigma, l2):
    def objective(p):
        return loss(p, data, scale, signed, ce_weight, sigma) + l2 * jnp.sum(p["theta"] ** 2)

    val, g = jax.value_and_grad(objective)(params)
    upd, state = opt.update(g, state, params)
    return optax.apply_updates(params, upd), state, val


@jax.jit
def _chosen_ade3(theta, data: LatticeData, scale, signed):
    i = _choose(theta, data.features, scale, signed, eligible(data))
    return jnp.mean(jnp.take_along_axis(data.ade3, i[:, None], 1))


def fit_model(
    train: LatticeData,
    steps: int = 400,
    lr: float = 0.05,
    ce_weight: float = 0.0,
    sigma: float = 0.5,
    l2: float = 0.0,
    log_every: int = 10,
    val: LatticeData | None = None,
    names=FEATURES,
    init: dict | None = None,
) -> tuple[ImitationModel, dict]:
    """Fit the model on ``train`` with Adam (warm-up + cosine schedule), full batch.

    Args:
        ce_weight: weight of the cross-entropy term beside the expected ADE3.
        l2: penalty on ``theta`` (default none: with weights normalised to unit length it pulls
            the penalties towards equal weights, not towards zero; 1e-3 cost nothing on
            held-out vehicles but made the weights harder to read).
        val: optional held-out data, evaluated (exact choice) every ``log_every`` steps.

    Returns:
        (model, history) with history ``step``, ``loss``, ``train_ade3`` (exact choice),
        ``val_ade3`` (if ``val``), ``temperature`` and ``weights`` (normalised) over training.
    """
    if steps < 1:
        raise ValueError(f"fit_model: steps must be >= 1, got {steps}")
    if train.features.shape[-1] != len(names):
        raise ValueError(f"fit_model: {len(names)} feature names for {train.features.shape[-1]} features")
    scale = jnp.asarray(feature_scale(train))
    signed = jnp.asarray(np.array([n in SIGNED for n in names]))
    params = init_params(names) if init is None else init
    opt = _adam(float(lr), int(steps))
    state = opt.init(params)
    hist: dict[str, list[Any]] = {
        "step": [],
        "loss": [],
        "train_ade3": [],
        "val_ade3": [],
        "temperature": [],
        "weights": [],
    }
    for i in range(steps):
        params, state, lv = _train_step(
            params, state, train, scale, signed, opt, float(ce_weight), float(sigma), float(l2)
        )
        if i % log_every == 0 or i == steps - 1:
            hist["step"].append(i)
            hist["loss"].append(float(lv))
            hist["train_ade3"].append(float(_chosen_ade3(params["theta"], train, scale, signed)))
            if val is not None:
                hist["val_ade3"].append(float(_chosen_ade3(params["theta"], val, scale, signed)))
            hist["temperature"].append(float(jnp.exp(params["log_tau"])))
            hist["weights"].append(dict(zip(names, np.asarray(direction(params["theta"], signed)).tolist())))
    model = ImitationModel(
        tuple(names), np.asarray(params["theta"]), np.asarray(scale), float(jnp.exp(params["log_tau"]))
    )
    return model, hist


def random_search_model(
    train: LatticeData, evals: int, seed: int = 0, names=FEATURES, spread: float = 2.0
) -> tuple[ImitationModel, float]:
    """The best of ``evals`` random ``theta`` (normal, sd ``spread``; the first is all zeros) by
    the exact choice's training ADE3 (the metric itself, no gradient): the gradient-free
    baseline with the same features and budget.

    Returns:
        (model, training ADE3).
    """
    scale = jnp.asarray(feature_scale(train))
    signed = jnp.asarray(np.array([n in SIGNED for n in names]))
    rng = np.random.default_rng(seed)
    thetas = np.concatenate([np.zeros((1, len(names))), rng.normal(0.0, spread, (max(evals, 1) - 1, len(names)))])
    scores = np.array([float(_chosen_ade3(jnp.asarray(th, jnp.float32), train, scale, signed)) for th in thetas])
    best = int(np.argmin(scores))
    return ImitationModel(tuple(names), thetas[best].astype(np.float32), np.asarray(scale), 1.0), float(scores[best])
