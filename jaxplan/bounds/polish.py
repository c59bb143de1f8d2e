"""OSQP's solution polishing of the path QP: the active set solved directly, corrected pass by pass.

After the ADMM, OSQP's solution polishing (``polish_state``, ``PathQPConfig.polish``): the QP
with the rows the ADMM finds active as equalities is solved directly (its KKT system is block
tridiagonal along the stations), the active set corrected pass by pass; the polished solution
replaces the ADMM's only where it passes the same convergence test. It finishes the QPs on
which the ADMM's tail is slow (rows next to the active ones almost active: thousands of
iterations for OSQP's ADMM too) and makes every polished path exact on its active set.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.bounds.path_qp import PathQPConfig
from jaxplan.solvers.linalg import block_factor, block_solve

__all__ = ["polish_state"]


def polish_state(P, q, A, lo, hi, z, act_lo, act_hi, config: PathQPConfig, matvec=None, skip=False):
    """OSQP-style solution polishing of ``state_problem``'s QP (one problem; vmap it).

    The QP with the active rows as equalities (``lo`` where ``act_lo``, ``hi`` where ``act_hi``,
    and every row with ``lo == hi``) is solved directly: its KKT matrix, ordered by station
    (each station's three states, the multipliers of its three box rows and of the three rows
    of the interval ending there), is block tridiagonal with ``9 x 9`` blocks, factorised by a
    block LDL' (``block_factor``, ``O(T)``; symmetrically scaled to a unit diagonal of ``P``
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
        config: ``PathQPConfig`` (``polish_passes``, ``polish_refine``, ``admm.eps_abs``,
            ``admm.eps_rel``, ``admm.early_exit``: stop once no row is wrong (``while_loop``), or
            run every pass).
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
        Si, G = block_factor(D, L)
        af = act.astype(dt)
        y = jnp.zeros(m, dt)
        for _ in range(1 + config.polish_refine):  # the first solve, then refinement on the exact system
            rx = -q - P @ x - A.T @ y
            ry = af * (b - mv(x))
            r = jnp.concatenate([rx[ix], ry[ix], ry[ri] * has], -1)
            v = scale * block_solve(Si, G, L, scale * r)
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
            & (prim <= config.admm.eps_abs + config.admm.eps_rel * p_scale)
            & (dual <= config.admm.eps_abs + config.admm.eps_rel * d_scale)
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
    if config.admm.early_exit:
        c = jax.lax.while_loop(lambda c: (c[0] < config.polish_passes) & ~c[4], one_pass, c)
    else:
        c = jax.lax.fori_loop(0, config.polish_passes, lambda _, c: one_pass(c), c)
    return c[7], c[8], c[5] & ~skip, c[0]
