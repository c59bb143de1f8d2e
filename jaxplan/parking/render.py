"""Sensor-like occupancy grids of a ``ParkingScene``: scan-line fill, edge noise, false positives,
occlusion from the car's four sensors, sensor range and unknown patches.

Everything works row by row: each obstacle (and each obstacle's shadow seen
from a sensor) cuts a grid row's centre line in intervals; the intervals go into
a difference array and one running sum per row fills the cells. A cell is
*blocked* when it is occupied or unknown; the planner treats both alike.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.grid import Grid, cell_centres, footprint_boxes, from_frame, to_frame
from jaxplan.parking.scenes import ParkingScene, box_gap, hash_uniform, hash_uniform_at
from jaxplan.types import VehicleParams, is_concrete

FAR = 200.0  # metres: shadows are cut this far from the sensor (well beyond any grid)
PATCH_NEAR = 3.0  # metres: no unknown patches this close to the car's box


def _cumsum_cols(d):
    """Running sum along the last axis (a scan over columns: one pass, cheap on CPU)."""
    dm = jnp.moveaxis(d, -1, 0)

    def step(acc, x):
        acc = acc + x
        return acc, acc

    _, out = lax.scan(step, jnp.zeros(dm.shape[1:], d.dtype), dm)
    return jnp.moveaxis(out, 0, -1)


def _fill(lo, hi, ok, config: ParkoutConfig):
    """Cells ``(rows, cols)`` whose centre lies in an interval ``[lo, hi]`` (x in the grid frame) of its row.

    Args:
        lo, hi: ``(rows, J)`` interval ends; ok: ``(rows, J)`` which are real.
    """
    h, cols = config.cell, config.cols
    ca = jnp.ceil((lo - config.x_min) / h - 0.5)
    cb = jnp.floor((hi - config.x_min) / h - 0.5)
    ok = ok & (cb >= ca) & (cb >= 0) & (ca <= cols - 1)
    a = jnp.clip(jnp.where(ok, ca, 0), 0, cols).astype(jnp.int32)
    b = jnp.clip(jnp.where(ok, cb + 1, 0), 0, cols).astype(jnp.int32)
    rows = lo.shape[0]
    base = (jnp.arange(rows, dtype=jnp.int32) * (cols + 1))[:, None]
    w = ok.astype(jnp.int16)
    d = jnp.zeros(rows * (cols + 1), jnp.int16)
    d = d.at[(base + a).reshape(-1)].add(w.reshape(-1)).at[(base + b).reshape(-1)].add(-w.reshape(-1))
    return _cumsum_cols(d.reshape(rows, cols + 1))[:, :cols] > 0


def _row_lines(config: ParkoutConfig, dtype):
    return config.y_min + (jnp.arange(config.rows, dtype=dtype) + 0.5) * config.cell


def polygon_row_intervals(poly, valid, y_rows, jitter_y=0.0, jitter_x=0.0):
    """Even-odd intervals of simple polygons on horizontal lines.

    Args:
        poly: ``(K, N, 2)`` vertices (closed implicitly; repeated vertices are fine).
        valid: ``(K,)``; y_rows: ``(R,)`` line heights.
        jitter_y: ``(R, K, 1)`` shift of each line per polygon; jitter_x: ``(R, K, N)``
            shift of each crossing (edge noise).

    Returns:
        (lo, hi, ok), each ``(R, K, N // 2)``: the crossings sorted and paired.
    """
    y = y_rows[:, None, None] + jitter_y
    p1 = jnp.roll(poly, -1, axis=-2)
    y0, y1 = poly[None, :, :, 1], p1[None, :, :, 1]
    x0, x1 = poly[None, :, :, 0], p1[None, :, :, 0]
    cross = ((y0 <= y) & (y < y1)) | ((y1 <= y) & (y < y0))
    t = (y - y0) / jnp.where(y1 == y0, 1.0, y1 - y0)
    x = jnp.where(cross & valid[None, :, None], x0 + t * (x1 - x0) + jitter_x, jnp.inf)
    xs = jnp.sort(x, axis=-1)
    m = poly.shape[-2] // 2
    lo, hi = xs[..., 0 : 2 * m : 2], xs[..., 1 : 2 * m : 2]
    return lo, hi, jnp.isfinite(lo) & jnp.isfinite(hi)


def shadow_row_intervals(poly, valid, sensor, y_rows):
    """Where each row line lies in an obstacle or its shadow seen from ``sensor``.

    For a convex outline ``P`` the set ``{p : segment(sensor, p) meets P}`` is
    convex: the hull of ``P`` and its vertices pushed ``FAR`` metres away from the
    sensor. Its cut with a line is the span of the cuts of all segments between
    those points. Non-convex outlines get the shadow of their hull (more unknown).

    Args:
        poly: ``(K, N, 2)``; valid: ``(K,)``; sensor: ``(2,)``; y_rows: ``(R,)``.

    Returns:
        (lo, hi, ok), each ``(R, K)``.
    """
    d = poly - sensor
    far = sensor + d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-6) * FAR
    q = jnp.concatenate([poly, far], axis=-2)  # (K, 2N, 2)
    n = q.shape[-2]
    i, j = jnp.triu_indices(n, 1)
    a, b = q[:, i], q[:, j]  # (K, P, 2)
    y = y_rows[:, None, None]
    ay, by = a[None, ..., 1], b[None, ..., 1]
    ax, bx = a[None, ..., 0], b[None, ..., 0]
    inside = (jnp.minimum(ay, by) <= y) & (y <= jnp.maximum(ay, by))
    flat = ay == by
    t = (y - ay) / jnp.where(flat, 1.0, by - ay)
    x = ax + t * (bx - ax)
    xlo = jnp.where(flat, jnp.minimum(ax, bx), x)
    xhi = jnp.where(flat, jnp.maximum(ax, bx), x)
    lo = jnp.min(jnp.where(inside, xlo, jnp.inf), axis=-1)
    hi = jnp.max(jnp.where(inside, xhi, -jnp.inf), axis=-1)
    return lo, hi, valid[None, :] & (hi >= lo)


def sensor_poses(car_pose, vehicle: VehicleParams):
    """Poses ``(4, 3)`` of the car's sensors: front and rear bumper centre, left and right mirror.

    Each sees the half-plane its pose faces (front: ahead, rear: behind,
    mirrors: their side), so together they see everything around the car.
    """
    a, ro, w = vehicle.length - vehicle.rear_overhang, vehicle.rear_overhang, 0.5 * vehicle.width
    mirror = 0.5 * vehicle.wheelbase + 0.3
    rel = jnp.stack(
        [
            jnp.stack([a, 0.0 * a, 0.0 * a]),
            jnp.stack([-ro, 0.0 * a, jnp.pi + 0.0 * a]),
            jnp.stack([mirror + 0.0 * a, w, 0.5 * jnp.pi + 0.0 * a]),
            jnp.stack([mirror + 0.0 * a, -w, -0.5 * jnp.pi + 0.0 * a]),
        ]
    ).astype(car_pose.dtype)
    xy = from_frame(car_pose, rel[:, :2])
    return jnp.concatenate([xy, (car_pose[2] + rel[:, 2])[:, None]], axis=-1)


class Layers(NamedTuple):
    """What the sensors report, per cell ``(rows, cols)`` bool: ``occupied`` and ``unknown``."""

    occupied: jnp.ndarray
    unknown: jnp.ndarray


def render_layers(
    scene: ParkingScene, pose, key, config: ParkoutConfig, vehicle: VehicleParams, car_pose=None, sensors: bool = True
) -> Layers:
    """The occupied and unknown cells of one scene in the grid frame at ``pose (3,)``.

    Args:
        scene: one scene (no batch dims).
        pose: ``(3,)`` the grid frame's pose in the slot frame.
        key: a legacy PRNG key (uint32 ``(2,)``) or any uint32 seed for the noise.
        car_pose: ``(3,)`` where the car stands (its sensors, and the cells under
            it, which read free); default ``scene.start``.
        sensors: model occlusion and range at all (static; ``False`` skips that
            work when no scene of a batch asks for it).
    """
    dtype = jnp.result_type(float)
    pose = jnp.asarray(pose, dtype)
    car = jnp.asarray(scene.start if car_pose is None else car_pose, dtype)
    poly = to_frame(pose, jnp.asarray(scene.polygons, dtype))  # (K, N, 2) in the grid frame
    K, N = poly.shape[-3], poly.shape[-2]
    rows = config.rows
    yr = _row_lines(config, dtype)
    e = jnp.asarray(scene.edge_noise, dtype)
    jy = e * (2.0 * hash_uniform(key, (rows, K, 1), 0, dtype) - 1.0)
    jx = e * (2.0 * hash_uniform(key, (rows, K, N), 1, dtype) - 1.0)
    lo, hi, ok = polygon_row_intervals(poly, scene.valid, yr, jy, jx)
    occ = _fill(lo.reshape(rows, -1), hi.reshape(rows, -1), ok.reshape(rows, -1), config)
    occ = occ | (hash_uniform(key, (rows, config.cols), 2, dtype) < scene.salt)
    centres = cell_centres(config, dtype)  # grid frame
    world = from_frame(pose, centres)  # slot frame
    under = box_gap(footprint_boxes(car, vehicle), world) <= 0.0  # the car itself: known free
    # sensor dropout: unknown 1 m patches, beyond PATCH_NEAR of the car (the near field is always seen)
    ij = jnp.floor(centres).astype(jnp.int32)
    patch = hash_uniform_at(key, ij[..., 0] * 7919 + ij[..., 1] * 104729, 3, dtype) < scene.unknown_patches
    patch = patch & (box_gap(footprint_boxes(car, vehicle), world) > PATCH_NEAR)

    def seen_by(sp):
        lo_s, hi_s, ok_s = shadow_row_intervals(poly, scene.valid, to_frame(pose, sp[:2]), yr)
        shadow = _fill(lo_s, hi_s, ok_s, config)
        rel = to_frame(sp, world)
        return ~shadow & (rel[..., 0] >= 0) & (jnp.sum(rel * rel, -1) <= scene.sensor_range**2)

    if sensors:
        seen = jnp.any(jax.vmap(seen_by)(sensor_poses(car, vehicle)), axis=0)
        unknown = patch | (scene.occlusion & ~seen)
    else:
        unknown = patch
    return Layers(occupied=occ & ~under, unknown=unknown & ~under & ~occ)


def render_grid(
    scene: ParkingScene, pose, key, config: ParkoutConfig, vehicle: VehicleParams, car_pose=None, sensors: bool = True
) -> Grid:
    """The grid of one scene in the frame at ``pose (3,)``: blocked = occupied or unknown (``render_layers``)."""
    lay = render_layers(scene, pose, key, config, vehicle, car_pose, sensors)
    return Grid(cells=lay.occupied | lay.unknown, pose=jnp.asarray(pose, jnp.result_type(float)))


@functools.partial(jax.jit, static_argnames=("config", "sensors"))
def _render_batch(scenes, keys, config, vehicle, sensors):
    def one(s, k):
        return render_grid(s, jnp.zeros(3, jnp.result_type(float)), k, config, vehicle, sensors=sensors).cells

    return jax.vmap(one)(scenes, keys)


def render_grids(
    scenes: ParkingScene, seed: int, config: ParkoutConfig, vehicle: VehicleParams, first: int = 0
) -> Grid:
    """Grids ``(n, rows, cols)`` of a batch of scenes ``(n,)`` in the slot frame (jitted, one call).

    Scene ``i`` gets the noise of key ``(seed, first + i)``.
    """
    n = scenes.batch_shape[0]
    keys = jnp.stack([jnp.full((n,), seed, jnp.uint32), first + jnp.arange(n, dtype=jnp.uint32)], -1)
    sensors = True
    if is_concrete(scenes):
        sensors = bool(np.any(np.asarray(scenes.occlusion)) or np.any(np.isfinite(np.asarray(scenes.sensor_range))))
    cells = _render_batch(scenes, keys, config, vehicle, sensors)
    return Grid(cells=cells, pose=jnp.zeros((n, 3), jnp.result_type(float)))
