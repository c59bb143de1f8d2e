"""What both peers' closed loops share: a driven row from a rear-axle state, the fallback brake when
a planner has no plan left, CommonRoad's goal check on the car's centre, and the route cropped to
what a drive can reach and extended backwards for planners that plan from the rear axle."""

from __future__ import annotations

import math

import numpy as np

from .config import WB_REAR


def _centre_row(k: int, dt: float, rear_x, rear_y, th, v, a) -> list:
    """A driven.json row from a rear-axle state."""
    return [
        round(k * dt, 6),
        float(rear_x + WB_REAR * math.cos(th)),
        float(rear_y + WB_REAR * math.sin(th)),
        float(th),
        float(v),
        float(a),
    ]


BRAKE = 8.0  # m/s^2: the fallback when a planner has no plan left (straight ahead, then standing)


def _brake(x: tuple, dt: float) -> tuple:
    """One step of the fallback from rear-axle state ``(x, y, theta, v, a)``: brake straight ahead."""
    v1 = max(0.0, x[3] - BRAKE * dt)
    d = 0.5 * (x[3] + v1) * dt
    return (x[0] + d * math.cos(x[2]), x[1] + d * math.sin(x[2]), x[2], v1, -BRAKE if x[3] > 0 else 0.0)


def _goal_reached(pp, row: list, k: int) -> bool:
    from commonroad.scenario.state import KSState

    return bool(
        pp.goal.is_reached(
            KSState(
                time_step=int(k),
                position=np.array(row[1:3]),
                orientation=float(math.remainder(row[3], 2 * math.pi)),
                velocity=float(row[4]),
                steering_angle=0.0,
            )
        )
    )


def _crop_route(job: dict, start) -> np.ndarray:
    """The route up to 1 km past what the drive can reach (a route planner may return kilometres:
    DEU_Hhr-1_1's goal lies behind the start, at the end of a 4.6 km loop); its start as given."""
    r = np.asarray(job["route"], float)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))])
    near = s <= 200.0  # the route begins at the start lanelet; a loop's end may pass the start again
    s0 = s[near][int(np.argmin(np.linalg.norm(r[near] - np.asarray(start, float), axis=1)))]
    reach = (max(job["v_set"], job.get("v0", 0.0)) + 10.0) * job["steps"] * 0.1 + 100.0
    keep = s <= s0 + reach + 1000.0
    return r[keep] if keep.sum() >= 2 else r


def _extend_back(ref: np.ndarray, metres: float = 10.0) -> np.ndarray:
    """The route extended ``metres`` straight backwards (the peers plan from the rear axle, which can lie
    behind the route's first point)."""
    u = ref[0] - ref[1]
    return np.concatenate([ref[:1] + np.linspace(metres, 1.0, 10)[:, None] * u / np.linalg.norm(u), ref])
