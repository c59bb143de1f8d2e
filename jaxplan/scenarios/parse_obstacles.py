"""The obstacles of a scenario object (the shared JSON format) read into ``Obstacles`` in the local
frame: recorded states, set-based occupancies (one box per step), and static boxes (a centre and
size, or a polygon's smallest covering box, ``_min_area_box``). Malformed fields raise
``ScenarioError`` naming the file and field.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from jaxplan.scenarios.fields import MAX_ANGLE, ScenarioError, _angle, _field, _int, _number, _points
from jaxplan.scenarios.scene import OBSTACLE_TYPES
from jaxplan.types import FLOAT32_MAX_COORD, Obstacles

# Sizes (length, width) for road users the files give without one.
DEFAULT_SIZE = {"pedestrian": (0.6, 0.6), "bicycle": (1.8, 0.6)}


def _min_area_box(poly: np.ndarray) -> np.ndarray:
    """Smallest oriented box ``(5,)`` around a polygon (edge-aligned search)."""
    p = poly[:-1] if np.allclose(poly[0], poly[-1]) else poly
    best = None
    for i in range(len(p)):
        e = p[(i + 1) % len(p)] - p[i]
        if np.linalg.norm(e) < 1e-9:
            continue
        th = math.atan2(e[1], e[0])
        c, s = math.cos(th), math.sin(th)
        u = p @ np.array([c, s])
        w = p @ np.array([-s, c])
        area = np.ptp(u) * np.ptp(w)
        if best is None or area < best[0]:
            cu, cw = 0.5 * (u.max() + u.min()), 0.5 * (w.max() + w.min())
            best = (area, [cu * c - cw * s, cu * s + cw * c, np.ptp(u), np.ptp(w), th])
    if best is None:
        raise ValueError("degenerate polygon")
    return np.asarray(best[1])


def _size(o, where, path) -> tuple[float, float]:
    kind = o.get("type")
    if "length" not in o and isinstance(kind, str) and kind in DEFAULT_SIZE:
        return DEFAULT_SIZE[kind]  # the format gives no size for these
    length, width = _number(o, "length", where, path), _number(o, "width", where, path)
    if length <= 0 or width <= 0:
        raise ScenarioError(f"{path}: field {where}.length/width must be positive")
    if max(length, width) > FLOAT32_MAX_COORD:
        raise ScenarioError(
            f"{path}: field {where}.length/width must be at most {FLOAT32_MAX_COORD:g} m, got {length!r} / {width!r}"
        )
    return length, width


def _states(o, where, path) -> np.ndarray:
    st = o["states"]
    try:
        st = np.asarray(st, dtype=np.float64)
    except (TypeError, ValueError):
        st = None
    if st is None or st.ndim != 2 or st.shape[1] < 4 or not np.all(np.isfinite(st[:, :4])):
        raise ScenarioError(f"{path}: field {where}.states should be rows of finite [t, x, y, theta, ...]")
    if np.abs(st[:, 3]).max() > MAX_ANGLE:
        raise ScenarioError(f"{path}: field {where}.states has a heading (column 3) beyond +-{MAX_ANGLE:g} rad")
    return st


def _occupancies(o, where, path) -> np.ndarray:
    """``(N, 6)`` rows ``[t, x, y, length, width, heading]`` of an obstacle's ``occupancies``."""
    rows = o["occupancies"]
    try:
        a = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.ndim != 2 or a.shape[1] != 6 or not len(a) or not np.all(np.isfinite(a)):
        raise ScenarioError(
            f"{path}: field {where}.occupancies should be rows of finite [t, x, y, length, width, heading]"
        )
    if np.any(a[:, 3:5] <= 0) or a[:, 3:5].max() > FLOAT32_MAX_COORD:
        raise ScenarioError(
            f"{path}: field {where}.occupancies has a length or width that is not positive "
            f"or above {FLOAT32_MAX_COORD:g} m"
        )
    if np.abs(a[:, 5]).max() > MAX_ANGLE:
        raise ScenarioError(f"{path}: field {where}.occupancies has a heading (column 5) beyond +-{MAX_ANGLE:g} rad")
    return a


def _obstacles(d: dict, dt: float, t0: float, origin: np.ndarray, horizon: float | None, path: str) -> tuple:
    """``(obstacles, ids, types, skipped, unknown types)`` of the scenario's ``obstacles``: boxes
    ``(K, T, 5)`` at times ``t = k * dt`` from the start time ``t0``, shifted by ``origin``, up to
    ``horizon`` (s; default all); ``skipped`` the ids without a shape or a trajectory, ``unknown
    types`` the types read as ``unknown``."""
    obstacles = _field(d, "obstacles", "scenario", path, list)
    for i, o in enumerate(obstacles):
        if not isinstance(o, dict):
            raise ScenarioError(f"{path}: field obstacles[{i}] should be an object")
    occupied = {}
    for i, o in enumerate(obstacles):
        if o.get("occupancies") is not None:
            if o.get("states"):
                raise ScenarioError(f"{path}: field obstacles[{i}] gives both states and occupancies (one of them)")
            occupied[i] = _occupancies(o, f"obstacles[{i}]", path)
    states = {i: _states(o, f"obstacles[{i}]", path) for i, o in enumerate(obstacles) if o.get("states")}
    n_steps = max(
        [1]
        + [len(st) for st in states.values()]
        + [int(np.rint((oc[:, 0].max() - t0) / dt)) + 1 for oc in occupied.values()]
    )
    if horizon is not None:
        n_steps = min(n_steps, int(round(horizon / dt)) + 1)
    t = np.arange(n_steps) * dt
    boxes, valids, statics, ids, types, skipped = [], [], [], [], [], []
    unknown_types = set()
    for i, o in enumerate(obstacles):
        where = f"obstacles[{i}]"
        oid = _int(o, "id", where, path)
        role = o.get("role", "dynamic")
        if role not in ("dynamic", "static"):
            raise ScenarioError(f"{path}: field {where}.role should be 'dynamic' or 'static', got {role!r}")
        b = np.zeros((n_steps, 5))
        ok = np.zeros(n_steps, bool)
        static = role == "static" or (i not in states and i not in occupied)  # polygon / centre: no motion
        if i in occupied:  # one box per step (set-based predictions)
            if role == "static":
                raise ScenarioError(f"{path}: field {where}.occupancies belong to a dynamic obstacle, not a static one")
            oc = occupied[i]
            k = np.rint((oc[:, 0] - t0) / dt).astype(int)
            if len(np.unique(k)) != len(k):
                raise ScenarioError(f"{path}: field {where}.occupancies has two rows for one time step")
            keep = (k >= 0) & (k < n_steps)
            b[k[keep]] = np.column_stack([oc[keep, 1] - origin[0], oc[keep, 2] - origin[1], oc[keep, 3:6]])
            ok[k[keep]] = True
        elif i in states and static:  # a static obstacle: its first recorded pose, held at every time
            length, width = _size(o, where, path)
            st = states[i]
            b[:] = [st[0, 1] - origin[0], st[0, 2] - origin[1], length, width, st[0, 3]]
            ok[:] = True
        elif i in states:
            length, width = _size(o, where, path)
            st = states[i]
            k = np.rint((st[:, 0] - t0) / dt)
            keep = (k >= 0) & (k < n_steps)
            k = k[keep].astype(int)
            b[k] = np.column_stack(
                [
                    st[keep, 1] - origin[0],
                    st[keep, 2] - origin[1],
                    np.full(keep.sum(), length),
                    np.full(keep.sum(), width),
                    st[keep, 3],
                ]
            )
            ok[k] = True
        elif "polygon" in o:
            poly = _points(o["polygon"], f"{where}.polygon", path, 3) - origin
            try:
                b[:] = _min_area_box(poly)
            except ValueError:
                raise ScenarioError(f"{path}: field {where}.polygon is degenerate") from None
            ok[:] = True
        elif "center" in o:
            c = _points([o["center"]], f"{where}.center", path)[0] - origin
            length, width = _size(o, where, path)
            b[:] = [c[0], c[1], length, width, _angle(o, "orientation", where, path)]
            ok[:] = True
        else:
            skipped.append(oid)
            continue
        if np.abs(b[ok][:, :2]).max(initial=0.0) > FLOAT32_MAX_COORD:
            raise ScenarioError(f"{path}: field {where} lies more than {FLOAT32_MAX_COORD:.0e} m from the ego start")
        boxes.append(b)
        valids.append(ok)
        statics.append(static)
        ids.append(oid)
        kind = str(o.get("type", "unknown"))
        if kind not in OBSTACLE_TYPES:
            unknown_types.add(kind)
            kind = "unknown"
        types.append(kind)
    K = len(boxes)
    obs = Obstacles(
        jnp.asarray(np.array(boxes).reshape(K, n_steps, 5), jnp.float32),
        jnp.asarray(np.array(valids, bool).reshape(K, n_steps)),
        jnp.asarray(t, jnp.float32),
        jnp.asarray(np.array(statics, bool).reshape(K)),
    )
    return obs, ids, types, skipped, unknown_types
