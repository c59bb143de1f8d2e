"""A piecewise-jerk path planned inside per-point bounds: an OSQP-style ADMM on the jerks.

Variables on a uniform s grid of T points (spacing ``ds``): the states ``x = [l, l', l'']``
(``3T``) and the constant jerk ``j_i = (l''_{i+1} - l''_i) / ds`` on each interval, so

    l''_{i+1} = l''_i + ds j_i
    l'_{i+1}  = l'_i + ds l''_i + ds^2/2 j_i
    l_{i+1}   = l_i + ds l'_i + ds^2/2 l''_i + ds^3/6 j_i

from the initial state ``x0 = (l_0, l'_0, l''_0)``: the states are a linear map of the
jerks, ``x = M j + H x0`` (``jerk_map``), and the QP is in the ``T - 1`` jerks alone:

    min  w_ref sum (l - l_ref)^2 + w_dl sum l'^2 + w_ddl sum l''^2 + w_dddl sum j^2
    s.t. lower <= l <= upper,  dl_lower <= l' <= dl_upper,  ddl_lower <= l'' <= ddl_upper,
         |j| <= jerk_max                                   (points 1 .. T-1; point 0 is x0)

``ddl`` bounds carry the curvature limit from the steering limit (``curvature_bounds``:
``kappa = l'' + kappa_ref`` to first order, so ``-kappa_max - kappa_ref <= l'' <=
kappa_max - kappa_ref``), the jerk bound bounds the steering rate.

The solver (``_admm``, one frame, batched with ``jax.vmap``) is OSQP's ADMM (Stellato et
al. 2020) for ``min 1/2 z'Pz + q'z s.t. lo <= C z <= hi``: modified Ruiz equilibration of
the KKT matrix and cost scaling, over-relaxation ``alpha = 1.6``, the convergence test on
the unscaled primal and dual residuals (``eps_abs``, ``eps_rel``), the adaptive ``rho``
(every ``check_every`` iterations, ``rho *= sqrt(scaled primal / scaled dual residual)``,
refactorised when it moves by more than 5x) and the primal-infeasibility certificate
(``delta y`` with ``||C' dy|| <= eps_pinf ||dy||`` and ``hi' dy+ + lo' dy- < -eps_pinf
||dy||``). The ``T - 1`` by ``T - 1`` matrix is inverted densely (it is small), so an
iteration is two small matrix-vector products. Warm starts (``z0``, ``y0``) are accepted.

Infeasible input is reported, never returned as a path: where ``lower > upper``
somewhere, the initial state lies outside its bounds, or the certificate fires,
``feasible`` is False and ``l`` is NaN. ``ok`` = feasible, converged, and every bound met
within ``tol_violation``.
"""
from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

# Infinite bounds become this (m, or its unit) inside the solver.
_FAR = 1e4


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
    """Static settings of the path QP.

    Attributes:
        dl_max: ``|l'|`` bound (default when no per-point bound is given).
        ddl_max: ``|l''|`` bound (default when no per-point bound is given), 1/m.
        jerk_max: ``|l'''|`` bound, 1/m^2.
        eps_abs, eps_rel: OSQP's convergence tolerances (unscaled residuals).
        eps_pinf: tolerance of the primal-infeasibility certificate.
        rho: initial ADMM step; adapted every ``check_every`` iterations (``adaptive_rho``).
        max_iter: iteration cap (a multiple of ``check_every``).
        tol_violation: bound violation (m) above which a solution is not ``ok``.
        ruiz_iters: equilibration passes.
    """

    dl_max: float = 2.0
    ddl_max: float = 1.0
    jerk_max: float = 1.0
    eps_abs: float = 1e-4
    eps_rel: float = 1e-4
    eps_pinf: float = 1e-5
    rho: float = 0.1
    adaptive_rho: bool = True
    check_every: int = 25
    max_iter: int = 4000
    tol_violation: float = 1e-3
    ruiz_iters: int = 10


class PathQPResult(NamedTuple):
    """Solution per frame: ``l, dl, ddl (..., T)``, ``jerk (..., T-1)`` (NaN where not
    feasible); flags and figures ``(...)``.

    Attributes:
        feasible: bounds consistent, start inside, no infeasibility certificate.
        infeasible_certificate: the ADMM's primal-infeasibility certificate fired.
        converged: OSQP's residual test passed.
        ok: feasible, converged and every bound met within ``tol_violation``.
        max_violation: largest bound violation of ``l`` (m).
        iterations: ADMM iterations run.
        rho: the final step size.
        z, y: the solver's jerks ``(..., T-1)`` and duals (warm start of a later solve).
    """

    l: jnp.ndarray
    dl: jnp.ndarray
    ddl: jnp.ndarray
    jerk: jnp.ndarray
    feasible: jnp.ndarray
    infeasible_certificate: jnp.ndarray
    converged: jnp.ndarray
    ok: jnp.ndarray
    max_violation: jnp.ndarray
    iterations: jnp.ndarray
    rho: jnp.ndarray
    z: jnp.ndarray
    y: jnp.ndarray


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


def curvature_bounds(kappa_ref, kappa_max, margin: float = 0.9):
    """``l''`` bounds ``(lower, upper)`` from the steering limit: ``|l'' + kappa_ref| <=
    margin * kappa_max`` (the path's curvature to first order in ``l, l'``).

    Args:
        kappa_ref: ``(..., T)`` curvature of the reference line.
        kappa_max: ``()`` or ``(...)`` ``tan(max_steer) / wheelbase``.
    """
    km = margin * jnp.asarray(kappa_max)[..., None]
    return -km - kappa_ref, km - kappa_ref


def jerk_problem(ds, l_ref, lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi, jerk_max, init, weights: PathWeights):
    """The QP in the jerks for one frame: ``min 1/2 z'Pz + q'z, lo <= C z <= hi``.

    Args:
        ds: ``()``; l_ref, lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi: ``(T,)``; jerk_max:
        ``()``; init: ``(3,)``.

    Returns:
        (P ``(n, n)``, q ``(n,)``, C ``(m, n)``, lo ``(m,)``, hi ``(m,)``, M, H) with
        ``n = T - 1``, ``m = 4 (T - 1)`` (rows: l, l', l'' at points 1.., then the jerks).
    """
    T = l_ref.shape[-1]
    dtype = l_ref.dtype
    M, H = jerk_map(T, ds, dtype)
    wq = jnp.concatenate([jnp.full((T,), weights.ref, dtype), jnp.full((T,), weights.dl, dtype),
                          jnp.full((T,), weights.ddl, dtype)])
    off = H @ init  # (3T,)
    xr = jnp.concatenate([l_ref, jnp.zeros(2 * T, dtype)])
    P = 2 * (M.T * wq) @ M + 2 * weights.dddl * jnp.eye(T - 1, dtype=dtype)
    q = 2 * M.T @ (wq * (off - xr))
    rows = jnp.concatenate([jnp.arange(1, T), T + jnp.arange(1, T), 2 * T + jnp.arange(1, T)])
    C = jnp.concatenate([M[rows], jnp.eye(T - 1, dtype=dtype)], axis=0)
    big = jnp.asarray(_FAR, dtype)
    hi_x = jnp.concatenate([upper, dl_hi, ddl_hi])[rows] - off[rows]
    lo_x = jnp.concatenate([lower, dl_lo, ddl_lo])[rows] - off[rows]
    jm = jnp.full((T - 1,), jerk_max, dtype)
    hi = jnp.clip(jnp.concatenate([hi_x, jm]), -big, big)
    lo = jnp.clip(jnp.concatenate([lo_x, -jm]), -big, big)
    return P, q, C, lo, hi, M, H


def _ruiz(P, C, iters):
    """Modified Ruiz equilibration of ``[[P, C'], [C, 0]]``: column scaling ``d (n,)``, row
    scaling ``e (m,)``, cost scaling ``c``."""
    n, m = P.shape[0], C.shape[0]
    d = jnp.ones(n, P.dtype)
    e = jnp.ones(m, P.dtype)

    def body(_, st):
        d, e = st
        Ps = d[:, None] * P * d[None, :]
        Cs = e[:, None] * C * d[None, :]
        col = jnp.maximum(jnp.max(jnp.abs(Ps), 0), jnp.max(jnp.abs(Cs), 0))
        row = jnp.max(jnp.abs(Cs), 1)
        d = d / jnp.sqrt(jnp.clip(col, 1e-4, 1e4))
        e = e / jnp.sqrt(jnp.clip(row, 1e-4, 1e4))
        return d, e

    d, e = jax.lax.fori_loop(0, iters, body, (d, e))
    Ps = d[:, None] * P * d[None, :]
    return d, e, Ps


def admm_solve(P, q, C, lo, hi, config: PathQPConfig, z0=None, y0=None):
    """OSQP's ADMM for ``min 1/2 z'Pz + q'z, lo <= C z <= hi`` (one problem; vmap it).

    Args:
        P: ``(n, n)`` positive definite; q: ``(n,)``; C: ``(m, n)``; lo, hi: ``(m,)`` finite.
        config: tolerances and iteration counts.
        z0, y0: optional warm start ``(n,)``, ``(m,)`` (unscaled).

    Returns:
        (z ``(n,)``, y ``(m,)``, converged, infeasible, iterations, rho).
    """
    dtype = P.dtype
    n, m = P.shape[0], C.shape[0]
    d, e, Ps = _ruiz(P, C, config.ruiz_iters)
    qs = d * q
    c = 1.0 / jnp.maximum(jnp.maximum(jnp.max(jnp.abs(Ps)), jnp.max(jnp.abs(qs))), 1e-6)
    c = jnp.clip(c, 1e-4, 1e4)
    Ps, qs = c * Ps, c * qs
    Cs = e[:, None] * C * d[None, :]
    los, his = e * lo, e * hi
    sigma, alpha = 1e-6, 1.6
    eye = jnp.eye(n, dtype=dtype)

    def factor(rho):
        return jnp.linalg.inv(Ps + sigma * eye + rho * Cs.T @ Cs)

    zs = jnp.zeros(n, dtype) if z0 is None else z0 / d
    ys = jnp.zeros(m, dtype) if y0 is None else y0 * c / e
    ws = jnp.clip(Cs @ zs, los, his)
    rho0 = jnp.asarray(config.rho, dtype)

    def residuals(zs, ws, ys):
        Cz = Cs @ zs
        prim = jnp.max(jnp.abs((Cz - ws) / e))
        Pz = Ps @ zs
        Cty = Cs.T @ ys
        dual = jnp.max(jnp.abs((Pz + qs + Cty) / d)) / c
        prim_scale = jnp.maximum(jnp.max(jnp.abs(Cz / e)), jnp.max(jnp.abs(ws / e)))
        dual_scale = jnp.maximum(jnp.maximum(jnp.max(jnp.abs(Pz / d)), jnp.max(jnp.abs(Cty / d))),
                                 jnp.max(jnp.abs(qs / d))) / c
        return prim, dual, prim_scale, dual_scale

    def block(st):
        zs, ws, ys, rho, Kinv, it, done, conv, infeas = st

        def step(_, inner):
            zs, ws, ys, _ = inner
            rhs = sigma * zs - qs + Cs.T @ (rho * ws - ys)
            zt = Kinv @ rhs
            wt = Cs @ zt
            wr = alpha * wt + (1 - alpha) * ws
            wn = jnp.clip(wr + ys / rho, los, his)
            yn = ys + rho * (wr - wn)
            zn = alpha * zt + (1 - alpha) * zs
            return zn, wn, yn, ys

        zn, wn, yn, yprev = jax.lax.fori_loop(0, config.check_every, step, (zs, ws, ys, ys))
        prim, dual, ps_, ds_ = residuals(zn, wn, yn)
        c_ok = (prim <= config.eps_abs + config.eps_rel * ps_) & (dual <= config.eps_abs + config.eps_rel * ds_)
        # Primal infeasibility certificate on the unscaled dual step dy = E (y_k - y_{k-1}) / c.
        dy = e * (yn - yprev) / c
        ndy = jnp.max(jnp.abs(dy))
        ctdy = jnp.max(jnp.abs((Cs.T @ (yn - yprev)) / d / c))
        support = jnp.sum(hi * jnp.maximum(dy, 0.0) + lo * jnp.minimum(dy, 0.0))
        inf_ok = (ndy > 1e-12) & (ctdy <= config.eps_pinf * ndy) & (support < -config.eps_pinf * ndy)
        if config.adaptive_rho:
            ratio = (prim / jnp.maximum(ps_, 1e-10)) / jnp.maximum(dual / jnp.maximum(ds_, 1e-10), 1e-10)
            rho_new = jnp.clip(rho * jnp.sqrt(ratio), 1e-6, 1e6)
            change = (rho_new > 5 * rho) | (rho_new < rho / 5)
            rho_new = jnp.where(change & ~c_ok & ~inf_ok, rho_new, rho)
            Kinv_new = jnp.where(change & ~c_ok & ~inf_ok, factor(rho_new), Kinv)
        else:
            rho_new, Kinv_new = rho, Kinv
        keep = done  # finished problems keep their state (vmap runs every lane)
        pick = lambda a, b: jnp.where(keep, a, b)
        return (pick(zs, zn), pick(ws, wn), pick(ys, yn), pick(rho, rho_new), pick(Kinv, Kinv_new),
                pick(it, it + config.check_every), done | c_ok | inf_ok, pick(conv, c_ok), pick(infeas, inf_ok))

    n_blocks = max(config.max_iter // config.check_every, 1)

    def cond(st):
        return (~st[6]) & (st[5] < n_blocks * config.check_every)

    st = (zs, ws, ys, rho0, factor(rho0), jnp.asarray(0, jnp.int32), jnp.asarray(False), jnp.asarray(False),
          jnp.asarray(False))
    zs, ws, ys, rho, _, it, _, conv, infeas = jax.lax.while_loop(cond, block, st)
    return d * zs, e * ys / c, conv, infeas, it, rho


def _frame(lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi, l_ref, init, ds, weights, config, z0, y0):
    T = lower.shape[-1]
    dtype = lower.dtype
    bad_bounds = jnp.any(lower[1:] > upper[1:]) | jnp.any(dl_lo[1:] > dl_hi[1:]) | jnp.any(ddl_lo[1:] > ddl_hi[1:])
    start_out = ((init[0] < lower[0] - config.tol_violation) | (init[0] > upper[0] + config.tol_violation)
                 | (init[1] < dl_lo[0] - 1e-6) | (init[1] > dl_hi[0] + 1e-6)
                 | (init[2] < ddl_lo[0] - 1e-6) | (init[2] > ddl_hi[0] + 1e-6))
    # Repaired bounds keep the solver well posed on bad input; the answer is masked.
    fix = lambda a, b: (jnp.where(a <= b, a, 0.5 * (a + b)), jnp.where(a <= b, b, 0.5 * (a + b)))
    lo_s, up_s = fix(lower, upper)
    dlo, dhi = fix(dl_lo, dl_hi)
    alo, ahi = fix(ddl_lo, ddl_hi)
    P, q, C, lo, hi, M, H = jerk_problem(ds, l_ref, lo_s, up_s, dlo, dhi, alo, ahi, config.jerk_max, init, weights)
    z, y, conv, infeas, it, rho = admm_solve(P, q, C, lo, hi, config, z0, y0)
    x = M @ z + H @ init
    l, dl, ddl = x[:T], x[T:2 * T], x[2 * T:]
    viol = jnp.maximum(jnp.max(jnp.maximum(l[1:] - upper[1:], lower[1:] - l[1:])), 0.0)
    feasible = ~bad_bounds & ~start_out & ~infeas
    ok = feasible & conv & (viol <= config.tol_violation)
    nan = jnp.asarray(jnp.nan, dtype)
    mask = lambda v: jnp.where(feasible, v, nan)
    return PathQPResult(mask(l), mask(dl), mask(ddl), mask(z), feasible, infeas, conv, ok, viol, it, rho, z, y)


def optimize_path(lower, upper, ds, l_ref=None, init=None, weights: PathWeights | None = None,
                  config: PathQPConfig = PathQPConfig(), dl_bounds=None, ddl_bounds=None,
                  warm=None) -> PathQPResult:
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
        warm: optional ``(z (..., T-1), y (..., 4(T-1)))`` from an earlier result.

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
    args = [flat(lower, (T,)), flat(upper, (T,)), flat(dl_bounds[0], (T,)), flat(dl_bounds[1], (T,)),
            flat(ddl_bounds[0], (T,)), flat(ddl_bounds[1], (T,)), flat(l_ref, (T,)), flat(init, (3,)),
            flat(ds, ())]
    if warm is None:
        fn = lambda *a: _frame(*a, weights, config, None, None)
    else:
        args += [flat(warm[0], (T - 1,)), flat(warm[1], (4 * (T - 1),))]
        fn = lambda *a: _frame(*a[:9], weights, config, a[9], a[10])
    out = jax.vmap(fn)(*args)
    return jax.tree_util.tree_map(lambda x: x.reshape(lead + x.shape[1:]), out)


optimize_path_jit = jax.jit(optimize_path, static_argnames=("config",))
