"""The candidate lattice: end speeds x lanes x lateral offsets, time-stamped at dt.

Layout: candidates are indexed ``(level, speed, lane, offset)`` flattened in that
order (``N = levels * speeds * lanes * offsets``). ``level`` is the speed-variation
escalation: level ``e`` uses the speed deltas scaled by ``escalation[e]``.

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
from jax import lax
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.geometry.lines import safe_sqrt
from jaxplan.lattice.profiles import accel_profile, jerk_profile
from jaxplan.lattice.quintic import cartesian_to_frenet_state, quintic_coeffs, quintic_eval
from jaxplan.types import Trajectory, VehicleParams, _pytree, check_coordinates, check_finite

KMH = 1.0 / 3.6
CHUNK_POINTS = 1 << 12  # candidate points per chunk of the generator (at least one speed profile)


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

    @property
    def n_steps(self) -> int:
        return int(round(self.horizon / self.dt)) + 1

    @property
    def grid(self) -> tuple:
        """``(levels, speeds, lanes, offsets)``."""
        return (len(self.escalation), len(self.speed_deltas_kmh), len(self.lanes), self.n_offsets)

    @property
    def n_candidates(self) -> int:
        return int(np.prod(self.grid))

    def validate(self) -> "LatticeConfig":
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
        self.vehicle.validate()
        return self


@_pytree(data_fields=("x", "y", "heading", "kappa", "v", "a", "v_set", "d_crossroad"))
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
    def make(cls, x, y, heading, v, a=0.0, kappa=0.0, v_set=None, d_crossroad=float("inf")) -> "PlanState":
        """Host-side constructor with checks; ``v_set`` defaults to ``v``."""
        f = jnp.result_type(float)
        st = cls(*(jnp.asarray(z, f) for z in (x, y, heading, kappa, v, a, v if v_set is None else v_set,
                                                d_crossroad)))
        return st.validate()

    @classmethod
    def from_rows(cls, ego) -> "PlanState":
        """Jittable: states from rows ``ego (..., 5)`` = [x, y, heading, v, a] (the layout of
        ``jaxplan.scenarios.synthetic`` and ``jaxplan.tuning.demos``): no curvature, the set
        speed is the current speed, no crossroad."""
        e = jnp.asarray(ego)
        zero = jnp.zeros_like(e[..., 0])
        return cls(e[..., 0], e[..., 1], e[..., 2], zero, e[..., 3], e[..., 4], e[..., 3], zero + jnp.inf)

    def validate(self) -> "PlanState":
        for name in ("x", "y", "heading", "kappa", "v", "a", "v_set"):
            check_finite(f"PlanState.{name}", getattr(self, name))
        check_coordinates("PlanState x, y", np.stack(np.broadcast_arrays(np.asarray(self.x), np.asarray(self.y)), -1))
        if np.any(np.asarray(self.v) < 0):
            raise ValueError("PlanState.v must be >= 0")
        if np.any(np.isnan(np.asarray(self.d_crossroad))):
            raise ValueError("PlanState.d_crossroad is NaN (use inf for no crossroad)")
        return self


@_pytree(data_fields=("traj", "axis", "s", "l", "dl", "v_end", "offset", "level", "speed_index", "lane", "l_target"))
class Candidates:
    """Every candidate of the lattice, flattened to ``N`` (see the module docstring).

    Attributes:
        traj: ``Trajectory`` with fields ``(..., N, T)`` (reference point of the car).
        axis: ``(..., N, T, 2)`` heading unit vectors ``(cos theta, sin theta)``.
        s, l, dl: ``(..., N, T)`` Frenet arc length (absolute), offset and dl/ds.
        v_end, offset: ``(..., N)`` target end speed (m/s) and lateral offset (m).
        level, speed_index, lane: ``(..., N)`` int grid indices.
        l_target: ``(...)`` the local reference path's offset (target lane centre).
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


def _grid_values(config: LatticeConfig, v0, dtype):
    E, V, Ln, O = config.grid
    scale = jnp.asarray(config.escalation, dtype)[:, None]
    deltas = jnp.asarray(config.speed_deltas_kmh, dtype)[None, :] * KMH
    v_end = jnp.clip(v0[..., None, None] + scale * deltas, 0.0, config.v_max)  # (..., E, V)
    centre = jnp.asarray(config.lanes, dtype) * config.lane_width
    offsets = centre[:, None] + jnp.linspace(-config.offset_span, config.offset_span, O, dtype=dtype) \
        if O > 1 else centre[:, None] + jnp.zeros((1,), dtype)
    return v_end, offsets  # (..., E, V), (Ln, O)


def generate(state: PlanState, ref: ReferenceLine, config: LatticeConfig) -> Candidates:
    """All candidates of the lattice for one state (any leading batch dims via vmap).

    Args:
        state: ``PlanState`` with scalar fields.
        ref: the reference line (the current lane's centre).
        config: static settings.

    Returns:
        ``Candidates`` with ``N = config.n_candidates`` and ``T = config.n_steps``.
    """
    dtype = ref.xy.dtype
    E, V, Ln, O = config.grid
    T = config.n_steps
    t = jnp.arange(T, dtype=dtype) * config.dt
    v0 = jnp.asarray(state.v, dtype)
    s0, l0, dl0, ddl0 = cartesian_to_frenet_state(ref, jnp.stack([state.x, state.y]).astype(dtype),
                                                  state.heading, state.kappa)
    _, _, kr0, _ = ref_state(ref, s0)
    # the profiles run in ds/dt along the reference line: ds/dt = v / sqrt((1 - kr l)^2 + l'^2)
    to_sdot = 1.0 / jnp.sqrt((1.0 - kr0 * l0) ** 2 + dl0 ** 2)
    sdot0 = v0 * to_sdot
    a0 = jnp.asarray(state.a, dtype) * to_sdot
    v_end, offsets = _grid_values(config, v0, dtype)
    if config.profile == "jerk":
        s_rel, sd, sdd = jerk_profile(sdot0, a0, v_end, t, config.jerk, config.a_min, config.a_max)
    else:
        s_rel, sd, sdd = accel_profile(sdot0, v_end, t, config.a_min, config.a_max)
    # s_rel, sd, sdd: (E, V, T)
    G, P = E * V, Ln * O
    k_lat = T - 1 if config.lateral_time <= 0 else min(T - 1, int(round(config.lateral_time / config.dt)))
    S = jnp.maximum(s_rel[..., k_lat], config.s_min).reshape(G)
    s_abs = (s0 + s_rel).reshape(G, T)  # the reference line is evaluated once per speed profile
    pos, theta_r, kr, dkr = ref_state(ref, s_abs)
    per_group = (s_rel.reshape(G, T), sd.reshape(G, T), sdd.reshape(G, T), S, pos, jnp.cos(theta_r),
                 jnp.sin(theta_r), theta_r, kr, dkr)
    offsets = offsets.reshape(P)

    def lateral(g):
        """Every offset of one speed profile: fields ``(P, T)``."""
        s_g, sd_g, sdd_g, S_g, pos_g, cr, sr, th_r, kr_g, dkr_g = g
        coeffs = quintic_coeffs(l0, dl0, ddl0, offsets, S_g)  # (P, 6)
        l, dl, ddl = quintic_eval(coeffs, jnp.broadcast_to(S_g, (P,)), jnp.broadcast_to(s_g, (P, T)))
        # Frenet -> Cartesian (frenet_to_cartesian_state's formulas, no trigonometry per candidate)
        one = 1.0 - kr_g * l
        q = jnp.sqrt(one ** 2 + dl ** 2)
        cos_d, sin_d, tan_d = one / q, dl / q, dl / one
        kappa = ((ddl + (dkr_g * l + kr_g * dl) * tan_d) * cos_d ** 2 / one + kr_g) * cos_d / one
        theta = th_r + atan2(dl, one)
        x = pos_g[:, 0] - l * sr
        y = pos_g[:, 1] + l * cr
        ux, uy = cr * cos_d - sr * sin_d, sr * cos_d + cr * sin_d  # heading unit vector
        speed = sd_g * q
        # d(speed)/dt = s'' q + s'^2 dq/ds, with dq/ds = (one * d(one)/ds + l' l'') / q
        acc = sdd_g * q + sd_g ** 2 * (one * -(dkr_g * l + kr_g * dl) + dl * ddl) / q
        seg = safe_sqrt(jnp.diff(x, axis=-1) ** 2 + jnp.diff(y, axis=-1) ** 2)  # chord lengths (0 when stopped)
        arc = jnp.concatenate([jnp.zeros((P, 1), dtype), jnp.cumsum(seg, axis=-1)], axis=-1)
        return x, y, theta, kappa, speed, acc, arc, ux, uy, l, dl

    # chunks of speed profiles small enough for the cache (XLA would otherwise materialise
    # every intermediate of all N x T points in memory)
    chunk = max(1, min(G, CHUNK_POINTS // (P * T)))
    out = lax.map(lateral, per_group, batch_size=chunk) if chunk < G else jax.vmap(lateral)(per_group)
    N = G * P
    x, y, theta, kappa, speed, acc, arc, ux, uy, l, dl = (o.reshape(N, T) for o in out)
    traj = Trajectory(x, y, theta, kappa, speed, acc, jnp.broadcast_to(t, (N, T)), arc,
                      jnp.ones((N, T), dtype))
    idx = np.indices((E, V, Ln, O)).reshape(4, N)
    lane_ids = np.asarray(config.lanes)[idx[2]]
    return Candidates(traj, jnp.stack([ux, uy], -1), jnp.broadcast_to(s_abs[:, None], (G, P, T)).reshape(N, T),
                      l, dl, jnp.broadcast_to(v_end.reshape(G, 1), (G, P)).reshape(N),
                      jnp.broadcast_to(offsets, (G, P)).reshape(N),
                      jnp.asarray(idx[0]), jnp.asarray(idx[1]), jnp.asarray(lane_ids),
                      jnp.asarray(config.target_lane * config.lane_width, dtype))

