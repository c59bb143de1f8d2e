"""The candidate lattice: longitudinal profiles x lanes x lateral offsets x lateral times, at dt.

Layout: candidates are indexed ``(profile, lane, offset, lateral time)`` flattened in that
order (``N = G * P``). The profiles (``jaxplan.lattice.longitudinal``) start with the cruise
``(level, speed)`` grid: level ``e`` uses the speed deltas scaled by ``escalation[e]``; then
the following, stopping and goal modes (level 0), the emergency and fallback levels. With
the default config this is the ``(level, speed, lane, offset)`` order.

Each speed profile gives the distance ``s(t)`` along the reference line; the lateral
path ``l(s)`` is a quintic reaching its offset after ``S = max(s(t_lat), s_min)``, where
``t_lat`` is ``lateral_time`` (or the horizon when it is 0), and holding it after.
Positions, headings (unwrapped) and curvatures follow ``frenet_to_cartesian_state``'s
formulas; the reference line is evaluated once per (level, speed, time) and shared
by every lateral offset. The Cartesian speed is ``ds/dt * sqrt((1 - kappa_r l)^2 + l'^2)``
and the acceleration its exact time derivative; ``s`` of the trajectory is the
running sum of chord lengths.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.geometry.lines import safe_sqrt
from jaxplan.geometry.quintic import cartesian_to_frenet_state, quintic_coeffs, quintic_eval
from jaxplan.planner import EMERGENCY_DECEL
from jaxplan.types import Trajectory, VehicleParams, check_coordinates, check_finite, pytree_dataclass

KMH = 1.0 / 3.6
CHUNK_POINTS = 1 << 12  # at most this many candidate points per chunk of the generator (``_chunk``)


@dataclasses.dataclass(frozen=True)
class LatticeConfig:
    """Static sizes and settings of the lattice (hashable; a static argument under jit).

    Attributes:
        horizon: planning horizon (s); the candidates have ``round(horizon / dt) + 1`` samples.
        dt: time step (s); keep 0.1 to compare with recorded futures.
        speed_deltas_kmh: end speeds ``v0 + delta`` (km/h), clipped to ``[0, v_max]``.
        escalation: scale of the deltas for each re-plan level; level 0 is the normal
            plan, the others are tried (in order) when every candidate of the lower
            levels collides. ``(1.0,)`` disables escalation.
        lanes: lane indices relative to the reference line (0 = current lane, +1 = left);
            ``(0,)`` is normal mode, ``(0, 1)`` a lane change to the left.
        target_lane: the lane of the local reference path (D_toLRP is measured to it).
        lane_width: metres between lane centres.
        n_offsets, offset_span: offsets per lane, ``linspace(-span, span, n)`` about its centre.
        profile: ``"jerk"`` (constant-jerk ramps) or ``"accel"`` (constant acceleration).
        jerk, a_min, a_max: profile limits.
        v_max: highest end speed (m/s).
        s_min: shortest lateral manoeuvre (m).
        lateral_time: time (s) by which the lateral offset is reached; 0 = the horizon.
            A short manoeuvre (2-3 s) lets a fast car swerve late, which a manoeuvre
            stretched over the whole horizon distance cannot.
        vehicle: the car (static floats).
        ttc_min: TTC floor (s) in the risk ``1 / max(TTC, ttc_min)``.
        sep_eps: softness (m) of the smooth collision feature ``sigmoid(-min_sep / eps)``.
        near_budget: broad phase of the collision check: at most this fraction of the
            (speed profile, obstacle, step) triples get the exact per-candidate test
            (more near triples: the dense test runs); 0 = always dense.
        broad_margin: distance (m) between bounding circles below which a triple is near.
        d_threshold, d_margin, stop_length, stop_width: crossroad virtual target: when
            the distance to the crossroad is below ``d_threshold`` a stopped box of
            ``stop_length x stop_width`` starts ``d_margin`` beyond it on the reference line.

    Longitudinal modes (``jaxplan.lattice.longitudinal``; all off by default, cruise profiles only):
        modes: a subset of ``("follow", "stop", "goal")``, each over ``end_times`` (s).
        follow_gap, follow_time_gap: the following mode's end state is
            ``follow_gap + follow_time_gap * v_lead`` behind the leader's rear (m, s).
        stop_gap: metres kept before a stopped obstacle (its box inflated by ``buffer_lon``) by the
            stopping mode.
        emergency: add the emergency level (after the escalation levels): braking with
            ``emergency_a_min`` (m/s^2) and jerk ``emergency_jerk`` (m/s^3), and speeding up
            with ``emergency_a_max`` (m/s^2; the escape from a vehicle closing in from behind).
        fallback: add the last level: braking at ``fallback_decel`` (m/s^2) to a stop.
    Lateral:
        lateral_times: several times (s) by which each offset is reached (empty: ``lateral_time``).
        hold_offset: add targets about the car's current offset (the in-lane braking path).
        goal_offset: add targets about the goal region's lateral middle.
    Feasibility filter (before the collision check; ``jaxplan.lattice.feasibility``):
        feasibility: reject candidates beyond the limits (never chosen while a feasible one exists).
        kappa_max: curvature limit (1/m); 0 = the steering limit ``tan(max_steer) / wheelbase``.
        lon_acc_limits, lon_jerk_max, lat_acc_max: limits of the comfortable levels;
        emergency_jerk_max, emergency_lat_acc_max: of the emergency and fallback levels (their
            deceleration limit is ``emergency_a_min``).
    Safety:
        buffer_lon, buffer_lat: obstacles are inflated by these (m) along and across their
            heading for the "free" test (``collided`` stays the plain overlap).
        edge_margin: the road's edges are moved in by this (m) for the same test: a candidate
            whose box comes closer to an edge is taken only when none keeps the margin (beyond
            the edge it leaves the road, ``plan.leaves_road``).
        terminal: the end state must be able to stop behind whatever is ahead in its corridor,
            decelerating at ``terminal_decel`` (m/s^2) with ``terminal_gap`` (m) left, the
            obstacle braking as hard.
        all_collide: ``"harm"`` (default: least impact speed at first contact, then the latest
            contact) or ``"risk"`` (least ``lambda + gamma / TTC``).
        lane_change_gain: metres of progress over the horizon by which another lane must beat
            the current and the route lane before the lattice takes it as its target lane.
        borrow_gain: metres more by which a lane running the other way must beat them
            (``RoadTargets.lane_borrow``: borrowed to pass what blocks the car's lane, as
            Apollo's lane borrow; oncoming traffic is checked like any obstacle).
        max_lanes: the road planner plans over at most this many lanes about the car's.
        select_temperature: 0 (default): the plan is the exact choice. > 0: the plan is the
            softmin-weighted mean of the candidates the exact rule considers (``cost.soft_choice``
            of the selection cost at this temperature, in cost units), smooth in the cost
            weights for gradients through a drive; its limit at 0 is the exact choice.
        near_k: collision broad phase keeping the ``near_k`` nearest obstacles per lateral group
            and step for the exact test (0: ``near_budget``'s exact broad phase); conservative:
            the bounding-circle distance stands in for the others (never a missed collision); used
            when there are more than ``2 near_k`` obstacles (with fewer the dense test is faster).
        goal_weight_time: seconds of arrival-time error that cost as much as 1 m/s of goal
            speed error or 1 m of lateral goal error in the ``goal`` feature.
    """

    horizon: float = 5.0
    dt: float = 0.1
    speed_deltas_kmh: tuple = (-20.0, -10.0, 0.0, 10.0, 20.0)
    escalation: tuple = (1.0, 2.0, 3.0)
    lanes: tuple = (0,)
    target_lane: int = 0
    lane_width: float = 3.5
    n_offsets: int = 5
    offset_span: float = 1.0
    profile: str = "jerk"
    jerk: float = 2.0
    a_min: float = -4.0
    a_max: float = 2.5
    v_max: float = 40.0
    s_min: float = 10.0
    lateral_time: float = 0.0
    vehicle: VehicleParams = VehicleParams()
    ttc_min: float = 0.1
    sep_eps: float = 0.05
    near_budget: float = 0.25
    broad_margin: float = 1.0
    d_threshold: float = 50.0
    d_margin: float = 0.0
    stop_length: float = 1.0
    stop_width: float = 12.0
    modes: tuple = ()
    end_times: tuple = (2.0, 3.5, 5.5)
    follow_gap: float = 4.0
    follow_time_gap: float = 1.0
    stop_gap: float = 2.0
    emergency: bool = False
    emergency_a_min: float = -EMERGENCY_DECEL
    emergency_a_max: float = 4.0
    emergency_jerk: float = 20.0
    fallback: bool = False
    fallback_decel: float = 5.0
    lateral_times: tuple = ()
    hold_offset: bool = False
    goal_offset: bool = False
    feasibility: bool = True
    kappa_max: float = 0.0
    lon_acc_limits: tuple = (-5.0, 3.0)
    lon_jerk_max: float = 15.0
    lat_acc_max: float = 4.0
    emergency_jerk_max: float = 45.0
    emergency_lat_acc_max: float = 6.0
    buffer_lon: float = 0.0
    buffer_lat: float = 0.0
    edge_margin: float = 0.0
    terminal: bool = False
    terminal_decel: float = 6.0
    terminal_gap: float = 1.0
    all_collide: str = "harm"
    lane_change_gain: float = 8.0
    borrow_gain: float = 30.0
    near_k: int = 0
    max_lanes: int = 5
    goal_weight_time: float = 1.0
    select_temperature: float = 0.0

    @property
    def n_steps(self) -> int:
        return int(round(self.horizon / self.dt)) + 1

    @property
    def grid(self) -> tuple:
        """``(levels, speeds, lanes, offsets)`` of the cruise part of the lattice."""
        return (len(self.escalation), len(self.speed_deltas_kmh), len(self.lanes), self.n_offsets)

    @property
    def n_profiles(self) -> int:
        """``G``: longitudinal profiles (the cruise levels x speeds, then the modes)."""
        from jaxplan.lattice.longitudinal import n_profiles

        return n_profiles(self)

    @property
    def lateral_grid(self) -> tuple:
        """``(lateral lanes, offsets, lateral times)``; the lateral lanes are ``lanes`` then the
        hold and goal targets when switched on."""
        return (
            len(self.lanes) + int(self.hold_offset) + int(self.goal_offset),
            self.n_offsets,
            max(1, len(self.lateral_times)),
        )

    @property
    def n_lateral(self) -> int:
        return int(np.prod(self.lateral_grid))

    @property
    def n_levels(self) -> int:
        """Selection levels: escalation levels, then emergency and fallback when on."""
        return len(self.escalation) + int(self.emergency) + int(self.fallback)

    @property
    def n_candidates(self) -> int:
        return self.n_profiles * self.n_lateral

    @property
    def curvature_limit(self) -> float:
        """``kappa_max``, or the steering limit ``tan(max_steer) / wheelbase``."""
        if self.kappa_max > 0:
            return float(self.kappa_max)
        return float(np.tan(float(self.vehicle.max_steer)) / float(self.vehicle.wheelbase))

    @classmethod
    def road(cls, **overrides) -> LatticeConfig:
        """The full lattice the road planner drives with: every longitudinal mode over end
        times, emergency and fallback levels, three lateral times, the hold and goal targets,
        the feasibility filter, safety buffers, the terminal condition and harm selection
        (the road planner gives the lanes' offsets in ``RoadTargets``, ``max_lanes`` of them)."""
        base: dict[str, Any] = dict(
            modes=("follow", "stop", "goal"),
            emergency=True,
            fallback=True,
            lateral_times=(2.0, 3.0, 4.5),
            hold_offset=True,
            goal_offset=True,
            lanes=(-2, -1, 0, 1, 2),
            n_offsets=3,
            offset_span=0.6,
            buffer_lon=1.0,
            buffer_lat=0.3,
            edge_margin=0.25,
            terminal=True,
            near_budget=0.0,
            near_k=6,
            d_threshold=150.0,
        )
        base.update(overrides)
        return cls(**base)

    def validate(self) -> LatticeConfig:
        if self.dt <= 0 or self.horizon < self.dt:
            raise ValueError(f"LatticeConfig: need 0 < dt <= horizon, got dt={self.dt}, horizon={self.horizon}")
        if self.profile not in ("jerk", "accel"):
            raise ValueError(f"LatticeConfig.profile must be 'jerk' or 'accel', got {self.profile!r}")
        if not self.speed_deltas_kmh or not self.escalation or not self.lanes or self.n_offsets < 1:
            raise ValueError("LatticeConfig: speeds, escalation levels, lanes and offsets must be non-empty")
        if self.target_lane not in self.lanes:
            raise ValueError(f"LatticeConfig.target_lane {self.target_lane} is not one of lanes {self.lanes}")
        if not (self.a_min < 0 < self.a_max) or self.jerk <= 0 or self.s_min <= 0:
            raise ValueError("LatticeConfig: need a_min < 0 < a_max, jerk > 0, s_min > 0")
        if not 0.0 <= self.lateral_time <= self.horizon:
            raise ValueError(f"LatticeConfig.lateral_time must be in [0, horizon], got {self.lateral_time}")
        if any(not 0.0 < x <= self.horizon for x in self.lateral_times):
            raise ValueError(f"LatticeConfig.lateral_times must be in (0, horizon], got {self.lateral_times}")
        bad = set(self.modes) - {"follow", "stop", "goal"}
        if bad:
            raise ValueError(f"LatticeConfig.modes: unknown {sorted(bad)}; known: follow, stop, goal")
        if any(x <= 0 for x in self.end_times) or (set(self.modes) & {"follow"} and not self.end_times):
            raise ValueError(f"LatticeConfig.end_times must be positive (and given for follow), got {self.end_times}")
        if not self.borrow_gain >= 0:
            raise ValueError(f"LatticeConfig.borrow_gain must be >= 0 m (inf: never borrow), got {self.borrow_gain}")
        if not (self.select_temperature >= 0 and self.select_temperature < float("inf")):
            raise ValueError(f"LatticeConfig.select_temperature must be finite and >= 0, got {self.select_temperature}")
        if self.all_collide not in ("harm", "risk"):
            raise ValueError(f"LatticeConfig.all_collide must be 'harm' or 'risk', got {self.all_collide!r}")
        if not (
            self.emergency_a_min < 0 < self.emergency_a_max and self.fallback_decel > 0 and self.emergency_jerk > 0
        ):
            raise ValueError(
                "LatticeConfig: need emergency_a_min < 0 < emergency_a_max, fallback_decel > 0, emergency_jerk > 0"
            )
        lo, hi = self.lon_acc_limits
        if not (lo < 0 < hi) or self.lon_jerk_max <= 0 or self.lat_acc_max <= 0 or self.kappa_max < 0:
            raise ValueError(
                "LatticeConfig: need lon_acc_limits (lo < 0 < hi), positive jerk, lateral "
                "acceleration limits and kappa_max >= 0"
            )
        if min(self.buffer_lon, self.buffer_lat, self.edge_margin) < 0 or self.terminal_decel <= 0 or self.near_k < 0:
            raise ValueError("LatticeConfig: buffers and near_k must be >= 0, terminal_decel > 0")
        self.vehicle.validate()
        return self


@pytree_dataclass(data_fields=("x", "y", "heading", "kappa", "v", "a", "v_set", "d_crossroad"))
class PlanState:
    """The car's state, each field ``(...)``.

    ``v_set`` is the set (cruise) speed; ``d_crossroad`` the distance along the
    reference line to the next crossroad (``inf`` when there is none).
    """

    x: Any
    y: Any
    heading: Any
    kappa: Any = 0.0
    v: Any = 0.0
    a: Any = 0.0
    v_set: Any = None
    d_crossroad: Any = float("inf")

    @classmethod
    def make(cls, x, y, heading, v, a=0.0, kappa=0.0, v_set=None, d_crossroad=float("inf")) -> PlanState:
        """Host-side constructor with checks; ``v_set`` defaults to ``v``."""
        f = jnp.result_type(float)
        st = cls(*(jnp.asarray(z, f) for z in (x, y, heading, kappa, v, a, v if v_set is None else v_set, d_crossroad)))
        return st.validate()

    @classmethod
    def from_rows(cls, ego) -> PlanState:
        """Jittable: states from rows ``ego (..., 5)`` = [x, y, heading, v, a] (the layout of
        ``jaxplan.scenarios.synthetic`` and ``jaxplan.tuning.demos``): no curvature, the set
        speed is the current speed, no crossroad."""
        e = jnp.asarray(ego)
        zero = jnp.zeros_like(e[..., 0])
        return cls(e[..., 0], e[..., 1], e[..., 2], zero, e[..., 3], e[..., 4], e[..., 3], zero + jnp.inf)

    def validate(self) -> PlanState:
        for name in ("x", "y", "heading", "kappa", "v", "a", "v_set"):
            check_finite(f"PlanState.{name}", getattr(self, name))
        check_coordinates("PlanState x, y", np.stack(np.broadcast_arrays(np.asarray(self.x), np.asarray(self.y)), -1))
        if np.any(np.asarray(self.v) < 0):
            raise ValueError("PlanState.v must be >= 0")
        if np.any(np.isnan(np.asarray(self.d_crossroad))):
            raise ValueError("PlanState.d_crossroad is NaN (use inf for no crossroad)")
        return self


@pytree_dataclass(
    data_fields=(
        "traj",
        "axis",
        "s",
        "l",
        "dl",
        "v_end",
        "offset",
        "level",
        "speed_index",
        "lane",
        "l_target",
        "kind",
        "available",
        "lat_time",
        "lane_slot",
        "profile",
        "end_time",
        "s_rel",
    )
)
class Candidates:
    """Every candidate of the lattice, flattened to ``N = G * P`` (see the module docstring).

    Attributes:
        traj: ``Trajectory`` with fields ``(..., N, T)`` (reference point of the car).
        axis: ``(..., N, T, 2)`` heading unit vectors ``(cos theta, sin theta)``.
        s, l, dl: ``(..., N, T)`` Frenet arc length (absolute), offset and dl/ds.
        v_end, offset: ``(..., N)`` target end speed (m/s) and lateral offset (m).
        level, speed_index, lane: ``(..., N)`` int: selection level, the cruise speed index
            (-1 for the other modes), lane id (``config.lanes`` value, ``HOLD_LANE`` / ``GOAL_LANE``).
        l_target: ``(...)`` the local reference path's offset (the route lane's centre).
        kind: ``(..., N)`` longitudinal mode (``longitudinal.CRUISE`` ... ``FALLBACK``).
        available: ``(..., N)`` its target exists (mode and lane).
        lat_time: ``(..., N)`` time (s) by which the lateral offset is reached.
        lane_slot: ``(..., N)`` index into the lateral lanes; profile: ``(..., N)`` index ``g``.
        end_time: ``(..., N)`` the profile's end time (inf for ramps); s_rel: ``(..., N, T)``
            distance along the line from the car.
    """

    traj: Any
    axis: Any
    s: Any
    l: Any
    dl: Any
    v_end: Any
    offset: Any
    level: Any
    speed_index: Any
    lane: Any
    l_target: Any
    kind: Any = None
    available: Any = None
    lat_time: Any = None
    lane_slot: Any = None
    profile: Any = None
    end_time: Any = None
    s_rel: Any = None


# Minimax odd polynomial for atan on [0, 1] (max error about 1e-7 rad in float32 arithmetic).
_ATAN = (0.99999934, -0.33329856, 0.19946536, -0.13908534, 0.09642004, -0.05590988, 0.02186122, -0.00405404)


def atan2(y, x):
    """``arctan2`` from multiplies and one division (XLA's CPU arctan2 is ~30x slower
    than arithmetic); agrees with ``jnp.arctan2`` to about 1e-6 rad."""
    ax, ay = jnp.abs(x), jnp.abs(y)
    big = jnp.maximum(ax, ay)
    z = jnp.minimum(ax, ay) / jnp.where(big > 0, big, 1.0)
    z2 = z * z
    p = _ATAN[-1]
    for c in _ATAN[-2::-1]:
        p = p * z2 + c
    r = p * z
    r = jnp.where(ay > ax, 0.5 * np.pi - r, r)
    r = jnp.where(x < 0, np.pi - r, r)
    return jnp.where(y < 0, -r, r)


def _lateral_targets(config: LatticeConfig, targets, l0, dtype):
    """Lateral target offsets ``(Pl,)`` = (lateral lane, offset) and whether each exists."""
    _, O, _ = config.lateral_grid
    centre_parts, ok_parts = [targets.lane_centres.astype(dtype)], [targets.lane_ok]
    if config.hold_offset:
        centre_parts.append(jnp.reshape(l0, (1,)).astype(dtype))
        ok_parts.append(jnp.ones((1,), bool))
    if config.goal_offset:
        gl = jnp.asarray(targets.goal_l, dtype)
        fin = jnp.all(jnp.isfinite(gl))
        centre_parts.append(jnp.reshape(jnp.where(fin, 0.5 * (gl[0] + gl[1]), l0), (1,)).astype(dtype))
        ok_parts.append(jnp.reshape(fin, (1,)))
    centres, ok = jnp.concatenate(centre_parts), jnp.concatenate(ok_parts)
    offs = jnp.linspace(-config.offset_span, config.offset_span, O, dtype=dtype) if O > 1 else jnp.zeros((1,), dtype)
    return (centres[:, None] + offs).reshape(-1), jnp.repeat(ok, O)


def _lateral_ids(config: LatticeConfig):
    """Static lane ids and lateral-lane slots ``(Pl,)`` of the lateral targets (numpy)."""
    from jaxplan.lattice.targets import GOAL_LANE, HOLD_LANE

    Lw, O, _ = config.lateral_grid
    ids = list(config.lanes) + [HOLD_LANE] * config.hold_offset + [GOAL_LANE] * config.goal_offset
    return np.repeat(np.asarray(ids), O), np.repeat(np.arange(Lw), O)


@pytree_dataclass(
    data_fields=("profiles", "ref_at", "S", "offsets", "lat_ok", "l0", "dl0", "ddl0", "s0", "t", "lon", "l_target")
)
class LatticeParts:
    """What every candidate of one plan is built from (``generate_from`` expands it).

    Attributes:
        profiles: ``(s_rel, sdot, sddot) (G, T)`` the longitudinal profiles along the line.
        ref_at: the reference line at each profile's stations: ``(pos (G, T, 2), cos, sin,
            theta, kappa, dkappa (G, T))``, evaluated once per profile and shared by its lateral paths.
        S: ``(G, P)`` arc length over which each lateral path reaches its offset.
        offsets: ``(P,)`` lateral target offsets; lat_ok: ``(P,)`` the target exists.
        l0, dl0, ddl0, s0: ``()`` the car's Frenet state; t: ``(T,)``.
        lon: the ``Longitudinal`` profiles' metadata; l_target: ``()`` the route lane's centre.
    """

    profiles: Any
    ref_at: Any
    S: Any
    offsets: Any
    lat_ok: Any
    l0: Any
    dl0: Any
    ddl0: Any
    s0: Any
    t: Any
    lon: Any
    l_target: Any


def lattice_parts(
    state: PlanState, ref: ReferenceLine, config: LatticeConfig, targets=None, leader=None, stop_s=None, sl=None
) -> LatticeParts:
    """The longitudinal profiles and lateral targets of one plan (arguments as ``generate``;
    ``sl``: optional ``(s, l)`` of the car's position on ``ref``, already computed)."""
    from jaxplan.lattice.longitudinal import longitudinal_set
    from jaxplan.lattice.targets import RoadTargets

    dtype = ref.xy.dtype
    if targets is None:
        targets = RoadTargets.from_config(config, dtype)
    T = config.n_steps
    t = jnp.arange(T, dtype=dtype) * config.dt
    v0 = jnp.asarray(state.v, dtype)
    s0, l0, dl0, ddl0 = cartesian_to_frenet_state(
        ref, jnp.stack([state.x, state.y]).astype(dtype), state.heading, state.kappa, sl
    )
    _, _, kr0, _ = ref_state(ref, s0)
    # the profiles run in ds/dt along the reference line: ds/dt = v / sqrt((1 - kr l)^2 + l'^2)
    to_sdot = 1.0 / jnp.sqrt((1.0 - kr0 * l0) ** 2 + dl0**2)
    sdot0 = v0 * to_sdot
    a0 = jnp.asarray(state.a, dtype) * to_sdot
    lead_s, lead_v, lead_ok = leader if leader is not None else (None, None, False)
    goal_s = jnp.asarray(targets.goal_s, dtype)
    goal_mid = jnp.where(jnp.all(jnp.isfinite(goal_s)), 0.5 * (goal_s[0] + goal_s[1]), jnp.inf)
    lon = longitudinal_set(
        sdot0,
        a0,
        t,
        config,
        lead_s,
        lead_v,
        lead_ok,
        jnp.inf if stop_s is None else stop_s,
        goal_mid - s0 - jnp.asarray(config.vehicle.center_offset, dtype),
        targets.goal_t,
        targets.goal_v,
        v_grid=v0,
    )
    G = lon.s.shape[0]
    Lw, O, Lt = config.lateral_grid
    offsets, lat_ok = _lateral_targets(config, targets, l0, dtype)
    Pl = Lw * O
    P = Pl * Lt
    k_lat = np.array([T - 1 if x <= 0 else min(T - 1, int(round(x / config.dt))) for x in _lateral_times(config)])
    S = jnp.maximum(lon.s[:, k_lat], config.s_min)  # (G, Lt)
    S = jnp.broadcast_to(S[:, None, :], (G, Pl, Lt)).reshape(G, P)
    per_lt = lambda a: jnp.broadcast_to(a[:, None], (Pl, Lt)).reshape(P)
    pos, theta_r, kr, dkr = ref_state(ref, s0 + lon.s)  # once per speed profile
    route_lane = jnp.asarray(targets.route_lane)
    return LatticeParts(
        (lon.s, lon.v, lon.a),
        (pos, jnp.cos(theta_r), jnp.sin(theta_r), theta_r, kr, dkr),
        S,
        per_lt(offsets),
        per_lt(lat_ok),
        l0,
        dl0,
        ddl0,
        s0,
        t,
        lon,
        targets.lane_centres.astype(dtype)[route_lane],
    )


def stations_finite(parts: LatticeParts):
    """``(N,)`` (``generate``'s layout): the candidate's speed profile has finite points, headings
    and curvatures on the reference line at every sample (its positions and heading are finite
    where these and its lateral offsets are)."""
    ok = jnp.ones(parts.profiles[0].shape[:1], bool)
    for a in parts.ref_at:
        ok &= jnp.all(jnp.isfinite(a).reshape(a.shape[0], -1), axis=-1)
    # a broadcast, not ``jnp.repeat``: XLA fused the repeat's gather with these reductions and
    # recomputed the profile's rows for every candidate (a quarter of a kinematic plan at N = 994)
    return jnp.broadcast_to(ok[:, None], (ok.shape[0], parts.offsets.shape[0])).reshape(-1)


def _lateral_times(config: LatticeConfig) -> tuple:
    return config.lateral_times or (config.lateral_time,)


def _lateral_paths(parts: LatticeParts, profile, ref_at, offsets, S):
    """The lateral paths to ``offsets (P,)`` (reached after ``S (P,)`` metres) along one speed
    profile (``profile``, ``ref_at``: that profile's ``(T,)`` rows of ``LatticeParts``).

    Returns:
        (x, y, theta, kappa, speed, acc, ux, uy, l, dl) each ``(P, T)``: Frenet -> Cartesian with
        ``frenet_to_cartesian_state``'s formulas, no trigonometry per candidate.
    """
    s_g, sd_g, sdd_g = profile
    pos_g, cr, sr, th_r, kr_g, dkr_g = ref_at
    P, T = offsets.shape[0], s_g.shape[-1]
    coeffs = quintic_coeffs(parts.l0, parts.dl0, parts.ddl0, offsets, S)  # (P, 6)
    l, dl, ddl = quintic_eval(coeffs, S, jnp.broadcast_to(s_g, (P, T)))
    one = 1.0 - kr_g * l
    q = jnp.sqrt(one**2 + dl**2)
    r_q, r_one = 1.0 / q, 1.0 / one  # two reciprocals per sample instead of six divisions
    cos_d, sin_d, tan_d = one * r_q, dl * r_q, dl * r_one
    d_one = dkr_g * l + kr_g * dl  # -d(one)/ds
    kappa = ((ddl + d_one * tan_d) * cos_d**2 * r_one + kr_g) * cos_d * r_one
    theta = th_r + atan2(dl, one)
    x = pos_g[:, 0] - l * sr
    y = pos_g[:, 1] + l * cr
    ux, uy = cr * cos_d - sr * sin_d, sr * cos_d + cr * sin_d  # heading unit vector
    speed = sd_g * q
    # d(speed)/dt = s'' q + s'^2 dq/ds, with dq/ds = (one * d(one)/ds + l' l'') / q
    acc = sdd_g * q + sd_g**2 * (dl * ddl - one * d_one) * r_q
    return x, y, theta, kappa, speed, acc, ux, uy, l, dl


def arc_length(x, y):
    """Running sum of chord lengths ``(..., T)`` of the points ``x, y (..., T)`` (0 at the first)."""
    seg = safe_sqrt(jnp.diff(x, axis=-1) ** 2 + jnp.diff(y, axis=-1) ** 2)  # 0 when stopped
    return jnp.concatenate([jnp.zeros(x.shape[:-1] + (1,), x.dtype), jnp.cumsum(seg, axis=-1)], axis=-1)


def _trajectory(fields, t):
    x, y, theta, kappa, speed, acc = fields[:6]
    return Trajectory(x, y, theta, kappa, speed, acc, jnp.broadcast_to(t, x.shape), arc_length(x, y), jnp.ones_like(x))


def candidate_trajectory(parts: LatticeParts, index) -> Trajectory:
    """The ``Trajectory (T,)`` of candidate ``index ()`` (the flat index of ``generate``'s layout),
    built alone: the same arithmetic as ``generate_from`` for that candidate."""
    P = parts.offsets.shape[0]
    g, p = index // P, index % P
    row = lambda a: a[g]
    profile = jax.tree_util.tree_map(row, parts.profiles)
    ref_at = jax.tree_util.tree_map(row, parts.ref_at)
    fields = _lateral_paths(parts, profile, ref_at, parts.offsets[p][None], parts.S[g, p][None])
    return jax.tree_util.tree_map(lambda a: a[0], _trajectory(fields, parts.t))


def _chunk(G: int, points: int) -> int:
    """Speed profiles per chunk of the generator's loop over ``G`` profiles of ``points``
    candidate samples each: the largest divisor of ``G`` below ``G`` whose chunk holds at most
    ``CHUNK_POINTS`` samples (1 if none).

    The loop writes the samples out chunk by chunk, while they are in the cache. Without a loop
    (one chunk of every profile) XLA fuses the generator into every per-candidate reduction that
    reads it and recomputes it there; a remainder chunk (``lax.map``'s, outside the loop) is fused
    the same way. The default ``LatticeConfig`` (15 profiles of 255 samples) would be one chunk
    under the alternative rule of ``CHUNK_POINTS // points`` profiles per chunk (up to all of
    them): with this rule its plan takes 0.56 ms instead of 1.26 and 0.49 instead of 0.93 (two
    runs, best of 50 rounds each, both rules in one process; per-round median ratios 0.63 and
    0.53), with the same choice. Where that rule also gives one profile per chunk (the
    benchmark's N = 994, 1748, 4992, the road planner) the two rules agree."""
    fits = [d for d in range(1, G) if G % d == 0 and d * points <= CHUNK_POINTS]
    return max(fits, default=1)


def generate_from(parts: LatticeParts, config: LatticeConfig) -> Candidates:
    """Every candidate of ``parts`` (built with ``config``); ``generate``'s layout.

    Under ``jit``, candidate arrays nobody reads are never computed or written: a plan that keeps
    only per-candidate figures and the chosen candidate (``candidate_trajectory``) writes out the
    few fields its figures read (curvature, speed, acceleration, offsets), not whole trajectories.
    """
    f = parts.t.dtype
    t = parts.t
    T = t.shape[0]
    lon = parts.lon
    s_rel = parts.profiles[0]
    G = s_rel.shape[0]
    P = parts.offsets.shape[0]
    N = G * P
    s_abs = parts.s0 + s_rel

    def group(g):
        """Every lateral target of one speed profile: fields ``(P, T)``."""
        profile, ref_at, S_g = g
        return _lateral_paths(parts, profile, ref_at, parts.offsets, S_g)

    chunk = _chunk(G, P * T)
    xs = (parts.profiles, parts.ref_at, parts.S)
    fields = lax.map(group, xs, batch_size=chunk) if chunk < G else jax.vmap(group)(xs)
    x, y, theta, kappa, speed, acc, ux, uy, l, dl = (o.reshape(N, T) for o in fields)
    traj = _trajectory((x, y, theta, kappa, speed, acc), t)
    per_g = lambda a: jnp.broadcast_to(jnp.asarray(a)[:, None], (G, P)).reshape(N)
    per_p = lambda a: jnp.broadcast_to(jnp.asarray(a)[None, :], (G, P)).reshape(N)
    Lw, O, Lt = config.lateral_grid
    Pl = Lw * O
    lat_p = lambda a: np.broadcast_to(np.asarray(a)[:, None], (Pl, Lt)).reshape(P)
    lane_ids, slots = _lateral_ids(config)
    times = _lateral_times(config)
    E, V = len(config.escalation), len(config.speed_deltas_kmh)
    speed_index = np.full(G, -1)
    speed_index[: E * V] = np.tile(np.arange(V), E)
    lat_times = np.broadcast_to(np.asarray([x if x > 0 else config.horizon for x in times], float)[None], (Pl, Lt))
    return Candidates(
        traj,
        jnp.stack([ux, uy], -1),
        jnp.broadcast_to(s_abs[:, None], (G, P, T)).reshape(N, T),
        l,
        dl,
        per_g(lon.v_end),
        per_p(parts.offsets),
        per_g(lon.level),
        per_g(jnp.asarray(speed_index)),
        per_p(jnp.asarray(lat_p(lane_ids))),
        parts.l_target,
        per_g(lon.kind),
        per_g(lon.available) & per_p(parts.lat_ok),
        per_p(jnp.asarray(lat_times.reshape(P), f)),
        per_p(jnp.asarray(lat_p(slots))),
        per_g(jnp.arange(G)),
        per_g(lon.end_time),
        jnp.broadcast_to(s_rel[:, None], (G, P, T)).reshape(N, T),
    )


def generate(
    state: PlanState, ref: ReferenceLine, config: LatticeConfig, targets=None, leader=None, stop_s=None
) -> Candidates:
    """All candidates of the lattice for one state (any leading batch dims via vmap).

    Layout: ``N = G * P``, the longitudinal profile ``g`` major (``jaxplan.lattice.longitudinal``:
    the cruise ``levels x speeds`` first), then the lateral target ``(lane, offset)`` and the
    lateral time (``P = lanes' * offsets * lateral times``). With the defaults this is the
    ``(level, speed, lane, offset)`` order.

    Args:
        state: ``PlanState`` with scalar fields.
        ref: the reference line (the route lane's centre).
        config: static settings.
        targets: ``RoadTargets`` (None: ``RoadTargets.from_config``).
        leader: optional ``(rear (T,), speed (T,), found ())`` for the following mode (relative
            to the car's reference point, the car's front length subtracted).
        stop_s: optional ``()`` distance from the car's reference point to where it stops.

    Returns:
        ``Candidates`` with ``N = config.n_candidates`` and ``T = config.n_steps``.
    """
    return generate_from(lattice_parts(state, ref, config, targets, leader, stop_s), config)
