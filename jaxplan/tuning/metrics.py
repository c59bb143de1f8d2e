"""Imitation metrics: displacement errors against the recorded future, and bootstrap
confidence intervals over scenarios.

ADE_h: mean distance over the samples in ``(0, h]`` s (the start excluded); FDE_h:
the distance at ``h``. A demonstration whose recording ends before ``h`` has no
ADE_h / FDE_h (``valid`` False); every demonstration has at least ``min_future``
seconds (``DemoConfig``), so ADE3 is defined for all of them by default.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

HORIZONS = (3.0, 5.0)


def displacement(pred_xy, human_xy, human_valid, dt: float = 0.1, horizons=HORIZONS) -> dict:
    """ADE / FDE of predictions against the human future.

    Args:
        pred_xy: ``(..., T', 2)`` predicted positions at ``k * dt`` (index 0 = start).
        human_xy: ``(T, 2)`` or broadcastable ``(..., T, 2)``; human_valid: ``(..., T)``.

    Returns:
        ``{"ade3", "fde3", "valid3", "ade5", ...}``: errors ``(...)`` and their validity
        ``(...)`` (broadcast over the leading dims of ``pred_xy``).
    """
    out = {}
    for h in horizons:
        k = int(round(h / dt))
        n = min(k, pred_xy.shape[-2] - 1, human_xy.shape[-2] - 1)
        err = jnp.linalg.norm(pred_xy[..., 1 : n + 1, :] - human_xy[..., 1 : n + 1, :], axis=-1)
        ok = human_valid[..., n] & (n == k)
        tag = f"{h:g}"
        out[f"ade{tag}"] = err.mean(-1)
        out[f"fde{tag}"] = err[..., -1]
        out[f"valid{tag}"] = jnp.broadcast_to(ok, err.shape[:-1])
    return out


def masked_mean(x, valid) -> float:
    x, valid = np.asarray(x, np.float64), np.asarray(valid, bool)
    return float(x[valid].mean()) if valid.any() else float("nan")


def bootstrap_ci(
    values, clusters, valid=None, n_boot: int = 1000, level: float = 0.95, seed: int = 0, ratio_to=None
) -> tuple[float, float, float]:
    """Mean of ``values`` and its bootstrap confidence interval, resampling whole clusters
    (scenarios) with replacement: demonstrations of one scenario are not independent.

    Args:
        values: ``(B,)``; clusters: ``(B,)`` labels (scenario ids); valid: ``(B,)`` mask.
        ratio_to: ``(B,)`` optional: the statistic is ``mean(values) / mean(ratio_to)`` over
            the same resampled demonstrations (a paired comparison).

    Returns:
        (estimate, low, high).
    """
    v = np.asarray(values, np.float64)
    m = np.ones(len(v), bool) if valid is None else np.asarray(valid, bool)
    r = None if ratio_to is None else np.asarray(ratio_to, np.float64)
    labels, inv = np.unique(np.asarray(clusters)[m].astype(str), return_inverse=True)
    v = v[m]
    r = None if r is None else r[m]
    if len(v) == 0:
        return float("nan"), float("nan"), float("nan")
    C = len(labels)
    sums = np.bincount(inv, v, C)
    cnt = np.bincount(inv, None, C)
    rs = None if r is None else np.bincount(inv, r, C)
    den = cnt if rs is None else rs
    est = float(sums.sum() / den.sum())
    rng = np.random.default_rng(seed)
    w = rng.multinomial(C, np.full(C, 1.0 / C), size=n_boot).astype(np.float64)  # (n_boot, C) cluster counts
    boots = (w @ sums) / np.maximum(w @ den, 1e-300)
    lo, hi = np.quantile(boots, [(1 - level) / 2, 1 - (1 - level) / 2])
    return est, float(lo), float(hi)


def summary(errors: dict, clusters, prefix: str = "", collided=None, n_boot: int = 1000, seed: int = 0) -> dict:
    """Flat figures from per-demonstration errors (``displacement`` of one prediction per demo):
    ``{prefix}ade3`` with ``{prefix}ade3_ci_lo`` / ``_ci_hi``, likewise FDE3, ADE5, FDE5, and
    ``{prefix}collision_share`` when ``collided (B,)`` is given."""
    out = {}
    for name in ("ade3", "fde3", "ade5", "fde5"):
        h = name[3:]
        est, lo, hi = bootstrap_ci(errors[name], clusters, errors[f"valid{h}"], n_boot, seed=seed)
        out[f"{prefix}{name}"] = est
        out[f"{prefix}{name}_ci_lo"] = lo
        out[f"{prefix}{name}_ci_hi"] = hi
    if collided is not None:
        out[f"{prefix}collision_share"] = float(np.mean(np.asarray(collided, np.float64)))
    return out
