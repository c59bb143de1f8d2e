"""Park-out scenes: ``ParkingScene`` (obstacle polygons, start pose, sensor model) and the slot generator."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry import box_corners
from jaxplan.parking.grid import to_frame
from jaxplan.types import VehicleParams, check_finite

# obstacle kinds, in the order make_scenes lays them out
FRONT_CAR, REAR_CAR, NEXT_FRONT, NEXT_REAR, CURB, WALL, STOPPED = range(7)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ParkingScene:
    """A park-out scene in the slot frame (origin at the start rear axle, X along the road, Y to the road).

    Attributes:
        polygons: ``(..., K, N, 2)`` obstacle outlines (simple polygons, either
            orientation; shorter ones padded by repeating their last vertex).
        valid: ``(..., K)`` bool.
        start: ``(..., 3)`` rear-axle pose [x, y, heading] the car starts from
            (x = y = 0 by the frame's definition; heading = misalignment with the road).
        edge_noise: ``(...)`` each obstacle boundary the sensors see moves by a
            uniform random amount in ``[-edge_noise, edge_noise]`` metres per grid row.
        salt: ``(...)`` probability that a free cell reads occupied.
        occlusion: ``(...)`` bool; cells no car-mounted sensor sees (behind
            obstacles, beyond ``sensor_range``) read unknown, which blocks like
            an obstacle.
        sensor_range: ``(...)`` metres (``inf``: unlimited).
        unknown_patches: ``(...)`` probability that a 1 m x 1 m patch of the grid
            reads unknown (sensor dropout).
    """

    polygons: Any
    valid: Any
    start: Any
    edge_noise: Any
    salt: Any
    occlusion: Any
    sensor_range: Any
    unknown_patches: Any

    @classmethod
    def make(
        cls,
        polygons,
        valid=None,
        start=None,
        *,
        edge_noise=0.0,
        salt=0.0,
        occlusion=False,
        sensor_range=np.inf,
        unknown_patches=0.0,
    ) -> ParkingScene:
        """A scene (or batch) with default start pose and an ideal sensor; validated."""
        p = np.asarray(polygons, np.float64)
        lead = p.shape[:-3]
        f = lambda x, dt=np.float32: jnp.asarray(np.broadcast_to(np.asarray(x, dt), lead))  # noqa: E731
        v = np.ones(p.shape[:-2], bool) if valid is None else np.asarray(valid, bool)
        st = np.zeros(lead + (3,)) if start is None else np.asarray(start, np.float64)
        scene = cls(
            polygons=jnp.asarray(p, jnp.float32),
            valid=jnp.asarray(v),
            start=jnp.asarray(st, jnp.float32),
            edge_noise=f(edge_noise),
            salt=f(salt),
            occlusion=f(occlusion, bool),
            sensor_range=f(sensor_range),
            unknown_patches=f(unknown_patches),
        )
        return scene.validate()

    @property
    def batch_shape(self):
        return tuple(np.shape(self.salt))

    def validate(self) -> ParkingScene:
        p = check_finite("ParkingScene.polygons", self.polygons)
        if p.ndim < 3 or p.shape[-1] != 2 or p.shape[-2] < 3:
            raise ValueError(f"ParkingScene.polygons: expected (..., K, N >= 3, 2), got {p.shape}")
        lead = p.shape[:-3]
        if np.shape(self.valid) != p.shape[:-2]:
            raise ValueError(f"ParkingScene.valid: expected shape {p.shape[:-2]}, got {np.shape(self.valid)}")
        if np.shape(self.start) != lead + (3,):
            raise ValueError(f"ParkingScene.start: expected shape {lead + (3,)}, got {np.shape(self.start)}")
        check_finite("ParkingScene.start", self.start)
        for f in ("edge_noise", "salt", "sensor_range", "unknown_patches", "occlusion"):
            a = np.asarray(getattr(self, f))
            if a.shape != lead:
                raise ValueError(f"ParkingScene.{f}: expected shape {lead}, got {a.shape}")
            if f != "occlusion" and (np.any(np.isnan(a)) or np.any(a < 0)):
                raise ValueError(f"ParkingScene.{f} must be >= 0")
        for f in ("salt", "unknown_patches"):
            if np.any(np.asarray(getattr(self, f)) > 1):
                raise ValueError(f"ParkingScene.{f} is a probability, got values above 1")
        return self


def boxes_to_polygons(boxes):
    """Obstacle outlines ``(..., K, 4, 2)`` of boxes ``(..., K, 5)`` = [x, y, length, width, heading]."""
    return box_corners(boxes)


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


def _seed_word(seed, stream: int):
    seed = jnp.asarray(seed).astype(jnp.uint32).reshape(-1)
    return _mix(seed[0] ^ _mix(seed[-1] + jnp.uint32(0x9E3779B9 * (stream + 1) & 0xFFFFFFFF)))


def hash_uniform(seed, shape, stream: int = 0, dtype=jnp.float32):
    """Uniform [0, 1) numbers from a counter hash of ``seed`` (uint32 ``(2,)`` key data or scalar).

    Much cheaper to compile than ``jax.random`` inside a batched loop; good
    enough for sensor noise, not for statistics that need a strong generator.
    """
    n = 1
    for k in shape:
        n *= k
    x = _mix(jnp.arange(n, dtype=jnp.uint32) * jnp.uint32(0x9E3779B9) ^ _seed_word(seed, stream))
    return ((x >> 8).astype(dtype) * (1.0 / (1 << 24))).reshape(shape)


def hash_uniform_at(seed, ints, stream: int = 0, dtype=jnp.float32):
    """Uniform [0, 1) numbers at integer labels ``ints (...)`` (equal labels, equal numbers)."""
    x = _mix(jnp.asarray(ints).astype(jnp.uint32) * jnp.uint32(0x9E3779B9) ^ _seed_word(seed, stream))
    return (x >> 8).astype(dtype) * (1.0 / (1 << 24))


def make_scenes(
    rng: np.random.Generator,
    n: int,
    vehicle: VehicleParams = VehicleParams(),
    *,
    front_gap=1.0,
    rear_gap=1.0,
    heading_noise_deg=0.0,
    offset_noise=0.0,
    edge_noise=0.0,
    salt=0.0,
    clutter: int = 3,
    curb_gap: tuple[float, float] = (0.25, 0.45),
    other_width: tuple[float, float] = (1.75, 1.95),
    other_length: tuple[float, float] = (4.2, 5.0),
    other_yaw_deg=1.0,
    other_shift=0.0,
    wall_y=None,
    stopped_x=None,
    stopped_y=None,
    occlusion=False,
    sensor_range=np.inf,
    unknown_patches=0.0,
):
    """Random parallel-slot scenes around a parked car (host-side, numpy), in the slot frame.

    The curb runs along X; the car's rear axle sits at the origin with a heading
    of ``N(0, heading_noise_deg)`` (the slot frame stays level with the road), its
    box ``front_gap`` / ``rear_gap`` (scalars or ``(n,)``) from the cars ahead and
    behind (nearest points along X) and ``curb_gap`` (plus ``U(-offset_noise,
    offset_noise)``) from the curb. The neighbours stand ``curb_gap`` from the curb
    with random size, a yaw of ``N(0, other_yaw_deg)`` and a lateral shift of
    ``U(-other_shift, other_shift)`` (misaligned neighbours). A further car stands
    beyond each, and ``clutter`` small boxes lie on the pavement. ``wall_y``
    (``(n,)``, NaN = none) puts a wall along the far side of the road with its
    near face at that ``y``; ``stopped_x`` / ``stopped_y`` (``(n,)``, NaN = none) a
    car stopped in the lane, rear bumper at ``x``, centre at ``y``.

    Returns:
        (``ParkingScene`` with ``K = 7 + clutter`` obstacles, dict of per-scene
        ``(n,)`` arrays: front_gap, rear_gap, slot_length, front_corner_y (y of the
        front car's nearest rear corner), start (slot-frame start pose), boxes
        ``(n, K, 5)``).
    """
    v = vehicle
    L, W, ro = float(v.length), float(v.width), float(v.rear_overhang)
    a = L - ro
    vec = lambda x: np.broadcast_to(np.asarray(np.nan if x is None else x, float), (n,)).copy()  # noqa: E731
    gf, gr = vec(front_gap), vec(rear_gap)
    th0 = np.radians(heading_noise_deg) * rng.standard_normal(n)
    # the car's own box at its start pose: gaps and curb distance are measured from its corners
    u, w = np.array([a, -ro, -ro, a]), 0.5 * np.array([W, W, -W, -W])
    c0, s0 = np.cos(th0)[:, None], np.sin(th0)[:, None]
    cx, cy = u * c0 - w * s0, u * s0 + w * c0
    off = rng.uniform(-1, 1, n) * offset_noise
    yc = cy.min(1) - rng.uniform(*curb_gap, n) - off  # curb edge
    K = 7 + clutter
    boxes = np.zeros((n, K, 5))
    lens = rng.uniform(*other_length, (n, 4))
    wids = rng.uniform(*other_width, (n, 4))
    yaw = np.radians(other_yaw_deg) * rng.standard_normal((n, 4))
    cg = rng.uniform(*curb_gap, (n, 4)) + rng.uniform(-1, 1, (n, 4)) * other_shift
    far = rng.uniform(0.6, 1.5, (n, 2))
    # a yawed neighbour keeps its nearest bumper corner at the nominal gap
    ext = lambda i: 0.5 * (lens[:, i] * np.cos(yaw[:, i]) + wids[:, i] * np.abs(np.sin(yaw[:, i])))  # noqa: E731
    x_front = cx.max(1) + gf + ext(0)
    x_rear = cx.min(1) - gr - ext(1)
    xs = [x_front, x_rear, x_front + ext(0) + far[:, 0] + ext(2), x_rear - ext(1) - far[:, 1] - ext(3)]
    for i in range(4):
        boxes[:, i] = np.stack([xs[i], yc + cg[:, i] + 0.5 * wids[:, i], lens[:, i], wids[:, i], yaw[:, i]], -1)
    boxes[:, CURB] = np.stack([np.zeros(n), yc - 0.15, np.full(n, 60.0), np.full(n, 0.3), np.zeros(n)], -1)
    valid = np.ones((n, K), bool)
    wy = vec(wall_y)
    boxes[:, WALL] = np.stack(
        [np.zeros(n), np.nan_to_num(wy) + 0.25, np.full(n, 60.0), np.full(n, 0.5), np.zeros(n)], -1
    )
    valid[:, WALL] = np.isfinite(wy)
    sx, sy = vec(stopped_x), vec(stopped_y)
    sl, sw = rng.uniform(*other_length, n), rng.uniform(*other_width, n)
    boxes[:, STOPPED] = np.stack(
        [np.nan_to_num(sx) + 0.5 * sl, np.nan_to_num(sy), sl, sw, np.radians(2.0) * rng.standard_normal(n)], -1
    )
    valid[:, STOPPED] = np.isfinite(sx) & np.isfinite(sy)
    for j in range(clutter):
        size = rng.uniform(0.2, 0.6, (n, 2))
        boxes[:, 7 + j] = np.stack(
            [
                rng.uniform(-8, 8, n),
                yc - 0.3 - size[:, 1] / 2 - rng.uniform(0, 2.5, n),
                size[:, 0],
                size[:, 1],
                rng.uniform(-np.pi, np.pi, n),
            ],
            -1,
        )
    start = np.stack([np.zeros(n), np.zeros(n), th0], -1)
    fc = boxes[:, FRONT_CAR]
    cs, sn = np.cos(fc[:, 4]), np.sin(fc[:, 4])
    corner_y = fc[:, 1] - 0.5 * fc[:, 2] * sn * np.sign(cs) + 0.5 * fc[:, 3] * np.abs(cs)
    info = {
        "front_gap": gf,
        "rear_gap": gr,
        "slot_length": gf + gr + L,
        "front_corner_y": corner_y,
        "start": start,
        "boxes": boxes,
    }
    poly = np.asarray(box_corners(jnp.asarray(boxes.reshape(-1, 5)))).reshape(n, K, 4, 2)
    scene = ParkingScene.make(
        poly,
        valid,
        start,
        edge_noise=edge_noise,
        salt=salt,
        occlusion=occlusion,
        sensor_range=sensor_range,
        unknown_patches=unknown_patches,
    )
    return scene, info
