"""The candidate lattice: longitudinal profiles x lanes x lateral offsets x lateral times, at dt.

Layout: candidates are indexed ``(profile, lane, offset, lateral time)`` flattened in that
order (``N = G * P``). The profiles (``jaxplan.lattice.longitudinal``) start with the cruise
``(level, speed)`` grid: level ``e`` uses the speed deltas scaled by ``escalation[e]``; then
the following, stopping and goal modes (level 0), the emergency and fallback levels. With
the default config this is the ``(level, speed, lane, offset)`` order.

``generate_from`` expands one plan's ``LatticeParts`` (``jaxplan.lattice.parts``) into every
candidate's samples: the lateral paths (``jaxplan.lattice.lateral``) along each speed profile,
a chunk of profiles at a time; ``candidate_trajectory`` builds one candidate alone with the same
arithmetic. ``s`` of the trajectory is the running sum of chord lengths.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.geometry.lines import safe_sqrt
from jaxplan.lattice.config import LatticeConfig
from jaxplan.lattice.lateral import lateral_ids, lateral_paths, lateral_times
from jaxplan.lattice.parts import LatticeParts, lattice_parts
from jaxplan.lattice.state import PlanState
from jaxplan.types import Trajectory, pytree_dataclass

CHUNK_POINTS = 1 << 12  # at most this many candidate points per chunk of the generator (``chunk_profiles``)


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
    fields = lateral_paths(parts, profile, ref_at, parts.offsets[p][None], parts.S[g, p][None])
    return jax.tree_util.tree_map(lambda a: a[0], _trajectory(fields, parts.t))


def chunk_profiles(G: int, points: int) -> int:
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
        return lateral_paths(parts, profile, ref_at, parts.offsets, S_g)

    chunk = chunk_profiles(G, P * T)
    xs = (parts.profiles, parts.ref_at, parts.S)
    fields = lax.map(group, xs, batch_size=chunk) if chunk < G else jax.vmap(group)(xs)
    x, y, theta, kappa, speed, acc, ux, uy, l, dl = (o.reshape(N, T) for o in fields)
    traj = _trajectory((x, y, theta, kappa, speed, acc), t)
    per_g = lambda a: jnp.broadcast_to(jnp.asarray(a)[:, None], (G, P)).reshape(N)
    per_p = lambda a: jnp.broadcast_to(jnp.asarray(a)[None, :], (G, P)).reshape(N)
    Lw, O, Lt = config.lateral_grid
    Pl = Lw * O
    lat_p = lambda a: np.broadcast_to(np.asarray(a)[:, None], (Pl, Lt)).reshape(P)
    lane_ids, slots = lateral_ids(config)
    times = lateral_times(config)
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
