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

After the ADMM, OSQP's solution polishing (``polish_state``, ``PathQPConfig.polish``): the QP
with the rows the ADMM finds active as equalities is solved directly (its KKT system is block
tridiagonal along the stations), the active set corrected pass by pass; the polished solution
replaces the ADMM's only where it passes the same convergence test. It finishes the QPs on
which the ADMM's tail is slow (rows next to the active ones almost active: thousands of
iterations for OSQP's ADMM too) and makes every polished path exact on its active set.

Infeasible input is reported, never returned as a path: where ``lower > upper``
somewhere, the initial state lies outside its bounds, or the certificate fires,
``feasible`` is False and ``l`` is NaN. ``ok`` = feasible, converged, and every bound met
within ``tol_violation``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
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
        eps_pinf: tolerance of the primal-infeasibility certificate, relative to ``||dy||``
            (3e-2: in float32 OSQP's 1e-4 lets 70 % of the infeasible frames of the OSQP test
            run to ``max_iter`` uncertified; no solvable frame is certified infeasible).
        rho: initial ADMM step; adapted (``adaptive_rho``) at most ``rho_updates`` times (6: with
            3, 8 % of the frames OSQP solves stop unconverged at ``max_iter``; with 6, 0.1 %).
        check_every: iterations between residual / certificate checks.
        max_iter: iteration cap (a multiple of ``check_every``).
        tol_violation: bound violation (m) above which a solution is not ``ok``.
        ruiz_iters: equilibration passes.
        polish: OSQP's solution polishing after the ADMM (``polish_state``): the QP with the
            constraints the ADMM finds active as equalities, solved directly, the active set
            corrected pass by pass (block principal pivoting); the polished solution replaces the
            ADMM's (and counts as converged) only where it passes the convergence test itself
            (``eps_abs``, ``eps_rel``: bounds met, complementary, correctly signed multipliers).
        polish_passes: at most this many active-set passes (each one block-tridiagonal KKT
            factorisation, ``O(T)``).
        polish_refine: iterative-refinement steps per pass.
        early_exit: stop when converged (``lax.while_loop``); False runs every iteration
            (``fori_loop``), so that ``jax.grad`` can differentiate through the solve by
            unrolling (solved problems keep their state).
    """

    dl_max: float = 2.0
    ddl_max: float = 1.0
    jerk_max: float = 1.0
    eps_abs: float = 1e-4
    eps_rel: float = 1e-4
    eps_pinf: float = 3e-2
    rho: float = 0.1
    adaptive_rho: bool = True
    check_every: int = 25
    rho_updates: int = 6
    early_exit: bool = True
    max_iter: int = 4000
    tol_violation: float = 1e-3
    ruiz_iters: int = 10
    polish: bool = True
    polish_passes: int = 16
    polish_refine: int = 2


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
    m_l = on * (ds**3 / 6 + n * ds**2 / 2 + n**2 * ds / 2)
    m_d = on * (ds**2 / 2 + n * ds)
    m_a = on * ds
    t = jnp.arange(T, dtype=dtype) * ds
    one, zero = jnp.ones(T, dtype), jnp.zeros(T, dtype)
    H = jnp.concatenate(
        [jnp.stack([one, t, t**2 / 2], -1), jnp.stack([zero, one, t], -1), jnp.stack([zero, zero, one], -1)], axis=0
    )
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


def state_problem(ds, l_ref, lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi, jerk_max, init, weights: PathWeights):
    """The QP in the states ``x = [l, l', l''] (3T)`` for one frame (Apollo's piecewise-jerk
    form): ``min 1/2 x'Px + q'x, lo <= A x <= hi`` with equality rows where ``lo = hi``.

    Rows of ``A`` (``m = 6T - 3``): the boxes on ``l, l', l''`` (``3T``; point 0 fixed to
    ``init``), the jerks ``(l''_{i+1} - l''_i) / ds`` (``T - 1``), the two integration
    equalities (``2 (T - 1)``).

    Args:
        ds: ``()``; l_ref, lower, upper, dl_lo, dl_hi, ddl_lo, ddl_hi: ``(T,)``; jerk_max:
        ``()``; init: ``(3,)``.

    Returns:
        (P ``(3T, 3T)``, q ``(3T,)``, A ``(m, 3T)``, lo ``(m,)``, hi ``(m,)``).
    """
    T = l_ref.shape[-1]
    dtype = l_ref.dtype
    ds = jnp.asarray(ds, dtype)
    eye = jnp.eye(T, dtype=dtype)
    D = (jnp.eye(T - 1, T, 1, dtype=dtype) - jnp.eye(T - 1, T, dtype=dtype)) / ds  # (T-1, T)
    Z = jnp.zeros((T, T), dtype)
    P = 2 * jnp.block(
        [[weights.ref * eye, Z, Z], [Z, weights.dl * eye, Z], [Z, Z, weights.ddl * eye + weights.dddl * D.T @ D]]
    )
    q = jnp.concatenate([-2 * weights.ref * l_ref, jnp.zeros(2 * T, dtype)])
    I0 = jnp.eye(T - 1, T, dtype=dtype)
    I1 = jnp.eye(T - 1, T, 1, dtype=dtype)
    Zr = jnp.zeros((T - 1, T), dtype)
    A_pos = jnp.concatenate([I1 - I0, -ds * I0, -(ds**2 / 3) * I0 - (ds**2 / 6) * I1], axis=1)
    A_vel = jnp.concatenate([Zr, I1 - I0, -(ds / 2) * (I0 + I1)], axis=1)
    A_jerk = jnp.concatenate([Zr, Zr, D], axis=1)
    A = jnp.concatenate([jnp.eye(3 * T, dtype=dtype), A_jerk, A_pos, A_vel], axis=0)
    big = jnp.asarray(_FAR, dtype)
    fix0 = lambda v, x0: v.at[0].set(x0)
    hi_x = jnp.concatenate([fix0(upper, init[0]), fix0(dl_hi, init[1]), fix0(ddl_hi, init[2])])
    lo_x = jnp.concatenate([fix0(lower, init[0]), fix0(dl_lo, init[1]), fix0(ddl_lo, init[2])])
    jm = jnp.full((T - 1,), jerk_max, dtype)
    zeq = jnp.zeros(2 * (T - 1), dtype)
    hi = jnp.clip(jnp.concatenate([hi_x, jm, zeq]), -big, big)
    lo = jnp.clip(jnp.concatenate([lo_x, -jm, zeq]), -big, big)
    return P, q, A, lo, hi


# No LAPACK here: jaxlib's CPU triangular-solve and Cholesky kernels split a vmapped batch over
# XLA's intra-op thread pool (``ParallelBatchMap``) and, with jaxlib 0.10 on a small machine, can
# wait forever for tasks the pool never runs (seen: every worker idle, the kernel blocked in
# ``lapack_strsm_ffi``). These loops are plain XLA ops, batch under vmap like any other.


def _lower_inverse(L):
    """Inverse of a lower-triangular ``(n, n)`` matrix by forward substitution, row by row."""
    n = L.shape[-1]
    eye = jnp.eye(n, dtype=L.dtype)

    def row(i, X):
        return X.at[i].set((eye[i] - L[i] @ X) / L[i, i])  # rows >= i of X are still zero

    return jax.lax.fori_loop(0, n, row, jnp.zeros_like(L))


def _tri_inverse(L):
    """Inverse of a lower-triangular ``(n, n)`` matrix by blocks (matrix products; blocks of
    at most 32 rows by forward substitution): on XLA's CPU backend far faster than one
    ``n x n`` substitution."""
    n = L.shape[-1]
    if n <= 32:
        return _lower_inverse(L)
    k = n // 2
    Ai, Ci = _tri_inverse(L[:k, :k]), _tri_inverse(L[k:, k:])
    low = -Ci @ (L[k:, :k] @ Ai)
    return jnp.concatenate([jnp.concatenate([Ai, jnp.zeros((k, n - k), L.dtype)], 1), jnp.concatenate([low, Ci], 1)], 0)


def _cholesky(K):
    """Lower Cholesky factor of a symmetric positive definite ``(n, n)`` matrix, column by column."""
    n = K.shape[-1]
    idx = jnp.arange(n)

    def col(j, L):
        v = K[:, j] - L @ L[j]  # columns >= j of L are still zero
        d = jnp.sqrt(jnp.maximum(v[j], jnp.finfo(K.dtype).tiny))
        return L.at[:, j].set(jnp.where(idx > j, v / d, jnp.where(idx == j, d, 0.0)))

    return jax.lax.fori_loop(0, n, col, jnp.zeros_like(K))


def spd_inverse(K):
    """Inverse of a symmetric positive definite ``(n, n)`` matrix (Cholesky, then ``_tri_inverse``)."""
    Li = _tri_inverse(_cholesky(K))
    return Li.T @ Li


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


def admm_solve(P, q, C, lo, hi, config: PathQPConfig, z0=None, y0=None, matvec=None):
    """OSQP's ADMM for ``min 1/2 z'Pz + q'z, lo <= C z <= hi`` (one problem; vmap it).

    The iterations run in stages: ``rho`` is adapted (and the matrix refactorised) only
    between stages, at most ``config.rho_updates`` times (stage ``k`` runs up to
    ``2^(k+1)`` blocks of ``check_every`` iterations, the last one up to ``max_iter``), so
    a batch pays a fixed, small number of factorisations.

    Args:
        P: ``(n, n)`` positive definite; q: ``(n,)``; C: ``(m, n)``; lo, hi: ``(m,)``
            finite (rows with ``lo == hi`` are equalities and get ``1e3 rho``).
        config: tolerances and iteration counts.
        z0, y0: optional warm start ``(n,)``, ``(m,)`` (unscaled).
        matvec: optional function ``z -> C z`` exploiting ``C``'s structure (the dense
            ``C`` is then used only for the equilibration).

    Returns:
        (z ``(n,)``, y ``(m,)``, converged, infeasible, iterations, rho, active_lo ``(m,)``,
        active_hi ``(m,)``): the last two OSQP's guess of the inequality rows active at their
        lower / upper bound (``w - lo < -y``, ``hi - w < y`` in the scaled problem), for
        ``polish_state``.
    """
    dtype = P.dtype
    n, m = P.shape[0], C.shape[0]
    d, e, Ps = _ruiz(P, C, config.ruiz_iters)
    qs = d * q
    c = 1.0 / jnp.maximum(jnp.maximum(jnp.max(jnp.abs(Ps)), jnp.max(jnp.abs(qs))), 1e-6)
    c = jnp.clip(c, 1e-4, 1e4)
    Ps, qs = c * Ps, c * qs
    Cs = e[:, None] * C * d[None, :]
    if matvec is None:
        cz = lambda z: Cs @ z
        cty = lambda y: Cs.T @ y
    else:
        cz = lambda z: e * matvec(d * z)
        tr = jax.linear_transpose(matvec, jnp.zeros(n, dtype))
        cty = lambda y: d * tr(e * y)[0]
    los, his = e * lo, e * hi
    sigma, alpha = 1e-6, 1.6
    eye = jnp.eye(n, dtype=dtype)
    eq = (hi - lo) <= 1e-9 * (1.0 + jnp.abs(hi))  # equality rows get 1e3 rho (as OSQP)
    rho_scale = jnp.where(eq, 1e3, 1.0).astype(dtype)
    CtC = Cs.T * rho_scale

    def factor(rho):
        return spd_inverse(Ps + sigma * eye + rho * CtC @ Cs)

    zs = jnp.zeros(n, dtype) if z0 is None else z0 / d
    ys = jnp.zeros(m, dtype) if y0 is None else y0 * c / e
    ws = jnp.clip(cz(zs), los, his)

    def residuals(zs, ws, ys):
        Cz = cz(zs)
        prim = jnp.max(jnp.abs((Cz - ws) / e))
        Pz = Ps @ zs
        Cty = cty(ys)
        dual = jnp.max(jnp.abs((Pz + qs + Cty) / d)) / c
        prim_scale = jnp.maximum(jnp.max(jnp.abs(Cz / e)), jnp.max(jnp.abs(ws / e)))
        dual_scale = (
            jnp.maximum(jnp.maximum(jnp.max(jnp.abs(Pz / d)), jnp.max(jnp.abs(Cty / d))), jnp.max(jnp.abs(qs / d))) / c
        )
        return prim, dual, prim_scale, dual_scale

    def run_stage(st, rho, Kinv, n_blocks_max):
        rv = rho * rho_scale

        def block(st):
            zs, ws, ys, it, nb, done, conv, infeas, prim, dual, ps_, ds_ = st

            def step(_, inner):
                zs, ws, ys, _ = inner
                rhs = sigma * zs - qs + cty(rv * ws - ys)
                zt = Kinv @ rhs
                wt = cz(zt)
                wr = alpha * wt + (1 - alpha) * ws
                wn = jnp.clip(wr + ys / rv, los, his)
                yn = ys + rv * (wr - wn)
                zn = alpha * zt + (1 - alpha) * zs
                return zn, wn, yn, ys

            zn, wn, yn, yprev = jax.lax.fori_loop(0, config.check_every, step, (zs, ws, ys, ys))
            pr, du, pscale, dscale = residuals(zn, wn, yn)
            c_ok = (pr <= config.eps_abs + config.eps_rel * pscale) & (du <= config.eps_abs + config.eps_rel * dscale)
            # Primal infeasibility certificate on the unscaled dual step dy = E (y_k - y_{k-1}) / c.
            dy = e * (yn - yprev) / c
            ndy = jnp.max(jnp.abs(dy))
            ctdy = jnp.max(jnp.abs(cty(yn - yprev) / d / c))
            support = jnp.sum(hi * jnp.maximum(dy, 0.0) + lo * jnp.minimum(dy, 0.0))
            inf_ok = (ndy > 1e-12) & (ctdy <= config.eps_pinf * ndy) & (support < -config.eps_pinf * ndy)
            keep = done  # finished problems keep their state (vmap runs every lane)
            pick = lambda a, b: jnp.where(keep, a, b)
            return (
                pick(zs, zn),
                pick(ws, wn),
                pick(ys, yn),
                pick(it, it + config.check_every),
                nb + 1,
                done | c_ok | inf_ok,
                pick(conv, c_ok),
                pick(infeas, inf_ok),
                pick(prim, pr),
                pick(dual, du),
                pick(ps_, pscale),
                pick(ds_, dscale),
            )

        st = st[:4] + (jnp.asarray(0, jnp.int32),) + st[5:]
        if config.early_exit:
            return jax.lax.while_loop(lambda s: (~s[5]) & (s[4] < n_blocks_max), block, st)
        return jax.lax.fori_loop(0, n_blocks_max, lambda _, s: block(s), st)  # reverse-differentiable

    z0_ = jnp.asarray(0.0, dtype)
    st = (
        zs,
        ws,
        ys,
        jnp.asarray(0, jnp.int32),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(False),
        jnp.asarray(False),
        jnp.asarray(False),
        z0_,
        z0_,
        z0_,
        z0_,
    )
    rho = jnp.asarray(config.rho, dtype)
    total = max(config.max_iter // config.check_every, 1)
    n_stages = config.rho_updates + 1 if config.adaptive_rho else 1
    budgets: list[int] = []  # blocks per stage: 2, 4, 8, ... and the rest of max_iter in the last
    for k in range(n_stages):
        rest = total - sum(budgets)
        if rest <= 0:
            break
        budgets.append(rest if k == n_stages - 1 else min(2 ** (k + 1), rest))

    def adapt(st, rho):
        prim, dual, ps_, ds_ = st[8:12]
        ratio = (prim / jnp.maximum(ps_, 1e-10)) / jnp.maximum(dual / jnp.maximum(ds_, 1e-10), 1e-10)
        return jnp.clip(rho * jnp.sqrt(ratio), 1e-6, 1e6)

    if config.early_exit:
        # One loop over the stages: the factorisation and the ADMM block are traced once (the
        # unrolled stages made the planners' programs several times larger and slower to compile).
        last = len(budgets) - 1

        def stage(k, carry):
            st, rho = carry
            st = run_stage(st, rho, factor(rho), jnp.asarray(budgets, jnp.int32)[k])
            return st, jnp.where(k < last, adapt(st, rho), rho)

        st, rho = jax.lax.fori_loop(0, len(budgets), stage, (st, rho))
    else:  # static trip counts, so that reverse mode can differentiate through the solve
        for k, budget in enumerate(budgets):
            st = run_stage(st, rho, factor(rho), budget)
            if k < len(budgets) - 1:
                rho = adapt(st, rho)
    zs, ws, ys, it, _, _, conv, infeas = st[:8]
    act_lo = ~eq & (ws - los < -ys)
    act_hi = ~eq & (his - ws < ys)
    return d * zs, e * ys / c, conv, infeas, it, rho, act_lo, act_hi


def state_matvec(ds, T):
    """``x -> A x`` of ``state_problem`` in O(T) (the rows' structure), for ``admm_solve``."""

    def mv(x):
        l, dl, ddl = x[:T], x[T : 2 * T], x[2 * T :]
        jerk = (ddl[1:] - ddl[:-1]) / ds
        pos = l[1:] - l[:-1] - ds * dl[:-1] - (ds**2 / 3) * ddl[:-1] - (ds**2 / 6) * ddl[1:]
        vel = dl[1:] - dl[:-1] - (ds / 2) * (ddl[:-1] + ddl[1:])
        return jnp.concatenate([x, jerk, pos, vel])

    return mv


# --------------------------------------------------------------------------- solution polishing
def _small_inverse(S):
    """Inverse of a small ``(k, k)`` quasi-definite matrix by Gauss-Jordan elimination without
    pivoting (unrolled; a quasi-definite matrix is strongly factorisable, Vanderbei 1995)."""
    k = S.shape[-1]
    M = jnp.concatenate([S, jnp.eye(k, dtype=S.dtype)], -1)
    for j in range(k):
        row = M[j] / M[j, j]
        M = (M - M[:, j : j + 1] * row[None, :]).at[j].set(row)
    return M[:, k:]


def _block_factor(D, L):
    """Block LDL' of a symmetric block-tridiagonal quasi-definite matrix: ``D (T, b, b)`` the
    diagonal blocks, ``L (T, b, b)`` the blocks below them (``L[i] = K[i, i-1]``, ``L[0]``
    unused). Returns ``Si`` (the inverses of the pivot blocks) and ``G[i] = L[i] Si[i-1]``."""

    def step(si_prev, dl):
        di, li = dl
        g = li @ si_prev
        si = _small_inverse(di - g @ li.T)
        return si, (si, g)

    si0 = _small_inverse(D[0])
    _, (Si, G) = jax.lax.scan(step, si0, (D[1:], L[1:]))
    return jnp.concatenate([si0[None], Si], 0), jnp.concatenate([jnp.zeros_like(G[:1]), G], 0)


def _block_solve(Si, G, L, r):
    """Solve ``K v = r`` (``r, v (T, b)``) with ``_block_factor``'s factors."""

    def fwd(u_prev, gr):
        u = gr[1] - gr[0] @ u_prev
        return u, u

    _, u = jax.lax.scan(fwd, r[0], (G[1:], r[1:]))
    u = jnp.concatenate([r[:1], u], 0)
    v_last = Si[-1] @ u[-1]

    def bwd(v_next, sul):
        si, ui, l_next = sul
        v = si @ (ui - l_next.T @ v_next)
        return v, v

    _, v = jax.lax.scan(bwd, v_last, (Si[:-1], u[:-1], L[1:]), reverse=True)
    return jnp.concatenate([v, v_last[None]], 0)


def polish_state(P, q, A, lo, hi, z, act_lo, act_hi, config: PathQPConfig, matvec=None, skip=False):
    """OSQP-style solution polishing of ``state_problem``'s QP (one problem; vmap it).

    The QP with the active rows as equalities (``lo`` where ``act_lo``, ``hi`` where ``act_hi``,
    and every row with ``lo == hi``) is solved directly: its KKT matrix, ordered by station
    (each station's three states, the multipliers of its three box rows and of the three rows
    of the interval ending there), is block tridiagonal with ``9 x 9`` blocks, factorised by a
    block LDL' (``_block_factor``, ``O(T)``; symmetrically scaled to a unit diagonal of ``P``
    and unit rows, regularised by ``-1e-8`` on the active rows' diagonal, inactive rows pinned
    to a zero multiplier), then iteratively refined against the exact KKT system. The active
    set is corrected pass by pass (block principal pivoting with Murty's single pivot as the
    fallback: rows whose multiplier has the wrong sign leave, rows the solution violates
    join), at most ``config.polish_passes`` passes, until no row is wrong. A pass's solution is
    a candidate if it passes OSQP's convergence test itself (``eps_abs``, ``eps_rel`` on the
    unscaled residuals, the multipliers projected onto their signs, every active row met with
    equality within the primal tolerance, every value finite): bounds met, stationary,
    complementary, so the QP's optimum to that tolerance. Of the candidates the one with the
    smallest primal residual is returned.

    Args:
        P ``(3T, 3T)``, q ``(3T,)``, A ``(6T-3, 3T)``, lo, hi ``(6T-3,)``: ``state_problem``'s data
            (its row layout: boxes, jerks, position and velocity integration).
        z: ``(3T,)`` the ADMM's solution (start of the refinement).
        act_lo, act_hi: ``(6T-3,)`` the ADMM's guess of the active rows (``admm_solve``).
        config: ``PathQPConfig`` (``eps_abs``, ``eps_rel``, ``polish_passes``, ``polish_refine``,
            ``early_exit``: stop once no row is wrong (``while_loop``), or run every pass).
        matvec: optional ``x -> A x`` (``state_matvec``).
        skip: ``()`` bool, no polishing (e.g. certified infeasible: the passes stop at once).

    Returns:
        (x ``(3T,)``, y ``(6T-3,)`` unscaled multipliers, ok: a candidate was found, passes run).
    """
    dt = P.dtype
    n, m = P.shape[0], A.shape[0]
    T = n // 3
    mv = (lambda x: A @ x) if matvec is None else matvec
    eq = (hi - lo) <= 1e-9 * (1.0 + jnp.abs(hi))
    i = jnp.arange(T)
    ix = jnp.stack([i, T + i, 2 * T + i], -1)  # (T, 3): the station's states, and its box rows
    ip = jnp.maximum(i - 1, 0)
    ri = jnp.stack([3 * T + ip, 4 * T - 1 + ip, 5 * T - 2 + ip], -1)  # rows of the interval ending at i
    has = (i > 0)[:, None]
    # The blocks, read off the dense data (so that they are state_problem's by construction),
    # scaled symmetrically: unit diagonal of P, unit largest entry of each constraint row.
    Pd = P[ix[:, :, None], ix[:, None, :]]
    sx = 1.0 / jnp.sqrt(jnp.diagonal(Pd, axis1=1, axis2=2))  # (T, 3)
    sxp = sx[ip]
    Pd = sx[:, :, None] * Pd * sx[:, None, :]
    Pl = sx[:, :, None] * P[ix[:, :, None], ix[ip][:, None, :]] * sxp[:, None, :] * has[..., None]
    Ab = A[ix[:, :, None], ix[:, None, :]] * sx[:, None, :]
    sb = 1.0 / jnp.maximum(jnp.max(jnp.abs(Ab), -1), 1e-12)  # (T, 3)
    Ab = sb[..., None] * Ab
    B1 = A[ri[:, :, None], ix[:, None, :]] * sx[:, None, :]
    B0 = A[ri[:, :, None], ix[ip][:, None, :]] * sxp[:, None, :]
    si = 1.0 / jnp.maximum(jnp.maximum(jnp.max(jnp.abs(B1), -1), jnp.max(jnp.abs(B0), -1)), 1e-12)
    B1, B0 = si[..., None] * B1, si[..., None] * B0
    scale = jnp.concatenate([sx, sb, si], -1)  # (T, 9): K = diag(1/scale) K~ diag(1/scale)
    Z3 = jnp.zeros((T, 3, 3), dt)
    eye3 = jnp.eye(3, dtype=dt)
    delta = jnp.asarray(1e-8, dt)
    tiny = 10 * jnp.finfo(dt).eps

    def solve_eqp(act, b, x):
        fb = act[ix].astype(dt)
        fi = (act[ri] & has).astype(dt)
        pin = lambda f: jnp.where(f > 0, -delta, -1.0)[..., None] * eye3
        Ab_, B1_, B0_ = fb[..., None] * Ab, fi[..., None] * B1, fi[..., None] * B0
        D = jnp.concatenate(
            [
                jnp.concatenate([Pd, jnp.swapaxes(Ab_, 1, 2), jnp.swapaxes(B1_, 1, 2)], 2),
                jnp.concatenate([Ab_, pin(fb), Z3], 2),
                jnp.concatenate([B1_, Z3, pin(fi)], 2),
            ],
            1,
        )
        L = jnp.concatenate(
            [jnp.concatenate([Pl, Z3, Z3], 2), jnp.concatenate([Z3, Z3, Z3], 2), jnp.concatenate([B0_, Z3, Z3], 2)], 1
        )
        Si, G = _block_factor(D, L)
        af = act.astype(dt)
        y = jnp.zeros(m, dt)
        for _ in range(1 + config.polish_refine):  # the first solve, then refinement on the exact system
            rx = -q - P @ x - A.T @ y
            ry = af * (b - mv(x))
            r = jnp.concatenate([rx[ix], ry[ix], ry[ri] * has], -1)
            v = scale * _block_solve(Si, G, L, scale * r)
            x = x + jnp.zeros(n, dt).at[ix].set(v[:, :3])
            y = y + af * jnp.zeros(m, dt).at[ix].set(v[:, 3:6]).at[ri[1:]].set(v[1:, 6:9])
        return x, y

    def one_pass(c):
        k, a_lo, a_hi, x, _, found, best, xb, yb, n_best, trials = c
        act = eq | a_lo | a_hi
        b = jnp.where(a_hi, hi, lo)
        x, y = solve_eqp(act, b, x)
        # OSQP's test on the polished point, multipliers projected onto their signs
        yp = jnp.where(eq, y, jnp.where(a_lo, jnp.minimum(y, 0.0), jnp.where(a_hi, jnp.maximum(y, 0.0), 0.0)))
        Ax = mv(x)
        w = jnp.clip(Ax, lo, hi)
        prim = jnp.maximum(jnp.max(jnp.abs(Ax - w)), jnp.max(jnp.where(act, jnp.abs(Ax - b), 0.0)))
        Px, Aty = P @ x, A.T @ yp
        dual = jnp.max(jnp.abs(Px + q + Aty))
        p_scale = jnp.maximum(jnp.max(jnp.abs(Ax)), jnp.max(jnp.abs(w)))
        d_scale = jnp.maximum(jnp.maximum(jnp.max(jnp.abs(Px)), jnp.max(jnp.abs(Aty))), jnp.max(jnp.abs(q)))
        finite = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(y))  # a singular active set: never a candidate
        good = (
            finite
            & (prim <= config.eps_abs + config.eps_rel * p_scale)
            & (dual <= config.eps_abs + config.eps_rel * d_scale)
        )
        take = good & (prim < best)
        xb, yb = jnp.where(take, x, xb), jnp.where(take, yp, yb)
        best = jnp.where(take, prim, best)
        # Active-set step (block principal pivoting, Judice & Pires 1994): every row whose
        # multiplier has the wrong sign leaves, every row the solution violates joins, while
        # that lowers the number of such rows (or for 3 more tries); otherwise only the first
        # of them changes (Murty's single pivot), so that the passes cannot cycle for ever.
        wrong_hi, wrong_lo = a_hi & (y < 0), a_lo & (y > 0)
        v_hi = ~eq & ~act & (Ax > hi + tiny * (1.0 + jnp.abs(hi)))
        v_lo = ~eq & ~act & (Ax < lo - tiny * (1.0 + jnp.abs(lo)))
        bad = wrong_hi | wrong_lo | v_hi | v_lo
        n_bad = jnp.sum(bad, dtype=jnp.int32)
        lower = n_bad < n_best
        block = lower | (trials > 0)
        trials = jnp.where(lower, 3, jnp.where(block, trials - 1, trials))
        n_best = jnp.minimum(n_best, n_bad)
        sel = jnp.where(block, bad, bad & (jnp.arange(m) == jnp.argmax(bad)))
        n_hi = (a_hi & ~(sel & wrong_hi)) | (sel & v_hi)
        n_lo = (a_lo & ~(sel & wrong_lo)) | (sel & v_lo)
        x = jnp.where(finite, x, z)
        return k + 1, n_lo, n_hi, x, (n_bad == 0) | ~finite, found | good, best, xb, yb, n_best, trials

    inf = jnp.asarray(jnp.inf, dt)
    c = (
        jnp.asarray(0, jnp.int32),
        act_lo & ~eq,
        act_hi & ~eq,
        z,
        jnp.asarray(skip),
        jnp.asarray(False),
        inf,
        z,
        jnp.zeros(m, dt),
        jnp.asarray(m + 1, jnp.int32),
        jnp.asarray(3, jnp.int32),
    )
    if config.early_exit:
        c = jax.lax.while_loop(lambda c: (c[0] < config.polish_passes) & ~c[4], one_pass, c)
    else:
        c = jax.lax.fori_loop(0, config.polish_passes, lambda _, c: one_pass(c), c)
    return c[7], c[8], c[5] & ~skip, c[0]


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
    z, y, conv, infeas, it, rho, act_lo, act_hi = admm_solve(P, q, A, lo, hi, config, z0, y0, mv)
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
