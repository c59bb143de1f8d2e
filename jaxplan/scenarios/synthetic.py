"""Seeded synthetic road scenes (host side, numpy): the built-in default scenario set.

A scene is a three-lane road (straight or an arc of radius >= 150 m) whose middle
lane's centre line is the reference line; the ego starts on it at the origin at a
random heading and speed; up to five other cars drive on the three lanes at their
own constant speeds. Arrays are padded to fixed sizes so scenes stack into batches.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class RoadScenes:
    """``n`` scenes. ego ``(n, 5)`` [x, y, heading, v, a]; ref_xy ``(n, P, 2)``;
    boxes ``(n, K, T, 5)``, valid ``(n, K, T)``; t ``(n, T)``; cruise ``(n, T, 2)``, the
    ego kept at its speed on the lane centre; static ``(n, K)`` (every generated car drives:
    all False, given so that batches carry the flag the planners read)."""

    ego: np.ndarray
    ref_xy: np.ndarray
    boxes: np.ndarray
    valid: np.ndarray
    t: np.ndarray
    cruise: np.ndarray
    static: np.ndarray


def road_scenes(
    n: int,
    seed: int = 0,
    n_obstacles: int = 16,
    horizon: float = 5.0,
    dt: float = 0.1,
    points: int = 96,
    back: float = 10.0,
    ahead: float = 180.0,
    lane_width: float = 3.5,
) -> RoadScenes:
    """Generate ``n`` scenes from ``seed`` (the same seed gives the same scenes)."""
    rng = np.random.default_rng(seed)
    n_t = int(round(horizon / dt)) + 1
    t = np.arange(n_t) * dt
    s_ref = np.linspace(-back, ahead, points)
    ego = np.zeros((n, 5))
    refs = np.zeros((n, points, 2))
    boxes = np.zeros((n, n_obstacles, n_t, 5))
    boxes[..., 2:4] = 1.0  # padding: unit boxes, never valid
    valid = np.zeros((n, n_obstacles, n_t), bool)
    cruise = np.zeros((n, n_t, 2))
    for i in range(n):
        kappa = rng.choice([0.0, 1.0]) * rng.uniform(-1 / 150, 1 / 150)
        th0 = rng.uniform(-np.pi, np.pi)
        th = th0 + kappa * s_ref
        if abs(kappa) < 1e-9:
            ref = np.column_stack([s_ref * np.cos(th0), s_ref * np.sin(th0)])
        else:  # closed-form arc through the origin with heading th0 at s = 0
            ref = np.column_stack([(np.sin(th) - np.sin(th0)) / kappa, (np.cos(th0) - np.cos(th)) / kappa])
        nrm = np.column_stack([-np.sin(th), np.cos(th)])

        def on_road(s, l):
            at = lambda a: np.interp(s, s_ref, a)
            return np.column_stack([at(ref[:, 0]), at(ref[:, 1])]) + l[:, None] * np.column_stack(
                [at(nrm[:, 0]), at(nrm[:, 1])]
            )

        v0 = rng.uniform(5.0, 25.0)
        for k in range(rng.integers(0, min(n_obstacles, 5) + 1)):
            lane = rng.integers(-1, 2)
            s0, vk = rng.uniform(8.0, 70.0), max(0.0, v0 + rng.uniform(-8.0, 4.0))
            s = s0 + vk * t
            boxes[i, k] = np.column_stack(
                [
                    on_road(s, np.full(n_t, lane_width * lane)),
                    np.full(n_t, 4.6),
                    np.full(n_t, 1.9),
                    np.interp(s, s_ref, th),
                ]
            )
            valid[i, k] = s < ahead
        ego[i] = [0.0, 0.0, th0, v0, 0.0]
        refs[i] = ref
        cruise[i] = on_road(v0 * t, np.zeros(n_t))
    return RoadScenes(
        ego, refs, boxes, valid, np.broadcast_to(t, (n, n_t)).copy(), cruise, np.zeros((n, n_obstacles), bool)
    )
