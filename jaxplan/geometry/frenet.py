"""Reference line and Frenet frame (s along the line, l to its left).

The line is a polyline: positions move along the chords, the heading is
interpolated linearly in arc length between vertex headings (the mean of the
adjoining chords), so the normal turns continuously and the Frenet map has a
unique inverse wherever ``1 - kappa * l > 0``. Beyond both ends the line is
extended straight along its end headings.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from jaxplan.types import check_finite, check_trailing


def _count_index(knots, s):
    """``searchsorted(knots (n,), s (...), side="right")`` by counting the knots at or below each
    query, the knots on a leading axis: one fused kernel and no reduction over a small trailing
    axis (XLA's CPU backend runs bisection as a loop of small kernels, and reductions over small
    trailing axes slowly). For lookups of few points or on short lines."""
    return jnp.sum((knots.reshape((-1,) + (1,) * s.ndim) <= s[None]).astype(jnp.int32), 0)


# Points closer than this (m) to the previous one are dropped.
MIN_SPACING = 1e-3
# Consecutive segments may turn by at most 120 degrees (a cusp has no Frenet frame).
MAX_TURN_COS = -0.5


def wrap_angle(a: Float[ArrayLike, " ..."]) -> Float[Array, " ..."]:
    """Angles wrapped to (-pi, pi]."""
    return jnp.arctan2(jnp.sin(a), jnp.cos(a))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ReferenceLine:
    """A reference line sampled at N >= 2 distinct points.

    Attributes:
        xy: ``(N, 2)`` vertices.
        s: ``(N,)`` arc length at the vertices (chord lengths summed), s[0] = 0.
        theta: ``(N,)`` unwrapped vertex headings.
        kappa: ``(N,)`` vertex curvatures (d theta / d s).
    """

    xy: Float[Any, "N 2"]
    s: Float[Any, " N"]
    theta: Float[Any, " N"]
    kappa: Float[Any, " N"]

    @property
    def length(self):
        return self.s[-1]

    @classmethod
    def from_polyline(cls, xy: Float[ArrayLike, "N 2"]) -> ReferenceLine:
        """Host-side constructor: checks the input and drops repeated points.

        Args:
            xy: ``(N, 2)`` finite points, at least two distinct.
        """
        a = check_trailing("reference line", xy, (2,), coords=2)
        if a.ndim != 2:
            raise ValueError(f"reference line: expected shape (N, 2), got {a.shape}")
        if len(a):  # drop points within MIN_SPACING of the previous kept point
            keep = [0]
            for i in range(1, len(a)):
                if np.linalg.norm(a[i] - a[keep[-1]]) > MIN_SPACING:
                    keep.append(i)
            a = a[keep]
        if len(a) < 2:
            raise ValueError("reference line: needs at least two distinct points")
        check_turns(a)
        return reference_line(jnp.asarray(a, dtype=jnp.result_type(float)))

    def validate(self) -> ReferenceLine:
        """Host-side check of a line built by the jittable ``reference_line`` (any leading batch dims).

        Refuses NaN / inf, fewer than two points, repeated points (a zero-length segment has
        no heading: ``ReferenceLine.from_polyline`` drops them), lines that turn back on
        themselves, coordinates too far from the origin for float32, and fields that disagree.
        """
        xy = check_trailing("reference line", self.xy, (2,), coords=2)
        if xy.ndim < 2 or xy.shape[-2] < 2:
            raise ValueError(f"reference line: expected shape (..., N, 2) with N >= 2, got {xy.shape}")
        seg = np.linalg.norm(np.diff(xy, axis=-2), axis=-1)
        if np.any(seg <= 0):
            i = int(np.argwhere(seg <= 0)[0, -1])
            raise ValueError(
                f"reference line: points {i} and {i + 1} coincide (a repeated point has no heading); "
                f"build it with ReferenceLine.from_polyline, which drops repeated points"
            )
        for name in ("s", "theta", "kappa"):
            a = check_finite(f"reference line {name}", getattr(self, name))
            if a.shape != xy.shape[:-1]:
                raise ValueError(f"reference line: {name} has shape {a.shape}, xy has {xy.shape}")
        check_turns(xy)
        return self


def check_turns(a: np.ndarray) -> None:
    """Refuse consecutive segments of ``a (..., N, 2)`` that turn by more than ``MAX_TURN_COS``."""
    d = np.diff(a, axis=-2)
    n = np.linalg.norm(d, axis=-1)
    cos_turn = np.sum(d[..., 1:, :] * d[..., :-1, :], axis=-1) / np.maximum(n[..., 1:] * n[..., :-1], 1e-300)
    bad = cos_turn < MAX_TURN_COS
    if np.any(bad):
        i = int(np.argwhere(bad)[0, -1]) + 1
        raise ValueError(
            f"reference line: turns back on itself at point {i} "
            f"(more than {np.degrees(np.arccos(MAX_TURN_COS)):.0f} degrees between segments)"
        )


@jax.jit
def reference_line(xy: Float[ArrayLike, "N 2"]) -> ReferenceLine:
    """Jittable constructor from ``(N, 2)`` distinct points (see ``ReferenceLine.from_polyline``).
    Jitted: called eagerly it is one compiled program per shape, not one per operation."""
    xy = jnp.asarray(xy)
    d = xy[1:] - xy[:-1]
    seg = jnp.linalg.norm(d, axis=-1)
    s = jnp.concatenate([jnp.zeros((1,), xy.dtype), jnp.cumsum(seg)])
    phi = jnp.unwrap(jnp.arctan2(d[:, 1], d[:, 0]))
    theta = jnp.concatenate([phi[:1], 0.5 * (phi[1:] + phi[:-1]), phi[-1:]])
    rate = (theta[1:] - theta[:-1]) / seg  # (N-1,) curvature on each segment
    kappa = jnp.concatenate([rate[:1], 0.5 * (rate[1:] + rate[:-1]), rate[-1:]])
    return ReferenceLine(xy, s, theta, kappa)


@jax.jit
def ref_state(
    ref: ReferenceLine, s: Float[ArrayLike, " ..."]
) -> tuple[Float[Array, "... 2"], Float[Array, " ..."], Float[Array, " ..."], Float[Array, " ..."]]:
    """Position, heading, curvature and its derivative of the line at arc length ``s``.

    Args:
        s: ``(...)``.

    Returns:
        (xy ``(..., 2)``, theta ``(...)`` unwrapped, kappa ``(...)``, dkappa ``(...)``).
    """
    s = jnp.asarray(s, ref.xy.dtype)
    x, y, theta, kappa, i = _line_state(ref, s, jnp.searchsorted(ref.s, s, side="right"))
    inside = (s >= ref.s[0]) & (s <= ref.s[-1])
    dkappa = jnp.where(inside, (ref.kappa[i + 1] - ref.kappa[i]) / (ref.s[i + 1] - ref.s[i]), 0.0)
    xy = jnp.stack([x, y], axis=-1)
    return xy, theta, kappa, dkappa


def _unit(theta):
    return jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)


def to_cartesian(ref: ReferenceLine, s: Float[ArrayLike, " ..."], l: Float[ArrayLike, " ..."]) -> Float[Array, "... 2"]:
    """Frenet ``(s, l)`` (each ``(...)``) to Cartesian ``(..., 2)``."""
    xy, theta, _, _ = ref_state(ref, s)
    nrm = _unit(theta + 0.5 * jnp.pi)
    return xy + jnp.asarray(l, xy.dtype)[..., None] * nrm


def _line_state(ref: ReferenceLine, s, right=None):
    """Position ``x, y``, heading and curvature of the line at arc lengths ``s (...)``, in
    components, and the chord index ``i``. ``right``: ``searchsorted(ref.s, s, side="right")``
    if already found (else ``_count_index``)."""
    n = ref.s.shape[0]
    i = jnp.clip((_count_index(ref.s, s) if right is None else right) - 1, 0, n - 2)
    s0 = ref.s[i]
    seg = ref.s[i + 1] - s0
    u = s - s0
    x0, y0 = ref.xy[i, 0], ref.xy[i, 1]
    x = x0 + u * ((ref.xy[i + 1, 0] - x0) / seg)
    y = y0 + u * ((ref.xy[i + 1, 1] - y0) / seg)
    inside = (s >= ref.s[0]) & (s <= ref.s[-1])
    f = jnp.clip(u / seg, 0.0, 1.0)
    theta = ref.theta[i] + f * (ref.theta[i + 1] - ref.theta[i])
    kappa = jnp.where(inside, ref.kappa[i] + f * (ref.kappa[i + 1] - ref.kappa[i]), 0.0)
    theta = jnp.where(inside, theta, jnp.where(s < ref.s[0], ref.theta[0], ref.theta[-1]))
    return x, y, theta, kappa, i


@functools.partial(jax.jit, static_argnames=("newton_steps",))
def frenet_points(ref: ReferenceLine, px, py, newton_steps: int = 4):
    """``to_frenet`` of points ``(px, py)`` ``(...)`` given as components, with the line's
    heading and curvature there: ``(s, l, theta, kappa)`` ``(...)``.

    The nearest chord gives a first guess; Newton steps on ``<p - pos(s), tangent(s)> = 0``
    make it the exact inverse of ``to_cartesian`` (the end chords extend the line). Written in
    components with the chords on a leading axis: XLA's CPU backend runs reductions over
    small trailing axes (2, or the chord count) slowly (several times faster on the speed
    planner's 720 boxes a plan; about 0.06 ms less for the lattice's one point on 600 chords)."""
    ax, ay = ref.xy[:-1, 0], ref.xy[:-1, 1]
    dx, dy = ref.xy[1:, 0] - ax, ref.xy[1:, 1] - ay
    seg = ref.s[1:] - ref.s[:-1]
    e = (slice(None),) + (None,) * px.ndim
    rx, ry = px[None] - ax[e], py[None] - ay[e]
    t = (rx * dx[e] + ry * dy[e]) / (seg * seg)[e]  # (N - 1, ...)
    tc = jnp.clip(t, 0.0, 1.0)
    qx, qy = rx - tc * dx[e], ry - tc * dy[e]
    i = jnp.argmin(jnp.sqrt(qx * qx + qy * qy), axis=0)
    nseg = seg.shape[0]
    ti = jnp.take_along_axis(t, i[None], axis=0)[0]
    ti = jnp.clip(ti, jnp.where(i == 0, -jnp.inf, 0.0), jnp.where(i == nseg - 1, jnp.inf, 1.0))
    s = ref.s[i] + ti * seg[i]
    max_step = jnp.max(seg)

    def newton(_, s):
        x, y, theta, kappa, j = _line_state(ref, s)
        tx, ty = jnp.cos(theta), jnp.sin(theta)
        wx, wy = px - x, py - y
        fp = -((dx[j] / seg[j]) * tx + (dy[j] / seg[j]) * ty) + kappa * (tx * wy - ty * wx)
        fp = jnp.where(fp < -0.05, fp, -0.05)
        return s - jnp.clip((wx * tx + wy * ty) / fp, -max_step, max_step)

    # a loop, not unrolled: each step's s is materialised (unrolled, XLA fuses every step
    # into each use of the next and recomputes them many times over)
    s = jax.lax.fori_loop(0, newton_steps, newton, s)
    x, y, theta, kappa, _ = _line_state(ref, s)
    return s, jnp.cos(theta) * (py - y) - jnp.sin(theta) * (px - x), theta, kappa


def to_frenet(
    ref: ReferenceLine, xy: Float[ArrayLike, "... 2"], newton_steps: int = 4
) -> tuple[Float[Array, " ..."], Float[Array, " ..."]]:
    """Cartesian points ``(..., 2)`` to Frenet ``(s, l)``, each ``(...)`` (``frenet_points``), in the
    line's float type as JAX runs it (float32 for a host-side float64 line unless x64 is on)."""
    p = jnp.asarray(xy, jax.dtypes.canonicalize_dtype(ref.xy.dtype))
    s, l, _, _ = frenet_points(ref, p[..., 0], p[..., 1], newton_steps)
    return s, l


def frenet_to_cartesian_state(
    ref: ReferenceLine,
    s: Float[ArrayLike, " ..."],
    l: Float[ArrayLike, " ..."],
    dl: Float[ArrayLike, " ..."],
    ddl: Float[ArrayLike, " ..."],
) -> tuple[Float[Array, "... 2"], Float[Array, " ..."], Float[Array, " ..."]]:
    """A Frenet curve l(s) with derivatives to Cartesian position, heading, curvature.

    Args:
        s, l, dl, ddl: ``(...)`` arc length, offset, dl/ds, d2l/ds2.

    Returns:
        (xy ``(..., 2)``, theta ``(...)`` wrapped, kappa ``(...)``).
    """
    pos, theta_r, kr, dkr = ref_state(ref, s)
    xy = pos + jnp.asarray(l, pos.dtype)[..., None] * _unit(theta_r + 0.5 * jnp.pi)
    one = 1.0 - kr * l
    dtheta = jnp.arctan2(dl, one)
    cos_d = jnp.cos(dtheta)
    tan_d = jnp.tan(dtheta)
    kappa = ((ddl + (dkr * l + kr * dl) * tan_d) * cos_d**2 / one + kr) * cos_d / one
    return xy, wrap_angle(theta_r + dtheta), kappa
