"""One QP solver: OSQP's ADMM (Stellato et al. 2020) as XLA ops, for

    min 1/2 z'Pz + q'z   s.t.   lo <= C z <= hi

(one problem; ``jax.vmap`` it). The parts: modified Ruiz equilibration of the KKT matrix
``[[P, C'], [C, 0]]`` and a cost scaling (``ruiz``), the over-relaxed ADMM iteration
(``admm_iterations``: the ``z``-update through the inverse of ``P + sigma I + C' R C``, then
the projection of ``C z`` onto the box), the convergence test on the unscaled primal and dual
residuals (``residuals``) and OSQP's rule for the step size ``rho`` (``adapted_rho``). Two
entry points share them:

- ``admm_solve``: ``P`` and ``C`` are computed in the program (the path QP, whose Hessian
  depends on traced weights). It equilibrates and inverts inside the program, adapts ``rho``
  in stages (a refactorisation each), certifies primal infeasibility, and reports the rows it
  finds active (for a polishing step).
- ``admm_prefactored``: ``P`` and ``C`` are constants (the speed QP on its fixed time grid).
  ``prefactor`` equilibrates them and inverts the KKT matrix on the host once for a ladder of
  ``rho``; in the program ``rho`` only moves along the ladder.

Why not a library: ``experiments/bench_speed.py`` and ``experiments/bench_bounds.py`` time
these against qpax's interior point and jaxopt's ``BoxOSQP`` on the planners' QPs.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.solvers.linalg import spd_inverse

__all__ = [
    "ADMMSettings",
    "LadderSettings",
    "Prefactored",
    "ruiz",
    "admm_iterations",
    "residuals",
    "adapted_rho",
    "admm_solve",
    "prefactor",
    "admm_prefactored",
]

SIGMA = 1e-6  # proximal term of the z-update
INF = 1e20  # bounds at or beyond this are infinite in ``admm_prefactored``
EQ_RHO = 1e3  # equality rows (lo == hi) get this times rho (as OSQP)


@dataclasses.dataclass(frozen=True)
class ADMMSettings:
    """Static settings of ``admm_solve``.

    Attributes:
        eps_abs, eps_rel: convergence tolerances on the unscaled residuals (OSQP's test).
        eps_pinf: tolerance of the primal-infeasibility certificate, relative to ``||dy||``.
        rho: first step size; adapted (``adaptive_rho``) at most ``rho_updates`` times.
        check_every: iterations between residual / certificate checks.
        max_iter: iteration cap (a multiple of ``check_every``).
        ruiz_iters: equilibration passes.
        alpha: over-relaxation.
        early_exit: stop when converged (``lax.while_loop``); False runs every iteration
            (``fori_loop``), so that reverse mode can differentiate through the solve.
    """

    eps_abs: float = 1e-4
    eps_rel: float = 1e-4
    eps_pinf: float = 3e-2
    rho: float = 0.1
    adaptive_rho: bool = True
    check_every: int = 25
    rho_updates: int = 6
    max_iter: int = 4000
    ruiz_iters: int = 10
    alpha: float = 1.6
    early_exit: bool = True


@dataclasses.dataclass(frozen=True)
class LadderSettings:
    """Static settings of ``admm_prefactored``: at least ``min_phases`` and at most ``phases``
    phases of ``iters`` iterations (it stops once the unscaled residuals are below
    ``eps_prim`` / ``eps_dual``; under ``vmap`` when every problem is), relaxation ``alpha``,
    the first step size ``rho0`` (snapped to the ladder)."""

    phases: int = 16
    min_phases: int = 4
    iters: int = 25
    alpha: float = 1.6
    rho0: float = 0.1
    eps_prim: float = 1e-2
    eps_dual: float = 5e-3


def _ruiz_pass(d, e, P, C, xp):
    Ps = d[:, None] * P * d[None, :]
    Cs = e[:, None] * C * d[None, :]
    col = xp.maximum(xp.max(xp.abs(Ps), 0), xp.max(xp.abs(Cs), 0))
    row = xp.max(xp.abs(Cs), 1)
    return d / xp.sqrt(xp.clip(col, 1e-4, 1e4)), e / xp.sqrt(xp.clip(row, 1e-4, 1e4))


def ruiz(P, C, iters: int):
    """Modified Ruiz equilibration of ``[[P, C'], [C, 0]]``: column scaling ``d (n,)`` and row
    scaling ``e (m,)`` so that ``diag(d) P diag(d)`` and ``diag(e) C diag(d)`` have columns and
    rows of largest entry near 1. On numpy arrays it runs on the host (float64), else in the
    program. Returns ``(d, e)``."""
    if isinstance(P, np.ndarray) and isinstance(C, np.ndarray):
        d, e = np.ones(P.shape[0]), np.ones(C.shape[0])
        for _ in range(iters):
            d, e = _ruiz_pass(d, e, P, C, np)
        return d, e
    d0, e0 = jnp.ones(P.shape[0], P.dtype), jnp.ones(C.shape[0], P.dtype)
    return jax.lax.fori_loop(0, iters, lambda _, de: _ruiz_pass(de[0], de[1], P, C, jnp), (d0, e0))


def admm_iterations(k: int, Kinv, cz, cty, qs, lo, hi, rho, alpha: float, state):
    """``k`` ADMM iterations of the scaled problem. ``Kinv`` the inverse of ``Ps + sigma I +
    Cs' diag(rho) Cs``; ``cz: z -> Cs z``, ``cty: y -> Cs' y``; ``rho`` a scalar or per row.
    ``state = (z, w, y)`` with ``w`` the projected ``C z``. Returns the new state and the
    ``y`` before the last iteration (for the infeasibility certificate)."""

    def step(_, carry):
        z, w, y, _ = carry
        zt = Kinv @ (SIGMA * z - qs + cty(rho * w - y))
        wr = alpha * cz(zt) + (1 - alpha) * w
        wn = jnp.clip(wr + y / rho, lo, hi)
        return alpha * zt + (1 - alpha) * z, wn, y + rho * (wr - wn), y

    z, w, y = state
    z, w, y, y_prev = jax.lax.fori_loop(0, k, step, (z, w, y, y))
    return (z, w, y), y_prev


def residuals(z, w, y, Ps, qs, cz, cty, d, e, c):
    """Unscaled primal and dual residuals and their scales (OSQP's test: ``prim <= eps_abs +
    eps_rel prim_scale``) of the scaled iterate; ``d, e, c`` the equilibration. Returns
    ``(prim, dual, prim_scale, dual_scale)``."""
    Cz = cz(z)
    prim = jnp.max(jnp.abs((Cz - w) / e))
    Pz = Ps @ z
    Cty = cty(y)
    dual = jnp.max(jnp.abs((Pz + qs + Cty) / d)) / c
    prim_scale = jnp.maximum(jnp.max(jnp.abs(Cz / e)), jnp.max(jnp.abs(w / e)))
    dual_scale = (
        jnp.maximum(jnp.maximum(jnp.max(jnp.abs(Pz / d)), jnp.max(jnp.abs(Cty / d))), jnp.max(jnp.abs(qs / d))) / c
    )
    return prim, dual, prim_scale, dual_scale


def adapted_rho(rho, prim, dual, prim_scale, dual_scale):
    """OSQP's step-size rule: ``rho sqrt((prim / prim_scale) / (dual / dual_scale))``, within [1e-6, 1e6]."""
    ratio = (prim / jnp.maximum(prim_scale, 1e-10)) / jnp.maximum(dual / jnp.maximum(dual_scale, 1e-10), 1e-10)
    return jnp.clip(rho * jnp.sqrt(ratio), 1e-6, 1e6)


def admm_solve(P, q, C, lo, hi, settings: ADMMSettings, z0=None, y0=None, matvec=None):
    """OSQP's ADMM for ``min 1/2 z'Pz + q'z, lo <= C z <= hi`` (one problem; vmap it).

    The iterations run in stages: ``rho`` is adapted (and the matrix refactorised) only
    between stages, at most ``settings.rho_updates`` times (stage ``k`` runs up to
    ``2^(k+1)`` blocks of ``check_every`` iterations, the last one up to ``max_iter``), so
    a batch pays a fixed, small number of factorisations. Primal infeasibility is certified by
    the dual step ``dy`` (``||C' dy|| <= eps_pinf ||dy||`` and ``hi' dy+ + lo' dy- < -eps_pinf
    ||dy||``).

    Args:
        P: ``(n, n)`` positive definite; q: ``(n,)``; C: ``(m, n)``; lo, hi: ``(m,)``
            finite (rows with ``lo == hi`` are equalities and get ``1e3 rho``).
        settings: tolerances and iteration counts.
        z0, y0: optional warm start ``(n,)``, ``(m,)`` (unscaled).
        matvec: optional function ``z -> C z`` exploiting ``C``'s structure (the dense
            ``C`` is then used only for the equilibration).

    Returns:
        (z ``(n,)``, y ``(m,)``, converged, infeasible, iterations, rho, active_lo ``(m,)``,
        active_hi ``(m,)``): the last two OSQP's guess of the inequality rows active at their
        lower / upper bound (``w - lo < -y``, ``hi - w < y`` in the scaled problem), for a
        polishing step.
    """
    cfg = settings
    dtype = P.dtype
    n, m = P.shape[0], C.shape[0]
    d, e = ruiz(P, C, cfg.ruiz_iters)
    Ps = d[:, None] * P * d[None, :]
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
    eye = jnp.eye(n, dtype=dtype)
    eq = (hi - lo) <= 1e-9 * (1.0 + jnp.abs(hi))
    rho_scale = jnp.where(eq, EQ_RHO, 1.0).astype(dtype)
    CtC = Cs.T * rho_scale

    def factor(rho):
        return spd_inverse(Ps + SIGMA * eye + rho * CtC @ Cs)

    zs = jnp.zeros(n, dtype) if z0 is None else z0 / d
    ys = jnp.zeros(m, dtype) if y0 is None else y0 * c / e
    ws = jnp.clip(cz(zs), los, his)
    res = lambda z, w, y: residuals(z, w, y, Ps, qs, cz, cty, d, e, c)

    def run_stage(st, rho, Kinv, n_blocks_max):
        rv = rho * rho_scale

        def block(st):
            zs, ws, ys, it, nb, done, conv, infeas, prim, dual, ps_, ds_ = st
            (zn, wn, yn), yprev = admm_iterations(
                cfg.check_every, Kinv, cz, cty, qs, los, his, rv, cfg.alpha, (zs, ws, ys)
            )
            pr, du, pscale, dscale = res(zn, wn, yn)
            c_ok = (pr <= cfg.eps_abs + cfg.eps_rel * pscale) & (du <= cfg.eps_abs + cfg.eps_rel * dscale)
            # primal infeasibility certificate on the unscaled dual step dy = E (y_k - y_{k-1}) / c
            dy = e * (yn - yprev) / c
            ndy = jnp.max(jnp.abs(dy))
            ctdy = jnp.max(jnp.abs(cty(yn - yprev) / d / c))
            support = jnp.sum(hi * jnp.maximum(dy, 0.0) + lo * jnp.minimum(dy, 0.0))
            inf_ok = (ndy > 1e-12) & (ctdy <= cfg.eps_pinf * ndy) & (support < -cfg.eps_pinf * ndy)
            pick = lambda a, b: jnp.where(done, a, b)  # finished problems keep their state (vmap runs every lane)
            return (
                pick(zs, zn),
                pick(ws, wn),
                pick(ys, yn),
                pick(it, it + cfg.check_every),
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
        if cfg.early_exit:
            return jax.lax.while_loop(lambda s: (~s[5]) & (s[4] < n_blocks_max), block, st)
        return jax.lax.fori_loop(0, n_blocks_max, lambda _, s: block(s), st)  # reverse-differentiable

    zero = jnp.asarray(0.0, dtype)
    i0 = jnp.asarray(0, jnp.int32)
    f0 = jnp.asarray(False)
    st = (zs, ws, ys, i0, i0, f0, f0, f0, zero, zero, zero, zero)
    rho = jnp.asarray(cfg.rho, dtype)
    total = max(cfg.max_iter // cfg.check_every, 1)
    n_stages = cfg.rho_updates + 1 if cfg.adaptive_rho else 1
    budgets: list[int] = []  # blocks per stage: 2, 4, 8, ... and the rest of max_iter in the last
    for k in range(n_stages):
        rest = total - sum(budgets)
        if rest <= 0:
            break
        budgets.append(rest if k == n_stages - 1 else min(2 ** (k + 1), rest))
    adapt = lambda st, rho: adapted_rho(rho, *st[8:12])

    if cfg.early_exit:
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


class Prefactored(NamedTuple):
    """A QP's constant part, equilibrated and factorised on the host (``prefactor``; float64
    numpy): ``Ps (n, n)``, ``Cs (m, n)`` scaled, ``d (n,)``, ``e (m,)``, ``c`` the scalings,
    ``ladder (L,)`` the step sizes and ``inv (L, n, n)`` the KKT inverses for each."""

    Ps: Any
    Cs: Any
    d: Any
    e: Any
    c: float
    ladder: Any
    inv: Any


def prefactor(P, C, ladder, ruiz_iters: int = 25) -> Prefactored:
    """Equilibrate constant ``P (n, n)``, ``C (m, n)`` (numpy) and invert the scaled KKT
    matrix for every ``rho`` of ``ladder``. The cost is scaled by the mean largest entry of
    the rows of ``P`` (``q`` is not known yet)."""
    P, C = np.asarray(P, np.float64), np.asarray(C, np.float64)
    d, e = ruiz(P, C, ruiz_iters)
    Ps = d[:, None] * P * d[None, :]
    Cs = e[:, None] * C * d[None, :]
    c = 1.0 / max(float(np.abs(Ps).max(1).mean()), 1e-4)
    Ps = c * Ps
    n = P.shape[0]
    ladder = np.asarray(ladder, np.float64)
    inv = np.stack([np.linalg.inv(Ps + SIGMA * np.eye(n) + r * Cs.T @ Cs) for r in ladder])
    return Prefactored(Ps, Cs, d, e, c, ladder, inv)


def admm_prefactored(fixed: Prefactored, q, lo, hi, settings: LadderSettings = LadderSettings(), z0=None):
    """``admm_solve``'s iteration on a ``prefactor``-ed problem: ``min 1/2 z'Pz + q'z, lo <=
    C z <= hi`` with ``q (n,)``, ``lo, hi (m,)`` (``+-INF`` allowed), one problem (vmap it).
    Between phases ``rho`` takes the ladder's step nearest OSQP's rule. Returns
    (z ``(n,)``, unscaled primal residual, unscaled dual residual)."""
    f = q.dtype
    Ps, Cs = jnp.asarray(fixed.Ps, f), jnp.asarray(fixed.Cs, f)
    d, e, c = jnp.asarray(fixed.d, f), jnp.asarray(fixed.e, f), fixed.c
    inv = jnp.asarray(fixed.inv, f)
    ladder = jnp.asarray(fixed.ladder, f)
    qs = c * d * q
    ls = jnp.where(lo <= -INF / 2, -INF, e * lo)
    us = jnp.where(hi >= INF / 2, INF, e * hi)
    cz = lambda z: Cs @ z
    cty = lambda y: Cs.T @ y
    z = jnp.zeros_like(qs) if z0 is None else z0 / d
    w = jnp.clip(cz(z), ls, us)
    y = jnp.zeros_like(w)
    k0 = int(np.argmin(np.abs(np.log(np.asarray(fixed.ladder)) - np.log(settings.rho0))))
    res = lambda z, w, y: residuals(z, w, y, Ps, qs, cz, cty, d, e, c)

    # the residuals ride in the loop's state: each phase computes them once, for its step size
    # and the next test
    def more(carry):
        *_, i, rp, rd = carry
        return (i < settings.min_phases) | (
            (i < settings.phases) & ((rp >= settings.eps_prim) | (rd >= settings.eps_dual))
        )

    def body(carry):
        z, w, y, k, i, _, _ = carry
        rho = ladder[k]
        (z, w, y), _ = admm_iterations(settings.iters, inv[k], cz, cty, qs, ls, us, rho, settings.alpha, (z, w, y))
        r = res(z, w, y)
        k_new = jnp.argmin(jnp.abs(jnp.log(ladder) - jnp.log(adapted_rho(rho, *r)))).astype(jnp.int32)
        return z, w, y, k_new, i + 1, r[0], r[1]

    r0 = res(z, w, y)
    z, w, y, *_ = jax.lax.while_loop(more, body, (z, w, y, jnp.int32(k0), jnp.int32(0), r0[0], r0[1]))
    r_prim, r_dual, _, _ = res(z, w, y)
    return d * z, r_prim, r_dual
