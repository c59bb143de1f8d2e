"""Random convex shapes for oracle tests and the geometry suite (numpy, host side)."""

from __future__ import annotations

import numpy as np

from jaxplan.types import check_polygons


def random_convex_polygons(
    rng: np.random.Generator,
    n: int,
    max_vertices: int = 8,
    min_vertices: int = 3,
    radius: tuple[float, float] = (0.5, 3.0),
    spread: float = 4.0,
):
    """``n`` random convex polygons, counter-clockwise, padded to ``max_vertices``.

    Vertices are sorted random angles on a random ellipse, rotated and placed
    uniformly in a square of side ``2 * spread``.

    Returns:
        (vertices ``(n, max_vertices, 2)`` float64, valid ``(n, max_vertices)`` bool).
    """
    k = rng.integers(min_vertices, max_vertices + 1, size=n)
    ang = np.sort(rng.uniform(0, 2 * np.pi, size=(n, max_vertices)), axis=1)
    slot = np.arange(max_vertices)
    valid = slot[None, :] < k[:, None]
    # Keep angular gaps below pi so the centre is inside and the shape is proper.
    ang = np.where(valid, ang, ang[:, :1])
    base = (
        2 * np.pi * slot[None, :] / k[:, None]
        + rng.uniform(0, 2 * np.pi / k)[:, None]
        + rng.uniform(-0.3, 0.3, size=(n, max_vertices)) * (2 * np.pi / k[:, None])
    )
    ang = np.where(valid, base, 0.0)
    a = rng.uniform(*radius, size=n)
    b = a * rng.uniform(0.3, 1.0, size=n)
    pts = np.stack([a[:, None] * np.cos(ang), b[:, None] * np.sin(ang)], -1)
    rot = rng.uniform(-np.pi, np.pi, size=n)
    c, s = np.cos(rot)[:, None], np.sin(rot)[:, None]
    pts = np.stack([c * pts[..., 0] - s * pts[..., 1], s * pts[..., 0] + c * pts[..., 1]], -1)
    pts += rng.uniform(-spread, spread, size=(n, 1, 2))
    last = np.take_along_axis(pts, (k - 1)[:, None, None].repeat(2, -1), axis=1)
    pts = np.where(valid[..., None], pts, last)
    check_polygons(pts, valid)
    return pts, valid


def random_boxes(rng: np.random.Generator, n: int, spread: float = 4.0, size: tuple[float, float] = (0.5, 5.0)):
    """``n`` random oriented boxes ``(n, 5)`` = [x, y, length, width, heading]."""
    return np.stack(
        [
            rng.uniform(-spread, spread, n),
            rng.uniform(-spread, spread, n),
            rng.uniform(*size, n),
            rng.uniform(*size, n) * 0.6,
            rng.uniform(-np.pi, np.pi, n),
        ],
        axis=-1,
    )


def edge_case_box_pairs():
    """Hand-made box pairs ``(P, 2, 5)``: touching, contained, identical, far, corner-on-edge."""
    pairs = [
        ([0, 0, 4, 2, 0], [4, 0, 4, 2, 0]),  # touching along an edge
        ([0, 0, 4, 2, 0], [4, 2, 4, 2, 0]),  # touching at a corner
        ([0, 0, 4, 2, 0], [0, 0, 1, 0.5, 0.3]),  # containment
        ([0, 0, 4, 2, 0.7], [0, 0, 4, 2, 0.7]),  # identical
        ([0, 0, 4, 2, 0], [100, 50, 4, 2, 1.0]),  # far apart
        ([0, 0, 4, 2, 0], [2 + np.sqrt(2) / 2, 0, 1, 1, np.pi / 4]),  # corner touching edge
        ([0, 0, 4, 2, 0], [3.9, 0, 4, 2, 0]),  # deep overlap, parallel edges
        ([0, 0, 4, 2, 0], [0, 0, 2, 4, np.pi / 2]),  # same box turned: identical shape
        ([0, 0, 4, 2, 0], [2.5, 1.5, 2, 2, np.pi / 4]),  # corner into corner
    ]
    return np.array(pairs, dtype=np.float64)
