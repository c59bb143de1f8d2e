"""One jitted lattice plan: candidates, collision risk, features, costs, exact and smooth choice."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.compile_options import NO_YNN, jit
from jaxplan.geometry.boxes import car_reach
from jaxplan.geometry.frenet import ReferenceLine, to_frenet, wrap_angle
from jaxplan.lattice.candidates import Candidates, candidate_trajectory, generate_from
from jaxplan.lattice.config import LatticeConfig
from jaxplan.lattice.cost import (
    INVALID,
    CostWeights,
    base_features,
    choose,
    costs,
    goal_error,
    motion_terms,
    obstacle_term,
    road_features_from,
    soft_choice,
)
from jaxplan.lattice.crossroad import with_stop_target
from jaxplan.lattice.feasibility import feasibility, usable, violation
from jaxplan.lattice.parts import lattice_parts, stations_finite
from jaxplan.lattice.risk import (
    BIG,
    Risk,
    align_obstacles,
    car_parts,
    first_contact,
    inflate,
    min_separation_axes,
    min_separation_broad,
    min_separation_pair,
    min_separation_topk,
    risk_from_separation,
)
from jaxplan.lattice.state import PlanState
from jaxplan.lattice.targets import RoadTargets, extents, lane_leader, obstacle_frenet, speed_along
from jaxplan.plan_context import goal_region_ahead
from jaxplan.types import Obstacles, is_concrete, pytree_dataclass


@pytree_dataclass(
    data_fields=(
        "candidates",
        "features",
        "cost",
        "selection_cost",
        "collided",
        "first_t",
        "ttc",
        "min_sep",
        "chosen",
        "mode",
        "obstacles",
        "finite",
        "ok",
        "feasible",
        "reasons",
        "collided_margin",
        "terminal_ok",
        "impact",
        "l_target",
        "off_road",
        "trajectory",
    )
)
class LatticeResult:
    """Everything one plan computed (``N`` candidates, ``T`` steps, any leading batch dims).

    Attributes:
        candidates: ``Candidates`` (trajectories ``(..., N, T)``: x, y, theta, kappa, v, a, t, s).
        features: ``(..., N, F)`` (see ``cost.FEATURES``).
        cost: ``(..., N)`` linear cost ``features @ weights`` (the smooth form's score).
        selection_cost: ``(..., N)`` the exact rule's cost (inf = excluded).
        collided: ``(..., N)``: the candidate hits a (plain) obstacle, or cannot be judged (not
            ``finite``: a NaN is never reported as free). first_t, ttc: ``(..., N)``;
            min_sep: ``(..., N, T)``.
        chosen: ``(...)`` index of the chosen candidate; mode: ``cost.FREE`` ... ``CONSTRAINED``,
            or ``cost.INVALID`` when no candidate is finite.
        obstacles: the obstacles checked (read at the candidates' times, virtual stop box last).
        finite: ``(..., N)`` the candidate's trajectory, separations and features hold no
            NaN / inf (only those are chosen).
        ok: ``(...)`` the chosen trajectory is finite: False means the plan must not be used
            (for example a reference line with repeated points built inside jit).
        feasible: ``(..., N)``; reasons: ``(..., N, R)`` why infeasible (``feasibility.REASONS``).
        collided_margin: ``(..., N)`` overlap with the obstacles inflated by the buffers.
        terminal_ok: ``(..., N)`` the end state can stop behind what is ahead (True when off).
        impact: ``(..., N)`` relative speed at first contact (m/s; 0 without contact).
        l_target: ``(...)`` the target lane's centre the lane decision took (m).
        off_road: ``(..., N)`` the candidate's box leaves the road (``RoadTargets.road_edges``, or
            its front passes ``RoadTargets.stop_s`` without a goal region ahead;
            counted in ``collided_margin``: taken only when nothing on the road is free).
        trajectory: the chosen candidate's ``Trajectory`` ``(..., T)``, built on its own
            (``candidates.candidate_trajectory``), so that a caller who keeps only it (and the
            per-candidate figures) never has every candidate's trajectory written out.
    """

    candidates: Any
    features: Any
    cost: Any
    selection_cost: Any
    collided: Any
    first_t: Any
    ttc: Any
    min_sep: Any
    chosen: Any
    mode: Any
    obstacles: Any
    finite: Any
    ok: Any
    feasible: Any = None
    reasons: Any = None
    collided_margin: Any = None
    terminal_ok: Any = None
    impact: Any = None
    l_target: Any = None
    off_road: Any = None
    trajectory: Any = None

    def chosen_trajectory(self):
        """The chosen ``Trajectory`` ``(..., T)``."""
        if self.trajectory is not None:
            return self.trajectory
        i = self.chosen[..., None, None]
        return jax.tree_util.tree_map(lambda f: jnp.take_along_axis(f, i, axis=-2)[..., 0, :], self.candidates.traj)

    def rejected(self) -> dict:
        """Host side: how many available candidates the feasibility filter rejected, and why
        (one candidate may fail several checks), summed over any batch dims."""
        from jaxplan.lattice.feasibility import REASONS

        avail = np.asarray(self.candidates.available)
        r = np.asarray(self.reasons) & avail[..., None]
        out = {"rejected": int(np.sum(~np.asarray(self.feasible) & avail)), "available": int(avail.sum())}
        out.update({k: int(r[..., i].sum()) for i, k in enumerate(REASONS)})
        return out


def _stop_distance(config, s_car, d_crossroad, stop_s, leader_rear, stopped, front):
    """Distance from the car's reference point to its stop point (inf: none): ``stop_gap`` before
    the stopped obstacle's inflated box (so that the stopped end state passes the terminal
    condition with ``terminal_gap <= stop_gap``)."""
    d = jnp.where(stopped, leader_rear[0] - config.stop_gap - config.buffer_lon, jnp.inf)
    d_c = jnp.asarray(d_crossroad, s_car.dtype)
    d = jnp.minimum(d, jnp.where(d_c < config.d_threshold, d_c + config.d_margin - front - 0.5, jnp.inf))
    return jnp.minimum(d, jnp.asarray(stop_s, s_car.dtype) - s_car - front)


def _kinematics(cand: Candidates, ref, targets, config, v_set, t, stations_ok):
    """Per-candidate reductions ``(N, ...)`` of the candidates' samples: the feasibility filter, the
    kinematic features, the goal error, the road-edge check, finiteness and the end state (one
    pass over the fields they read; nothing else of the trajectories is needed for the choice).

    Args:
        stations_ok: ``(N,)`` the candidate's profile has finite points on the line
            (``parts.stations_finite``).

    Returns:
        dict of ``(N, ...)`` arrays.
    """
    tr = cand.traj
    f = tr.x.dtype
    feasible, reasons = feasibility(tr, cand.level, config)
    # within the emergency limits whatever the level: what the choice may take to avoid a collision
    # that every comfortable candidate has
    emergency_ok, _ = feasibility(tr, jnp.full_like(cand.level, len(config.escalation)), config)
    centres = targets.lane_centres.astype(f)
    # NaN / inf anywhere makes the sum non-finite. The positions, the heading and the arc length are
    # finite where l and the profile's points on the line are (x = x_r - l sin(theta_r), ...), so
    # they are not summed: with few obstacles nothing else reads x and y, which are then never
    # written out (about 5 % of a kinematic plan at N = 994)
    total = jnp.sum(cand.l + tr.kappa + tr.v + tr.a, axis=-1)
    veh = config.vehicle
    out = dict(
        feasible=feasible,
        reasons=reasons,
        emergency_ok=emergency_ok,
        viol=violation(tr, cand.level, config),
        rho=jnp.max(jnp.abs(tr.kappa), axis=-1),
        d_lane=jnp.mean(jnp.abs(cand.l[..., None] - centres), axis=-2),  # (N, Ln): d_lrp to each lane
        motion=motion_terms(tr, config.dt, v_set),
        goal=goal_error(
            cand.s,
            cand.l,
            tr.v,
            t,
            targets.goal_s,
            targets.goal_l,
            targets.goal_t,
            targets.goal_v,
            jnp.asarray(veh.center_offset, f),
            config.goal_weight_time,
        ),
        finite=jnp.isfinite(total) & stations_ok,
        s_end=cand.s[:, -1],
        l_end=cand.l[:, -1],
        v_last=tr.v[:, -1],
        s_rel_end=cand.s_rel[:, -1],
    )
    if targets.road_edges is not None:  # coming closer to a road edge than edge_margin, or leaving the road,
        # counts as touching an obstacle's buffer
        cl, cr = edge_clearance(ref, cand, targets.road_edges, veh)
        out["off_road"] = past_edge(cl, cr)
        out["near_edge"] = in_edge_margin(cl, cr, config.edge_margin)
        out["edge_excess"] = jnp.maximum(-jnp.min(jnp.minimum(cl, cr), axis=-1), 0.0)  # (N,) m past an edge
    else:
        out["off_road"] = out["near_edge"] = jnp.zeros(feasible.shape, bool)
        out["edge_excess"] = jnp.zeros(feasible.shape, f)
    # so does driving on past the stop point (a dead end of the road: beyond it is no road) unless a goal
    # region lies ahead (the drive ends there; the map often ends just past it)
    goal_ahead = goal_region_ahead(jnp.asarray(targets.goal_s, f), cand.s[0, 0] + jnp.asarray(veh.center_offset, f))
    past = jnp.max(cand.s, axis=-1) + jnp.asarray(veh.front_offset, f) > jnp.asarray(targets.stop_s, f) + 0.1
    out["off_road"] = out["off_road"] | (past & ~goal_ahead)
    out["near_edge"] = out["near_edge"] | out["off_road"]
    return out


def plan_unchecked(
    state: PlanState,
    ref: ReferenceLine,
    obstacles: Obstacles,
    config: LatticeConfig,
    weights: CostWeights,
    targets: RoadTargets | None = None,
    keep_candidates: bool = True,
) -> LatticeResult:
    """``plan`` without its host-side checks and not jitted (for a caller's own transformation:
    ``jax.grad``, ``jax.vmap``, ``jax.jit``); the arguments are ``plan``'s."""
    f = ref.xy.dtype
    if targets is None:
        targets = RoadTargets.from_config(config, f)
    veh = config.vehicle
    T = config.n_steps
    t = jnp.arange(T, dtype=f) * config.dt
    obs = align_obstacles(obstacles, t)
    sl = targets.obstacle_sl  # given: on the planner's grid (step k at k * dt), as road_context windows it
    sl = obstacle_frenet(ref, obs) if sl is None else jnp.asarray(sl, f)[..., :T, :]
    s_car, l_car = to_frenet(ref, jnp.stack([state.x, state.y]).astype(f))
    front = jnp.asarray(veh.front_offset, f)
    half_w = 0.5 * jnp.asarray(veh.width, f)
    K = obs.boxes.shape[-3]
    if K:
        ext = extents(ref, obs.boxes, sl[..., 0])
        v_along = speed_along(sl, obs.valid, config.dt)
        _, rear, lead_v, found, stopped = lane_leader(s_car, l_car, half_w, front, sl, ext, obs.valid, v_along)
    else:
        ext = jnp.zeros(sl.shape, f)
        v_along = jnp.zeros(sl.shape[:-1], f)
        rear, lead_v, found, stopped = jnp.zeros_like(t), jnp.zeros_like(t), jnp.asarray(False), jnp.asarray(False)
    d_stop = _stop_distance(config, s_car, state.d_crossroad, targets.stop_s, rear, stopped, front)
    parts = lattice_parts(state, ref, config, targets, (rear, lead_v, found), d_stop, (s_car, l_car))
    cand = generate_from(parts, config)
    kin = _kinematics(cand, ref, targets, config, state.v_set, t, stations_finite(parts))
    # every obstacle counts, those behind the car too: one closing in faster than the car is
    # avoided as any other (speeding up, changing lane), not left to run into it
    obs = with_stop_target(obs, ref, parts.s0 + parts.profiles[0][0, 0], state.d_crossroad, config)
    if K:
        hits = _collisions(cand, obs, t, config)
    else:  # only the virtual stop box, valid before a crossroad: checked only then, on candidates generated
        # again inside the branch (so that without it no candidate's trajectory is written out)
        hits = jax.lax.cond(
            jnp.any(obs.valid),
            lambda: _collisions(generate_from(parts, config), obs, t, config),
            lambda: _no_collisions(cand.level.shape[0], T, f),
        )
    sep, risk, collided_m = hits["sep"], hits["risk"], hits["collided_margin"] | kin["near_edge"]
    first_t, impact = hits["first_t"], hits["impact"]
    off_road = kin["off_road"]
    feasible, reasons = kin["feasible"], kin["reasons"]
    if config.terminal and K:
        terminal_ok = _terminal(
            ref, kin["s_end"], kin["l_end"], kin["v_last"], obs, sl, ext, v_along, front, half_w, config
        )
    else:
        terminal_ok = jnp.ones(risk.collided.shape, bool)
    route = jnp.asarray(targets.route_lane)
    base = base_features(
        kin["d_lane"][:, route],
        kin["rho"],
        risk.ttc,
        cand.v_end,
        state.v_set,
        hits["sep_min"],
        cand.level,
        config.ttc_min,
        config.sep_eps,
    )
    feats = road_features_from(base, kin["motion"], hits["obstacle"], kin["goal"], feasible, terminal_ok, risk.collided)
    # a candidate with a NaN / inf in its trajectory, separations or features is never chosen
    finite = kin["finite"] & hits["sep_finite"] & jnp.all(jnp.isfinite(feats), axis=-1)
    avail = cand.available & finite
    use = usable(feasible, reasons, kin["viol"], avail)  # feasible, else the least infeasible
    pool = avail & use
    ok = pool & ~collided_m & terminal_ok
    l_target, lane = _lane_decision(cand, kin["s_rel_end"], targets, ok, l_car, config)
    feats = feats.at[:, 0].set(kin["d_lane"][:, lane])
    n_comfort = len(config.escalation)
    risk_cost = weights.gamma * feats[:, 2]
    on_road = least_off_road(off_road, kin["edge_excess"], pool & ~risk.collided)
    idx, mode, sel = choose(
        weights,
        feats,
        cand.level,
        avail,
        use,
        ~collided_m,
        ~risk.collided,
        terminal_ok,
        impact,
        first_t,
        risk_cost,
        n_comfort,
        config.all_collide,
        avail & kin["emergency_ok"] & ~off_road,
        on_road,
    )
    mode = jnp.where(jnp.any(avail), mode, INVALID)
    ok_plan = jnp.take(finite, idx)
    chosen_traj = candidate_trajectory(parts, idx)
    if config.select_temperature > 0:  # the smooth selection: the softmin-weighted mean candidate
        w_soft = soft_choice(sel, idx, config.select_temperature)
        use_w = (w_soft > 0)[:, None]
        mean = lambda a: jnp.sum(jnp.where(use_w, w_soft[:, None] * a, 0.0), axis=0)  # noqa: E731
        # headings averaged about the exact choice's (no wrap at +-pi)
        theta = chosen_traj.theta + mean(wrap_angle(cand.traj.theta - chosen_traj.theta))
        chosen_traj = dataclasses.replace(
            chosen_traj,
            x=mean(cand.traj.x),
            y=mean(cand.traj.y),
            theta=theta,
            kappa=mean(cand.traj.kappa),
            v=mean(cand.traj.v),
            a=mean(cand.traj.a),
            s=mean(cand.traj.s),
        )
    if not keep_candidates:  # the per-candidate figures and the choice, not every trajectory
        cand = dataclasses.replace(cand, traj=None, axis=None, s=None, l=None, dl=None, s_rel=None)
        sep = None
    return LatticeResult(
        cand,
        feats,
        costs(weights, feats),
        sel,
        risk.collided | ~finite,
        risk.first_t,
        risk.ttc,
        sep,
        idx,
        mode,
        obs,
        finite,
        ok_plan,
        feasible,
        reasons,
        collided_m,
        terminal_ok,
        impact,
        l_target,
        off_road,
        chosen_traj,
    )


def _collisions(cand: Candidates, obs: Obstacles, t, config: LatticeConfig) -> dict:
    """The candidates against the obstacles (the broad phase ``config`` asks for).

    Returns:
        dict: ``sep`` ``(N, T)`` separation to the plain boxes, ``risk`` (``Risk``), ``collided_margin``
        ``(N,)`` overlap with the inflated boxes, ``first_t``, ``impact`` (``first_contact``),
        ``sep_min`` (least separation), ``obstacle`` (``cost.obstacle_term``), ``sep_finite`` ``(N,)``.
    """
    veh = config.vehicle
    center, half = car_parts(jnp.stack([cand.traj.x, cand.traj.y], -1), cand.axis, veh)
    G, P = config.n_profiles, config.n_lateral
    buf = (config.buffer_lon, config.buffer_lat)
    if config.near_k > 0 and obs.boxes.shape[-3] > 2 * config.near_k:  # (with few obstacles the dense test is faster)
        Lw, O, Lt = config.lateral_grid
        lane_ok = cand.available.reshape(G * Lw, O * Lt).any(-1)
        sep, sep_m = min_separation_topk(center, cand.axis, half, obs, O * Lt, config.near_k, buf, lane_ok)
    elif config.near_budget > 0:
        Kb = obs.boxes.shape[-3]
        budget = max(1, int(np.ceil(config.near_budget * G * Kb * config.n_steps)))
        check = lambda o: min_separation_broad(center, cand.axis, half, o, P, budget, config.broad_margin + max(buf))
        sep = check(obs)
        sep_m = check(inflate(obs, *buf)) if max(buf) > 0 else sep
    elif max(buf) > 0:
        sep, sep_m = min_separation_pair(center, cand.axis, half, obs, buf, P)
    else:
        sep = sep_m = min_separation_axes(center, cand.axis, half, obs)
    first_t, impact = first_contact(sep, t, center, cand.axis, cand.traj.v, obs, half, config.dt)
    return dict(
        sep=sep,
        risk=risk_from_separation(sep, t),
        collided_margin=jnp.any(sep_m < 0, axis=-1),
        first_t=first_t,
        impact=impact,
        sep_min=jnp.min(sep, axis=-1),
        obstacle=obstacle_term(sep),
        sep_finite=jnp.all(jnp.isfinite(sep), axis=-1),
    )


def _no_collisions(N: int, T: int, f) -> dict:
    """``_collisions``' result without any valid obstacle (every separation ``BIG``)."""
    no = jnp.zeros((N,), bool)
    inf = jnp.full((N,), jnp.inf, f)
    return dict(
        sep=jnp.full((N, T), BIG, f),
        risk=Risk(jnp.full((N, T), BIG, f), no, inf, inf),
        collided_margin=no,
        first_t=inf,
        impact=jnp.zeros((N,), f),
        sep_min=jnp.full((N,), BIG, f),
        obstacle=obstacle_term(jnp.full((N, 1), BIG, f)),
        sep_finite=~no,
    )


ROAD_TOL = 0.1  # m: a candidate's box may reach this far past a road edge (map seams, edge sampling)
MARGIN_TOL = 0.01  # m: how much closer to an edge than the car is now a candidate inside the margin may come
LEAST_OFF_ROAD_TOL = 0.05  # m: candidates within this of the least excess past an edge count as leaving it least


def least_off_road(off_road, edge_excess, pool):
    """``(N,)``: the candidate stays on the road, or, where every candidate of ``pool`` leaves it
    (the route's corridor can be narrower than the road, e.g. in a junction), leaves it about as
    little as any does (``edge_excess`` within ``LEAST_OFF_ROAD_TOL`` of the least)."""
    least = jnp.min(jnp.where(pool, edge_excess, jnp.inf))
    return ~off_road | (edge_excess <= least + LEAST_OFF_ROAD_TOL)


def edge_clearance(ref, cand, road_edges, vehicle):
    """``(N, T)`` twice: how far (m) each sample of the candidate's box stays inside the road's left
    and right edge (negative: past it); ``road_edges (R, 2)`` at ``ref``'s points, interpolated in s.

    The body's lateral reach is ``geometry.car_reach`` at the heading relative to the line
    (``atan(dl/ds)``, the line's curvature neglected).

    Args:
        cand: ``s, l, dl`` ``(N, T)`` (``Candidates``); road_edges: ``(R, 2)``; vehicle: ``VehicleParams``.
    """
    f = cand.l.dtype
    left = jnp.interp(cand.s, ref.s, road_edges[:, 0].astype(f))
    right = jnp.interp(cand.s, ref.s, road_edges[:, 1].astype(f))
    reach_l, reach_r = car_reach(vehicle, jnp.arctan(cand.dl))
    return left - (cand.l + reach_l), (cand.l - reach_r) - right


def past_edge(cl, cr, tol=ROAD_TOL):
    """``(N,)``: some sample reaches more than ``tol`` (m) past the left or right edge, from the
    clearances ``cl, cr (N, T)`` (``edge_clearance``)."""
    return jnp.any((cl < -tol) | (cr < -tol), axis=-1)


def in_edge_margin(cl, cr, margin):
    """``(N,)``: some sample comes closer than ``margin`` (m) to the left or right edge, and closer
    than the car is now (the clearances' first sample): a car already inside the margin may stay
    there or move away, not closer. ``cl, cr (N, T)``: ``edge_clearance``."""
    lim_l = jnp.minimum(margin, cl[:, :1]) - MARGIN_TOL
    lim_r = jnp.minimum(margin, cr[:, :1]) - MARGIN_TOL
    return jnp.any((cl < lim_l) | (cr < lim_r), axis=-1)


def leaves_road(ref, cand, road_edges, vehicle, tol=ROAD_TOL):
    """``(N,)``: some sample of the candidate's box reaches more than ``tol`` (m) past the road's
    left or right edge (``edge_clearance``, ``past_edge``)."""
    return past_edge(*edge_clearance(ref, cand, road_edges, vehicle), tol)


def _terminal(ref, s_e, l_e, v_e, obs, sl, ext, v_along, front, half_w, config):
    """``(N,)``: the end states ``s_e, l_e, v_e (N,)`` can stop behind every obstacle ahead in
    their corridor (module ``cost``)."""
    K = sl.shape[0]
    valid = obs.valid[:K, -1]
    so, lo, es, el = sl[:, -1, 0], sl[:, -1, 1], ext[:, -1, 0], ext[:, -1, 1]
    vo = jnp.maximum(v_along[:, -1], 0.0)
    # the virtual stop box (last obstacle) counts too, where it is active
    box = obs.boxes[-1, -1]
    s_box, l_box = to_frenet(ref, box[:2])
    so = jnp.concatenate([so, s_box[None]])
    lo = jnp.concatenate([lo, l_box[None]])
    es = jnp.concatenate([es, 0.5 * box[2][None]])
    el = jnp.concatenate([el, 0.5 * box[3][None]])
    vo = jnp.concatenate([vo, jnp.zeros((1,), vo.dtype)])
    valid = jnp.concatenate([valid, obs.valid[-1:, -1]])
    rel = (
        valid[None]
        & (jnp.abs(lo[None] - l_e[:, None]) < el[None] + half_w + config.buffer_lat)
        & (so[None] > s_e[:, None])
    )
    gap = so[None] - es[None] - (s_e[:, None] + front) - config.buffer_lon
    need = jnp.maximum(v_e[:, None] ** 2 - vo[None] ** 2, 0.0) / (2 * config.terminal_decel) + config.terminal_gap
    return jnp.all(~rel | (gap >= need), axis=-1)


def _lane_decision(cand, progress, targets, ok, l_car, config):
    """The target lane: its centre ``()`` and index ``()`` into ``targets.lane_centres``. The route
    lane unless another lane lets the car get further over the horizon (``progress (N,)``, of the
    level-0 candidates that pass every check) by more than ``lane_change_gain`` than the route
    lane and the car's current lane (each keeps that bonus); a lane running the other way
    (``RoadTargets.lane_borrow``) needs ``borrow_gain`` more."""
    Ln = targets.lane_centres.shape[0]
    prog = progress
    slot = cand.lane_slot
    good = ok & (cand.level == 0) & (slot < Ln)
    best = jnp.max(jnp.where(good[None] & (slot[None] == jnp.arange(Ln)[:, None]), prog[None], -jnp.inf), axis=-1)
    centres = targets.lane_centres.astype(prog.dtype)
    current = jnp.argmin(jnp.where(targets.lane_ok, jnp.abs(centres - l_car), jnp.inf))
    route = targets.route_lane
    lanes = jnp.arange(Ln)
    score = best + config.lane_change_gain * ((lanes == route).astype(prog.dtype) + (lanes == current))
    if targets.lane_borrow is not None:
        score = score - config.borrow_gain * jnp.asarray(targets.lane_borrow, prog.dtype)
    score = jnp.where(targets.lane_ok, score, -jnp.inf)
    # ties go to the route lane
    score = score + 1e-3 * (lanes == route)
    j = jnp.argmax(score)
    lane = jnp.where(jnp.isfinite(score[j]), j, route)
    return centres[lane], lane


# the jitted kernel ``plan`` dispatches to after its host-side checks
plan_kernel = jit(plan_unchecked, options=NO_YNN, static_argnames=("config", "keep_candidates"))


@jit(options=NO_YNN, static_argnames=("config", "keep_candidates"))
def _plan_batch_jit(state, reference_line, obstacles, config, weights, targets=None, keep_candidates=True):
    if targets is None:
        return jax.vmap(lambda s, r, o: plan_unchecked(s, r, o, config, weights, None, keep_candidates))(
            state, reference_line, obstacles
        )
    return jax.vmap(lambda s, r, o, g: plan_unchecked(s, r, o, config, weights, g, keep_candidates))(
        state, reference_line, obstacles, targets
    )


def _check_shapes(where: str, state: PlanState, ref: ReferenceLine, obstacles: Obstacles, batch: int):
    """Refuse arguments whose batch dimensions do not fit ``plan`` (0) / ``plan_batch`` (1)."""
    got = (jnp.ndim(state.x), jnp.ndim(ref.xy) - 2, jnp.ndim(obstacles.boxes) - 3)
    if got == (batch,) * 3:
        return
    if batch == 0:
        raise ValueError(
            f"{where}: plans one state at a time, got batch dimensions (state {got[0]}, reference line "
            f"{got[1]}, obstacles {got[2]}); use jaxplan.lattice.plan_batch or jax.vmap(plan) for batches"
        )
    raise ValueError(
        f"{where}: needs one leading batch dimension on the state, the reference line and the obstacles, "
        f"got (state {got[0]}, reference line {got[1]}, obstacles {got[2]}); use jaxplan.lattice.plan "
        f"for one state"
    )


def _validate(state, reference_line, obstacles, config, weights):
    """Host-side checks of concrete inputs (skipped under jit)."""
    config.validate()
    if is_concrete(state, reference_line, obstacles, weights):
        state.validate()
        reference_line.validate()
        obstacles.validate()
        weights.validate()


def plan(
    state: PlanState,
    reference_line: ReferenceLine,
    obstacles: Obstacles,
    config: LatticeConfig = LatticeConfig(),
    weights: CostWeights | None = None,
    targets: RoadTargets | None = None,
    keep_candidates: bool = True,
) -> LatticeResult:
    """Plan once: every candidate of the lattice, its risk and cost, and the choice.

    Host-side checks run on concrete inputs (under jit they are skipped; then check
    ``LatticeResult.ok``: a NaN / inf in the chosen trajectory makes it False).

    Args:
        state: ``PlanState`` with scalar fields (``plan_batch`` or ``jax.vmap`` for batches).
        reference_line: the current lane's centre line ``(P, 2)``.
        obstacles: boxes ``(K, T_obs, 5)`` stamped at ``obstacles.t`` ``(T_obs,)`` (seconds
            from now, any step: they are interpolated to the candidates' times ``k *
            config.dt``; dynamic obstacles are invalid outside their stamps, static ones held);
            ``K = 0`` means nothing in the way.
        config: static settings (hashable).
        weights: ``CostWeights`` (default weights if None).
        targets: ``RoadTargets`` (lanes, stop point, goal, the obstacles' Frenet coordinates);
            None: the lanes of ``config`` and nothing else.
        keep_candidates: False: the result holds every candidate's figures (features, costs,
            flags, metadata) and the chosen ``trajectory``, but not every candidate's trajectory
            (``candidates.traj``, ``axis``, ``s``, ``l``, ``dl``, ``s_rel`` and ``min_sep`` are None),
            which are then never written out: with few obstacles that is most of a plan's time.
            Inside a caller's ``jit`` the same happens by itself for whatever is not read.

    Returns:
        ``LatticeResult``.
    """
    weights = CostWeights() if weights is None else weights
    _check_shapes("plan", state, reference_line, obstacles, 0)
    _validate(state, reference_line, obstacles, config, weights)
    return plan_kernel(state, reference_line, obstacles, config, weights, targets, keep_candidates)


def plan_batch(
    state: PlanState,
    reference_line: ReferenceLine,
    obstacles: Obstacles,
    config: LatticeConfig = LatticeConfig(),
    weights: CostWeights | None = None,
    targets: RoadTargets | None = None,
    keep_candidates: bool = True,
) -> LatticeResult:
    """``plan`` over a leading batch dimension ``B`` of the state, the reference line and the
    obstacles (and of ``targets`` when given; ``config`` and ``weights`` are shared; default
    weights if None; ``keep_candidates`` as in ``plan``)."""
    weights = CostWeights() if weights is None else weights
    _check_shapes("plan_batch", state, reference_line, obstacles, 1)
    sizes = {
        "state": jnp.shape(state.x)[0],
        "reference line": jnp.shape(reference_line.xy)[0],
        "obstacles": jnp.shape(obstacles.boxes)[0],
    }
    if len(set(sizes.values())) > 1:
        raise ValueError(f"plan_batch: batch sizes differ ({', '.join(f'{k} {v}' for k, v in sizes.items())})")
    # scalar state fields (PlanState.make's defaults) are shared by the batch
    state = jax.tree_util.tree_map(
        lambda f: jnp.broadcast_to(f, (sizes["state"],) + jnp.shape(f)[1:]) if jnp.ndim(f) == 0 else f, state
    )
    _validate(state, reference_line, obstacles, config, weights)
    return _plan_batch_jit(state, reference_line, obstacles, config, weights, targets, keep_candidates)
