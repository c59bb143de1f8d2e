"""The smoothing QP after the DP: the executed speed profile (piecewise-jerk, every ``qp_dt``).

Variables: the accelerations ``a_1..a_n`` at the times ``k h`` (``h = qp_dt``, ``n h`` the
horizon); the acceleration is linear between samples (constant jerk), starting at the
car's ``a_0``, and speed and station are its exact integrals from ``v_0``
(``v_{k+1} = v_k + h (a_k + a_{k+1}) / 2``, ``s_{k+1} = s_k + h v_k + h^2 (a_k / 3 +
a_{k+1} / 6)``). So the speed difference over a step is the mean of two sampled
accelerations: bounding the samples bounds what a finite difference of the executed
states sees. Minimise

    sum_k  w_ref (s_k - s_ref)^2 + w_vref (v_k - v_ref)^2 + w_acc a_k^2 + w_jerk j_k^2  (times h)

subject to ``a_brake <= a_k <= a_max``, ``|j_k| <= jerk_max``, ``0 <= v_k <= v_limit_k`` and
``lower_k <= s_k <= upper_k``: the station corridor the DP chose, per obstacle and time
(behind every blocking boundary the DP stayed behind, ahead of every one it passed).

Each side of the corridor is one the limits can keep: the upper side is widened to what the
hardest braking the limits allow reaches (``hardest_braking``: the jerk-limited stop at
``a_brake``, ``upper_k >= s_brake_k``), the lower side narrowed to the most they reach
(``hardest_acceleration``, less ``LOWER_MARGIN``) and below the upper side, and the speed limit
relaxed to what braking at ``LIMIT_DECEL`` reaches and, where the DP's profile runs above it
(the DP weighs the limit against its other costs), raised to the DP's speed, up to
``sqrt((EMERGENCY_LAT_ACCEL - LAT_TRACKING_MARGIN) / a_lat_max)`` times the limit (in a bend: the
curvature limit at the emergency lateral acceleration instead of ``SpeedConfig.a_lat_max``); that
stretched limit is relaxed only to what the hardest braking reaches. The limit is a bound per
time, read at the stations the car is at then: first the DP's, then (``LIMIT_ROUNDS`` solves in
all) the least limit between the DP's station and the last solution's, since the executed profile
lags the DP where it cannot follow it (the jerk limit, braking when the cycle starts) and meets a
bend later.
Where the DP could not avoid a boundary,
only the hardest braking is left there, and ``slack`` (how far the corridor had to be widened)
says so. The references are clipped into the corridor, so the QP tracks the boundary, not the
DP's profile through an obstacle. Where both sides and the speed limit bind at once (a vehicle
behind pushes the car faster than a bend ahead allows), a corridor the limits cannot keep may
be left: the QP is solved with and without the corridor's lower sides (the two as one vmapped
solve), and the one without them is executed where the first's iterate does not keep its
bounds; ``ok`` is that solve's.

The solver is ``jaxplan.solvers.admm_prefactored`` (OSQP's ADMM on constant matrices): the
Hessian and the constraint matrix depend only on the weights and the grid, so they are
equilibrated and the KKT matrix is inverted once on the host for a ladder of step sizes
``rho`` (``RHO_LADDER``); each iteration is a few dense matrix-vector products, and ``rho``
moves along the ladder between phases of iterations, until the primal and dual residuals are
small (``ok``) or a phase budget is spent.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.planner import EMERGENCY_LAT_ACCEL
from jaxplan.solvers.qp import INF, LadderSettings, admm_prefactored, prefactor
from jaxplan.speed.problem import SpeedConfig, SpeedPlan, profile_at

RHO_LADDER = tuple(float(r) for r in 10.0 ** np.linspace(-3, 3, 13))
LIMIT_DECEL = 3.0  # m/s^2: the speed limit of the QP is relaxed to what braking at this meets
V_TOL = 0.01  # m/s: speeds down to -V_TOL are feasible in the QP (the output is held at 0)
LOWER_MARGIN = 0.1  # m: the corridor's lower side stays this far below the most the limits reach
LIMIT_ROUNDS = 3  # QP solves: the speed limit at the DP's stations, then also where the last solution is
HARD_MARGIN = 0.2  # m/s: the stretched limit stays this far above the hardest braking (0.02 stalled the ADMM)
# m/s^2: the stretched limit is taken this far below EMERGENCY_LAT_ACCEL: the simulated car, tracking
# a profile at that limit through a bend, ran up to 0.03 m/s^2 above it
LAT_TRACKING_MARGIN = 0.1


@dataclasses.dataclass(frozen=True)
class SmoothWeights:
    """Weights of the smoothing QP (static: its matrices are built from them once)."""

    w_ref: float = 1.0
    w_vref: float = 1.0
    w_acc: float = 1.0
    w_jerk: float = 0.3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpeedProfile:
    """The executed speed profile of one scene (add leading dims for batches).

    Attributes:
        t, s, v, a: ``(..., n + 1)`` at ``k qp_dt`` from now (``s[0] = 0``, ``v[0] = v0``).
        jerk: ``(..., n)``.
        ok: ``(...)`` the QP converged (else its last iterate, clipped and integrated, is
            returned; the DP's profile only if that is not finite).
        slack: ``(...)`` how far (m) the DP's corridor had to be widened to what the hardest
            braking reaches: > 0 when it could not be kept within the limits.
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


def integration_maps(n: int, h: float):
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


@functools.cache
def qp_matrices(n: int, h: float, w: SmoothWeights):
    """The constant QP data (float64 numpy): ``P (n, n)``, the constraint matrix ``A (4n, n)``
    with its row blocks [a, jerk, v, s], the affine parts (``Va, Vy, Sa, Sy, Ja, Jy``) and
    ``fixed``, the ``jaxplan.solvers.Prefactored`` problem for ``RHO_LADDER``."""
    Va, Vy, Sa, Sy = integration_maps(n, h)
    I = np.eye(n)
    Ja = (I - np.eye(n, k=-1)) / h  # j_k = (a_{k+1} - a_k) / h, a_0 in Jy
    Jy = np.zeros((n, 2))
    Jy[0, 0] = -1.0 / h
    A = np.concatenate([I, Ja, Va, Sa])
    P = 2.0 * h * (w.w_ref * Sa.T @ Sa + w.w_vref * Va.T @ Va + w.w_acc * I + w.w_jerk * Ja.T @ Ja)
    fixed = prefactor(P, A, RHO_LADDER)
    return dict(Va=Va, Vy=Vy, Sa=Sa, Sy=Sy, Ja=Ja, Jy=Jy, A=A, P=P, fixed=fixed)


def _advance(a, v, a1, h: float):
    """One step of the QP's integration: ``(v1, ds)`` from ``(a, v)`` with the acceleration
    linear from ``a`` to ``a1`` over ``h``."""
    return v + 0.5 * h * (a + a1), h * v + h * h * (a / 3.0 + a1 / 6.0)


def _braking_step(a, v, h: float, config: SpeedConfig):
    """The next acceleration of the jerk-limited hardest braking from ``(a, v)``: braking harder
    at ``jerk_max`` (to ``a_brake``) unless the speed left after that step would be less than
    what the jerk-limited rise back to 0 still takes away; then rising."""
    J = config.jerk_max
    a_f = jnp.maximum(a - J * h, config.a_brake)
    v_f = v + 0.5 * h * (a + a_f)
    rising = v_f <= 0.5 * a_f * a_f / J + 0.5 * h * jnp.abs(a_f)
    return jnp.where(rising, jnp.minimum(a + J * h, 0.0), a_f)


def hardest_braking(a0, v0, n: int, h: float, config: SpeedConfig):
    """The jerk-limited hardest braking from ``(a0, v0)`` in the QP's discretisation: the
    acceleration falls at ``jerk_max`` to ``a_brake`` and rises again at ``jerk_max`` to 0 as
    the car comes to a stop (early enough never to reverse, so it may end creeping at a few
    tenths of a m/s). Returns
    ``(s, v, a)`` each ``(n,)`` at ``k h``, k = 1..n: a profile within every limit, close
    to the least station the limits allow."""

    def step(c, _):
        a, v, s = c
        a1 = _braking_step(a, v, h, config)
        v1, ds = _advance(a, v, a1, h)
        return (a1, v1, s + ds), (s + ds, v1, a1)

    f = jnp.result_type(a0, v0, jnp.float32)
    _, out = jax.lax.scan(step, (jnp.asarray(a0, f), jnp.asarray(v0, f), jnp.zeros((), f)), None, length=n)
    return out


def hardest_acceleration(a0, v0, v_lim, n: int, h: float, config: SpeedConfig):
    """The most station ``(n,)`` at ``k h`` (k = 1..n) the QP's limits reach from ``(a0, v0)``,
    in the QP's own integration: each step the acceleration rises at ``jerk_max`` towards
    ``a_max`` unless that passes the speed limit ``v_lim (n,)``, now or (by the hardest braking
    from the state it leaves, ``hardest_braking``'s rule) later; then it is the one that meets
    the limit as it eases off at ``jerk_max``, else the one that meets it now, else none, else it
    falls at ``jerk_max``. A profile within the acceleration, jerk and speed limits wherever
    one exists (the limit met within a centimetre per second)."""
    J, ab, am = config.jerk_max, config.a_brake, config.a_max
    f = v_lim.dtype
    steps = jnp.arange(n)

    def brakes_within(a, v, k):
        """The hardest braking from ``(a, v)`` after step ``k`` keeps every later limit."""

        def brake(c, j):
            a, v, ok = c
            a1 = _braking_step(a, v, h, config)
            v1, _ = _advance(a, v, a1, h)
            later = j > k
            ok = ok & (~later | (v1 <= v_lim[j] + 0.01))
            return (jnp.where(later, a1, a), jnp.where(later, v1, v), ok), None

        (_, _, ok), _ = jax.lax.scan(brake, (a, v, jnp.asarray(True)), steps)
        return ok

    def step(c, k):
        a, v, s = c
        lo, hi = jnp.maximum(a - J * h, ab), jnp.minimum(a + J * h, am)
        # the first of: the most acceleration, the one that meets the limit as it eases off to
        # none at jerk_max, the one that meets it now, none, the least
        gap = v_lim[k] - v - 0.5 * h * a
        meet = J * (jnp.sqrt(jnp.maximum(0.25 * h * h + 2.0 * gap / J, 0.0)) - 0.5 * h)
        exact = 2.0 * (v_lim[k] - v) / h - a
        tries = jnp.clip(jnp.stack([hi, meet, exact, jnp.zeros_like(a), lo]), lo, hi)
        v_try, _ = _advance(a, v, tries, h)
        ok = (v_try <= v_lim[k] + 0.01) & jax.vmap(brakes_within, (0, 0, None))(tries, v_try, k)
        a1 = tries[jnp.argmax(ok.at[-1].set(True))]
        v1, ds = _advance(a, v, a1, h)
        return (a1, v1, s + ds), s + ds

    _, s = jax.lax.scan(step, (jnp.asarray(a0, f), jnp.asarray(v0, f), jnp.zeros((), f)), steps)
    return s


def leavable_a0(a0, v0, config: SpeedConfig):
    """The car's acceleration as the QP starts from it: within ``[a_brake, a_max]``, and no
    harder braking than the jerk limit can still end at rest without reversing
    (``a0 >= -sqrt(jerk_max v0)``)."""
    a0 = jnp.clip(a0, config.a_brake, config.a_max)
    return jnp.maximum(a0, -jnp.sqrt(config.jerk_max * jnp.maximum(v0, 0.0)))


def qp_problem(s_ref, v_ref, lower, upper, v_lim, a0, v0, config: SpeedConfig, w: SmoothWeights, v_hard=None):
    """The QP of one scene: ``(q (n,), l (4n,), u (4n,), slack ())`` for the constant ``P``,
    ``A`` of ``qp_matrices`` (references, bounds and limits ``(n,)`` at ``k h``, k = 1..n;
    ``a0`` one the car can leave, ``leavable_a0``). ``v_lim`` is relaxed to what braking at
    ``LIMIT_DECEL`` reaches; ``v_hard (n,)`` (default none), a limit relaxed only to what the
    hardest braking reaches, caps it."""
    n = s_ref.shape[-1]
    h = config.qp_dt
    m = qp_matrices(n, h, w)
    f = s_ref.dtype
    tk = h * jnp.arange(1, n + 1, dtype=f)
    s_b, v_b, _ = hardest_braking(a0, v0, n, h, config)
    # always feasible: the corridor's upper side widened to the hardest braking, its lower side
    # narrowed to the most the limits reach (and below the upper side), the limit to braking at
    # LIMIT_DECEL (and never below the hardest braking)
    slack = jnp.max(jnp.maximum(s_b - upper, 0.0))
    upper = jnp.maximum(upper, s_b + 0.02)
    v_lim = jnp.maximum(v_lim, jnp.maximum(jnp.asarray(v0, f) - LIMIT_DECEL * tk, v_b) + 0.02)
    if v_hard is not None:
        v_lim = jnp.minimum(v_lim, jnp.maximum(v_hard, v_b + HARD_MARGIN))
    s_a = hardest_acceleration(a0, v0, v_lim, n, h, config)
    lower = jnp.minimum(lower, jnp.minimum(s_a - LOWER_MARGIN, upper - 0.02))
    # references inside the corridor: where the DP's profile leaves it, track the boundary
    over = s_ref > upper
    du = jnp.diff(jnp.concatenate([upper[:1], upper])) / h
    v_ref = jnp.where(over, jnp.clip(du, 0.0, v_ref), v_ref)
    s_ref = jnp.clip(s_ref, lower, upper)
    y = jnp.stack([jnp.asarray(a0, f), jnp.asarray(v0, f)])
    cv = jnp.asarray(m["Vy"], f) @ y
    cs = jnp.asarray(m["Sy"], f) @ y
    cj = jnp.asarray(m["Jy"], f) @ y
    Va, Sa, Ja = (jnp.asarray(m[k], f) for k in ("Va", "Sa", "Ja"))
    q = 2.0 * h * (w.w_ref * Sa.T @ (cs - s_ref) + w.w_vref * Va.T @ (cv - v_ref) + w.w_jerk * Ja.T @ cj)
    full = lambda x: jnp.full((n,), x, f)
    J = config.jerk_max
    l = jnp.concatenate([full(config.a_brake), -J - cj, -V_TOL - cv, lower - cs])
    u = jnp.concatenate([full(config.a_max), J - cj, v_lim - cv, upper - cs])
    return q, l, u, slack


def corridor(plan: SpeedPlan, config: SpeedConfig, t):
    """Station bounds ``(lower (n,), upper (n,))`` at QP times ``t (n,)`` from the DP's side
    of each blocking boundary: the boundaries at the check times, conservatively
    interpolated (a QP time between two checks is covered by both), and per obstacle and
    time: ``upper <= lower_k`` where the DP stayed behind it (or could not avoid it),
    ``lower >= upper_k`` where the DP had passed it; none from the stop wall when the car is
    already past it. Vehicles behind the car (``Classified.rear``): ``lower >= upper_k``
    where the DP stays ahead of one."""
    lo, hi, hit, _ = plan.scene.blocking()  # (K, F)
    hc = config.dt / config.n_sub
    F = lo.shape[-1]
    fa = jnp.clip(jnp.floor(t / hc + 1e-6).astype(jnp.int32), 0, F - 1)
    fb = jnp.clip(jnp.ceil(t / hc - 1e-6).astype(jnp.int32), 0, F - 1)
    big = 1e9

    def at_times(lo, hi, hit):
        """A boundary ``(K, F)`` at the QP times, covered by both checks around each: ``(low,
        up, hit)`` each ``(K, n)``."""
        ha, hb = hit[:, fa], hit[:, fb]
        low = jnp.minimum(jnp.where(ha, lo[:, fa], big), jnp.where(hb, lo[:, fb], big))
        up = jnp.maximum(jnp.where(ha, hi[:, fa], -big), jnp.where(hb, hi[:, fb], -big))
        return low, up, ha | hb

    low, up, covered = at_times(lo, hi, hit)
    # the stop wall (the last row) where the car already stands past it (a blockage of the path at
    # the car itself): the DP could not stay behind it and charges entering, not staying, so it is no
    # bound of the corridor either (the obstacles themselves are rows of their own)
    past = (jnp.arange(lo.shape[0]) == lo.shape[0] - 1) & hit[:, 0] & (lo[:, 0] <= 0.0)
    on = covered & ~past[:, None]
    s_dp, _, _ = profile_at(plan, t)
    passed = on & (s_dp >= 0.5 * (low + up))
    behind = on & ~passed
    upper = jnp.min(jnp.where(behind, low, INF), 0)
    lower = jnp.max(jnp.where(passed, up, -INF), 0)
    # the vehicles behind the DP stays ahead of (a vehicle closing in from behind that will not brake)
    rear = plan.scene.classified.rear
    _, r_up, r_on = at_times(rear.lower, rear.upper, rear.hit)
    ahead = r_on & (s_dp >= r_up)
    lower = jnp.maximum(lower, jnp.max(jnp.where(ahead, r_up, -INF), 0, initial=-INF))
    return lower, upper


def smooth_plan(
    plan: SpeedPlan,
    v0,
    a0,
    config: SpeedConfig,
    w: SmoothWeights = SmoothWeights(),
    solver: LadderSettings = LadderSettings(),
) -> SpeedProfile:
    """The executed profile of one scene's DP plan (``SpeedProfile`` at ``k qp_dt``)."""
    h = config.qp_dt
    n = int(round(config.horizon / h))
    f = plan.s.dtype
    t = jnp.arange(n + 1, dtype=f) * h
    v0 = jnp.maximum(jnp.asarray(v0, f), 0.0)
    a0 = leavable_a0(a0, v0, config)
    s_ref, v_ref, a_ref = profile_at(plan, t[1:])
    lower, upper = corridor(plan, config, t[1:])
    vl = plan.scene.v_limit
    stretch = math.sqrt(max((EMERGENCY_LAT_ACCEL - LAT_TRACKING_MARGIN) / config.a_lat_max, 1.0))

    def limits(lo, hi):
        # ``(2, n)``: from the least speed limit over the stations ``[lo, hi] (n,)`` (where the car
        # may be at each time), the QP's limit (where the DP runs above that limit, as it weighed
        # it against a vehicle behind, the DP's speed) and its cap (the limit stretched as the
        # emergency lateral acceleration allows)
        def at(x):
            qi = jnp.clip(x / config.ds, 0.0, vl.shape[0] - 1.0)
            k = jnp.clip(jnp.floor(qi).astype(jnp.int32), 0, vl.shape[0] - 2)
            return vl[k] + (qi - k) * (vl[k + 1] - vl[k])

        grid = jnp.arange(vl.shape[0], dtype=f) * config.ds
        inside = (grid >= lo[:, None]) & (grid <= hi[:, None])
        lim = jnp.minimum(jnp.minimum(at(lo), at(hi)), jnp.min(jnp.where(inside, vl, INF), -1))
        return jnp.stack([jnp.maximum(lim, jnp.minimum(v_ref, stretch * lim)), stretch * lim])

    m = qp_matrices(n, h, w)
    Va, Vy, Sa, Sy = (jnp.asarray(m[k], f) for k in ("Va", "Vy", "Sa", "Sy"))
    y = jnp.stack([a0, v0])

    def solve(lim, warm):
        q, l, u, slack = qp_problem(s_ref, v_ref, lower, upper, lim[0], a0, v0, config, w, lim[1])
        # the QP, and the QP without the corridor's lower sides (its last n rows), as one
        # vmapped solve: the second where the first's iterate does not keep its bounds (no
        # profile keeps them) and the second is solved
        both = jnp.stack([l, l.at[3 * n :].set(-INF)])
        xs, rps, rds = jax.vmap(lambda lo: admm_prefactored(m["fixed"], q, lo, u, solver, warm))(both)
        solved = (rps < solver.eps_prim) & (rds < solver.eps_dual) & jnp.all(jnp.isfinite(xs), axis=-1)
        i = jnp.where((rps[0] >= solver.eps_prim) & solved[1], 1, 0)
        return xs[i], rps[i], rds[i], solved[i], slack

    def rounds(r, carry):
        # the limit is also taken where the last solution is: the executed profile lags the DP
        # where it cannot follow it (the jerk limit, braking when the cycle starts), and a bend
        # the DP has passed at that time is still ahead of the car
        lim, x, *_ = carry
        good = jnp.all(jnp.isfinite(x))
        s_last = jnp.where(good, Sa @ jnp.clip(x, config.a_brake, config.a_max) + Sy @ y, s_ref)
        lo, hi = jnp.minimum(s_last, s_ref), jnp.maximum(s_last, s_ref)
        lim = jnp.where(r > 0, jnp.minimum(lim, limits(lo, hi)), lim)
        return (lim, *solve(lim, a_ref))

    zero = jnp.zeros((), f)
    init = (limits(s_ref, s_ref), a_ref, zero, zero, jnp.asarray(False), zero)
    _, x, rp, rd, ok, slack = jax.lax.fori_loop(0, LIMIT_ROUNDS, rounds, init)
    acc = jnp.clip(x, config.a_brake, config.a_max)
    v = Va @ acc + Vy @ y
    s = Sa @ acc + Sy @ y
    finite = jnp.all(jnp.isfinite(x))
    # the iterate, clipped to the acceleration bounds and integrated exactly, is a valid
    # profile even where the solver stopped early (held at a stop, never backwards)
    acc = jnp.where(v <= 0.0, jnp.maximum(acc, 0.0), acc)
    z = jnp.zeros((1,), f)
    qp = (
        jax.lax.cummax(jnp.concatenate([z, s])),
        jnp.concatenate([v0[None], jnp.maximum(v, 0.0)]),
        jnp.concatenate([a0[None], acc]),
    )
    s_d, v_d, a_d = profile_at(plan, t)
    s, v, a = (jnp.where(finite, p, d) for p, d in zip(qp, (s_d, v_d, a_d)))
    return SpeedProfile(t, s, v, a, jnp.diff(a) / h, ok, slack, rp, rd)


smooth_plan_jit = jax.jit(smooth_plan, static_argnames=("config", "w", "solver"))
