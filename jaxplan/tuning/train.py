"""Positive weights, a max-entropy choice loss and an optax training loop (shared by
the lattice and the speed tuning).

Weights are kept positive by a log parametrisation: ``w = exp(theta)``. The choice
model is a softmin over candidates, ``p_i = softmax(-cost_i / temperature)``; its loss
is the cross entropy to a target distribution that puts the probability on the
candidates closest to the human trajectory (``target_distribution``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxplan.weights import HANDSET, load_weights, save_weights  # noqa: F401  (the tuning commands' files)


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
