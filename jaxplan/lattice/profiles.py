"""Longitudinal velocity profiles from (v0, a0) to an end speed, in closed form.

Both profiles are piecewise polynomials in t, evaluated without loops:
for segments i with start time ``T_i``, duration ``d_i``, start speed ``v_i``,
start acceleration ``a_i`` and jerk ``j_i``, with ``tau_i = clip(t - T_i, 0, d_i)``,

    s(t) = sum_i v_i tau_i + a_i tau_i^2 / 2 + j_i tau_i^3 / 6,

which is exact for every t because completed segments contribute their full
length and later ones contribute nothing.

(a) ``accel_profile``: one constant acceleration ``a = clip((v_end - v0) / t_reach,
a_min, a_max)`` until ``v_end`` is reached, then ``v_end`` held (the three cases
speed up / slow down / keep). ``a(0)`` is that constant, not ``a0``. Where the
clip binds, ``v_end`` is reached after ``t_reach`` (or not within the horizon).

(b) ``jerk_profile``: acceleration ramps with jerk ``+-J`` from ``a0`` to a peak
``a_p`` (capped at ``a_max`` / ``a_min``), holds it, and ramps back to 0 at
``t_end``; then ``v_end`` is held. Derivation, with ``sigma`` the direction of the
peak and primes denoting the mirrored problem (``x' = sigma x``): ramping
``a0' -> a_p -> 0`` changes the speed by ``(a_p^2 - a0'^2) / (2J) + a_p^2 / (2J)``,
so without the cap ``a_p = sqrt((2 J dv' + a0'^2) / 2)``; ``sigma = +1`` exactly when
``dv >= a0 |a0| / (2J)`` (the speed change of ramping ``a0`` straight to 0), which
makes ``a_p >= max(a0', 0)``. With the cap ``A`` the plateau lasts
``(dv' - dv1 - dv3) / A``. Then ``a(0) = a0``, ``a(t_end) = 0``, ``v(t_end) = v_end``
and ``v, a`` are continuous. Not feasible: if ``|a0|`` already exceeds the cap in
the peak's direction and ramping back overshoots ``dv``, the plateau is clamped to 0
and ``v_end`` is overshot (``v(t_end) != v_end``); ``t_end`` may exceed the horizon,
then ``v_end`` is not reached inside it. Speeds are clamped at 0 (a car does not
reverse): where braking at ``a0 < 0`` would reverse the car before the ramp
back to 0 ends (``a0^2 / (2J) > v0``), ``a0`` is raised to ``-sqrt(2 J v0)``, so then
``a(0) != a0``; with that, ``v >= 0`` holds exactly and the clamp only removes rounding.

All functions broadcast: ``v0, a0, v_end`` are ``(...)``, ``t`` is ``(..., T)``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

from jaxplan.geometry.lines import safe_sqrt


def eval_segments(t, v_start, a_start, jerks, durations, v_hold):
    """Evaluate piecewise-constant-jerk segments followed by a hold at ``v_hold``.

    Args:
        t: ``(..., T)``.
        v_start, a_start, jerks, durations: lists of ``(...)`` per segment.
        v_hold: ``(...)`` speed after the last segment.

    Returns:
        (s, v, a) each ``(..., T)``.
    """
    s = jnp.zeros_like(t)
    v = jnp.zeros_like(t)
    a = jnp.zeros_like(t)
    start = jnp.zeros_like(v_hold)
    for vi, ai, ji, di in zip(v_start, a_start, jerks, durations):
        vi, ai, ji, di, T0 = (x[..., None] for x in (vi, ai, ji, di, start))
        tau = jnp.clip(t - T0, 0.0, di)
        inside = (t >= T0) & (t < T0 + di)
        s = s + vi * tau + 0.5 * ai * tau**2 + ji * tau**3 / 6.0
        v = jnp.where(inside, vi + ai * tau + 0.5 * ji * tau**2, v)
        a = jnp.where(inside, ai + ji * tau, a)
        start = start + di[..., 0]
    after = t >= start[..., None]
    s = s + v_hold[..., None] * jnp.maximum(t - start[..., None], 0.0)
    v = jnp.where(after, v_hold[..., None], v)
    a = jnp.where(after, 0.0, a)
    return s, v, a


def _no_reverse(s, v, a):
    """Clamp speeds at 0 and keep s from going back (``s`` becomes its running maximum)."""
    stopped = v < 0
    return lax.cummax(s, axis=s.ndim - 1), jnp.maximum(v, 0.0), jnp.where(stopped, 0.0, a)


def accel_profile(v0, v_end, t, a_min=-3.0, a_max=2.0, t_reach=None):
    """Constant-acceleration (three-case) profile.

    Args:
        v0, v_end: ``(...)`` start and end speeds (m/s), ``v_end >= 0``.
        t: ``(..., T)`` times from now (s).
        a_min, a_max: acceleration limits (a_min < 0 < a_max).
        t_reach: time to reach ``v_end`` before clipping; default the last ``t``.

    Returns:
        (s, v, a) each ``(..., T)``.
    """
    t = jnp.asarray(t)
    v0 = jnp.asarray(v0, t.dtype)
    v_end = jnp.asarray(v_end, t.dtype)
    if t_reach is None:
        t_reach = t[..., -1]
    dv = v_end - v0
    acc = jnp.clip(dv / jnp.maximum(t_reach, 1e-6), a_min, a_max)
    safe = jnp.where(acc == 0, 1.0, acc)
    t_hit = jnp.where(acc == 0, 0.0, dv / safe)
    shape = jnp.broadcast_shapes(v0.shape, v_end.shape, jnp.shape(acc))
    v0, acc, t_hit, v_end = (jnp.broadcast_to(x, shape) for x in (v0, acc, t_hit, v_end))
    s, v, a = eval_segments(t, [v0], [acc], [jnp.zeros_like(acc)], [t_hit], v_end)
    return _no_reverse(s, v, a)


def jerk_profile_params(v0, a0, v_end, jerk=2.0, a_min=-3.0, a_max=2.0):
    """Segment parameters of the constant-jerk profile.

    Returns:
        dict of ``(...)`` arrays: ``a0`` (as used, see the module docstring), ``a_peak``, ``j1``, ``j3`` (jerks of the ramps),
        ``t1``, ``t2``, ``t3`` (ramp up, plateau, ramp down), ``t_end = t1 + t2 + t3``.
    """
    v0, a0, v_end = jnp.broadcast_arrays(*(jnp.asarray(x, jnp.result_type(float)) for x in (v0, a0, v_end)))
    J = jnp.asarray(jerk, v0.dtype)
    a0 = jnp.maximum(a0, -safe_sqrt(2 * J * v0))
    dv = v_end - v0
    sigma = jnp.where(dv >= a0 * jnp.abs(a0) / (2 * J), 1.0, -1.0)
    a0p, dvp = sigma * a0, sigma * dv
    cap = jnp.where(sigma > 0, a_max, -a_min)
    ap_tri = safe_sqrt(0.5 * (2 * J * dvp + a0p**2))  # finite gradient at 0 (end speed = start speed)
    tri = ap_tri <= cap
    ap = jnp.where(tri, ap_tri, cap)
    sgn1 = jnp.where(ap >= a0p, 1.0, -1.0)
    t1 = jnp.abs(ap - a0p) / J
    dv1 = sgn1 * (ap**2 - a0p**2) / (2 * J)
    dv3 = ap**2 / (2 * J)
    t2 = jnp.where(tri, 0.0, jnp.maximum((dvp - dv1 - dv3) / jnp.maximum(ap, 1e-9), 0.0))
    t3 = ap / J
    return {
        "a0": a0,
        "a_peak": sigma * ap,
        "j1": sigma * sgn1 * J,
        "j3": -sigma * J,
        "t1": t1,
        "t2": t2,
        "t3": t3,
        "t_end": t1 + t2 + t3,
    }


def jerk_profile(v0, a0, v_end, t, jerk=2.0, a_min=-3.0, a_max=2.0):
    """Constant-jerk profile (see the module docstring).

    Args:
        v0, a0, v_end: ``(...)`` start speed, start acceleration, end speed.
        t: ``(..., T)`` times from now (s).
        jerk: ramp jerk magnitude ``J > 0`` (m/s^3).
        a_min, a_max: acceleration limits.

    Returns:
        (s, v, a) each ``(..., T)``.
    """
    t = jnp.asarray(t)
    p = jerk_profile_params(v0, a0, v_end, jerk, a_min, a_max)
    v0 = jnp.broadcast_to(jnp.asarray(v0, t.dtype), p["t1"].shape)
    a0 = p["a0"].astype(t.dtype)
    ap = p["a_peak"]
    v1 = v0 + a0 * p["t1"] + 0.5 * p["j1"] * p["t1"] ** 2
    v2 = v1 + ap * p["t2"]
    v3 = v2 + ap * p["t3"] + 0.5 * p["j3"] * p["t3"] ** 2
    zero = jnp.zeros_like(ap)
    s, v, a = eval_segments(t, [v0, v1, v2], [a0, ap, ap], [p["j1"], zero, p["j3"]], [p["t1"], p["t2"], p["t3"]], v3)
    return _no_reverse(s, v, a)
