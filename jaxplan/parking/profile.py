"""Speed profile of each park-out move: start and end at standstill, accelerate and brake at
``config.accel``, cruise at ``v_forward`` / ``v_reverse``, and slow down where the steering changes fast.

Between moves the car stands still while it turns the wheels to the next move's
first steering angle at ``config.steer_speed``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from jaxplan.parking.config import ParkoutConfig


def move_speeds(steer, valid, gear, config: ParkoutConfig):
    """Unsigned speed ``(..., T)`` at each point of one move (0 at its first and last valid point).

    Args:
        steer: ``(..., T)`` steering angle leaving each point [rad].
        valid: ``(..., T)`` the driven points (a prefix), ``dl`` apart.
        gear: ``(...)`` +1 / -1 (0: not driven).

    The cap at a point is the cruise speed, and ``steer_speed * dl / |steering
    change to the next point|``; a forward and a backward pass then keep
    ``v^2`` within ``2 accel dl`` of its neighbours.
    """
    dl, a2 = config.dl, 2.0 * config.accel * config.dl
    n = jnp.sum(valid, -1)
    vmax = jnp.where(gear < 0, config.v_reverse, config.v_forward)
    dsteer = jnp.abs(jnp.diff(steer, axis=-1, append=steer[..., -1:]))
    cap = jnp.minimum(vmax[..., None], config.steer_speed * dl / jnp.maximum(dsteer, 1e-9))
    k = jnp.arange(steer.shape[-1])
    cap = jnp.where((k == 0) | (k >= n[..., None] - 1), 0.0, cap)
    cap2 = jnp.moveaxis(cap * cap, -1, 0)

    def fwd(prev, c):
        v = jnp.minimum(c, prev + a2)
        return v, v

    def bwd(nxt, c):
        v = jnp.minimum(c, nxt + a2)
        return v, v

    _, f = lax.scan(fwd, jnp.zeros_like(cap2[0]), cap2)
    _, b = lax.scan(bwd, jnp.zeros_like(cap2[0]), f, reverse=True)
    return jnp.where(valid, jnp.sqrt(jnp.moveaxis(b, 0, -1)), 0.0)


def speed_profile(steer, valid, gear, config: ParkoutConfig):
    """Signed speed and time of every point of a park-out's moves.

    Args:
        steer: ``(..., M, T)``; valid: ``(..., M, T)``; gear: ``(..., M)`` (a
            ``ParkoutResult``'s fields).

    Returns:
        (v ``(..., M, T)`` signed by gear, t ``(..., M, T)`` seconds since the
        start, including the standstill steering between moves).
    """
    steer = jnp.asarray(steer)
    v = move_speeds(steer, valid, gear, config)
    dl = config.dl
    mean = 0.5 * (v[..., 1:] + v[..., :-1])
    seg = jnp.where(valid[..., 1:], dl / jnp.maximum(mean, 1e-3), 0.0)
    drive = jnp.concatenate([jnp.zeros_like(v[..., :1]), jnp.cumsum(seg, -1)], -1)  # (..., M, T) within a move
    n = jnp.sum(valid, -1)
    dur = jnp.take_along_axis(drive, jnp.maximum(n - 1, 0)[..., None], -1)[..., 0]  # (..., M)
    last = jnp.take_along_axis(steer, jnp.maximum(n - 1, 0)[..., None], -1)[..., 0]
    prev = jnp.concatenate([jnp.zeros_like(last[..., :1]), last[..., :-1]], -1)
    turn = jnp.where(n > 0, jnp.abs(steer[..., 0] - prev) / config.steer_speed, 0.0)
    start = jnp.cumsum(turn + dur, -1) - dur  # each move starts after the previous ones and its own wheel turn
    t = start[..., None] + drive
    return jnp.where(valid, gear[..., None] * v, 0.0), jnp.where(valid, t, 0.0)


speed_profile_jit = jax.jit(speed_profile, static_argnames=("config",))
