"""Lines in vector form: a point ``p (..., 2)`` and a direction ``d (..., 2)``.

Never slope form, so vertical lines need no special case. Parallel lines are
reported through a ``valid`` flag instead of producing inf.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


def cross2(u: Float[Array, "... 2"], v: Float[Array, "... 2"]) -> Float[Array, " ..."]:
    """z-component of the cross product of ``(..., 2)`` vectors. Returns ``(...)``."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def dot2(u: Float[Array, "... 2"], v: Float[Array, "... 2"]) -> Float[Array, " ..."]:
    """Dot product of ``(..., 2)`` vectors. Returns ``(...)``."""
    return jnp.sum(u * v, axis=-1)


def safe_sqrt(x: Float[Array, " ..."]) -> Float[Array, " ..."]:
    """``sqrt(max(x, 0))`` with a finite gradient everywhere (0 at and below 0).

    The plain form has an infinite derivative at 0, and ``0 * inf = NaN`` poisons every
    gradient that flows through it; the inner ``where`` keeps the square root away from
    0 (the double-``where`` trick), the outer one gives the exact value.
    """
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def safe_norm(d: Float[Array, " ..."], axis=-1, keepdims=False) -> Float[Array, " ..."]:
    """Euclidean norm of ``d`` along ``axis`` with a finite gradient at the zero vector (0 there)."""
    return safe_sqrt(jnp.sum(d * d, axis=axis, keepdims=keepdims))


def normalize(d: Float[Array, "... 2"], eps=1e-12) -> Float[Array, "... 2"]:
    """Unit vectors ``(..., 2)``; a zero vector stays zero."""
    n = jnp.linalg.norm(d, axis=-1, keepdims=True)
    return d / jnp.where(n > eps, n, 1.0)


def perpendicular(d: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
    """``d`` rotated by +90 degrees (to the left). ``(..., 2)``."""
    return jnp.stack([-d[..., 1], d[..., 0]], axis=-1)


def line_intersection(
    p1: Float[Array, "... 2"],
    d1: Float[Array, "... 2"],
    p2: Float[Array, "... 2"],
    d2: Float[Array, "... 2"],
    rel_eps=1e-9,
) -> tuple[Float[Array, "... 2"], Float[Array, " ..."], Float[Array, " ..."], Bool[Array, " ..."]]:
    """Intersection of the lines ``p1 + t1 d1`` and ``p2 + t2 d2``.

    Args:
        p1, d1, p2, d2: ``(..., 2)``.

    Returns:
        (point ``(..., 2)``, t1 ``(...)``, t2 ``(...)``, valid ``(...)``); valid is
        False for parallel lines or a zero direction, and then the point is ``p1``.
    """
    den = cross2(d1, d2)
    scale = jnp.linalg.norm(d1, axis=-1) * jnp.linalg.norm(d2, axis=-1)
    valid = jnp.abs(den) > rel_eps * scale
    safe = jnp.where(valid, den, 1.0)
    w = p2 - p1
    t1 = jnp.where(valid, cross2(w, d2) / safe, 0.0)
    t2 = jnp.where(valid, cross2(w, d1) / safe, 0.0)
    return p1 + t1[..., None] * d1, t1, t2, valid


def project_point(
    p: Float[Array, "... 2"], a: Float[Array, "... 2"], d: Float[Array, "... 2"]
) -> tuple[Float[Array, " ..."], Float[Array, "... 2"]]:
    """Orthogonal projection of ``p`` on the line ``a + t d``.

    Returns:
        (t ``(...)`` in units of ``d``, foot point ``(..., 2)``); t = 0 for a zero ``d``.
    """
    dd = dot2(d, d)
    t = jnp.where(dd > 0, dot2(p - a, d) / jnp.where(dd > 0, dd, 1.0), 0.0)
    return t, a + t[..., None] * d


def point_on_segment(
    p: Float[Array, "... 2"], a: Float[Array, "... 2"], b: Float[Array, "... 2"], tol=1e-6
) -> Bool[Array, " ..."]:
    """Whether ``p`` lies on the segment ``a-b`` within distance ``tol``.

    A zero-length segment is its single point. Returns ``(...)`` bool.
    """
    t, foot = project_point(p, a, b - a)
    length = jnp.linalg.norm(b - a, axis=-1)
    slack = tol / jnp.maximum(length, tol)
    near = jnp.linalg.norm(p - foot, axis=-1) <= tol
    return near & (t >= -slack) & (t <= 1 + slack)


def segment_point_distance(
    p: Float[Array, "... 2"], a: Float[Array, "... 2"], b: Float[Array, "... 2"]
) -> Float[Array, " ..."]:
    """Distance from ``p`` to the segment ``a-b`` (``(...)``); works for zero length."""
    t, _ = project_point(p, a, b - a)
    foot = a + jnp.clip(t, 0.0, 1.0)[..., None] * (b - a)
    return jnp.linalg.norm(p - foot, axis=-1)
