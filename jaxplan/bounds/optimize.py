"""A piecewise-jerk path planned inside per-point bounds (the QP of ``jaxplan.bounds.path_qp``).

The solver is ``jaxplan.solvers.admm_solve`` (OSQP's ADMM, Stellato et al. 2020), one frame
batched with ``jax.vmap``, on the states with the rows' structure (``state_matvec``), warm
started from an earlier result (``z``, ``y``) where given.

After the ADMM, OSQP's solution polishing (``jaxplan.bounds.polish.polish_state``,
``PathQPConfig.polish``) finishes the QPs on which the ADMM's tail is slow; the polished
solution replaces the ADMM's only where it passes the same convergence test.

Infeasible input is reported, never returned as a path: where ``lower > upper``
somewhere, the initial state lies outside its bounds, or the certificate fires,
``feasible`` is False and ``l`` is NaN. ``ok`` = feasible, converged, and every bound met
within ``tol_violation``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from jaxplan.bounds.path_qp import PathQPConfig, PathWeights, state_matvec, state_problem
from jaxplan.bounds.polish import polish_state
from jaxplan.solvers.qp import admm_solve

__all__ = ["PathQPResult", "optimize_path", "optimize_path_jit"]


class PathQPResult(NamedTuple):
    """Solution per frame: ``l, dl, ddl (..., T)``, ``jerk (..., T-1)`` (NaN where not
    feasible); flags and figures ``(...)``.

    Attributes:
        feasible: bounds consistent, start inside, no infeasibility certificate.
        infeasible_certificate: the ADMM's primal-infeasibility certificate fired.
        converged: OSQP's residual test passed (by the ADMM's iterate or the polished solution).
        polished: the polished solution was accepted (``PathQPConfig.polish``).
        ok: feasible, converged and every bound met within ``tol_violation``.
        max_violation: largest bound violation of ``l`` (m).
        iterations: ADMM iterations run.
        rho: the final step size.
        z, y: the solver's states ``(..., 3T)`` and duals ``(..., 6T-3)`` (warm start of a later solve).
    """

    l: jnp.ndarray
    dl: jnp.ndarray
    ddl: jnp.ndarray
    jerk: jnp.ndarray
    feasible: jnp.ndarray
    infeasible_certificate: jnp.ndarray
    converged: jnp.ndarray
    polished: jnp.ndarray
    ok: jnp.ndarray
    max_violation: jnp.ndarray
    iterations: jnp.ndarray
    rho: jnp.ndarray
    z: jnp.ndarray
    y: jnp.ndarray


def _frame(lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi, l_ref, init, ds, weights, config, z0, y0):
    T = lower.shape[-1]
    dtype = lower.dtype
    bad_bounds = jnp.any(lower[1:] > upper[1:]) | jnp.any(dl_lo[1:] > dl_hi[1:]) | jnp.any(ddl_lo[1:] > ddl_hi[1:])
    start_out = (
        (init[0] < lower[0] - config.tol_violation)
        | (init[0] > upper[0] + config.tol_violation)
        | (init[1] < dl_lo[0] - 1e-6)
        | (init[1] > dl_hi[0] + 1e-6)
        | (init[2] < ddl_lo[0] - 1e-6)
        | (init[2] > ddl_hi[0] + 1e-6)
    )
    # Repaired bounds keep the solver well posed on bad input; the answer is masked.
    fix = lambda a, b: (jnp.where(a <= b, a, 0.5 * (a + b)), jnp.where(a <= b, b, 0.5 * (a + b)))
    lo_s, up_s = fix(lower, upper)
    dlo, dhi = fix(dl_lo, dl_hi)
    alo, ahi = fix(ddl_lo, ddl_hi)
    P, q, A, lo, hi = state_problem(ds, l_ref, lo_s, up_s, dlo, dhi, alo, ahi, config.jerk_max, init, weights)
    mv = state_matvec(ds, T)
    z, y, conv, infeas, it, rho, act_lo, act_hi = admm_solve(P, q, A, lo, hi, config.admm, z0, y0, mv)
    polished = jnp.asarray(False)
    if config.polish:
        zp, yp, pol_ok, _ = polish_state(P, q, A, lo, hi, z, act_lo, act_hi, config, mv, skip=infeas)
        polished = pol_ok & ~infeas
        z, y = jnp.where(polished, zp, z), jnp.where(polished, yp, y)
        conv = conv | polished
    l, dl, ddl = z[:T], z[T : 2 * T], z[2 * T :]
    viol = jnp.maximum(jnp.max(jnp.maximum(l[1:] - upper[1:], lower[1:] - l[1:])), 0.0)
    feasible = ~bad_bounds & ~start_out & ~infeas
    ok = feasible & conv & (viol <= config.tol_violation) & jnp.all(jnp.isfinite(z))
    nan = jnp.asarray(jnp.nan, dtype)
    mask = lambda v: jnp.where(feasible, v, nan)
    jerk = (ddl[1:] - ddl[:-1]) / ds
    return PathQPResult(
        mask(l), mask(dl), mask(ddl), mask(jerk), feasible, infeas, conv, polished, ok, viol, it, rho, z, y
    )


def optimize_path(
    lower,
    upper,
    ds,
    l_ref=None,
    init=None,
    weights: PathWeights | None = None,
    config: PathQPConfig = PathQPConfig(),
    dl_bounds=None,
    ddl_bounds=None,
    warm=None,
) -> PathQPResult:
    """Piecewise-jerk path inside bounds, batched over frames (``jax.vmap`` of one frame).

    Args:
        lower, upper: ``(..., T)`` bounds on ``l`` (``+-inf`` allowed).
        ds: grid spacing (m), a scalar or ``(...)``.
        l_ref: ``(..., T)`` reference offset (default 0).
        init: ``(..., 3)`` initial ``(l, l', l'')`` (default zeros).
        weights: ``PathWeights`` (arrays; differentiable by unrolling).
        config: ``PathQPConfig`` (static).
        dl_bounds: ``(lo, hi)`` each ``(..., T)``; default ``+-config.dl_max``.
        ddl_bounds: ``(lo, hi)`` each ``(..., T)`` (e.g. ``curvature_bounds``); default
            ``+-config.ddl_max``.
        warm: optional ``(z (..., 3T), y (..., 6T-3))`` from an earlier result.

    Returns:
        ``PathQPResult`` with leading dims ``...``.
    """
    lower, upper = jnp.asarray(lower), jnp.asarray(upper)
    dtype = jnp.result_type(lower, upper, float)
    lead = jnp.broadcast_shapes(lower.shape[:-1], upper.shape[:-1])
    T = lower.shape[-1]
    if T < 2:
        raise ValueError(f"optimize_path: needs at least 2 points, got {T}")
    l_ref = jnp.zeros(lead + (T,), dtype) if l_ref is None else jnp.asarray(l_ref, dtype)
    init = jnp.zeros(lead + (3,), dtype) if init is None else jnp.asarray(init, dtype)
    weights = PathWeights() if weights is None else weights
    weights = jax.tree_util.tree_map(lambda w: jnp.asarray(w, dtype), weights)
    if dl_bounds is None:
        dl_bounds = (jnp.full((T,), -config.dl_max, dtype), jnp.full((T,), config.dl_max, dtype))
    if ddl_bounds is None:
        ddl_bounds = (jnp.full((T,), -config.ddl_max, dtype), jnp.full((T,), config.ddl_max, dtype))
    flat = lambda x, tail: jnp.broadcast_to(jnp.asarray(x, dtype), lead + tail).reshape((-1,) + tail)
    args = [
        flat(lower, (T,)),
        flat(upper, (T,)),
        flat(dl_bounds[0], (T,)),
        flat(dl_bounds[1], (T,)),
        flat(ddl_bounds[0], (T,)),
        flat(ddl_bounds[1], (T,)),
        flat(l_ref, (T,)),
        flat(init, (3,)),
        flat(ds, ()),
    ]
    fn: Callable[..., Any]
    if warm is None:
        fn = lambda lo, up, dlo, dhi, ddlo, ddhi, lr, x0, ds_: _frame(
            lo, up, dlo, dhi, ddlo, ddhi, lr, x0, ds_, weights, config, None, None
        )
    else:
        args += [flat(warm[0], (3 * T,)), flat(warm[1], (6 * T - 3,))]
        fn = lambda lo, up, dlo, dhi, ddlo, ddhi, lr, x0, ds_, z0, y0: _frame(
            lo, up, dlo, dhi, ddlo, ddhi, lr, x0, ds_, weights, config, z0, y0
        )
    out = jax.vmap(fn)(*args)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


optimize_path_jit = jax.jit(optimize_path, static_argnames=("config",))
