"""Named families of park-out scenes (host side), in the slot frame and as world-frame scene files.

Each family draws slots with a random spare length (front gap + rear gap,
split at random) and a random world placement (origin, road heading, and the
side the road is on), so a scene file exercises the mirror for a road on the
right. Families:

* ``standard``: plain slots (aligned neighbours, empty road), road on the left.
* ``right``: the same slots with the road on the right.
* ``wall``: a narrow road, a wall along its far side with its near face 4.6 to
  6.0 m from the start rear axle.
* ``stopped``: a car stopped in the lane (centre 2.6 to 3.6 m into the road),
  ahead (rear bumper 9 to 14 m ahead of the start rear axle) or behind (front
  bumper 6 to 10 m behind it).
* ``angled``: neighbours yawed by N(0, 6 deg), shifted +-0.3 m sideways, the car
  itself 3 deg off the road.
* ``sensor``: the standard slots seen by the car's sensors: occlusion, a 15 m
  range, unknown 1 m patches (0.5 % of them, beyond 3 m of the car), 3 cm edge
  noise and false positives.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxplan.parking.frames import LEFT, RIGHT, SlotFrame, axle_to_centre
from jaxplan.parking.scenes import make_scenes
from jaxplan.types import VehicleParams

FAMILIES = ("standard", "right", "wall", "stopped", "angled", "sensor")


def family_scenes(
    name: str,
    rng: np.random.Generator,
    n: int,
    vehicle: VehicleParams = VehicleParams(),
    spare: tuple[float, float] | np.ndarray = (1.5, 3.0),
    **overrides,
):
    """``n`` slot-frame scenes of family ``name``; returns (``ParkingScene``, info dict with ``side`` too).

    ``spare``: range of front gap + rear gap in metres (or an ``(n,)`` array).
    """
    if name not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, got {name!r}")
    sp = rng.uniform(*spare, n) if isinstance(spare, tuple) else np.broadcast_to(np.asarray(spare, float), (n,))
    split = rng.uniform(0.15, 0.85, n)
    kw: dict[str, Any] = dict(front_gap=sp * split, rear_gap=sp * (1 - split), heading_noise_deg=1.0, offset_noise=0.05)
    side = np.full(n, LEFT, dtype="<U5")
    if name == "right":
        side[:] = RIGHT
    elif name == "wall":
        kw["wall_y"] = rng.uniform(4.6, 6.0, n)
    elif name == "stopped":
        ahead = rng.random(n) < 0.75
        kw["stopped_x"] = np.where(ahead, rng.uniform(9.0, 14.0, n), -rng.uniform(6.0, 10.0, n) - 4.6)
        kw["stopped_y"] = rng.uniform(2.6, 3.6, n)
    elif name == "angled":
        kw.update(other_yaw_deg=6.0, other_shift=0.3, heading_noise_deg=3.0)
    elif name == "sensor":
        kw.update(occlusion=True, sensor_range=15.0, unknown_patches=0.005, edge_noise=0.03, salt=1e-5)
    if name in ("wall", "stopped", "angled"):
        side = np.where(rng.random(n) < 0.5, LEFT, RIGHT)
    kw.update(overrides)
    scene, info = make_scenes(rng, n, vehicle, **kw)
    info["side"] = side
    info["spare"] = sp
    return scene, info


def scene_dicts(scene, info, vehicle: VehicleParams, rng: np.random.Generator):
    """World-frame scene-file dicts of slot-frame scenes (random origin and road heading; ``info['side']``)."""
    out = []
    polys = np.asarray(scene.polygons, float)
    valid = np.asarray(scene.valid)
    starts = np.asarray(scene.start, float)
    for i in range(len(starts)):
        road = float(rng.uniform(-np.pi, np.pi))
        frame = SlotFrame(
            origin=tuple(rng.uniform(-200, 200, 2)), heading=road, sign=1 if info["side"][i] == LEFT else -1
        )
        start = axle_to_centre(frame.to_world_pose(starts[i]), vehicle)
        obs = [
            {"polygon": np.round(frame.to_world_xy(polys[i, k]), 6).tolist()}
            for k in range(polys.shape[1])
            if valid[i, k]
        ]
        out.append(
            {
                "vehicle": {
                    f: float(getattr(vehicle, f))
                    for f in ("length", "width", "wheelbase", "rear_overhang", "max_steer")
                },
                "start": {"x": float(start[0]), "y": float(start[1]), "heading": float(start[2])},
                "road_heading": road,
                "side": str(info["side"][i]),
                "obstacles": obs,
            }
        )
    return out
