"""Planned trajectory points: point types, arc length, gear-shift split.

A plan is a ``jaxplan.types.Trajectory`` of ``N`` points with a boolean
``valid`` mask ``(N,)`` whose True entries form a prefix (fixed shapes under jit).
Point ``i`` is a *gear-shift point* when ``gear[i] != gear[i + 1]`` (both valid):
the car stops there and drives ``i -> i + 1`` in the new gear. Splitting at the
gear-shift points gives single-direction *sub-trajectories*; sub-trajectory
``k`` runs from index ``lo[k]`` to ``hi[k]`` inclusive, and consecutive ones
share their gear-shift point (``hi[k] == lo[k + 1]``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.types import Trajectory

# Point types (int codes).
NORMAL, START, END, GEAR_SHIFT, BRAKE_STOP, COLLISION = 0, 1, 2, 3, 4, 5
POINT_TYPE_NAMES = ("normal", "start", "end", "gear_shift", "brake_stop", "collision")


def last_valid_index(valid):
    """Index of the last True of a prefix mask ``(..., N)`` (0 when none). Returns ``(...)`` int32."""
    return jnp.maximum(jnp.sum(valid, axis=-1).astype(jnp.int32) - 1, 0)


def arc_length(xy, valid):
    """Unsigned cumulative path length ``(..., N)``, 0 at the first point.

    Invalid (padding) points repeat the last valid value.

    Args:
        xy: ``(..., N, 2)``; valid: ``(..., N)`` prefix mask.
    """
    d = jnp.linalg.norm(xy[..., 1:, :] - xy[..., :-1, :], axis=-1)
    d = jnp.where(valid[..., 1:], d, 0.0)
    return jnp.concatenate([jnp.zeros_like(d[..., :1]), jnp.cumsum(d, axis=-1)], axis=-1)


def gear_shift_points(gear, valid):
    """Gear-shift mask ``(..., N)``: ``gear[i] != gear[i+1]`` with both points valid."""
    shift = (gear[..., :-1] != gear[..., 1:]) & valid[..., :-1] & valid[..., 1:]
    return jnp.concatenate([shift, jnp.zeros_like(shift[..., :1])], axis=-1)


def sub_trajectories(gear, valid, max_sub: int = 8):
    """Bounds of the single-direction sub-trajectories of one plan.

    Args:
        gear: ``(N,)`` +1 forward / -1 reverse (the gear used to reach each point).
        valid: ``(N,)`` prefix mask.
        max_sub: static bound on the number of sub-trajectories.

    Returns:
        (lo ``(max_sub,)``, hi ``(max_sub,)``, direction ``(max_sub,)`` in {+1, -1},
        count ``()``). Entries ``k >= count`` repeat the last point.
    """
    n = gear.shape[-1]
    last = last_valid_index(valid)
    shift = gear_shift_points(gear, valid)
    (idx,) = jnp.nonzero(shift, size=max_sub - 1, fill_value=last)
    idx = idx.astype(jnp.int32)
    lo = jnp.concatenate([jnp.zeros((1,), jnp.int32), idx])
    hi = jnp.concatenate([idx, last[None]])
    count = jnp.minimum(jnp.sum(shift).astype(jnp.int32) + 1, max_sub)
    # Direction of sub-trajectory k: the gear of its first motion, lo -> lo + 1.
    direction = gear[jnp.minimum(lo + 1, n - 1)]
    direction = jnp.where(hi > lo, direction, gear[lo])
    return lo, hi, jnp.sign(direction).astype(jnp.int32), count


def point_types(gear, valid, brake_idx=-1, collision_idx=-1):
    """Type code of every plan point ``(N,)`` (see the module constants).

    Start and end come first, then gear shifts; a brake-stop or collision
    index ``>= 0`` marks that point (collision wins over brake stop).
    """
    n = gear.shape[-1]
    i = jnp.arange(n)
    t = jnp.where(gear_shift_points(gear, valid), GEAR_SHIFT, NORMAL)
    t = jnp.where(i == last_valid_index(valid), END, t)
    t = jnp.where(i == 0, START, t)
    t = jnp.where(i == brake_idx, BRAKE_STOP, t)
    t = jnp.where(i == collision_idx, COLLISION, t)
    return jnp.where(valid, t, NORMAL)


def index_at_s(s_path, s):
    """Largest point index whose arc length is ``<= s`` (clipped to ``[0, N-1]``)."""
    return jnp.clip(jnp.searchsorted(s_path, s, side="right") - 1, 0, s_path.shape[-1] - 1).astype(jnp.int32)


def interpolate_pose(xy, theta, s_path, s):
    """Pose ``(x, y, heading)`` at arc length ``s`` on a piecewise-linear plan.

    Args:
        xy: ``(N, 2)``; theta: ``(N,)``; s_path: ``(N,)`` non-decreasing; s: ``()``.

    Returns:
        (xy ``(2,)``, heading ``()``, segment index ``()``).
    """
    n = s_path.shape[-1]
    j = jnp.clip(index_at_s(s_path, s), 0, n - 2)
    ds = s_path[j + 1] - s_path[j]
    u = jnp.where(ds > 1e-9, jnp.clip((s - s_path[j]) / jnp.where(ds > 1e-9, ds, 1.0), 0.0, 1.0), 0.0)
    p = xy[j] + u * (xy[j + 1] - xy[j])
    dth = jnp.arctan2(jnp.sin(theta[j + 1] - theta[j]), jnp.cos(theta[j + 1] - theta[j]))
    return p, theta[j] + u * dth, j


def split_at_gear_shifts(traj: Trajectory, valid=None) -> list[Trajectory]:
    """Host-side split of one plan ``(N,)`` into single-direction sub-trajectories.

    Each piece keeps its points in order; neighbouring pieces share the gear-shift point.
    """
    x = np.asarray(traj.x)
    if x.ndim != 1:
        raise ValueError(f"split_at_gear_shifts: expects one plan with fields (N,), got {x.shape}")
    valid = np.ones(x.shape, bool) if valid is None else np.asarray(valid, bool)
    k = int(valid.sum())
    if k == 0 or not valid[:k].all():
        raise ValueError("split_at_gear_shifts: valid must be a non-empty prefix mask")
    gear = np.asarray(traj.gear)[:k]
    cuts = [i for i in range(k - 1) if gear[i] != gear[i + 1]]
    bounds = list(zip([0] + cuts, cuts + [k - 1]))
    fields = {f: np.asarray(getattr(traj, f)) for f in ("x", "y", "theta", "kappa", "v", "a", "t", "s", "gear")}
    return [Trajectory(**{f: a[lo : hi + 1] for f, a in fields.items()}) for lo, hi in bounds]


sub_trajectories_jit = jax.jit(sub_trajectories, static_argnames="max_sub")
