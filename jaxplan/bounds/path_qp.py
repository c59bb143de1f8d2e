"""The path QP: a piecewise-jerk lateral offset inside per-point bounds, its weights and settings.

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
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.solvers.qp import ADMMSettings

__all__ = ["PathWeights", "PathQPConfig", "jerk_map", "curvature_bounds", "state_problem", "state_matvec"]

# Infinite bounds become this (m, or its unit) inside the solver.
FAR = 1e4


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
        tol_violation: bound violation (m) above which a solution is not ``ok``.
        admm: the ADMM's settings (``jaxplan.solvers.ADMMSettings``; its ``eps_abs`` and
            ``eps_rel`` are also the polished solution's convergence test). Its defaults suit
            this QP: ``eps_pinf`` 3e-2 (in float32 OSQP's 1e-4 lets 70 % of the infeasible
            frames of the OSQP test run to ``max_iter`` uncertified; no solvable frame is
            certified infeasible) and ``rho_updates`` 6 (with 3, 8 % of the frames OSQP solves
            stop unconverged at ``max_iter``; with 6, 0.1 %). With ``early_exit=False`` every
            iteration runs (``fori_loop``), and so does every polishing pass, so that
            ``jax.grad`` can differentiate through the solve by unrolling (solved problems keep
            their state).
        polish: OSQP's solution polishing after the ADMM (``polish_state``): the QP with the
            constraints the ADMM finds active as equalities, solved directly, the active set
            corrected pass by pass (block principal pivoting); the polished solution replaces the
            ADMM's (and counts as converged) only where it passes the convergence test itself
            (``admm.eps_abs``, ``admm.eps_rel``: bounds met, complementary, correctly signed
            multipliers).
        polish_passes: at most this many active-set passes (each one block-tridiagonal KKT
            factorisation, ``O(T)``).
        polish_refine: iterative-refinement steps per pass.
    """

    dl_max: float = 2.0
    ddl_max: float = 1.0
    jerk_max: float = 1.0
    tol_violation: float = 1e-3
    admm: ADMMSettings = ADMMSettings()
    polish: bool = True
    polish_passes: int = 16
    polish_refine: int = 2


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
    big = jnp.asarray(FAR, dtype)
    fix0 = lambda v, x0: v.at[0].set(x0)
    hi_x = jnp.concatenate([fix0(upper, init[0]), fix0(dl_hi, init[1]), fix0(ddl_hi, init[2])])
    lo_x = jnp.concatenate([fix0(lower, init[0]), fix0(dl_lo, init[1]), fix0(ddl_lo, init[2])])
    jm = jnp.full((T - 1,), jerk_max, dtype)
    zeq = jnp.zeros(2 * (T - 1), dtype)
    hi = jnp.clip(jnp.concatenate([hi_x, jm, zeq]), -big, big)
    lo = jnp.clip(jnp.concatenate([lo_x, -jm, zeq]), -big, big)
    return P, q, A, lo, hi


def state_matvec(ds, T):
    """``x -> A x`` of ``state_problem`` in O(T) (the rows' structure), for ``admm_solve``."""

    def mv(x):
        l, dl, ddl = x[:T], x[T : 2 * T], x[2 * T :]
        jerk = (ddl[1:] - ddl[:-1]) / ds
        pos = l[1:] - l[:-1] - ds * dl[:-1] - (ds**2 / 3) * ddl[:-1] - (ds**2 / 6) * ddl[1:]
        vel = dl[1:] - dl[:-1] - (ds / 2) * (ddl[:-1] + ddl[1:])
        return jnp.concatenate([x, jerk, pos, vel])

    return mv
