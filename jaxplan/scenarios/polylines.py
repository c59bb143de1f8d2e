"""Host-side (numpy) polyline tools shared by the loaders, demonstrations and experiments."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def arc_length(xy: np.ndarray) -> np.ndarray:
    """``(P,)`` cumulative chord length of ``xy (P, 2)``, starting at 0."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def resample_polyline(xy: np.ndarray, s: np.ndarray, s_query: ArrayLike) -> np.ndarray:
    """Points ``(Q, 2)`` at arc lengths ``s_query (Q,)`` on ``xy (P, 2)`` with arc lengths ``s (P,)``,
    extended straight past both ends."""
    s_query = np.asarray(s_query, float)
    out = np.column_stack([np.interp(s_query, s, xy[:, 0]), np.interp(s_query, s, xy[:, 1])])
    # beyond each end: straight along the end chord's forward direction (before the start
    # s_query - s[0] < 0, so the points lie behind the first point)
    for end, base, (a, b) in ((s_query < s[0], 0, (0, 1)), (s_query > s[-1], -1, (-2, -1))):
        if end.any():
            d = xy[b] - xy[a]
            d = d / max(np.linalg.norm(d), 1e-9)
            out[end] = xy[base] + (s_query[end] - s[base])[:, None] * d
    return out


def uniform_resample(xy: np.ndarray, n: int, min_spacing: float = 1e-3) -> np.ndarray:
    """``n`` points ``(n, 2)`` evenly spaced by arc length along ``xy (P, 2)`` (repeated points dropped)."""
    xy = np.asarray(xy, float)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > min_spacing])
    xy = xy[keep]
    s = arc_length(xy)
    return resample_polyline(xy, s, np.linspace(0.0, s[-1], n))


def nearest_on_polyline(poly: np.ndarray, p: np.ndarray) -> tuple[int, float, float]:
    """The point of polyline ``poly (P, 2)`` nearest ``p (2,)``.

    Returns:
        (segment index j, distance along that segment from ``poly[j]`` (m), distance to ``p`` (m)).
    """
    seg = poly[1:] - poly[:-1]
    L2 = np.maximum(np.sum(seg * seg, 1), 1e-12)
    u = np.clip(np.sum((p - poly[:-1]) * seg, 1) / L2, 0, 1)
    d = np.linalg.norm(poly[:-1] + u[:, None] * seg - p, axis=1)
    j = int(np.argmin(d))
    return j, float(u[j] * np.sqrt(L2[j])), float(d[j])


def smooth_polyline(xy: np.ndarray, wavelength: float, max_dev: float, order: int = 3) -> np.ndarray:
    """A smoothed copy of a uniformly sampled polyline ``xy (N, 2)`` (host side).

    Lanelet centre lines are polylines: their vertices are kinks, so the curvature of a line
    resampled from them is a train of spikes and its derivative (which the lattice's
    Cartesian acceleration and curvature use) is noise. As production stacks smooth the
    reference line before planning, this is a Whittaker smoother: it minimises
    ``|p - xy|^2 + lam |D^order p|^2`` per coordinate, ``lam`` set so that wiggles shorter than
    ``wavelength`` metres are damped, then divided by 4 until no point moves more than
    ``max_dev`` metres (tight turns keep their shape). ``wavelength <= 0``: unchanged.
    """
    xy = np.asarray(xy, float)
    n = len(xy)
    if wavelength > 0 and not max_dev > 0:
        raise ValueError(
            f"smooth_polyline: max_dev must be > 0 m when smoothing, got {max_dev!r} (SceneConfig.route_max_dev)"
        )
    if wavelength <= 0 or n <= order + 1:
        return xy.copy()
    ds = float(np.mean(np.linalg.norm(np.diff(xy, axis=0), axis=1)))
    lam = (wavelength / (2.0 * np.pi * max(ds, 1e-6))) ** (2 * order)
    D = np.diff(np.eye(n), order, axis=0)
    P = D.T @ D
    for _ in range(12):
        out = np.linalg.solve(np.eye(n) + lam * P, xy)
        if np.max(np.linalg.norm(out - xy, axis=1)) <= max_dev:
            return out
        lam /= 4.0
    return xy.copy()


def simplify(xy: np.ndarray, tol: float) -> np.ndarray:
    """Douglas-Peucker simplification of a polyline ``(P, 2)`` within ``tol`` metres (keeps ends)."""
    xy = np.asarray(xy, float)
    if len(xy) <= 2 or tol <= 0:
        return xy
    keep = np.zeros(len(xy), bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(xy) - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = xy[i], xy[j]
        d = b - a
        n = np.linalg.norm(d)
        p = xy[i + 1 : j]
        if n < 1e-12:
            dist = np.linalg.norm(p - a, axis=1)
        else:
            dist = np.abs(d[0] * (p[:, 1] - a[1]) - d[1] * (p[:, 0] - a[0])) / n
        k = int(np.argmax(dist))
        if dist[k] > tol:
            m = i + 1 + k
            keep[m] = True
            stack += [(i, m), (m, j)]
    return xy[keep]
