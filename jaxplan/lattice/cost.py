"""Cost features, weights, exact selection with escalation and its smooth (softmin) form.

Features ``(..., N, F)`` in the order of ``FEATURES``:

- ``d_lrp``: mean over the horizon of ``|l - l_target|`` (m), the distance to the
  local reference path (the target lane's centre).
- ``rho_max``: maximum ``|kappa|`` over the horizon (1/m).
- ``risk``: ``1 / max(TTC, ttc_min)`` (1/s), 0 without collision: a larger TTC
  is safer, so the risk decreases with TTC (``gamma`` weighs ``1 / TTC``, not ``TTC``).
- ``speed``: ``|v_end - v_set|`` (m/s).
- ``collision``: ``sigmoid(-min_sep / sep_eps)``, the smooth collision indicator from
  the signed separation (``min_sep`` = minimum over steps and obstacles).
- ``level_free``: escalation level times ``(1 - collision)``.

The road lattice adds (``road_features``, all linear in their weights, so ``jax.grad`` and
optax tune them like the base features):

- ``jerk_lon``: mean squared ``da/dt`` (m^2/s^6); ``jerk_lat``: mean squared ``d(v^2 kappa)/dt``;
- ``obstacle``: mean over the horizon of ``exp(-max(min_sep, 0) / obstacle_scale)``, the
  distance to obstacles (1 at contact, ``1/e`` at ``obstacle_scale`` metres);
- ``v_offset``: mean ``|v - v_set|`` over the horizon, ``v_set`` the set speed (from the
  scene's speed limit in the road planner, not the current speed);
- ``goal``: whether the car is inside the goal region's stretch of the route at some time in
  the goal's window (``goal_error``: followed past the horizon at its end speed): the seconds
  by which it arrives late or passes through before the window opens (``/
  config.goal_weight_time``) + m/s outside its speed range + metres outside its lateral range
  then (0 without a goal; capped at ``GOAL_CAP``);
- ``infeasible``: the feasibility filter's verdict; ``unsafe_end``: collision-free but the
  terminal condition fails (both as 0/1, with large weights, so that the smooth form ranks
  like the exact rule).

The exact rule (selection with escalation): if some level-0 candidate is collision-free,
take the free one of least ``lambda = alpha d_lrp + beta rho_max + delta speed``;
else the lowest escalation level with a free candidate, likewise; if every
candidate collides, the least ``lambda + gamma risk`` over all of them.

The smooth form scores ``cost = features @ weights`` and takes a softmin with a
temperature. With ``collision`` much larger than ``level`` times the number of levels, and
``level`` much larger than the spread of ``lambda``, its argmin is the exact rule's choice
as the temperature and ``sep_eps`` go to 0.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxplan.types import check_weights, pytree_dataclass

FEATURES = (
    "d_lrp",
    "rho_max",
    "risk",
    "speed",
    "collision",
    "level_free",
    "jerk_lon",
    "jerk_lat",
    "obstacle",
    "v_offset",
    "goal",
    "infeasible",
    "unsafe_end",
)
BASE_FEATURES = 6  # the first six are the base risk / comfort features (``base_features``)
# The exact selection's modes: FREE / ESCALATED (a comfortable level, every check passed),
# RISK (every candidate collides), EMERGENCY (the emergency or fallback level, every check
# passed), CONSTRAINED (collision-free, but inside a safety buffer or failing the terminal condition),
# INVALID (no candidate could be judged: NaN / inf in all of them).
FREE, ESCALATED, RISK, EMERGENCY, CONSTRAINED, INVALID = 0, 1, 2, 3, 4, 5
MODE_NAMES = ("free", "escalated", "risk", "emergency", "constrained", "invalid")
GOAL_CAP = 10.0
OBSTACLE_SCALE = 2.0


WEIGHT_FIELDS = (
    "alpha",
    "beta",
    "gamma",
    "delta",
    "collision",
    "level",
    "jerk_lon",
    "jerk_lat",
    "obstacle",
    "v_offset",
    "goal",
    "infeasible",
    "unsafe_end",
)
EXTRA_WEIGHTS = ("jerk_lon", "jerk_lat", "obstacle", "v_offset", "goal")  # enter lambda beside the base terms


@pytree_dataclass(data_fields=WEIGHT_FIELDS)
class CostWeights:
    """Cost weights (array pytree, differentiable). Each field ``(...)``, one per ``FEATURES``.

    alpha: D_toLRP; beta: rho_max; gamma: risk (1/TTC); delta: |v_end - v_set|;
    collision: smooth collision indicator; level: escalation level of free candidates;
    jerk_lon, jerk_lat: mean squared jerks; obstacle: distance to obstacles; v_offset: mean
    |v - v_set|; goal: goal arrival error; infeasible, unsafe_end: the smooth form's
    penalties for the feasibility filter and the terminal condition.
    """

    alpha: Any = 1.0
    beta: Any = 10.0
    gamma: Any = 10.0
    delta: Any = 0.1
    collision: Any = 1e4
    level: Any = 1e3
    jerk_lon: Any = 0.02
    jerk_lat: Any = 0.02
    obstacle: Any = 2.0
    v_offset: Any = 0.2
    goal: Any = 3.0
    infeasible: Any = 1e6
    unsafe_end: Any = 5e3

    def validate(self) -> CostWeights:
        """Host-side: every weight finite and >= 0 (a ``ValueError`` names the field)."""
        check_weights(self)
        return self

    def vector(self):
        """``(..., F)`` in the order of ``FEATURES``."""
        f = jnp.result_type(float)
        return jnp.stack(jnp.broadcast_arrays(*(jnp.asarray(getattr(self, k), f) for k in WEIGHT_FIELDS)), -1)


def cost_features(l, kappa, l_target, ttc, v_end, v_set, min_sep, level, ttc_min=0.1, sep_eps=0.05):
    """Per-candidate features ``(..., N, F)``.

    Args:
        l, kappa: ``(..., N, T)`` lateral offset and curvature.
        l_target: ``(...)`` offset of the local reference path.
        ttc: ``(..., N)`` time to collision (inf = none).
        v_end: ``(..., N)``; v_set: ``(...)``.
        min_sep: ``(..., N, T)`` minimum signed separation to the obstacles.
        level: ``(..., N)`` escalation level.
    """
    d_lrp = jnp.mean(jnp.abs(l - jnp.asarray(l_target)[..., None, None]), axis=-1)
    rho = jnp.max(jnp.abs(kappa), axis=-1)
    return base_features(d_lrp, rho, ttc, v_end, v_set, jnp.min(min_sep, axis=-1), level, ttc_min, sep_eps)


def base_features(d_lrp, rho, ttc, v_end, v_set, sep_min, level, ttc_min=0.1, sep_eps=0.05):
    """``cost_features`` from per-candidate reductions ``(..., N)``: ``d_lrp`` (mean ``|l -
    l_target|``), ``rho`` (max ``|kappa|``) and ``sep_min`` (least separation over the horizon)."""
    risk = jnp.where(jnp.isfinite(ttc), 1.0 / jnp.maximum(ttc, ttc_min), 0.0)
    speed = jnp.abs(v_end - jnp.asarray(v_set)[..., None])
    coll = jax.nn.sigmoid(-sep_min / sep_eps)
    lvl = level.astype(d_lrp.dtype) * (1.0 - coll)
    return jnp.stack([d_lrp, rho, risk, speed, coll, lvl], axis=-1)


def costs(weights: CostWeights, features):
    """Linear cost ``(..., N)`` of features ``(..., N, F)`` (the first ``F`` weights)."""
    return jnp.einsum("...nf,...f->...n", features, weights.vector()[..., : features.shape[-1]])


def lam(weights: CostWeights, features, speed: bool = True):
    """The comfort cost ``lambda = alpha D_toLRP + beta rho_max (+ delta speed)``, ``(..., N)``, plus the
    road terms (``EXTRA_WEIGHTS``) where ``features`` has them (weights without those
    attributes count them 0). ``speed=False`` drops both speed terms (``delta``, ``v_offset``)."""
    out = weights.alpha * features[..., 0] + weights.beta * features[..., 1]
    if speed:
        out = out + weights.delta * features[..., 3]
    if features.shape[-1] > BASE_FEATURES:
        for name in EXTRA_WEIGHTS:
            if name == "v_offset" and not speed:
                continue
            out = out + getattr(weights, name, 0.0) * features[..., FEATURES.index(name)]
    return out


def eligible(collided, level):
    """The candidates the exact rule chooses among.

    Args:
        collided: ``(..., N)`` bool; level: ``(..., N)`` int escalation level.

    Returns:
        (eligible ``(..., N)``: the free candidates of the lowest level that has one, or every
        candidate when all collide; any_free ``(...)``; first free level ``(...)``).
    """
    free = ~collided
    big = jnp.iinfo(jnp.int32).max
    first_level = jnp.min(jnp.where(free, level, big), axis=-1)  # (...)
    any_free = first_level < big
    ok = jnp.where(any_free[..., None], free & (level == first_level[..., None]), True)
    return ok, any_free, first_level


def rule_cost(weights, features, collided):
    """The exact rule's cost ``(..., N)``: ``lambda``, plus ``gamma * risk`` when every
    candidate collides. ``weights`` needs ``alpha, beta, gamma, delta`` attributes."""
    all_collide = jnp.all(collided, axis=-1, keepdims=True)
    return lam(weights, features) + jnp.where(all_collide, weights.gamma * features[..., 2], 0.0)


def select(weights: CostWeights, features, collided, level, valid=None):
    """Exact selection (see the module docstring).

    Args:
        features: ``(..., N, F)``; collided: ``(..., N)`` bool; level: ``(..., N)`` int.
        valid: ``(..., N)`` bool or None: candidates that can be judged (finite trajectory,
            separation and features). The others count as colliding and are never chosen;
            when no candidate is valid the mode is ``INVALID``.

    Returns:
        (index ``(...)`` int, mode ``(...)`` in {FREE, ESCALATED, RISK, INVALID}, selection
        cost ``(..., N)`` with ``inf`` for candidates the rule excluded).
    """
    if valid is not None:
        collided = collided | ~valid
    ok, any_free, first_level = eligible(collided, level)
    if valid is not None:
        ok = ok & valid
    c = jnp.where(ok, rule_cost(weights, features, collided), jnp.inf)
    idx = jnp.argmin(c, axis=-1)
    mode = jnp.where(any_free, jnp.where(first_level == 0, FREE, ESCALATED), RISK)
    if valid is not None:
        mode = jnp.where(jnp.any(valid, axis=-1), mode, INVALID)
    return idx, mode, c


def soft_select(weights: CostWeights, features, temperature):
    """Smooth selection: softmin of ``costs(weights, features)`` with a temperature.

    Returns:
        ``(..., N)`` probabilities (differentiable in the weights and the features).
    """
    return jax.nn.softmax(-costs(weights, features) / temperature, axis=-1)


def soft_choice(selection_cost, chosen, temperature: float):
    """``(..., N)`` weights of a smooth selection: the softmin of the exact rule's selection cost
    (``choose``; inf for the candidates it excluded, which get weight 0) at ``temperature`` (cost
    units, > 0). As the temperature goes to 0 it tends to the one-hot of the exact choice; where
    the rule excluded every candidate it is the one-hot of ``chosen (...)``. Differentiable in
    the weights through the finite costs."""
    finite = jnp.isfinite(selection_cost)
    c = jnp.where(finite, selection_cost, 0.0)
    m = jnp.min(jnp.where(finite, c, jnp.inf), axis=-1, keepdims=True)
    z = jnp.where(finite, -(c - jax.lax.stop_gradient(jnp.where(jnp.isfinite(m), m, 0.0))) / temperature, -jnp.inf)
    p = jax.nn.softmax(jnp.where(jnp.any(finite, axis=-1, keepdims=True), z, 0.0), axis=-1)
    one = jax.nn.one_hot(chosen, selection_cost.shape[-1], dtype=p.dtype)
    return jnp.where(jnp.any(finite, axis=-1, keepdims=True), p, one)


def road_features(base, traj, dt, min_sep, v_set, goal_err, feasible, terminal_ok, collided):
    """The base features ``base (..., N, 6)`` (``base_features``) followed by the road terms (module docstring).

    Args:
        traj: ``Trajectory`` ``(..., N, T)``; dt: step (s); min_sep: ``(..., N, T)``.
        v_set: ``(...)``; goal_err: ``(..., N)``; feasible, terminal_ok, collided: ``(..., N)`` bool.

    Returns:
        ``(..., N, len(FEATURES))``.
    """
    return road_features_from(
        base, motion_terms(traj, dt, v_set), obstacle_term(min_sep), goal_err, feasible, terminal_ok, collided
    )


def motion_terms(traj, dt, v_set):
    """``(..., N, 3)``: the road features ``jerk_lon``, ``jerk_lat`` and ``v_offset`` of
    trajectories ``(..., N, T)`` (``v_set (...)``)."""
    f = traj.v.dtype
    jl = jnp.mean((jnp.diff(traj.a, axis=-1) / dt) ** 2, axis=-1)
    lat = traj.v**2 * traj.kappa
    jt = jnp.mean((jnp.diff(lat, axis=-1) / dt) ** 2, axis=-1)
    voff = jnp.mean(jnp.abs(traj.v - jnp.asarray(v_set, f)[..., None, None]), axis=-1)
    return jnp.stack([jl, jt, voff], axis=-1)


def obstacle_term(min_sep):
    """``(..., N)``: the road feature ``obstacle`` from the separations ``(..., N, T)``."""
    return jnp.mean(jnp.exp(-jnp.maximum(min_sep, 0.0) / OBSTACLE_SCALE), axis=-1)


def road_features_from(base, motion, obstacle, goal_err, feasible, terminal_ok, collided):
    """``road_features`` from ``motion_terms (..., N, 3)`` and ``obstacle_term (..., N)``."""
    f = base.dtype
    extra = jnp.stack(
        [
            motion[..., 0],
            motion[..., 1],
            obstacle,
            motion[..., 2],
            goal_err.astype(f),
            (~feasible).astype(f),
            ((~terminal_ok) & ~collided).astype(f),
        ],
        axis=-1,
    )
    return jnp.concatenate([base, extra], axis=-1)


GOAL_INSIDE = 0.5  # m: the box centre counts as in the goal region this far inside its ends
GOAL_OVERLAP = 0.5  # s: how long a plan should be in the goal region inside its window
GOAL_INSIDE_L = 0.3  # m: the box centre aims this far inside the goal region's lateral range


def goal_error(s, l, v, t, goal_s, goal_l, goal_t, goal_v, center_offset, time_weight=1.0):
    """The goal error ``(..., N)`` of candidates (see the module docstring): whether the car's box
    centre is inside the goal region's stretch of the route at some time inside the goal's window,
    with its speed and offset in their ranges then.

    Each candidate is followed past its horizon at its end speed: it enters the stretch (its near
    end, ``GOAL_INSIDE`` m in) at ``t_in`` and leaves it (the far end) at ``t_out``. The error is the
    seconds by which ``[t_in, t_out]`` misses the window (late: ``t_in`` after its end; through
    before it opens: ``t_out`` before its start), divided by ``time_weight``, plus the m/s outside the
    speed range and the metres outside the lateral range when it is first inside in the window.
    The stay should overlap the window by ``GOAL_OVERLAP`` s (at most half the window, and half the stay
    itself: a short region passed at speed asks only that the middle of the pass be inside): the seconds
    it falls short of that are the time error (late arrivals and passes before the window alike).
    Likewise the speed aims a tenth of its range (at most 1 m/s) and the offset ``GOAL_INSIDE_L`` m
    inside their ranges (at most half of each).

    Args:
        s, l, v: ``(..., N, T)`` arc length on the line, offset and speed of the reference point.
        t: ``(T,)``; goal_s, goal_l, goal_t (from now), goal_v: ``(..., 2)``.
        center_offset: reference point to box centre (m): the goal is judged at the box centre.
    """
    f = s.dtype
    gs = jnp.asarray(goal_s, f)
    has = jnp.all(jnp.isfinite(gs), axis=-1)
    lo0 = jnp.where(has, gs[..., 0], 0.0)
    hi0 = jnp.where(has, gs[..., 1], 0.0)
    inside = jnp.minimum(GOAL_INSIDE, 0.5 * (hi0 - lo0))
    lo = (lo0 + inside - center_offset)[..., None]  # (..., 1): reference point positions
    hi = (hi0 - inside - center_offset)[..., None]
    s_end, v_end = s[..., -1], v[..., -1]
    slow = jnp.maximum(v_end, 1e-3)
    entered = s >= lo[..., None]
    k_in = jnp.argmax(entered, axis=-1)
    t_in = jnp.where(jnp.any(entered, axis=-1), t[k_in], t[-1] + jnp.maximum(lo - s_end, 0.0) / slow)
    left = s > hi[..., None]
    t_out = jnp.where(jnp.any(left, axis=-1), t[jnp.argmax(left, axis=-1)], t[-1] + jnp.maximum(hi - s_end, 0.0) / slow)
    gt, gv, gl = (jnp.asarray(x, f) for x in (goal_t, goal_v, goal_l))
    t0, t1 = gt[..., 0, None], gt[..., 1, None]
    # the stay should overlap the window by GOAL_OVERLAP s (half the window when it is shorter): a
    # plan that only grazes it is missed by the next re-plan's small deviations
    want = jnp.minimum(
        jnp.minimum(GOAL_OVERLAP, 0.5 * jnp.maximum(t1 - t0, 0.0)),
        0.5 * jnp.maximum(jnp.minimum(t_out, 1e3) - jnp.minimum(t_in, 1e3), 0.0),
    )
    terr = jnp.maximum(want - (jnp.minimum(t_out, t1) - jnp.maximum(t_in, t0)), 0.0)
    terr = jnp.where(jnp.isfinite(t1), terr, jnp.maximum(t_in - 1e3, 0.0) + jnp.maximum(t0 - t_out, 0.0))
    # the state when it is first inside in the window (past the horizon: its end state)
    tau = jnp.maximum(t_in, t0)
    k = jnp.clip(jnp.searchsorted(t, tau), 0, t.shape[0] - 1)
    beyond = tau > t[-1]
    at = lambda a: jnp.take_along_axis(a, k[..., None], axis=-1)[..., 0]  # noqa: E731
    v_at = jnp.where(beyond, v_end, at(v))
    l_at = jnp.where(beyond, l[..., -1], at(l))

    def out(x, rng, margin):  # outside the range shrunk by ``margin`` (at most half of it) on both sides
        lo_, hi_ = rng[..., 0, None], rng[..., 1, None]
        m = jnp.minimum(margin, 0.5 * jnp.where(jnp.isfinite(hi_ - lo_), hi_ - lo_, 0.0))
        return jnp.maximum(lo_ + m - x, 0.0) + jnp.maximum(x - (hi_ - m), 0.0)

    # a tenth of the speed range (at most 1 m/s) and GOAL_INSIDE_L metres inside: not on the edges,
    # which the next plans' small deviations cross
    span_v = jnp.where(jnp.isfinite(gv[..., 1] - gv[..., 0]), gv[..., 1] - gv[..., 0], 0.0)[..., None]
    err = (
        jnp.minimum(terr, 1e3) / time_weight
        + out(v_at, gv, jnp.minimum(0.1 * span_v, 1.0))
        + out(l_at, gl, GOAL_INSIDE_L)
    )
    return jnp.where(has[..., None], jnp.minimum(err, GOAL_CAP), 0.0)


def choose(
    weights,
    features,
    level,
    available,
    feasible,
    free_margin,
    free,
    terminal_ok,
    impact,
    first_t,
    risk_cost=None,
    n_comfort: int = 1,
    rule: str = "harm",
    emergency_ok=None,
    on_road=None,
):
    """The road lattice's exact selection.

    Among the available candidates, the feasible ones if any (else all): the candidates that
    are free of the inflated obstacles and pass the terminal condition; if none, those free
    of the inflated obstacles; if none, those free of the plain obstacles and on the road
    (``on_road``); if none, those free of the plain obstacles. When every one of
    them collides with a plain obstacle, the candidates within the emergency limits
    (``emergency_ok``, any level) that do not are taken instead, in the same groups: a
    collision is avoided at the emergency limits before a comfortable plan is taken into it.
    In the first non-empty group: the lowest level that has one, then the least ``lambda``. If
    every candidate collides: ``rule="harm"`` takes the least impact speed at first contact,
    then the latest first contact, then the least ``lambda`` without the speed terms;
    ``rule="risk"`` the least ``lambda + gamma * risk`` (``risk_cost``).

    Args:
        features: ``(..., N, F)``; level: ``(..., N)`` int; available, feasible, free_margin,
        free, terminal_ok: ``(..., N)`` bool; impact, first_t: ``(..., N)``.
        n_comfort: the number of comfortable levels (the rest are emergency / fallback).
        emergency_ok: ``(..., N)`` bool or None: candidates within the emergency limits (and on the
            road) that may replace a pool whose every candidate collides.
        on_road: ``(..., N)`` bool or None (every candidate): the candidate stays on the road (or,
            where none does, leaves it least: ``plan.least_off_road``).

    Returns:
        (index ``(...)``, mode ``(...)`` (``FREE``, ``ESCALATED``, ``EMERGENCY``, ``CONSTRAINED``,
        ``RISK``), selection cost ``(..., N)`` with inf for the candidates the rule excluded).
    """
    big = jnp.iinfo(jnp.int32).max
    pool = available & jnp.where(jnp.any(available & feasible, axis=-1, keepdims=True), feasible, True)
    swap = jnp.zeros(pool.shape[:-1] + (1,), bool)
    if emergency_ok is not None:
        rescue = emergency_ok & available & free
        swap = ~jnp.any(pool & free, axis=-1, keepdims=True) & jnp.any(rescue, axis=-1, keepdims=True)
        pool = jnp.where(swap, rescue, pool)
    road = True if on_road is None else on_road
    groups = [pool & free_margin & terminal_ok, pool & free_margin, pool & free & road, pool & free]
    lam_c = lam(weights, features)
    chosen_set = jnp.zeros_like(pool)
    found = jnp.zeros(pool.shape[:-1], bool)
    tier = jnp.full(pool.shape[:-1], len(groups))
    for i, g in enumerate(groups):
        lvl = jnp.min(jnp.where(g, level, big), axis=-1, keepdims=True)
        here = g & (level == lvl) & ~found[..., None]
        take = jnp.any(g, axis=-1) & ~found
        chosen_set = jnp.where(take[..., None], here, chosen_set)
        tier = jnp.where(take, i, tier)
        found = found | take
    sel_free = jnp.where(chosen_set, lam_c, jnp.inf)
    if rule == "risk":
        rc = lam_c + (0.0 if risk_cost is None else risk_cost)
        sel_risk = jnp.where(pool, rc, jnp.inf)
    else:
        imp = jnp.where(pool, impact, jnp.inf)
        m = jnp.min(imp, axis=-1, keepdims=True)
        c1 = pool & (imp <= m + 1e-3)
        ft = jnp.where(c1, first_t, -jnp.inf)
        late = jnp.max(ft, axis=-1, keepdims=True)
        c2 = c1 & (ft >= late - 1e-6)
        sel_risk = jnp.where(c2, lam(weights, features, speed=False), jnp.inf)
    sel = jnp.where(found[..., None], sel_free, sel_risk)
    idx = jnp.argmin(sel, axis=-1)
    lvl = jnp.take_along_axis(level, idx[..., None], axis=-1)[..., 0]
    mode = jnp.where(
        ~found,
        RISK,
        jnp.where(tier > 0, CONSTRAINED, jnp.where(lvl == 0, FREE, jnp.where(lvl < n_comfort, ESCALATED, EMERGENCY))),
    )
    mode = jnp.where(found & swap[..., 0], EMERGENCY, mode)  # taken at the emergency limits
    return idx, mode, sel
