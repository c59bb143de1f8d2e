"""The slot frame of a scene given in world coordinates (host side, float64).

The slot frame has its origin at the car's starting rear-axle centre, X along
the road in the direction the car faces (``road_heading`` or its reverse,
whichever is nearer the car's heading) and Y towards the road. A road on the
car's right is mirrored (Y points right in the world), so the planner always
sees the road on its left; poses map back with the heading mirrored too.
"""

from __future__ import annotations

import dataclasses

import numpy as np

LEFT, RIGHT = "left", "right"


def wrap(a):
    """Angles wrapped to (-pi, pi] (numpy)."""
    return np.angle(np.exp(1j * np.asarray(a, float)))


@dataclasses.dataclass(frozen=True)
class SlotFrame:
    """World pose of the slot frame.

    Attributes:
        origin: world (x, y) of the slot frame's origin.
        heading: world direction of the slot frame's X axis [rad].
        sign: +1 if Y (towards the road) is the world's left of X, -1 if its right.
    """

    origin: tuple
    heading: float
    sign: int

    @classmethod
    def of_start(cls, centre_xy, heading, road_heading, side, vehicle) -> SlotFrame:
        """The frame of a car whose box centre is at ``centre_xy`` with ``heading`` (world)."""
        road = float(road_heading)
        if np.cos(heading - road) < 0:
            road += np.pi
        off = float(vehicle.length) / 2 - float(vehicle.rear_overhang)
        axle = np.asarray(centre_xy, float) - off * np.array([np.cos(heading), np.sin(heading)])
        return cls(origin=(float(axle[0]), float(axle[1])), heading=float(wrap(road)), sign=1 if side == LEFT else -1)

    def _axes(self):
        c, s = np.cos(self.heading), np.sin(self.heading)
        return np.array([c, s]), self.sign * np.array([-s, c])

    def to_slot_xy(self, xy):
        """World points ``(..., 2)`` to the slot frame."""
        ex, ey = self._axes()
        d = np.asarray(xy, float) - np.asarray(self.origin)
        return np.stack([d @ ex, d @ ey], -1)

    def to_world_xy(self, uv):
        """Slot-frame points ``(..., 2)`` to the world."""
        ex, ey = self._axes()
        uv = np.asarray(uv, float)
        return np.asarray(self.origin) + uv[..., :1] * ex + uv[..., 1:2] * ey

    def to_slot_heading(self, th):
        return wrap(self.sign * (np.asarray(th, float) - self.heading))

    def to_world_heading(self, th):
        return wrap(self.heading + self.sign * np.asarray(th, float))

    def to_slot_pose(self, p):
        """World poses ``(..., 3)`` to the slot frame."""
        p = np.asarray(p, float)
        return np.concatenate([self.to_slot_xy(p[..., :2]), self.to_slot_heading(p[..., 2])[..., None]], -1)

    def to_world_pose(self, p):
        """Slot-frame poses ``(..., 3)`` to the world."""
        p = np.asarray(p, float)
        return np.concatenate([self.to_world_xy(p[..., :2]), self.to_world_heading(p[..., 2])[..., None]], -1)


def axle_to_centre(poses, vehicle):
    """Rear-axle poses ``(..., 3)`` to box-centre poses (numpy)."""
    p = np.asarray(poses, float)
    off = float(vehicle.length) / 2 - float(vehicle.rear_overhang)
    return np.concatenate([p[..., :2] + off * np.stack([np.cos(p[..., 2]), np.sin(p[..., 2])], -1), p[..., 2:3]], -1)


def centre_to_axle(poses, vehicle):
    """Box-centre poses ``(..., 3)`` to rear-axle poses (numpy)."""
    p = np.asarray(poses, float)
    off = float(vehicle.length) / 2 - float(vehicle.rear_overhang)
    return np.concatenate([p[..., :2] - off * np.stack([np.cos(p[..., 2]), np.sin(p[..., 2])], -1), p[..., 2:3]], -1)
