"""Pytrees shared by every planner.

Array fields carry any number of leading batch dimensions. Each type has a
host-side ``validate()`` that raises ``ValueError`` with a clear message; call it
at the API boundary, before ``jax.jit``. The fields' annotations give their dtype
kind and shape (jaxtyping, e.g. ``Float[Any, "... K T 5"]``); their array type is
``Any``: JAX arrays, or numpy arrays on the host.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

REAR_AXLE = "rear_axle"
CENTER = "center"


if TYPE_CHECKING:
    from typing_extensions import dataclass_transform
else:

    def dataclass_transform(**_):
        return lambda f: f


@dataclass_transform(frozen_default=True)
def pytree_dataclass(data_fields, meta_fields=()):
    """Class decorator: a frozen dataclass registered as a JAX pytree whose ``data_fields`` are
    its leaves (traced under ``jit``) and ``meta_fields`` its static part."""

    def wrap(cls):
        cls = dataclasses.dataclass(frozen=True)(cls)
        return jax.tree_util.register_dataclass(cls, data_fields=list(data_fields), meta_fields=list(meta_fields))

    return wrap


def check_finite(name: str, x: Any) -> np.ndarray:
    """Host-side check: ``x`` is a real array with no NaN or inf."""
    a = np.asarray(x)
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name}: expected a numeric array, got dtype {a.dtype}")
    if a.size and not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or inf")
    return a


# Times within this fraction of a step of a time stamp take that stamp exactly (``Obstacles.at_times``).
SNAP = 1e-4

# Beyond this distance from the origin float32 keeps less than about 1 cm.
FLOAT32_MAX_COORD = 1e5


def check_coordinates(name: str, xy: np.ndarray) -> None:
    """Refuse coordinates too far from the origin for float32 (unless x64 is on)."""
    if xy.size and not jax.config.read("jax_enable_x64") and np.abs(xy).max() > FLOAT32_MAX_COORD:
        raise ValueError(
            f"{name}: coordinates up to {np.abs(xy).max():.3g} m are too far from the origin "
            f"for float32 (limit {FLOAT32_MAX_COORD:g} m); move the scene to a local frame "
            f"(the scenario loaders do) or enable jax_enable_x64"
        )


def check_trailing(name: str, x: Any, trailing: tuple[int, ...], coords: int = 0) -> np.ndarray:
    """Host-side check: ``x`` is finite and its trailing shape is ``trailing``.

    The first ``coords`` entries of the last axis are positions, checked by
    ``check_coordinates``.
    """
    a = check_finite(name, x)
    k = len(trailing)
    if a.ndim < k or tuple(a.shape[a.ndim - k :]) != tuple(trailing):
        raise ValueError(f"{name}: expected shape (..., {', '.join(map(str, trailing))}), got {a.shape}")
    if coords:
        check_coordinates(name, a[..., :coords])
    return a


def check_boxes(boxes: Any, name: str = "boxes") -> np.ndarray:
    """Host-side check of oriented boxes ``(..., 5)`` = [x, y, length, width, heading]."""
    a = check_trailing(name, boxes, (5,), coords=2)
    if a.size and np.any(a[..., 2:4] <= 0):
        raise ValueError(f"{name}: length and width must be positive")
    return a


def check_polygons(
    vertices: Any, valid: Any = None, name: str = "polygon", reorient: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Host-side check of convex polygons ``(..., N, 2)`` with optional mask ``(..., N)``.

    Valid vertices must form a prefix, number at least 3, span a positive area,
    and be convex and counter-clockwise. With ``reorient=True`` clockwise polygons
    are reversed (in the returned copy) instead of refused. Vectorised.

    Returns:
        (vertices as float64 ``(..., N, 2)``, mask ``(..., N)``).
    """
    v = check_trailing(name, vertices, (2,), coords=2).astype(np.float64)
    if v.ndim < 2:
        raise ValueError(f"{name}: expected shape (..., N, 2), got {v.shape}")
    m = np.ones(v.shape[:-1], bool) if valid is None else np.asarray(valid, bool)
    if m.shape != v.shape[:-1]:
        raise ValueError(f"{name}: valid mask shape {m.shape} != vertices shape {v.shape[:-1]}")
    n = v.shape[-2]
    k = m.sum(-1)
    if np.any(np.cumprod(m, axis=-1) != m):
        raise ValueError(f"{name}: valid vertices must come first (padding at the end)")
    if np.any(k < 3):
        raise ValueError(f"{name}: a polygon needs at least 3 valid vertices, got {int(k.min())}")
    idx = np.arange(n)
    nxt = np.where((idx + 1 < k[..., None]), idx + 1, 0)
    e = np.take_along_axis(v, nxt[..., None], axis=-2) - v
    e_next = np.take_along_axis(e, nxt[..., None], axis=-2)
    cross = e[..., 0] * e_next[..., 1] - e[..., 1] * e_next[..., 0]
    area2 = np.sum(np.where(m, v[..., 0] * (v + e)[..., 1] - v[..., 1] * (v + e)[..., 0], 0.0), axis=-1)
    scale = np.maximum(1.0, np.max(np.abs(np.where(m[..., None], v, 0.0)), axis=(-2, -1)))
    if np.any(np.abs(area2) <= 1e-12 * scale**2):
        raise ValueError(f"{name}: degenerate polygon (zero area)")
    cw = area2 < 0
    if np.any(cw):
        if not reorient:
            raise ValueError(f"{name}: polygon is clockwise; give vertices counter-clockwise")
        rev = np.where(idx < k[..., None], k[..., None] - 1 - idx, idx)
        v = np.where(cw[..., None, None], np.take_along_axis(v, rev[..., None], axis=-2), v)
        cross = np.where(cw[..., None], -cross, cross)
    if np.any(m & (cross < -1e-9 * scale[..., None] ** 2)):
        raise ValueError(f"{name}: polygon is not convex")
    return v, m


def check_weights(weights) -> None:
    """Host-side check of a weights dataclass: every field finite and >= 0, the field named."""
    cls = type(weights).__name__
    for f in dataclasses.fields(weights):
        v = getattr(weights, f.name)
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{cls}.{f.name}: expected a number, got {v!r}") from None
        if a.size and not np.all(np.isfinite(a)):
            raise ValueError(f"{cls}.{f.name}: must be finite, got {v!r}")
        if a.size and np.any(a < 0):
            raise ValueError(f"{cls}.{f.name}: must be >= 0, got {v!r}")


def weights_from(cls, values=None):
    """A weights dataclass pytree ``cls`` with ``values`` (``{field: value}``; the defaults for the
    fields not named, an unknown name a ``TypeError`` naming it) in its fields, checked
    (``check_weights``) and each field a float array of the default float dtype: a planner's
    ``init_params``."""
    w = cls(**dict(values or {}))
    check_weights(w)
    f = jnp.result_type(float)
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, f), w)


def is_concrete(*xs) -> bool:
    """True when none of ``xs`` is a JAX tracer (so host-side checks can run)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(xs))


@pytree_dataclass(
    data_fields=("length", "width", "wheelbase", "rear_overhang", "max_steer"), meta_fields=("reference",)
)
class VehicleParams:
    """Car geometry. Lengths in metres, ``max_steer`` in radians (front wheel).

    ``reference`` says where trajectory points sit on the car: ``"rear_axle"``
    (centre of the rear axle) or ``"center"`` (centre of the box). The front
    overhang is ``length - wheelbase - rear_overhang``.
    """

    length: Any = 4.8
    width: Any = 1.9
    wheelbase: Any = 2.9
    rear_overhang: Any = 0.95
    max_steer: Any = 0.55
    reference: str = REAR_AXLE

    @property
    def front_overhang(self):
        return self.length - self.wheelbase - self.rear_overhang

    @property
    def front_offset(self):
        """Distance from the reference point forward to the front bumper."""
        return 0.5 * self.length if self.reference == CENTER else self.length - self.rear_overhang

    @property
    def rear_offset(self):
        """Signed distance from the reference point to the rear bumper (<= 0)."""
        return -0.5 * self.length if self.reference == CENTER else -self.rear_overhang

    @property
    def center_offset(self):
        """Distance from the reference point forward to the box centre."""
        if self.reference == CENTER:
            return 0.0 * self.length
        return 0.5 * self.length - self.rear_overhang

    def validate(self) -> VehicleParams:
        if self.reference not in (REAR_AXLE, CENTER):
            raise ValueError(f"VehicleParams.reference must be '{REAR_AXLE}' or '{CENTER}', got {self.reference!r}")
        for f in ("length", "width", "wheelbase", "max_steer"):
            a = check_finite(f"VehicleParams.{f}", getattr(self, f))
            if np.any(a <= 0):
                raise ValueError(f"VehicleParams.{f} must be positive, got {a}")
        ro = check_finite("VehicleParams.rear_overhang", self.rear_overhang)
        if np.any(ro < 0):
            raise ValueError("VehicleParams.rear_overhang must be >= 0")
        if np.any(np.asarray(self.front_overhang) < 0):
            raise ValueError("VehicleParams: wheelbase + rear_overhang exceeds length")
        if np.any(np.asarray(self.max_steer) >= np.pi / 2):
            raise ValueError("VehicleParams.max_steer must be below pi/2")
        return self


@pytree_dataclass(data_fields=("vertices", "valid"))
class Polygon:
    """Convex polygons, counter-clockwise, padded to a fixed vertex count.

    Attributes:
        vertices: ``(..., N, 2)``.
        valid: ``(..., N)`` bool; valid vertices form a prefix.
    """

    vertices: Float[Any, "... N 2"]
    valid: Bool[Any, "... N"]

    @classmethod
    def from_vertices(
        cls, vertices: Float[ArrayLike, "... N 2"], valid: Bool[ArrayLike, "... N"] | None = None, reorient: bool = True
    ) -> Polygon:
        v, m = check_polygons(vertices, valid, reorient=reorient)
        return cls(jnp.asarray(v, dtype=jnp.result_type(float)), jnp.asarray(m))

    def validate(self) -> Polygon:
        check_polygons(self.vertices, self.valid)
        return self


@pytree_dataclass(data_fields=("x", "y", "theta", "kappa", "v", "a", "t", "s", "gear"))
class Trajectory:
    """Time-stamped trajectory, every field ``(..., T)``.

    ``gear`` is +1 forward, -1 reverse; ``s`` is signed arc length travelled.
    """

    x: Float[Any, "... T"]
    y: Float[Any, "... T"]
    theta: Float[Any, "... T"]
    kappa: Float[Any, "... T"]
    v: Float[Any, "... T"]
    a: Float[Any, "... T"]
    t: Float[Any, "... T"]
    s: Float[Any, "... T"]
    gear: Real[Any, "... T"]

    @property
    def xy(self) -> Float[Array, "... T 2"]:
        return jnp.stack([self.x, self.y], axis=-1)

    def validate(self) -> Trajectory:
        shape = np.shape(self.x)
        if len(shape) < 1 or shape[-1] < 1:
            raise ValueError(f"Trajectory: fields must have shape (..., T) with T >= 1, got {shape}")
        for f in dataclasses.fields(self):
            a = check_finite(f"Trajectory.{f.name}", getattr(self, f.name))
            if a.shape != shape:
                raise ValueError(f"Trajectory.{f.name}: shape {a.shape} differs from x's {shape}")
        if np.any(np.diff(np.asarray(self.t), axis=-1) < 0):
            raise ValueError("Trajectory.t must be non-decreasing")
        return self


@pytree_dataclass(data_fields=("boxes", "valid", "t", "static"))
class Obstacles:
    """Moving and static box obstacles padded to a fixed count.

    Attributes:
        boxes: ``(..., K, T, 5)`` pose and size of each obstacle at each time
            ``[x, y, length, width, heading]``; a static obstacle repeats its box.
        valid: ``(..., K, T)`` bool; False for padding and for times where the
            obstacle is not known (it then blocks nothing).
        t: ``(..., T)`` the time stamps of the predictions, ``t[k] = t[0] + k * dt``.
        static: ``(..., K)`` bool; a static obstacle is there at every time, also
            beyond ``T`` (``aligned`` / ``window`` hold it), and its box is the one of
            its first valid step. Dynamic obstacles are there only where ``valid``
            says so (CommonRoad semantics: they disappear when their recording ends).
            Default: all False.
    """

    boxes: Float[Any, "... K T 5"]
    valid: Bool[Any, "... K T"]
    t: Float[Any, "... T"]
    static: Bool[Any, "... K"] = None

    def __post_init__(self):
        # default flag for arrays (not for the prefix specs jax.vmap builds, whose leaves are ints / None)
        if self.static is None and hasattr(self.boxes, "shape") and len(self.boxes.shape) >= 3:
            object.__setattr__(self, "static", jnp.zeros(self.boxes.shape[:-2], bool))

    @classmethod
    def empty(cls, t) -> Obstacles:
        t = jnp.asarray(t)
        return cls(jnp.zeros(t.shape[:-1] + (0, t.shape[-1], 5)), jnp.zeros(t.shape[:-1] + (0, t.shape[-1]), bool), t)

    @classmethod
    def held(
        cls,
        boxes: Float[ArrayLike, "... K 5"],
        t: Float[ArrayLike, " T"],
        valid: Bool[ArrayLike, "... K"] | None = None,
    ) -> Obstacles:
        """Static obstacles ``(..., K, 5)`` held over times ``(T,)`` (and beyond)."""
        boxes = jnp.asarray(boxes)
        t = jnp.asarray(t)
        b = jnp.broadcast_to(boxes[..., None, :], boxes.shape[:-1] + (t.shape[-1], 5))
        m = jnp.ones(boxes.shape[:-1], bool) if valid is None else jnp.asarray(valid, bool)
        return cls(b, jnp.broadcast_to(m[..., None], b.shape[:-1]), t, m)

    def window(self, start: Int[ArrayLike, ""], n_steps: int) -> Obstacles:
        """Predictions for steps ``start .. start + n_steps - 1`` (jittable; ``start`` may be traced).

        Steps past the end of the recording are invalid for dynamic obstacles and
        held for static ones; so are steps before the start (``start < 0``). The time
        stamps count from the window's first step (``t[0] + k * dt``, ``dt`` the
        recording's step): step ``start`` is "now", as the planners read ``t``.

        Args:
            start: ``()`` int, first step.
            n_steps: static count.

        Returns:
            ``Obstacles`` with boxes ``(..., K, n_steps, 5)``.
        """
        T = self.boxes.shape[-2]
        k = jnp.asarray(start) + jnp.arange(n_steps)
        inside = (k >= 0) & (k < T)
        kc = jnp.clip(k, 0, T - 1)
        static = jnp.asarray(self.static, bool)
        v = jnp.take(self.valid, kc, axis=-1) & inside
        v = jnp.where(static[..., None], jnp.any(self.valid, axis=-1, keepdims=True), v)
        dt = self.t[..., 1:2] - self.t[..., :1] if T > 1 else jnp.ones_like(self.t[..., :1])
        t = self.t[..., :1] + dt * jnp.arange(n_steps, dtype=self.t.dtype)
        return Obstacles(self.window_of(self.boxes, start, n_steps), v, t, static)

    def window_of(self, values, start, n_steps: int):
        """Any per-obstacle, per-step array ``values (..., K, T, ...)`` (e.g. the obstacles'
        Frenet coordinates) over the steps of ``window(start, n_steps)``: static obstacles
        hold their first valid step's value. Returns ``(..., K, n_steps, ...)``."""
        nb = self.valid.ndim  # axes up to and including T
        T = self.valid.shape[-1]
        k = jnp.clip(jnp.asarray(start) + jnp.arange(n_steps), 0, T - 1)
        first = jnp.argmax(self.valid, axis=-1)  # (..., K)
        extra = values.ndim - nb
        idx = first.reshape(first.shape + (1,) + (1,) * extra)
        held = jnp.take_along_axis(values, idx, axis=nb - 1)  # (..., K, 1, ...)
        moving = jnp.take(values, k, axis=nb - 1)
        st = jnp.asarray(self.static, bool).reshape(self.static.shape + (1,) * (extra + 1))
        return jnp.where(st, held, moving)

    def at_times(self, t: Float[ArrayLike, " T2"]) -> Obstacles:
        """Predictions at times ``t`` ``(T2,)`` (jittable): what the planners see at their own time grid.

        Poses and sizes are interpolated linearly between the two neighbouring stamps of
        ``self.t`` (heading along the shorter turn); a time within ``SNAP`` of a step of a
        stamp takes that stamp's box exactly, so predictions already on the grid come back
        unchanged. A dynamic obstacle is valid where both neighbours are (or the stamp it
        sits on), and never outside ``[t[0], t[-1]]``; a static one is held at every time
        (the box of its first valid step). Leading batch dimensions of ``self.t`` are
        mapped over.

        Args:
            t: ``(T2,)`` increasing times, on the same clock as ``self.t`` (seconds from now).

        Returns:
            ``Obstacles`` with boxes ``(..., K, T2, 5)`` and ``t`` broadcast to ``(..., T2)``.
        """
        if jnp.ndim(self.t) > 1:
            return jax.vmap(lambda o: o.at_times(t))(self)
        dtype = self.boxes.dtype
        t = jnp.asarray(t, dtype)
        tt = jnp.asarray(self.t, dtype)
        n = tt.shape[-1]
        K = self.boxes.shape[-3]
        static = jnp.asarray(self.static, bool)
        lead = self.boxes.shape[:-2]
        if n == 0:
            return Obstacles(
                jnp.zeros(lead + (t.shape[-1], 5), dtype).at[..., 2:4].set(1.0),
                jnp.zeros(lead + (t.shape[-1],), bool),
                t,
                static,
            )
        if n == 1:
            b = jnp.broadcast_to(self.boxes, lead + (t.shape[-1], 5))
            ok = self.valid & (jnp.abs(t - tt[0]) <= SNAP)
        else:
            i = jnp.clip(jnp.searchsorted(tt, t, side="right") - 1, 0, n - 2)
            f = jnp.clip((t - tt[i]) / (tt[i + 1] - tt[i]), 0.0, 1.0)
            f = jnp.where(f < SNAP, 0.0, jnp.where(f > 1.0 - SNAP, 1.0, f))
            b0, b1 = self.boxes[..., i, :], self.boxes[..., i + 1, :]
            turn = jnp.arctan2(jnp.sin(b1[..., 4] - b0[..., 4]), jnp.cos(b1[..., 4] - b0[..., 4]))
            mix = (b0 + f[:, None] * (b1 - b0)).at[..., 4].set(b0[..., 4] + f * turn)
            b = jnp.where(f[:, None] == 0.0, b0, jnp.where(f[:, None] == 1.0, b1, mix))
            v0, v1 = self.valid[..., i], self.valid[..., i + 1]
            ok = jnp.where(f == 0.0, v0, jnp.where(f == 1.0, v1, v0 & v1))
            pad = SNAP * (tt[1] - tt[0])
            ok = ok & (t >= tt[0] - pad) & (t <= tt[-1] + pad)
        if K:
            first = jnp.argmax(self.valid, axis=-1)  # (..., K) first valid step of each obstacle
            held = jnp.take_along_axis(self.boxes, first[..., None, None], axis=-2)  # (..., K, 1, 5)
            b = jnp.where(static[..., None, None], held, b)
            ok = jnp.where(static[..., None], jnp.any(self.valid, axis=-1, keepdims=True), ok)
        return Obstacles(b, ok, t, static)

    def aligned(self, n_steps: int) -> Obstacles:
        """The first ``n_steps`` predictions (``window(0, n_steps)``): cut, or padded past the end."""
        return self.window(0, n_steps)

    def validate(self) -> Obstacles:
        b = check_trailing("Obstacles.boxes", self.boxes, (5,), coords=2)
        if b.ndim < 3:
            raise ValueError(f"Obstacles.boxes: expected shape (..., K, T, 5), got {b.shape}")
        m = np.asarray(self.valid)
        if m.shape != b.shape[:-1]:
            raise ValueError(f"Obstacles.valid: shape {m.shape} != boxes shape {b.shape[:-1]}")
        if np.any(b[..., 2:4][m] <= 0):
            raise ValueError("Obstacles.boxes: valid boxes must have positive length and width")
        st = np.asarray(self.static)
        if st.shape != b.shape[:-2] or st.dtype != bool:
            raise ValueError(f"Obstacles.static: expected bool of shape {b.shape[:-2]}, got {st.dtype} {st.shape}")
        t = check_finite("Obstacles.t", self.t)
        if t.ndim < 1 or t.shape[-1] != b.shape[-2]:
            raise ValueError(f"Obstacles.t: {t.shape[-1] if t.ndim else 0} time stamps for {b.shape[-2]} poses")
        if t.shape[-1] > 1 and np.any(np.diff(t, axis=-1) <= 0):
            raise ValueError("Obstacles.t: time stamps must increase strictly")
        return self

    def check_time_grid(self, dt: float, name: str = "obstacles") -> Obstacles:
        """Host-side: refuse predictions not sampled at ``t[k] = k * dt`` (the planner's grid).

        Resample them first (``jaxplan.speed.path_profile.resample_obstacles``) when they are
        sampled at another step or start at another time.
        """
        t = np.asarray(self.t, np.float64)
        if t.shape[-1] == 0:
            return self
        want = np.arange(t.shape[-1]) * dt
        tol = 1e-4 * max(1.0, dt * t.shape[-1])
        if np.any(np.abs(t - want) > tol):
            step = (
                float(t.reshape(-1, t.shape[-1])[0, 1] - t.reshape(-1, t.shape[-1])[0, 0])
                if t.shape[-1] > 1
                else float("nan")
            )
            raise ValueError(
                f"{name}.t: predictions are stamped from t = {float(t.reshape(-1)[0]):g} s every "
                f"{step:g} s, but the planner's grid is t = k * {dt:g} s; resample them to that grid "
                f"(jaxplan.speed.path_profile.resample_obstacles)"
            )
        return self


# ``Obstacles.at_times`` compiled once per shape, for host code that reads many recordings.
at_times_jit = jax.jit(lambda obstacles, t: obstacles.at_times(t))
