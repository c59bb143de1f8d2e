"""The lateral half of the lattice: the targets every speed profile is combined with, and the paths to them.

The lateral targets are the lateral lanes (``config.lanes``, then the hold and goal targets when
switched on) x offsets about each lane's centre x lateral times (``lateral_times``), in that order.

Each speed profile gives the distance ``s(t)`` along the reference line; the lateral path ``l(s)``
is a quintic reaching its offset after ``S`` metres (``LatticeParts.S``: ``max(s(t_lat), s_min)``,
where ``t_lat`` is ``lateral_time``, or the horizon when it is 0) and holding it after.
``lateral_paths`` turns the paths into Cartesian samples: positions, headings (unwrapped) and
curvatures follow ``frenet_to_cartesian_state``'s formulas, from the reference line evaluated once
per speed profile and shared by every lateral offset. The Cartesian speed is
``ds/dt * sqrt((1 - kappa_r l)^2 + l'^2)`` and the acceleration its exact time derivative.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.quintic import quintic_coeffs, quintic_eval
from jaxplan.lattice.config import LatticeConfig

if TYPE_CHECKING:
    from jaxplan.lattice.parts import LatticeParts


def lateral_times(config: LatticeConfig) -> tuple:
    """The times (s) by which the lateral offsets are reached: ``config.lateral_times``, else
    ``(config.lateral_time,)`` (0: the horizon)."""
    return config.lateral_times or (config.lateral_time,)


def lateral_targets(config: LatticeConfig, targets, l0, dtype):
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


def lateral_ids(config: LatticeConfig):
    """Static lane ids and lateral-lane slots ``(Pl,)`` of the lateral targets (numpy)."""
    from jaxplan.lattice.targets import GOAL_LANE, HOLD_LANE

    Lw, O, _ = config.lateral_grid
    ids = list(config.lanes) + [HOLD_LANE] * config.hold_offset + [GOAL_LANE] * config.goal_offset
    return np.repeat(np.asarray(ids), O), np.repeat(np.arange(Lw), O)


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


def lateral_paths(parts: LatticeParts, profile, ref_at, offsets, S):
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
