"""The smoothing QP after the DP: the executed speed profile (piecewise-jerk, every ``qp_dt``).

Variables: the accelerations ``a_1..a_n`` at the times ``k h`` (``h = qp_dt``, ``n h`` the
horizon) and two slacks ``eps_s, eps_v >= 0``; the acceleration is linear between samples (constant
jerk), starting at the car's ``a_0``, and speed and station are its exact integrals from
``v_0`` (``v_{k+1} = v_k + h (a_k + a_{k+1}) / 2``, ``s_{k+1} = s_k + h v_k + h^2 (a_k / 3 +
a_{k+1} / 6)``). So the speed difference over a step is the mean of two sampled
accelerations: bounding the samples bounds what a finite difference of the executed
states sees. Minimise

    sum_k  w_ref (s_k - s_dp)^2 + w_vref (v_k - v_dp)^2 + w_acc a_k^2 + w_jerk j_k^2  (times h)
    + w_eps2 eps_s^2 + w_eps1 eps_s + w_lim2 eps_v^2 + w_lim1 eps_v

subject to ``a_brake <= a_k <= a_max``, ``|j_k| <= jerk_max``, ``v_k >= 0``, the speed limit
``v_k <= v_limit(s_dp) + eps_v`` and the station corridor the DP chose, per obstacle and
time (behind every blocking boundary the DP stayed behind: ``s_k <= lower + eps_s``; ahead of
every one it passed: ``s_k >= upper - eps_s``). The slacks make the QP always feasible: when
the DP could not avoid a boundary, the QP brakes as hard as the limits allow; a speed limit
it cannot meet in time (a curve that starts too close) costs far less than the corridor.

The solver is ADMM (OSQP's iteration) on the fixed matrices of this QP: the Hessian and the
constraint matrix depend only on the weights and the grid, so they are equilibrated
(Ruiz) and the KKT matrix is inverted once on the host for a ladder of step sizes ``rho``;
each iteration is a few dense matrix-vector products, and ``rho`` adapts (OSQP's rule,
snapped to the ladder) between phases of iterations. ``ok`` reports the primal and dual
residuals at the end.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.speed.dp import SpeedConfig, SpeedPlan, profile_at

INF = 1e20
RHO_LADDER = tuple(float(r) for r in 10.0 ** np.linspace(-3, 3, 13))
SIGMA = 1e-6  # proximal term of the x-update


@dataclasses.dataclass(frozen=True)
class SmoothWeights:
    """Weights of the smoothing QP (static: its matrices are built from them once)."""

    w_ref: float = 1.0
    w_vref: float = 1.0
    w_acc: float = 1.0
    w_jerk: float = 0.3
    w_eps2: float = 1e3
    w_eps1: float = 1e2
    w_lim2: float = 10.0
    w_lim1: float = 10.0


@dataclasses.dataclass(frozen=True)
class SolverConfig:
    """ADMM settings: ``phases`` of ``iters`` iterations, relaxation ``alpha``, the first
    step size ``rho0`` and the residuals under which ``ok`` holds."""

    phases: int = 10
    iters: int = 25
    alpha: float = 1.6
    rho0: float = 0.1
    eps_prim: float = 5e-2
    eps_dual: float = 5e-2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedProfile:
    """The executed speed profile of one scene (add leading dims for batches).

    Attributes:
        t, s, v, a: ``(..., n + 1)`` at ``k qp_dt`` from now (``s[0] = 0``, ``v[0] = v0``).
        jerk: ``(..., n)``.
        ok: ``(...)`` the QP converged (else the DP's profile is returned).
        slack: ``(...)`` the QP's corridor slack (m): > 0 when the DP's corridor could not be
            kept within the acceleration limits.
        r_prim, r_dual: ``(...)`` the solver's final residuals.
    """

    t: Any
    s: Any
    v: Any
    a: Any
    jerk: Any
    ok: Any
    slack: Any
    r_prim: Any
    r_dual: Any


def _maps(n: int, h: float):
    """Linear maps of the QP (float64): ``(v, s) = M_x x + M_y [a0, v0]`` for accelerations
    ``x (n,)``: returns Va, Vy, Sa, Sy ``(n, n) / (n, 2)``."""
    def simulate(a_full, v0):
        v = np.zeros(n + 1)
        s = np.zeros(n + 1)
        v[0] = v0
        for k in range(n):
            v[k + 1] = v[k] + h * 0.5 * (a_full[k] + a_full[k + 1])
            s[k + 1] = s[k] + h * v[k] + h * h * (a_full[k] / 3.0 + a_full[k + 1] / 6.0)
        return v[1:], s[1:]

    Va, Sa = np.zeros((n, n)), np.zeros((n, n))
    for i in range(n):
        e = np.zeros(n + 1)
        e[i + 1] = 1.0
        Va[:, i], Sa[:, i] = simulate(e, 0.0)
    e = np.zeros(n + 1)
    e[0] = 1.0
    va0, sa0 = simulate(e, 0.0)
    vv0, sv0 = simulate(np.zeros(n + 1), 1.0)
    return Va, np.stack([va0, vv0], 1), Sa, np.stack([sa0, sv0], 1)


@functools.lru_cache(maxsize=None)
def qp_matrices(n: int, h: float, w: SmoothWeights):
    """The constant QP data (float64 numpy): ``P (n+2, n+2)``, the dense constraint matrix
    ``A (6n+2, n+2)`` with its row blocks [a, jerk, v, v - eps_v, s - eps_s, s + eps_s, eps_s,
    eps_v] (variables: n accelerations, eps_s, eps_v), the
    affine parts, the Ruiz scalings ``D, E, c`` and the KKT inverses for ``RHO_LADDER``."""
    Va, Vy, Sa, Sy = _maps(n, h)
    I = np.eye(n)
    Ja = (I - np.eye(n, k=-1)) / h  # j_k = (a_{k+1} - a_k) / h, a_0 in Jy
    Jy = np.zeros((n, 2))
    Jy[0, 0] = -1.0 / h
    N = n + 2  # accelerations, eps_s, eps_v
    z1 = np.zeros((n, 1))
    one = np.ones((n, 1))
    pad = lambda M, cs, cv: np.concatenate([M, cs, cv], 1)
    e = np.zeros((2, N))
    e[0, n], e[1, n + 1] = 1.0, 1.0
    A = np.concatenate([pad(I, z1, z1), pad(Ja, z1, z1), pad(Va, z1, z1), pad(Va, z1, -one), pad(Sa, -one, z1),
                        pad(Sa, one, z1), e])
    P = np.zeros((N, N))
    P[:n, :n] = 2.0 * h * (w.w_ref * Sa.T @ Sa + w.w_vref * Va.T @ Va + w.w_acc * I + w.w_jerk * Ja.T @ Ja)
    P[n, n], P[n + 1, n + 1] = 2.0 * w.w_eps2, 2.0 * w.w_lim2
    # Ruiz equilibration of the KKT matrix [[P, A^T], [A, 0]]
    D, E, c = np.ones(N), np.ones(A.shape[0]), 1.0
    Ps, As = P.copy(), A.copy()
    for _ in range(25):
        d = 1.0 / np.sqrt(np.maximum(np.maximum(np.abs(Ps).max(0), np.abs(As).max(0)), 1e-4))
        ee = 1.0 / np.sqrt(np.maximum(np.abs(As).max(1), 1e-4))
        Ps = d[:, None] * Ps * d[None, :]
        As = ee[:, None] * As * d[None, :]
        D, E = D * d, E * ee
    c = 1.0 / max(np.abs(Ps).max(1).mean(), 1e-4)
    Ps = c * Ps
    inv = np.stack([np.linalg.inv(Ps + SIGMA * np.eye(N) + r * As.T @ As) for r in RHO_LADDER])
    return dict(Va=Va, Vy=Vy, Sa=Sa, Sy=Sy, Ja=Ja, Jy=Jy, A=A, P=P, D=D, E=E, c=c, Ps=Ps, As=As, inv=inv)


def qp_problem(s_ref, v_ref, lower, upper, v_lim, a0, v0, config: SpeedConfig, w: SmoothWeights):
    """The QP of one scene: ``(q (n+2,), l (6n+2,), u (6n+2,))`` for the constant ``P``, ``A``
    of ``qp_matrices`` (all references ``(n,)`` at ``k h``, k = 1..n)."""
    n = s_ref.shape[-1]
    h = config.qp_dt
    m = qp_matrices(n, h, w)
    f = s_ref.dtype
    y = jnp.stack([jnp.asarray(a0, f), jnp.asarray(v0, f)])
    cv = jnp.asarray(m["Vy"], f) @ y
    cs = jnp.asarray(m["Sy"], f) @ y
    cj = jnp.asarray(m["Jy"], f) @ y
    Va, Sa, Ja = (jnp.asarray(m[k], f) for k in ("Va", "Sa", "Ja"))
    q = 2.0 * h * (w.w_ref * Sa.T @ (cs - s_ref) + w.w_vref * Va.T @ (cv - v_ref) + w.w_jerk * Ja.T @ cj)
    q = jnp.concatenate([q, jnp.array([w.w_eps1, w.w_lim1], f)])
    full = lambda x: jnp.full((n,), x, f)
    J = config.jerk_max
    l = jnp.concatenate([full(config.a_brake), -J - cj, -cv, full(-INF), full(-INF), lower - cs, jnp.zeros((2,), f)])
    u = jnp.concatenate([full(config.a_max), J - cj, full(INF), v_lim - cv, upper - cs, full(INF), jnp.full((2,), INF, f)])
    return q, l, u


def admm(q, l, u, n: int, h: float, w: SmoothWeights, x0=None, solver: SolverConfig = SolverConfig()):
    """OSQP-style ADMM for ``min 1/2 x'Px + q'x, l <= Ax <= u`` with the constant ``P, A`` of
    ``qp_matrices(n, h, w)``. Returns (x ``(n+2,)``, primal residual, dual residual)."""
    m = qp_matrices(n, h, w)
    f = q.dtype
    Ps, As = jnp.asarray(m["Ps"], f), jnp.asarray(m["As"], f)
    D, E, c = jnp.asarray(m["D"], f), jnp.asarray(m["E"], f), m["c"]
    inv = jnp.asarray(m["inv"], f)
    ladder = jnp.asarray(RHO_LADDER, f)
    qs = c * D * q
    ls = jnp.where(l <= -INF / 2, -INF, E * l)
    us = jnp.where(u >= INF / 2, INF, E * u)
    x = jnp.zeros_like(qs) if x0 is None else x0 / D
    z = jnp.clip(As @ x, ls, us)
    y = jnp.zeros_like(z)
    k0 = int(np.argmin(np.abs(np.log(np.asarray(RHO_LADDER)) - np.log(solver.rho0))))
    sig, alpha = SIGMA, solver.alpha

    def phase(carry, _):
        x, z, y, k = carry
        K = inv[k]
        rho = ladder[k]

        def it(c2, _):
            x, z, y = c2
            xt = K @ (sig * x - qs + As.T @ (rho * z - y))
            zt = As @ xt
            x = alpha * xt + (1 - alpha) * x
            zr = alpha * zt + (1 - alpha) * z
            zn = jnp.clip(zr + y / rho, ls, us)
            y = y + rho * (zr - zn)
            return (x, zn, y), None

        (x, z, y), _ = jax.lax.scan(it, (x, z, y), None, length=solver.iters)
        ax = As @ x
        px = Ps @ x
        aty = As.T @ y
        rp = jnp.max(jnp.abs(ax - z))
        rd = jnp.max(jnp.abs(px + qs + aty))
        np_ = rp / jnp.maximum(jnp.maximum(jnp.max(jnp.abs(ax)), jnp.max(jnp.abs(z))), 1e-8)
        nd = rd / jnp.maximum(jnp.maximum(jnp.max(jnp.abs(px)), jnp.maximum(jnp.max(jnp.abs(aty)), jnp.max(jnp.abs(qs)))), 1e-8)
        want = rho * jnp.sqrt(np_ / jnp.maximum(nd, 1e-12))
        k_new = jnp.argmin(jnp.abs(jnp.log(ladder) - jnp.log(jnp.maximum(want, 1e-12)))).astype(jnp.int32)
        return (x, z, y, k_new), None

    (x, z, y, _), _ = jax.lax.scan(phase, (x, z, y, jnp.int32(k0)), None, length=solver.phases)
    r_prim = jnp.max(jnp.abs((As @ x - z) / E))
    r_dual = jnp.max(jnp.abs((Ps @ x + qs + As.T @ y) / (c * D)))
    return D * x, r_prim, r_dual


def corridor(plan: SpeedPlan, config: SpeedConfig, t):
    """Station bounds ``(lower (n,), upper (n,))`` at QP times ``t (n,)`` from the DP's side
    of each blocking boundary: the boundaries at the check times, conservatively
    interpolated (a QP time between two checks is covered by both), and per obstacle and
    time: ``upper <= lower_k`` where the DP stayed behind it (or could not avoid it),
    ``lower >= upper_k`` where the DP had passed it."""
    lo, hi, hit, _ = plan.scene.blocking()  # (K, F)
    hc = config.dt / config.n_sub
    F = lo.shape[-1]
    fa = jnp.clip(jnp.floor(t / hc + 1e-6).astype(jnp.int32), 0, F - 1)
    fb = jnp.clip(jnp.ceil(t / hc - 1e-6).astype(jnp.int32), 0, F - 1)
    ha, hb = hit[:, fa], hit[:, fb]
    big = 1e9
    low = jnp.minimum(jnp.where(ha, lo[:, fa], big), jnp.where(hb, lo[:, fb], big))
    up = jnp.maximum(jnp.where(ha, hi[:, fa], -big), jnp.where(hb, hi[:, fb], -big))
    on = ha | hb
    s_dp, _, _ = profile_at(plan, t)
    passed = on & (s_dp >= 0.5 * (low + up))
    behind = on & ~passed
    upper = jnp.min(jnp.where(behind, low, INF), 0)
    lower = jnp.max(jnp.where(passed, up, -INF), 0)
    return lower, upper


def smooth_plan(plan: SpeedPlan, v0, a0, config: SpeedConfig, w: SmoothWeights = SmoothWeights(),
                solver: SolverConfig = SolverConfig()) -> SpeedProfile:
    """The executed profile of one scene's DP plan (``SpeedProfile`` at ``k qp_dt``)."""
    h = config.qp_dt
    n = int(round(config.horizon / h))
    f = plan.s.dtype
    t = jnp.arange(n + 1, dtype=f) * h
    v0 = jnp.maximum(jnp.asarray(v0, f), 0.0)
    J = config.jerk_max
    # an acceleration the car can leave without reversing (braking towards a stop)
    a0 = jnp.clip(jnp.asarray(a0, f), config.a_brake, config.a_max)
    a0 = jnp.maximum(a0, -jnp.sqrt(J * v0))
    s_ref, v_ref, a_ref = profile_at(plan, t[1:])
    lower, upper = corridor(plan, config, t[1:])
    vl = plan.scene.v_limit
    qi = jnp.clip(s_ref / config.ds, 0.0, vl.shape[0] - 1.0)
    k = jnp.clip(jnp.floor(qi).astype(jnp.int32), 0, vl.shape[0] - 2)
    v_lim = vl[k] + (qi - k) * (vl[k + 1] - vl[k])
    q, l, u = qp_problem(s_ref, v_ref, lower, upper, v_lim, a0, v0, config, w)
    x, rp, rd = admm(q, l, u, n, h, w, jnp.concatenate([a_ref, jnp.zeros((2,), f)]), solver)
    m = qp_matrices(n, h, w)
    acc = jnp.clip(x[:n], config.a_brake, config.a_max)
    y = jnp.stack([a0, v0])
    v = jnp.asarray(m["Va"], f) @ acc + jnp.asarray(m["Vy"], f) @ y
    s = jnp.asarray(m["Sa"], f) @ acc + jnp.asarray(m["Sy"], f) @ y
    ok = (rp < solver.eps_prim) & (rd < solver.eps_dual) & jnp.all(jnp.isfinite(x))
    z = jnp.zeros((1,), f)
    qp = (jnp.concatenate([z, s]), jnp.concatenate([v0[None], jnp.maximum(v, 0.0)]), jnp.concatenate([a0[None], acc]))
    s_d, v_d, a_d = profile_at(plan, t)
    s, v, a = (jnp.where(ok, p, d) for p, d in zip(qp, (s_d, v_d, a_d)))
    return SpeedProfile(t, s, v, a, jnp.diff(a) / h, ok, jnp.where(ok, jnp.maximum(x[n], 0.0), 0.0), rp, rd)


smooth_plan_jit = jax.jit(smooth_plan, static_argnames=("config", "w", "solver"))
