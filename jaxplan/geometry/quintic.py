"""Closed-form quintic lateral paths l(s) in the Frenet frame, and the Frenet state of a car pose.

A candidate path is ``l(s)`` for ``0 <= s <= S`` (s measured from the car along the
reference line), a 5th-degree polynomial from the car's ``(l0, l0', l0'')`` to
``(l1, l1', 0)`` at ``s = S`` (a lateral path ends with ``l1' = 0``; the lattice's longitudinal
quintic ``s(t)`` ends at a speed); beyond ``S`` a path keeps ``l = l1``. With
``h = l1 - (l0 + l0' S + l0'' S^2 / 2)``, ``h1 = l1' - (l0' + l0'' S)`` and ``h2 = -l0''``,

    c3 = (10 h - 4 h1 S + h2 S^2 / 2) / S^3
    c4 = (-15 h + 7 h1 S - h2 S^2) / S^4
    c5 = (6 h - 3 h1 S + h2 S^2 / 2) / S^5

(no linear solve).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from jaxplan.geometry.frenet import ReferenceLine, ref_state, to_frenet, wrap_angle


def quintic_coeffs(
    l0: Float[ArrayLike, " ..."],
    dl0: Float[ArrayLike, " ..."],
    ddl0: Float[ArrayLike, " ..."],
    l1: Float[ArrayLike, " ..."],
    S: Float[ArrayLike, " ..."],
    dl1: Float[ArrayLike, " ..."] | None = None,
) -> Float[Array, "... 6"]:
    """Coefficients ``(..., 6)`` (ascending powers of s) of the quintic from
    ``(l0, dl0, ddl0)`` at 0 to ``(l1, dl1, 0)`` at ``S`` (``dl1`` None: 0); all args ``(...)``,
    ``S > 0``."""
    l0, dl0, ddl0, l1, S = jnp.broadcast_arrays(
        *(jnp.asarray(x, jnp.result_type(float)) for x in (l0, dl0, ddl0, l1, S))
    )
    h = l1 - (l0 + dl0 * S + 0.5 * ddl0 * S**2)
    h1 = -(dl0 + ddl0 * S) if dl1 is None else jnp.asarray(dl1, h.dtype) - (dl0 + ddl0 * S)
    h2 = -ddl0
    c3 = (10 * h - 4 * h1 * S + 0.5 * h2 * S**2) / S**3
    c4 = (-15 * h + 7 * h1 * S - h2 * S**2) / S**4
    c5 = (6 * h - 3 * h1 * S + 0.5 * h2 * S**2) / S**5
    return jnp.stack([l0, dl0, 0.5 * ddl0, c3, c4, c5], axis=-1)


def quintic_eval(
    coeffs: Float[Array, "... 6"], S: Float[ArrayLike, " ..."], s: Float[ArrayLike, "... T"]
) -> tuple[Float[Array, "... T"], Float[Array, "... T"], Float[Array, "... T"]]:
    """``l, dl/ds, d2l/ds2`` at ``s`` ``(..., T)`` for coefficients ``(..., 6)`` and
    length ``S`` ``(...)``; for ``s >= S`` the end value with zero slope and curvature."""
    c = [coeffs[..., i, None] for i in range(6)]
    S = jnp.asarray(S)[..., None]
    x = jnp.clip(s, 0.0, S)
    l = c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * (c[4] + x * c[5]))))
    dl = c[1] + x * (2 * c[2] + x * (3 * c[3] + x * (4 * c[4] + x * 5 * c[5])))
    ddl = 2 * c[2] + x * (6 * c[3] + x * (12 * c[4] + x * 20 * c[5]))
    past = s >= S
    return l, jnp.where(past, 0.0, dl), jnp.where(past, 0.0, ddl)


def cartesian_to_frenet_state(
    ref: ReferenceLine,
    xy: Float[ArrayLike, "... 2"],
    theta: Float[ArrayLike, " ..."],
    kappa: Float[ArrayLike, " ..."],
    sl: tuple[Float[Array, " ..."], Float[Array, " ..."]] | None = None,
) -> tuple[Float[Array, " ..."], Float[Array, " ..."], Float[Array, " ..."], Float[Array, " ..."]]:
    """Frenet state ``(s, l, dl/ds, d2l/ds2)`` of a pose with curvature.

    Inverse of ``frenet_to_cartesian_state`` (valid where ``1 - kappa_r l > 0`` and the
    heading is within 90 degrees of the line).

    Args:
        xy: ``(..., 2)``; theta, kappa: ``(...)``.
        sl: optional ``(s, l)`` of ``xy`` already computed (``to_frenet``).

    Returns:
        (s, l, dl, ddl) each ``(...)``.
    """
    s, l = to_frenet(ref, xy) if sl is None else sl
    _, theta_r, kr, dkr = ref_state(ref, s)
    d = wrap_angle(jnp.asarray(theta) - theta_r)
    one = 1.0 - kr * l
    tan_d, cos_d = jnp.tan(d), jnp.cos(d)
    dl = one * tan_d
    ddl = -(dkr * l + kr * dl) * tan_d + one / cos_d**2 * (kappa * one / cos_d - kr)
    return s, l, dl, ddl
