"""The lattice's static settings (``LatticeConfig``): the grid's sizes, the longitudinal modes, the
lateral targets, the feasibility limits, the safety margins and the selection rule.

``LatticeConfig`` is a frozen dataclass (hashable, a static argument under ``jit``); its
properties give the sizes of the candidate layout (``jaxplan.lattice.candidates``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from jaxplan.planner import EMERGENCY_DECEL
from jaxplan.types import VehicleParams

KMH = 1.0 / 3.6  # m/s per km/h (``LatticeConfig.speed_deltas_kmh`` are in km/h)


@dataclasses.dataclass(frozen=True)
class LatticeConfig:
    """Static sizes and settings of the lattice (hashable; a static argument under jit).

    Attributes:
        horizon: planning horizon (s); the candidates have ``round(horizon / dt) + 1`` samples.
        dt: time step (s); keep 0.1 to compare with recorded futures.
        speed_deltas_kmh: end speeds ``v0 + delta`` (km/h), clipped to ``[0, v_max]``.
        target_speed: one more cruise end speed on level 0: the set speed, capped by the
            reference line's curvature ahead (``longitudinal.target_speed``), so that a car
            whose grid steps past what a curve allows still reaches that speed.
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
    target_speed: bool = False

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
            target_speed=True,
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
