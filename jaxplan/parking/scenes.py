"""Parallel-slot scenes (obstacle boxes) and the surround-view grids they render."""
from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.grid import Grid, cell_centres, from_frame, to_frame
from jaxplan.types import VehicleParams

# obstacle kinds, in the order make_scenes lays them out
FRONT_CAR, REAR_CAR, NEXT_FRONT, NEXT_REAR, CURB = range(5)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Scene:
    """A slot scene in the initial world frame (the car's start pose is the origin).

    Attributes:
        boxes: ``(..., K, 5)`` obstacles [x, y, length, width, heading].
        valid: ``(..., K)`` bool.
        edge_noise: ``(...)`` each cell's obstacle boundary moves by a uniform
            random amount in ``[-edge_noise, edge_noise]`` metres when rendered.
        salt: ``(...)`` probability that a free cell reads occupied.
    """

    boxes: Any
    valid: Any
    edge_noise: Any
    salt: Any


def box_gap(boxes, xy):
    """Chebyshev-style signed gap of points ``(..., 2)`` to boxes ``(..., 5)``: <= 0 inside."""
    uv = to_frame(jnp.stack([boxes[..., 0], boxes[..., 1], boxes[..., 4]], -1), xy)
    return jnp.maximum(jnp.abs(uv[..., 0]) - 0.5 * boxes[..., 2], jnp.abs(uv[..., 1]) - 0.5 * boxes[..., 3])


def _mix(x):
    """A 32-bit integer hash (xor-shift-multiply), elementwise on uint32."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def hash_uniform(seed, shape, stream: int = 0, dtype=jnp.float32):
    """Uniform [0, 1) numbers from a counter hash of ``seed`` (uint32 ``(2,)`` key data or scalar).

    Much cheaper to compile than ``jax.random`` inside a batched loop; good
    enough for sensor noise, not for statistics that need a strong generator.
    """
    seed = jnp.asarray(seed).astype(jnp.uint32).reshape(-1)
    s = _mix(seed[0] ^ _mix(seed[-1] + jnp.uint32(0x9E3779B9 * (stream + 1) & 0xFFFFFFFF)))
    n = 1
    for k in shape:
        n *= k
    x = _mix(jnp.arange(n, dtype=jnp.uint32) * jnp.uint32(0x9E3779B9) ^ s)
    return ((x >> 8).astype(dtype) * (1.0 / (1 << 24))).reshape(shape)


def render_grid(scene: Scene, pose, key, config: ParkoutConfig, vehicle: VehicleParams) -> Grid:
    """The surround-view grid of one scene read at ``pose (3,)``.

    A cell is occupied when its centre lies inside an obstacle box grown by its
    edge noise, or by salt noise; cells under the car itself read free (the
    sensors do not see there). ``key``: a legacy PRNG key (uint32 ``(2,)``) or
    any uint32 seed; the noise comes from ``hash_uniform``.
    """
    pts = from_frame(pose, cell_centres(config, pose.dtype))  # (rows, cols, 2)
    shape = pts.shape[:-1]
    jitter = scene.edge_noise * (2.0 * hash_uniform(key, shape, 0, pose.dtype) - 1.0)

    def one(occ, kb):
        box, ok = kb
        return occ | (ok & (box_gap(box, pts) <= jitter)), None

    occ, _ = jax.lax.scan(one, jnp.zeros(pts.shape[:-1], bool), (scene.boxes, scene.valid))
    occ = occ | (hash_uniform(key, shape, 1, pose.dtype) < scene.salt)
    own = cell_centres(config, pose.dtype)
    off = vehicle.center_offset
    under = (jnp.abs(own[..., 0] - off) <= 0.5 * vehicle.length) & (jnp.abs(own[..., 1]) <= 0.5 * vehicle.width)
    return Grid(cells=occ & ~under, pose=pose)


def _rel(q, boxes):
    """Boxes (n, K, 5) from the slot frame into the frame of poses q (n, 3) (numpy)."""
    c, s = np.cos(q[:, 2])[:, None], np.sin(q[:, 2])[:, None]
    dx, dy = boxes[..., 0] - q[:, :1], boxes[..., 1] - q[:, 1:2]
    out = boxes.copy()
    out[..., 0] = c * dx + s * dy
    out[..., 1] = -s * dx + c * dy
    out[..., 4] = boxes[..., 4] - q[:, 2:3]
    return out


def make_scenes(rng: np.random.Generator, n: int, vehicle: VehicleParams = VehicleParams(), *,
                front_gap=1.0, rear_gap=1.0, heading_noise_deg=0.0, offset_noise=0.0,
                edge_noise=0.0, salt=0.0, clutter: int = 3, curb_gap=(0.25, 0.45),
                other_width=(1.75, 1.95), other_length=(4.2, 5.0), other_yaw_deg=1.0):
    """Random parallel-slot scenes around a parked car (host-side, numpy).

    In the slot frame the curb runs along X and the car's rear axle sits at the
    origin, heading 0, ``front_gap`` / ``rear_gap`` (scalars or ``(n,)``) from the
    cars ahead and behind (bumper to bumper), which stand ``curb_gap`` from the
    curb with random size and a small yaw. A further car stands beyond each,
    and ``clutter`` small boxes lie on the pavement. The car's start pose is then
    perturbed by a heading (``N(0, heading_noise_deg)``) and lateral offset
    (``U(-offset_noise, offset_noise)``), and the scene is expressed in that
    start frame (the initial world frame).

    Returns:
        (``Scene`` with ``K = 5 + clutter`` boxes, dict of per-scene ``(n,)`` arrays:
        front_gap, rear_gap, slot_length, front_corner_y (y of the front car's
        nearest rear corner in the initial frame), start (slot-frame pose)).
    """
    v = vehicle
    L, W, ro = float(v.length), float(v.width), float(v.rear_overhang)
    a = L - ro
    gf = np.broadcast_to(np.asarray(front_gap, float), (n,)).copy()
    gr = np.broadcast_to(np.asarray(rear_gap, float), (n,)).copy()
    yc = -0.5 * W - rng.uniform(*curb_gap, n)  # curb edge, our car's right side is curb_gap above it
    K = 5 + clutter
    boxes = np.zeros((n, K, 5))
    lens = rng.uniform(*other_length, (n, 4))
    wids = rng.uniform(*other_width, (n, 4))
    yaw = np.radians(other_yaw_deg) * rng.standard_normal((n, 4))
    cg = rng.uniform(*curb_gap, (n, 4))
    far = rng.uniform(0.6, 1.5, (n, 2))
    x_front = a + gf + 0.5 * lens[:, 0]
    x_rear = -ro - gr - 0.5 * lens[:, 1]
    xs = [x_front, x_rear, x_front + 0.5 * lens[:, 0] + far[:, 0] + 0.5 * lens[:, 2],
          x_rear - 0.5 * lens[:, 1] - far[:, 1] - 0.5 * lens[:, 3]]
    for i in range(4):
        boxes[:, i] = np.stack([xs[i], yc + cg[:, i] + 0.5 * wids[:, i], lens[:, i], wids[:, i], yaw[:, i]], -1)
    boxes[:, CURB] = np.stack([np.zeros(n), yc - 0.15, np.full(n, 60.0), np.full(n, 0.3), np.zeros(n)], -1)
    for j in range(clutter):
        size = rng.uniform(0.2, 0.6, (n, 2))
        boxes[:, 5 + j] = np.stack([rng.uniform(-8, 8, n), yc - 0.3 - size[:, 1] / 2 - rng.uniform(0, 2.5, n),
                                    size[:, 0], size[:, 1], rng.uniform(-np.pi, np.pi, n)], -1)
    q = np.stack([np.zeros(n), rng.uniform(-1, 1, n) * offset_noise,
                  np.radians(heading_noise_deg) * rng.standard_normal(n)], -1)
    rel = _rel(q, boxes)
    # y of the front car's rear corner nearest the road, in the initial frame
    fc = rel[:, FRONT_CAR]
    cs, sn = np.cos(fc[:, 4]), np.sin(fc[:, 4])
    corner_y = fc[:, 1] - 0.5 * fc[:, 2] * sn + 0.5 * fc[:, 3] * cs
    info = {"front_gap": gf, "rear_gap": gr, "slot_length": gf + gr + L, "front_corner_y": corner_y,
            "start": q}
    scene = Scene(boxes=jnp.asarray(rel, jnp.float32), valid=jnp.ones((n, K), bool),
                  edge_noise=jnp.full((n,), edge_noise, jnp.float32), salt=jnp.full((n,), salt, jnp.float32))
    return scene, info
