"""Positive weights, a max-entropy choice loss and an optax training loop (shared by
the lattice and the speed tuning).

Weights are kept positive by a log parametrisation: ``w = exp(theta)``. The choice
model is a softmin over candidates, ``p_i = softmax(-cost_i / temperature)``; its loss
is the cross entropy to a target distribution that puts the probability on the
candidates closest to the human trajectory (``target_distribution``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.cli_args import HANDSET  # the name, not a file, of every planner's built-in weights


def to_log(weights: dict) -> dict:
    """``{name: w}`` (positive) to the trainable ``{name: log w}``."""
    return {k: jnp.log(jnp.asarray(v, jnp.float32)) for k, v in weights.items()}


def from_log(params: dict) -> dict:
    """The trainable ``{name: log w}`` back to positive weights ``{name: w}``."""
    return {k: jnp.exp(v) for k, v in params.items()}


def target_distribution(dist, valid, sigma: float | None = None):
    """Target probabilities ``(..., N)`` from each candidate's distance to the human ``(..., N)``.

    ``sigma=None``: all the mass on the nearest valid candidate (one-hot);
    otherwise ``softmax(-dist / sigma)`` over the valid candidates.
    """
    d = jnp.where(valid, dist, jnp.inf)
    if sigma is None:
        return jax.nn.one_hot(jnp.argmin(d, axis=-1), d.shape[-1], dtype=jnp.result_type(float))
    return jax.nn.softmax(-d / sigma, axis=-1)


def choice_nll(cost, target, valid, temperature=1.0):
    """Cross entropy ``(...)`` of the softmin choice model to ``target``.

    Args:
        cost: ``(..., N)`` candidate costs; target: ``(..., N)`` probabilities;
        valid: ``(..., N)`` candidates that exist.
    """
    logp = jax.nn.log_softmax(jnp.where(valid, -cost / temperature, -jnp.inf), axis=-1)
    return -jnp.sum(jnp.where(target > 0, target * logp, 0.0), axis=-1)


def fit(
    loss_fn: Callable,
    params: dict,
    data,
    steps: int = 300,
    lr: float = 0.05,
    batch_size: int | None = None,
    seed: int = 0,
    log_every: int = 10,
    frozen: tuple = (),
):
    """Minimise ``loss_fn(params, batch)`` with Adam and a warm-up + cosine learning-rate schedule.

    Args:
        loss_fn: ``(params, data) -> scalar`` for a batch (leading axis of every leaf of ``data``).
        params: initial pytree (a dict of arrays).
        data: pytree of arrays with a leading example axis.
        batch_size: examples per step (None: all of them every step).
        frozen: names of ``params`` kept fixed.

    Returns:
        (params, history) where history holds ``step``, ``loss`` and ``params`` every ``log_every`` steps.
    """
    sched = optax.warmup_cosine_decay_schedule(0.0, lr, max(1, steps // 10), steps, lr * 0.05)
    mask = {k: k not in frozen for k in params}
    opt = optax.masked(optax.adam(sched), mask)
    state = opt.init(params)
    n = jax.tree_util.tree_leaves(data)[0].shape[0]

    @jax.jit
    def step(params, state, idx):
        batch = jax.tree_util.tree_map(lambda x: x[idx], data)
        loss, g = jax.value_and_grad(loss_fn)(params, batch)
        upd, state = opt.update(g, state, params)
        return optax.apply_updates(params, upd), state, loss

    key = jax.random.PRNGKey(seed)
    hist: dict[str, list[Any]] = {"step": [], "loss": [], "params": []}
    for i in range(steps):
        if batch_size is None or batch_size >= n:
            idx = jnp.arange(n)
        else:
            key, sub = jax.random.split(key)
            idx = jax.random.choice(sub, n, (batch_size,), replace=False)
        params, state, loss = step(params, state, idx)
        if i % log_every == 0 or i == steps - 1:
            hist["step"].append(i)
            hist["loss"].append(float(loss))
            hist["params"].append({k: float(v) for k, v in from_log(params).items()})
    return params, hist


def random_search(
    loss_fn: Callable, params: dict, data, evals: int, scale: float = 2.0, seed: int = 0, frozen: tuple = ()
):
    """The best of ``evals`` random log-weight vectors around ``params`` (uniform in +-``scale``).

    Returns:
        (params, best loss).
    """
    rng = np.random.default_rng(seed)
    loss_j = jax.jit(loss_fn)
    best, best_loss = params, float(loss_j(params, data))
    for _ in range(evals - 1):
        cand = {k: (v if k in frozen else v + rng.uniform(-scale, scale)) for k, v in params.items()}
        loss = float(loss_j(cand, data))
        if loss < best_loss:
            best, best_loss = cand, loss
    return best, best_loss


def save_weights(path: str, weights: dict, meta: dict | None = None) -> None:
    """Write positive weights (and optional metadata) as JSON, atomically."""
    d = {"weights": {k: float(v) for k, v in weights.items()}, **({"meta": meta} if meta else {})}
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path + ".tmp", "w") as f:
        json.dump(d, f, indent=1, sort_keys=True)
    os.replace(path + ".tmp", path)


def load_weights(path: str, allowed=None, planner: str | None = None) -> dict:
    """Read weights written by ``save_weights``; a clear ``ValueError`` names a bad file.

    Args:
        path: the JSON file, or ``HANDSET`` (``"handset"``): no file, ``{}``, so that every planner
            keeps its built-in (hand-set) weights (``init_params({})``), to compare with a tuned file.
        allowed: the weight names the caller's planner has (e.g.
            ``jaxplan.tuning.lattice_tuning.WEIGHT_NAMES``); any other key, a misspelling
            like ``alhpa`` included, is refused with the list of allowed names.
        planner: the planner the weights are for; a file whose ``meta.planner`` names another
            one is refused.

    Returns:
        ``{name: weight}``, every weight finite and positive.
    """
    if path == HANDSET:
        return {}
    try:
        with open(path) as f:
            d = json.load(f)
        if isinstance(d, dict) and str(d.get("kind", "")).startswith("jaxplan.imitation"):
            raise LookupError
        w = d["weights"]
        out = {str(k): float(v) for k, v in w.items()}
    except LookupError as e:
        if isinstance(e, KeyError):
            raise ValueError(f"{path}: not a weights file (KeyError: {e})") from None
        raise ValueError(
            f"{path}: an imitation cost over scene features (jaxplan.tuning.imitation.ImitationModel), "
            "not the lattice rule's weights (the `.rule.json` beside it holds those)"
        ) from None
    except (OSError, json.JSONDecodeError, TypeError, ValueError, AttributeError) as e:
        raise ValueError(f"{path}: not a weights file ({type(e).__name__}: {e})") from None
    meta = d.get("meta") if isinstance(d, dict) else None
    if planner is not None and isinstance(meta, dict) and meta.get("planner") not in (None, planner):
        raise ValueError(f"{path}: weights for the {meta.get('planner')!r} planner, not for {planner!r}")
    if allowed is not None:
        unknown = sorted(set(out) - set(allowed))
        if unknown:
            raise ValueError(
                f"{path}: unknown weight {unknown[0]!r}"
                f"{f' (and {len(unknown) - 1} more)' if len(unknown) > 1 else ''}; "
                f"allowed: {', '.join(allowed)}"
            )
    bad = [k for k, v in out.items() if not (np.isfinite(v) and v > 0)]
    if bad:
        raise ValueError(f"{path}: weights must be positive and finite, not {bad}")
    return out
