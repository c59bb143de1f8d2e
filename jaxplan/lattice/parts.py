"""What every candidate of one plan is built from: ``LatticeParts``, made by ``lattice_parts``.

The car's Frenet state on the reference line, the longitudinal profiles
(``jaxplan.lattice.longitudinal``), the reference line at each profile's stations (evaluated
once per (profile, time) and shared by every lateral offset), the lateral targets
(``jaxplan.lattice.lateral``) and the arc length ``S = max(s(t_lat), s_min)`` after which each
lateral path holds its offset, ``t_lat`` being its lateral time (the horizon when it is 0).
``stations_finite`` flags the candidates whose profile has a non-finite point on the line.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine, ref_state
from jaxplan.geometry.quintic import cartesian_to_frenet_state
from jaxplan.lattice.config import LatticeConfig
from jaxplan.lattice.lateral import lateral_targets, lateral_times
from jaxplan.lattice.state import PlanState
from jaxplan.types import pytree_dataclass


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
    from jaxplan.lattice.longitudinal import longitudinal_set, target_speed
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
    v_target = None
    if config.target_speed:
        reach = jnp.maximum(v0, 5.0) * config.horizon
        _, _, k_ahead, _ = ref_state(ref, s0 + reach * jnp.linspace(0.0, 1.0, 16, dtype=dtype))
        v_target = target_speed(k_ahead, state.v_set, config.lat_acc_max)
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
        v_target=v_target,
    )
    G = lon.s.shape[0]
    Lw, O, Lt = config.lateral_grid
    offsets, lat_ok = lateral_targets(config, targets, l0, dtype)
    Pl = Lw * O
    P = Pl * Lt
    k_lat = np.array([T - 1 if x <= 0 else min(T - 1, int(round(x / config.dt))) for x in lateral_times(config)])
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
