"""A piecewise-jerk path planned inside per-point bounds, as a QP (ADMM; qpax optional).

Variables on a uniform s grid of T points (spacing ``ds``): ``x = [l, l', l'']``
(``3T``). Between grid points the jerk is constant, so

    l'_{i+1} = l'_i + ds/2 (l''_i + l''_{i+1})
    l_{i+1}  = l_i + ds l'_i + ds^2/3 l''_i + ds^2/6 l''_{i+1}

are equality constraints, with the initial state ``(l_0, l'_0, l''_0)``. The
cost is ``w_ref sum (l - l_ref)^2 + w_dl sum l'^2 + w_ddl sum l''^2 +
w_dddl sum ((l''_{i+1} - l''_i)/ds)^2``; the bounds ``lower <= l <= upper``,
``|l'| <= dl_max`` and ``|l''| <= ddl_max`` are inequalities.

Solvers (``PathQPConfig.backend``):

* ``"admm"`` (default): the equalities are eliminated in closed form (the
  states are a linear map of the jerks, ``jerk_map``) and an OSQP-style ADMM
  runs on the jerks for a fixed number of iterations. The ADMM matrix depends
  only on the weights and ``ds``, so it is inverted once for all frames and
  each iteration is a batched matmul; differentiable by unrolling.
* ``"qpax"``: qpax's primal-dual interior point (``solve_qp_primal``,
  implicit-function gradients), vmapped. Why it is not the default, measured
  on this jax 0.10.2 CPU build (shared 2-core machine): 1.6 s for one frame
  (warm), 3.3 s for 8 vmapped frames, 84 frames did not finish in 150 s; and in
  float32 its convergence flag is never set (it floors s, z at sqrt(eps), the
  KKT residual stalls near 1e-2) although its x matched a float64 SLSQP oracle
  to 1e-7. The ADMM matches the same oracle to ~4e-5 m in 1000 iterations
  (tests/test_bounds_core.py) for every frame of a batch in one call.

Infeasible input is reported, not solved into garbage: where any ``lower >
upper`` (or the initial ``l_0`` is outside its bounds) ``feasible`` is False,
the solver runs on repaired bounds and the returned path is NaN. ``ok`` also
requires convergence (qpax's flag or a relative KKT residual below ``rel_tol``:
in float32 qpax's absolute flag is unreachable, see ``_single``) and a bound
violation below ``tol_violation``.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import qpax

# Infinite bounds become this (m) for the interior point method.
_FAR = 1e3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PathWeights:
    """Cost weights (an array pytree: ``jax.grad`` / optax can update them)."""

    ref: Any = 1.0
    dl: Any = 10.0
    ddl: Any = 100.0
    dddl: Any = 1000.0


@dataclasses.dataclass(frozen=True)
class PathQPConfig:
    """Static settings of the path QP."""

    dl_max: float = 2.0
    ddl_max: float = 1.0
    max_iter: int = 40
    solver_tol: float = 1e-5
    tol_violation: float = 1e-3
    rel_tol: float = 1e-4
    backend: str = "admm"  # "admm" (default) or "qpax"
    admm_iters: int = 1000
    rho: float = 0.1


class PathQPResult(NamedTuple):
    """Solution per frame: ``l, dl, ddl (..., T)`` (NaN where not feasible), flags ``(...)``."""

    l: jnp.ndarray
    dl: jnp.ndarray
    ddl: jnp.ndarray
    feasible: jnp.ndarray
    converged: jnp.ndarray
    ok: jnp.ndarray
    max_violation: jnp.ndarray


def qp_matrices(T: int, ds, l_ref, lower, upper, init, weights: PathWeights, config: PathQPConfig):
    """Dense QP data ``(Q, q, A, b, G, h)`` for one frame (``l_ref, lower, upper (T,)``, ``init (3,)``)."""
    dtype = l_ref.dtype
    n = 3 * T
    eye = jnp.eye(T, dtype=dtype)
    D = (jnp.eye(T - 1, T, 1, dtype=dtype) - jnp.eye(T - 1, T, dtype=dtype)) / ds  # (T-1, T)
    Z = jnp.zeros((T, T), dtype)
    Q = 2 * jnp.block([[weights.ref * eye, Z, Z], [Z, weights.dl * eye, Z],
                       [Z, Z, weights.ddl * eye + weights.dddl * D.T @ D]])
    q = jnp.concatenate([-2 * weights.ref * l_ref, jnp.zeros(2 * T, dtype)])
    I0 = jnp.eye(T - 1, T, dtype=dtype)
    I1 = jnp.eye(T - 1, T, 1, dtype=dtype)
    A_pos = jnp.concatenate([I1 - I0, -ds * I0, -(ds ** 2 / 3) * I0 - (ds ** 2 / 6) * I1], axis=1)
    A_vel = jnp.concatenate([jnp.zeros((T - 1, T), dtype), I1 - I0, -(ds / 2) * (I0 + I1)], axis=1)
    A_init = jnp.zeros((3, n), dtype).at[0, 0].set(1.0).at[1, T].set(1.0).at[2, 2 * T].set(1.0)
    A = jnp.concatenate([A_pos, A_vel, A_init], axis=0)
    b = jnp.concatenate([jnp.zeros(2 * (T - 1), dtype), init])
    G1 = jnp.eye(n, dtype=dtype)
    G = jnp.concatenate([G1, -G1], axis=0)
    hi = jnp.concatenate([upper, jnp.full((T,), config.dl_max, dtype), jnp.full((T,), config.ddl_max, dtype)])
    lo = jnp.concatenate([lower, jnp.full((T,), -config.dl_max, dtype), jnp.full((T,), -config.ddl_max, dtype)])
    h = jnp.concatenate([hi, -lo])
    return Q, q, A, b, G, h


def _single(lower, upper, l_ref, init, ds, weights, config):
    T = lower.shape[0]
    dtype = l_ref.dtype
    lower = jnp.maximum(lower, -_FAR)
    upper = jnp.minimum(upper, _FAR)
    feasible = jnp.all(lower <= upper) & (init[0] >= lower[0]) & (init[0] <= upper[0])
    # Repaired bounds for infeasible input keep the solver well posed; the answer is masked.
    mid = 0.5 * (lower + upper)
    lo_s = jnp.where(lower <= upper, lower, mid - 1.0)
    up_s = jnp.where(lower <= upper, upper, mid + 1.0)
    init_s = init.at[0].set(jnp.clip(init[0], lo_s[0], up_s[0]))
    Q, q, A, b, G, h = qp_matrices(T, ds, l_ref, lo_s, up_s, init_s, weights, config)
    x = qpax.solve_qp_primal(Q, q, A, b, G, h, solver_tol=config.solver_tol, max_iter=config.max_iter)
    # Convergence of the same solve (forward only): qpax's own flag, or a relative KKT
    # residual. qpax floors s and z at sqrt(eps), so in float32 its absolute residual
    # stalls near 1e-2 on this problem even when x agrees with a float64 oracle to
    # 1e-7; the relative test is the float32-meaningful one.
    sg = jax.lax.stop_gradient
    xs, ss, zs, ys, flag, _ = qpax.solve_qp(sg(Q), sg(q), sg(A), sg(b), sg(G), sg(h),
                                            solver_tol=config.solver_tol, max_iter=config.max_iter)
    scale = 1.0 + jnp.max(jnp.abs(Q)) * (1.0 + jnp.max(jnp.abs(xs))) + jnp.max(jnp.abs(q))
    stat = jnp.max(jnp.abs(Q @ xs + q + A.T @ ys + G.T @ zs)) / scale
    comp = jnp.max(ss * zs) / scale
    prim = jnp.maximum(jnp.max(jnp.abs(A @ xs - b)), jnp.max(jnp.maximum(G @ xs - h, 0.0)))
    rel_ok = (stat <= config.rel_tol) & (comp <= config.rel_tol) & (prim <= config.tol_violation)
    l, dl, ddl = x[:T], x[T:2 * T], x[2 * T:]
    viol = jnp.maximum(jnp.max(jnp.maximum(l - upper, lower - l)), 0.0)
    converged = (flag == 1) | rel_ok
    ok = feasible & converged & (viol <= config.tol_violation)
    nan = jnp.asarray(jnp.nan, dtype)
    mask = lambda v: jnp.where(feasible, v, nan)
    return PathQPResult(mask(l), mask(dl), mask(ddl), feasible, converged, ok, viol)


def jerk_map(T: int, ds, dtype=jnp.float32):
    """Piecewise-jerk states as a linear map: ``x = M j + H x0``.

    ``x = [l, l', l''] (3T)``, ``j (T-1)`` the constant jerk on each interval and
    ``x0 = (l_0, l'_0, l''_0)``. Closed form (``Phi^n`` of the jerk integrator).

    Returns:
        (M ``(3T, T-1)``, H ``(3T, 3)``).
    """
    ds = jnp.asarray(ds, dtype)
    i = jnp.arange(T)[:, None]
    k = jnp.arange(T - 1)[None, :]
    n = (i - 1 - k).astype(dtype) * ds  # n * ds for k < i
    on = (k < i).astype(dtype)
    m_l = on * (ds ** 3 / 6 + n * ds ** 2 / 2 + n ** 2 * ds / 2)
    m_d = on * (ds ** 2 / 2 + n * ds)
    m_a = on * ds
    t = jnp.arange(T, dtype=dtype) * ds
    one, zero = jnp.ones(T, dtype), jnp.zeros(T, dtype)
    H = jnp.concatenate([jnp.stack([one, t, t ** 2 / 2], -1), jnp.stack([zero, one, t], -1),
                         jnp.stack([zero, zero, one], -1)], axis=0)
    return jnp.concatenate([m_l, m_d, m_a], axis=0), H


def _admm(lower, upper, l_ref, init, ds, weights, config):
    """OSQP-style ADMM on the jerks, all frames at once. Inputs ``(F, T)``, ``(F, 3)``."""
    F, T = lower.shape
    dtype = lower.dtype
    M, H = jerk_map(T, ds, dtype)
    Q, _, _, _, _, _ = qp_matrices(T, ds, l_ref[0], lower[0], upper[0], init[0], weights, config)
    q = jnp.concatenate([-2 * weights.ref * l_ref, jnp.zeros((F, 2 * T), dtype)], axis=1)  # (F, 3T)
    P = M.T @ Q @ M  # (T-1, T-1), shared by all frames
    c = 1.0 / jnp.max(jnp.abs(jnp.diag(P)))  # cost scaling (same minimiser)
    P = c * P
    off = init @ H.T  # (F, 3T) state from the initial condition alone
    qz = c * (off @ Q + q) @ M  # (F, T-1)
    # Constraint scaling: rows of M normalised so that one rho fits l, l' and l''.
    rs = 1.0 / jnp.maximum(jnp.linalg.norm(M, axis=1), 1e-6)
    rs = jnp.where(jnp.linalg.norm(M, axis=1) > 1e-9, rs, 0.0)  # rows fixed by x0 alone
    A = M * rs[:, None]
    big = jnp.asarray(_FAR, dtype)
    lim = jnp.concatenate([jnp.full((T,), config.dl_max, dtype), jnp.full((T,), config.ddl_max, dtype)])
    hi = (jnp.concatenate([upper, jnp.broadcast_to(lim, (F, 2 * T))], 1) - off) * rs
    lo = (jnp.concatenate([lower, jnp.broadcast_to(-lim, (F, 2 * T))], 1) - off) * rs
    hi, lo = jnp.minimum(hi, big), jnp.maximum(lo, -big)
    rho, sigma, alpha = config.rho, 1e-6, 1.6
    K = P + sigma * jnp.eye(T - 1, dtype=dtype) + rho * A.T @ A
    Kinv = jnp.linalg.inv(K)  # one small matrix for every frame: no batched solve

    def step(_, st):
        z, w, y = st  # jerks (F, T-1), constraint copy (F, 3T), duals (F, 3T)
        rhs = sigma * z - qz + (rho * w - y) @ A
        zt = rhs @ Kinv.T
        wt = zt @ A.T
        wr = alpha * wt + (1 - alpha) * w
        wn = jnp.clip(wr + y / rho, lo, hi)
        y = y + rho * (wr - wn)
        z = alpha * zt + (1 - alpha) * z
        return z, wn, y

    z0 = jnp.zeros((F, T - 1), dtype)
    w0 = jnp.clip(jnp.zeros((F, 3 * T), dtype), lo, hi)
    z, w, y = jax.lax.fori_loop(0, config.admm_iters, step, (z0, w0, jnp.zeros((F, 3 * T), dtype)))
    x = z @ M.T + off
    prim = jnp.max(jnp.abs(z @ A.T - w) / jnp.maximum(rs, 1e-6) * (rs > 0), axis=1)
    dual = jnp.max(jnp.abs(z @ P + qz + y @ A), axis=1)
    return x, (prim <= config.tol_violation) & (dual <= config.rel_tol)


def _admm_frames(lower, upper, l_ref, init, ds, weights, config):
    T = lower.shape[-1]
    lower = jnp.maximum(lower, -_FAR)
    upper = jnp.minimum(upper, _FAR)
    feasible = jnp.all(lower <= upper, -1) & (init[:, 0] >= lower[:, 0]) & (init[:, 0] <= upper[:, 0])
    mid = 0.5 * (lower + upper)
    lo_s = jnp.where(lower <= upper, lower, mid)
    up_s = jnp.where(lower <= upper, upper, mid)
    init_s = init.at[:, 0].set(jnp.clip(init[:, 0], lo_s[:, 0], up_s[:, 0]))
    x, converged = _admm(lo_s, up_s, l_ref, init_s, ds, weights, config)
    l, dl, ddl = x[:, :T], x[:, T:2 * T], x[:, 2 * T:]
    viol = jnp.maximum(jnp.max(jnp.maximum(l - upper, lower - l), -1), 0.0)
    ok = feasible & converged & (viol <= config.tol_violation)
    nan = jnp.asarray(jnp.nan, x.dtype)
    mask = lambda v: jnp.where(feasible[:, None], v, nan)
    return PathQPResult(mask(l), mask(dl), mask(ddl), feasible, converged, ok, viol)


def optimize_path(lower, upper, ds, l_ref=None, init=None, weights: PathWeights | None = None,
                  config: PathQPConfig = PathQPConfig()) -> PathQPResult:
    """Piecewise-jerk path inside bounds, batched over frames.

    Args:
        lower, upper: ``(..., T)`` bounds on ``l`` (``+-inf`` allowed).
        ds: grid spacing (m), a scalar.
        l_ref: ``(..., T)`` reference offset (default 0).
        init: ``(..., 3)`` initial ``(l, l', l'')`` (default zeros).
        weights: ``PathWeights`` (arrays; differentiable).
        config: ``PathQPConfig`` (static).

    Returns:
        ``PathQPResult``.
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
    flat = lambda x, tail: jnp.broadcast_to(x.astype(dtype), lead + tail).reshape((-1,) + tail)
    ds = jnp.asarray(ds, dtype)
    if config.backend == "admm":
        out = _admm_frames(flat(lower, (T,)), flat(upper, (T,)), flat(l_ref, (T,)), flat(init, (3,)),
                           ds, weights, config)
        return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)
    out = jax.vmap(lambda lo, up, r, i0: _single(lo, up, r, i0, ds, weights, config))(
        flat(lower, (T,)), flat(upper, (T,)), flat(l_ref, (T,)), flat(init, (3,)))
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


optimize_path_jit = jax.jit(optimize_path, static_argnames=("config",))
