"""Lane centre-line paths of a map (host side): where a road user on a lanelet drives next.

``lane_paths(lanes)`` gives one path per lanelet, and one more from every ``LANE_PATH_EVERY``
metres of a long lanelet: the lanelet's centre line from there, followed by a chain of
successors (at each junction the straightest one: the successor whose direction, end to end,
turns least from the path's last chord), cut at ``LANE_PATH_LENGTH`` metres and resampled to
``LANE_PATH_POINTS`` points evenly spaced in arc length. ``Scene.lane_paths`` holds them; the
simulator's constant-velocity predictions follow them (``jaxplan.sim.prediction``).
"""

from __future__ import annotations

import numpy as np

from jaxplan.scenarios.polylines import arc_length, resample_polyline

LANE_PATH_POINTS = 64  # Q: points per path
LANE_PATH_LENGTH = 150.0  # m: the longest path
LANE_PATH_EVERY = 50.0  # m: a lanelet longer than this has a path from every this many metres of it


def _distinct(xy: np.ndarray, tol: float = 1e-3) -> np.ndarray:
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > tol])
    return xy[keep]


def _direction(xy: np.ndarray) -> float:
    d = xy[-1] - xy[0]
    return float(np.arctan2(d[1], d[0]))


def _chain(by_id: dict, lane, start: float, length: float) -> np.ndarray:
    """Centre-line points from arc length ``start`` of ``lane`` on, through the straightest
    successors, until ``length`` metres are covered (or the chain ends or loops)."""
    c = _distinct(np.asarray(lane.center, float))
    s = arc_length(c)
    keep = s > start
    pts = [np.concatenate([resample_polyline(c, s, [start]), c[keep]])]
    total = s[-1] - start
    cur, seen = lane, {lane.id}
    while total < length:
        here = _direction(_distinct(np.concatenate(pts))[-2:])
        nxt = [by_id[i] for i in cur.successors if i in by_id and i not in seen]
        if not nxt:
            break
        turn = [abs(np.angle(np.exp(1j * (_direction(np.asarray(n.center, float)) - here)))) for n in nxt]
        cur = nxt[int(np.argmin(turn))]
        seen.add(cur.id)
        c = _distinct(np.asarray(cur.center, float))
        pts.append(c)
        total += arc_length(c)[-1]
    return _distinct(np.concatenate(pts))


def lane_paths(
    lanes, n_points: int = LANE_PATH_POINTS, length: float = LANE_PATH_LENGTH, every: float = LANE_PATH_EVERY
) -> tuple[np.ndarray, np.ndarray]:
    """The lane paths of a map (see the module docstring).

    Args:
        lanes: the scenario's ``Lane``s (``centre (P_i, 2)``, ``successors``).
        n_points: ``Q``, points per path.
        length: metres of the longest path.
        every: a lanelet gets a path from every ``every`` metres of its centre line.

    Returns:
        (paths ``(P, Q, 2)``, valid ``(P, Q)`` bool): at least one path (an invalid one when the map
        has no lanelet); a valid path's points are all valid, evenly spaced over its length.
    """
    by_id = {ln.id: ln for ln in lanes}
    out = []
    for ln in lanes:
        c = _distinct(np.asarray(ln.center, float))
        if len(c) < 2:
            continue
        total = arc_length(c)[-1]
        for start in np.arange(0.0, max(total - 1e-6, 1e-6), every):
            xy = _chain(by_id, ln, float(start), length)
            s = arc_length(xy)
            if len(xy) < 2 or s[-1] < 0.1:
                continue
            out.append(resample_polyline(xy, s, np.linspace(0.0, min(s[-1], length), n_points)))
    if not out:
        return np.zeros((1, n_points, 2)), np.zeros((1, n_points), bool)
    return np.stack(out), np.ones((len(out), n_points), bool)
