"""Obstacle-free cost-to-go of the park-out goal, the search's heuristic.

Without obstacles the park-out goal (``y >= d``, heading level with the road)
does not depend on ``x``, so the shortest driving distance to it is a function
of the lateral offset ``y`` and the heading alone. It is computed once per car
and config by value iteration on a ``(y, heading)`` lattice (host side, numpy):
moves are arcs of ``step`` metres at the search's steering levels, forward or
backward, and the value is interpolated bilinearly between lattice points.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxplan.parking.config import ParkoutConfig


class CostToGo(NamedTuple):
    """``value (Ny, Nth)`` metres on ``y = y0 + i dy``, ``heading = -pi + j dth`` (periodic)."""

    value: np.ndarray
    y0: float
    dy: float
    dth: float


def _interp(v, y0, dy, dth, y, th):
    """Bilinear look-up (numpy or jax arrays): clamped in ``y``, periodic in heading."""
    xp = jnp if isinstance(v, jnp.ndarray) else np
    ny, nt = v.shape
    fy = xp.clip((y - y0) / dy, 0.0, ny - 1.000001)
    ft = xp.mod(th + np.pi, 2 * np.pi) / dth
    iy = xp.floor(fy).astype(xp.int32)
    it = xp.floor(ft).astype(xp.int32) % nt
    wy, wt = fy - iy, ft - xp.floor(ft)
    it1 = (it + 1) % nt
    a = v[iy, it] * (1 - wt) + v[iy, it1] * wt
    b = v[iy + 1, it] * (1 - wt) + v[iy + 1, it1] * wt
    return a * (1 - wy) + b * wy


@functools.lru_cache(maxsize=8)
def _table(wheelbase, max_steer, d, out_heading, out_tol, levels, step, dy, nth, y_lo, y_hi, iters):
    ys = np.arange(y_lo, y_hi + 1e-9, dy)
    dth = 2 * np.pi / nth
    th = -np.pi + dth * np.arange(nth)
    Y, TH = np.meshgrid(ys, th, indexing="ij")
    goal = (Y >= d) & (np.abs(np.angle(np.exp(1j * (TH - out_heading)))) < out_tol)
    big = 1e3
    v = np.where(goal, 0.0, big)
    kap = np.tan(np.asarray(levels) * max_steer) / wheelbase
    nxt = []
    for k in kap:
        for g in (1.0, -1.0):
            s = g * step
            th1 = TH + k * s
            if abs(k) < 1e-9:
                y1 = Y + s * np.sin(TH)
            else:
                y1 = Y - (np.cos(th1) - np.cos(TH)) / k
            nxt.append((y1, th1))
    for _ in range(iters):
        best = np.full_like(v, big)
        for y1, th1 in nxt:
            cand = step + _interp(v, y_lo, dy, dth, y1, th1)
            cand = np.where(y1 < y_lo, big, cand)
            best = np.minimum(best, cand)
        new = np.where(goal, 0.0, np.minimum(best, big))
        if np.max(np.abs(new - v)) < 1e-6:
            v = new
            break
        v = new
    return v.astype(np.float32), float(y_lo), float(dy), float(dth)


def cost_to_go(vehicle, config: ParkoutConfig, step: float = 0.3, dy: float = 0.1, nth: int = 120) -> CostToGo:
    """The obstacle-free cost-to-go table of ``vehicle`` under ``config`` (cached per car and config)."""
    from jaxplan.parking.circles import stop_line

    d = float(np.max(stop_line(vehicle, config.c)))
    y_lo, y_hi = config.y_min, config.y_min + config.rows * config.cell
    v, y0, ddy, dth = _table(
        float(np.min(vehicle.wheelbase)),
        float(np.min(vehicle.max_steer)),
        d,
        config.out_heading,
        config.out_tol,
        tuple(config.steer_levels),
        step,
        dy,
        nth,
        y_lo,
        y_hi,
        400,
    )
    return CostToGo(v, y0, ddy, dth)


def lookup(table: CostToGo, pose):
    """Cost-to-go ``(...)`` at poses ``(..., 3)`` (jittable; the table is a constant)."""
    v = jnp.asarray(table.value)
    return _interp(v, table.y0, table.dy, table.dth, pose[..., 1], pose[..., 2])
