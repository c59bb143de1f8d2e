"""Occupancy grid in the slot frame, frame transforms, exact footprint collision check.

Frames: the *slot frame* sits at the car's starting rear-axle centre, X along
the road in the direction the car faces, Y towards the road. A grid carries the
pose of its own frame (usually the slot frame itself, pose 0); cell ``[r, c]``
has its centre at ``(x_min + (c + 0.5) cell, y_min + (r + 0.5) cell)`` in the
grid's frame (``ParkoutConfig``). Cells beyond the grid count as occupied
(``config.outside_occupied``): a plan never leaves the space the grid covers.

The collision check works on a *cell table*: for every row and column the
column of the next occupied cell at or right of it (``cell_table``), so a row
interval is one look-up.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxplan.geometry import poses_to_boxes
from jaxplan.parking.config import ParkoutConfig


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Grid:
    """An occupancy grid and the pose of its frame.

    Attributes:
        cells: ``(..., rows, cols)`` bool (or 0/1), True = blocked: occupied, or
            unknown to the sensors (both are obstacles for the planner).
        pose: ``(..., 3)`` = [x, y, heading] of the grid's frame in the slot frame.
    """

    cells: Any
    pose: Any

    def validate(self, config: ParkoutConfig) -> Grid:
        c = np.asarray(self.cells)
        if c.shape[-2:] != (config.rows, config.cols):
            raise ValueError(f"Grid.cells: expected (..., {config.rows}, {config.cols}), got {c.shape}")
        if not (c.dtype == bool or np.all((c == 0) | (c == 1))):
            raise ValueError("Grid.cells must be 0 (free) or 1 (occupied)")
        p = np.asarray(self.pose)
        if p.shape[-1:] != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"Grid.pose: expected finite (..., 3), got shape {p.shape}")
        if p.shape[:-1] != c.shape[:-2]:
            raise ValueError(f"Grid.pose: batch shape {p.shape[:-1]} != cells batch shape {c.shape[:-2]}")
        return self


def to_frame(pose, xy):
    """World points ``(..., 2)`` into the frame of ``pose (..., 3)``. Returns ``(..., 2)``."""
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    dx, dy = xy[..., 0] - pose[..., 0], xy[..., 1] - pose[..., 1]
    return jnp.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def from_frame(pose, uv):
    """Points ``(..., 2)`` given in the frame of ``pose (..., 3)`` into the world."""
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    u, v = uv[..., 0], uv[..., 1]
    return jnp.stack([pose[..., 0] + c * u - s * v, pose[..., 1] + s * u + c * v], axis=-1)


def compose(pose, rel):
    """Pose ``rel (..., 3)`` given in the frame of ``pose (..., 3)``, in the world."""
    xy = from_frame(pose, rel[..., :2])
    th = jnp.arctan2(jnp.sin(pose[..., 2] + rel[..., 2]), jnp.cos(pose[..., 2] + rel[..., 2]))
    return jnp.concatenate([xy, th[..., None]], axis=-1)


def relative(pose, other):
    """Pose ``other (..., 3)`` (world) expressed in the frame of ``pose (..., 3)``."""
    uv = to_frame(pose, other[..., :2])
    d = other[..., 2] - pose[..., 2]
    return jnp.concatenate([uv, jnp.arctan2(jnp.sin(d), jnp.cos(d))[..., None]], axis=-1)


def cell_centres(config: ParkoutConfig, dtype=jnp.float32):
    """Centres of all cells in the grid's own frame, ``(rows, cols, 2)``."""
    h = config.cell
    u = config.x_min + (jnp.arange(config.cols, dtype=dtype) + 0.5) * h
    v = config.y_min + (jnp.arange(config.rows, dtype=dtype) + 0.5) * h
    uu, vv = jnp.meshgrid(u, v)
    return jnp.stack([uu, vv], axis=-1)


def world_to_cell(grid_pose, xy, config: ParkoutConfig):
    """Fractional cell coordinates ``(..., 2)`` = (row, col) of world points ``(..., 2)``.

    The centre of cell ``[r, c]`` maps to ``(r + 0.5, c + 0.5)``.
    """
    uv = to_frame(grid_pose, xy)
    h = config.cell
    return jnp.stack([(uv[..., 1] - config.y_min) / h, (uv[..., 0] - config.x_min) / h], axis=-1)


def cell_to_world(grid_pose, rc, config: ParkoutConfig):
    """Inverse of ``world_to_cell``: (row, col) ``(..., 2)`` to world points ``(..., 2)``."""
    h = config.cell
    return from_frame(grid_pose, jnp.stack([config.x_min + rc[..., 1] * h, config.y_min + rc[..., 0] * h], axis=-1))


def occupied_at(grid: Grid, xy, config: ParkoutConfig):
    """Occupancy of the cell holding each world point.

    Args:
        grid: one grid, ``cells (rows, cols)``, ``pose (3,)``.
        xy: ``(..., 2)`` world points.

    Returns:
        ``(...)`` bool; points beyond the grid read ``config.outside_occupied``.
    """
    rc = jnp.floor(world_to_cell(grid.pose, xy, config)).astype(jnp.int32)
    r, c = rc[..., 0], rc[..., 1]
    inside = (r >= 0) & (r < config.rows) & (c >= 0) & (c < config.cols)
    flat = jnp.asarray(grid.cells, bool).reshape(-1)
    val = flat[jnp.clip(r, 0, config.rows - 1) * config.cols + jnp.clip(c, 0, config.cols - 1)]
    return jnp.where(inside, val, config.outside_occupied)


def footprint_boxes(poses, vehicle, margin=0.0):
    """Car boxes ``(..., 5)`` at rear-axle poses ``(..., 3)``, inflated by ``margin``."""
    b = poses_to_boxes(poses[..., :2], poses[..., 2], vehicle)
    return b.at[..., 2:4].add(2 * margin)


def cell_table(cells):
    """Next occupied column per cell, stored column-major: ``(..., cols + 1, rows)`` int16.

    ``N[c, r]`` is the smallest ``c' >= c`` with cell ``[r, c']`` occupied, else
    ``cols`` (column ``cols`` is the sentinel). A row interval ``[a, b]`` holds an
    occupied cell iff ``N[a, r] <= b``: one look-up per row. (Column-major
    because the table is built by one pass over the columns.)
    """
    c = jnp.asarray(cells).astype(bool)
    cols = c.shape[-1]
    lead = c.shape[:-2]
    cm = jnp.moveaxis(c, -1, 0)  # (cols, ..., rows)

    def step(nxt, k):
        nxt = jnp.where(cm[k], k.astype(jnp.int16), nxt)
        return nxt, nxt

    _, out = lax.scan(step, jnp.full(cm.shape[1:], cols, jnp.int16), jnp.arange(cols - 1, -1, -1))
    out = jnp.concatenate([out[::-1], jnp.full((1,) + cm.shape[1:], cols, jnp.int16)], axis=0)
    return jnp.moveaxis(out, 0, len(lead))


def _rows_occupied(table, r, c_lo, c_hi, hit_row, config: ParkoutConfig, base=0):
    """Whether scanned rows ``r (..., R)`` hold an occupied cell centre in columns
    ``[c_lo, c_hi]`` (inside the grid); also which rows lie inside the grid.

    ``table`` may hold many grids' tables; ``base (...)`` is the flat offset of this one's.

    """
    in_rows = (r >= 0) & (r < config.rows)
    a = jnp.clip(c_lo, 0, config.cols).astype(jnp.int32)
    rr = jnp.clip(r, 0, config.rows - 1)
    base = jnp.asarray(base, jnp.int32)[..., None]
    nxt = table.reshape(-1)[base + a * config.rows + rr]
    return hit_row & in_rows & (nxt.astype(c_hi.dtype) <= jnp.minimum(c_hi, config.cols - 1.0)), in_rows


def _beyond(hit_row, in_rows, c_lo, c_hi, config: ParkoutConfig):
    """Rows whose interval of cell centres ``[c_lo, c_hi]`` (unclipped) holds one beyond the grid."""
    some = hit_row & (c_hi >= c_lo)
    left = c_lo <= jnp.minimum(c_hi, -1.0)
    right = jnp.maximum(c_lo, float(config.cols)) <= c_hi
    return some & (~in_rows | left | right)


def polygon_covers_occupied(table, grid_pose, poly, config: ParkoutConfig):
    """Whether a convex polygon contains the centre of an occupied cell.

    Exact scan conversion: for each of ``config.scan_rows`` grid rows around the
    polygon, the row's centre line cuts the polygon in one interval, looked up
    in the cell table. Cells beyond the grid read ``config.outside_occupied``.

    Args:
        table: ``(cols + 1, rows)`` from ``cell_table`` of one grid.
        grid_pose: ``(3,)`` pose of the grid's frame.
        poly: ``(..., N, 2)`` convex polygons in the world frame (any orientation).

    Returns:
        ``(...)`` bool.
    """
    rc = world_to_cell(grid_pose, poly, config)  # (..., N, 2) fractional (row, col)
    pr, pc = rc[..., 0] - 0.5, rc[..., 1] - 0.5  # cell-centre coordinates: centre r at r
    k = jnp.arange(config.scan_rows) - config.scan_rows // 2
    r = jnp.floor(jnp.mean(pr, axis=-1))[..., None].astype(jnp.int32) + k  # (..., R)
    y = r.astype(pr.dtype)[..., None]  # (..., R, 1)
    y0, y1 = pr[..., None, :], jnp.roll(pr, -1, axis=-1)[..., None, :]  # (..., 1, N)
    x0, x1 = pc[..., None, :], jnp.roll(pc, -1, axis=-1)[..., None, :]
    dy = y1 - y0
    cross = ((y0 <= y) & (y <= y1)) | ((y1 <= y) & (y <= y0))
    t = (y - y0) / jnp.where(dy == 0, 1.0, dy)
    x = jnp.where(dy == 0, jnp.where(cross, jnp.minimum(x0, x1), jnp.inf), x0 + t * (x1 - x0))
    xhi_e = jnp.where(dy == 0, jnp.where(cross, jnp.maximum(x0, x1), -jnp.inf), x)
    lo = jnp.min(jnp.where(cross, x, jnp.inf), axis=-1)  # (..., R)
    hi = jnp.max(jnp.where(cross, xhi_e, -jnp.inf), axis=-1)
    hit_row = jnp.isfinite(lo) & (hi >= lo)
    big = 4.0 * (config.cols + config.rows)
    c_lo = jnp.ceil(jnp.clip(jnp.where(hit_row, lo, 0.0), -big, big))
    c_hi = jnp.floor(jnp.clip(jnp.where(hit_row, hi, -1.0), -big, big))
    occ, in_rows = _rows_occupied(table, r, c_lo, c_hi, hit_row, config)
    if config.outside_occupied:
        occ = occ | _beyond(hit_row, in_rows, c_lo, c_hi, config)
    return jnp.any(occ, axis=-1)


def box_covers_occupied(table, grid_pose, boxes, config: ParkoutConfig, base=0):
    """``polygon_covers_occupied`` for oriented boxes ``(..., 5)``, by slabs (about 4x fewer flops).

    Each scanned row's centre line meets the box where both slab conditions
    ``|u| <= length/2`` and ``|v| <= width/2`` (box frame) hold; that interval is
    looked up in the cell table. Exact like the polygon version. ``base``: see
    ``footprint_hits_grid``.
    """
    h = config.cell
    c = world_to_cell(grid_pose, boxes[..., :2], config) - 0.5  # (..., 2) centre in cell-centre units
    cy, cx = c[..., 0], c[..., 1]
    phi = boxes[..., 4] - grid_pose[..., 2]
    cs, sn = jnp.cos(phi), jnp.sin(phi)
    tiny = 1e-9
    ic = 1.0 / jnp.where(jnp.abs(cs) < tiny, tiny, cs)
    is_ = 1.0 / jnp.where(jnp.abs(sn) < tiny, tiny, sn)
    hl, hw = 0.5 * boxes[..., 2] / h, 0.5 * boxes[..., 3] / h
    half_rows = 0.5 * (jnp.abs(boxes[..., 2] * sn) + jnp.abs(boxes[..., 3] * cs)) / h
    k = jnp.arange(config.scan_rows) - config.scan_rows // 2
    r = jnp.floor(cy)[..., None].astype(jnp.int32) + k  # (..., R)
    dy = r.astype(cy.dtype) - cy[..., None]
    # u = (x - cx) cs + dy sn ;  v = -(x - cx) sn + dy cs
    ku = dy * sn[..., None]
    kv = dy * cs[..., None]
    u1, u2 = (-hl[..., None] - ku) * ic[..., None], (hl[..., None] - ku) * ic[..., None]
    v1, v2 = (kv - hw[..., None]) * is_[..., None], (kv + hw[..., None]) * is_[..., None]
    lo = cx[..., None] + jnp.maximum(jnp.minimum(u1, u2), jnp.minimum(v1, v2))
    hi = cx[..., None] + jnp.minimum(jnp.maximum(u1, u2), jnp.maximum(v1, v2))
    hit_row = (hi >= lo) & (jnp.abs(dy) <= half_rows[..., None] + 1e-3)
    big = 4.0 * (config.cols + config.rows)
    c_lo = jnp.ceil(jnp.clip(lo, -big, big))
    c_hi = jnp.floor(jnp.clip(hi, -big, big))
    occ, in_rows = _rows_occupied(table, r, c_lo, c_hi, hit_row, config, base)
    if config.outside_occupied:
        occ = occ | _beyond(hit_row, in_rows, c_lo, c_hi, config)
    return jnp.any(occ, axis=-1)


def footprint_hits_grid(table, grid_pose, poses, vehicle, config: ParkoutConfig, margin=None, base=0):
    """Whether the footprint inflated by ``margin`` (default ``config.margin``) covers an occupied cell centre.

    Args:
        table: ``(cols + 1, rows)`` cell table of one grid (``cell_table``).
        grid_pose: ``(3,)`` the pose of that grid's frame.
        poses: ``(..., 3)`` rear-axle poses in the slot frame.
        margin: ``()`` or broadcastable to ``(..., 1)``.
        base: flat offset of this grid's table when ``table`` holds the tables of
            many grids (``(n, cols + 1, rows)``, base ``= i * rows * (cols + 1)``).

    Returns:
        ``(...)`` bool.
    """
    margin = config.margin if margin is None else margin
    return box_covers_occupied(table, grid_pose, footprint_boxes(poses, vehicle, margin), config, base)
