"""``ParkoutConfig``: the static sizes and thresholds of the park-out planner."""

from __future__ import annotations

import dataclasses
import math
from typing import Any


@dataclasses.dataclass(frozen=True)
class ParkoutConfig:
    """Sizes, counts and thresholds (hashable, static under ``jit``).

    Lengths in metres, angles in degrees where the name says ``_deg``. The
    planner works in the *slot frame*: origin at the car's starting rear-axle
    centre, X along the road (the direction the car faces), Y towards the road.

    Attributes:
        rows, cols, cell, x_min, y_min: the occupancy grid, ``rows x cols`` cells
            of ``cell`` metres; cell ``[r, c]`` has its centre at
            ``(x_min + (c + 0.5) cell, y_min + (r + 0.5) cell)`` in the grid's
            frame. The default spans x in [-11, 15] m and y in [-2.5, 7] m around
            the start (``ParkoutConfig.for_vehicle`` of the default car): every
            footprint the moves can reach (see ``for_vehicle``).
        outside_occupied: cells beyond the grid count as occupied (default), so a
            plan never leaves the space the grid has seen.
        c: stop line at ``y = d = vehicle.width + c`` in the slot frame.
        dl: step length of every rollout; ``steps`` points per forward-curve move,
            ``back_steps`` per backward-curve move.
        look_ahead: pure-pursuit look-ahead distance along the reference curve.
        steer_rate: largest change of the front steering angle per step [rad].
        steer_in_place: the wheels may be turned at standstill before the first
            step (the first step is not rate limited).
        theta1_deg: below this heading the backward curve is the line ``y = 0``.
        back_cap: length cap of that line.
        theta2_deg: the backward circle O2 stops once the heading exceeds this.
        out_heading_deg, out_tol_deg: full park-out needs ``y >= d`` and
            ``|heading - out_heading| < out_tol`` (level with the road).
        overshoot: the forward curve aims ``overshoot`` above the stop line so that
            the rollout crosses it instead of approaching it asymptotically.
        margin: the footprint is inflated by this much on every side in the
            collision check.
        shrink_margin: if the current pose is already within ``margin`` of an
            occupied cell (a car parked close to the curb), plan with the largest
            of four margins from ``margin`` down to ``min_margin`` that is clear at
            the current pose (else ``min_margin``, which then stops the car).
        min_margin: the floor; it should cover the grid's error (half a cell
            diagonal plus the sensor's edge noise).
        scan_rows: grid rows scanned per pose in the footprint check; must cover
            the inflated footprint's diagonal (``hypot(L + 2m, W + 2m) / cell + 3``).
        max_moves: moves of a whole park-out (two-curve loop and search alike).
        min_progress: a chosen move shorter than this counts as stuck.
        search: when the two reference curves fail (stuck, out of moves or no
            progress), search over moves at several steering levels (a beam
            search, ``jaxplan.parking.search``).
        steer_levels: steering levels of the search's arcs, as fractions of
            ``max_steer`` (each driven forward and backward).
        arc_steps: points per search arc (``arc_steps * dl`` metres at most).
        beam: nodes kept per search depth.
        gear_penalty: search cost of a gear change, in metres of driving.
        v_forward, v_reverse: cruise speed of forward and reverse moves [m/s].
        accel: acceleration and braking of the speed profile [m/s^2].
        steer_speed: largest steering-wheel rate at the road wheels [rad/s]; the
            speed profile slows down where the path's steering changes fast.
    """

    rows: int = 190
    cols: int = 520
    cell: float = 0.05
    x_min: float = -11.0
    y_min: float = -2.5
    outside_occupied: bool = True
    c: float = 1.0
    dl: float = 0.05
    steps: int = 160
    back_steps: int = 80
    look_ahead: float = 1.0
    steer_rate: float = 0.05
    steer_in_place: bool = True
    theta1_deg: float = 5.0
    back_cap: float = 2.0
    theta2_deg: float = 45.0
    out_heading_deg: float = 0.0
    out_tol_deg: float = 10.0
    overshoot: float = 0.03
    margin: float = 0.1
    shrink_margin: bool = True
    min_margin: float = 0.05
    scan_rows: int = 112
    max_moves: int = 16
    min_progress: float = 0.05
    search: bool = True
    steer_levels: tuple = (1.0, 0.4, -0.4, -1.0)
    arc_steps: int = 48
    beam: int = 8
    gear_penalty: float = 1.0
    v_forward: float = 1.0
    v_reverse: float = 0.6
    accel: float = 0.5
    steer_speed: float = 0.4

    def __post_init__(self):
        for f in ("rows", "cols", "steps", "back_steps", "max_moves", "arc_steps", "beam"):
            if int(getattr(self, f)) < 1:
                raise ValueError(f"ParkoutConfig.{f} must be >= 1")
        for f in (
            "cell",
            "dl",
            "look_ahead",
            "steer_rate",
            "back_cap",
            "v_forward",
            "v_reverse",
            "accel",
            "steer_speed",
        ):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"ParkoutConfig.{f} must be positive, got {v}")
        for f in ("x_min", "y_min", "gear_penalty"):
            if not math.isfinite(getattr(self, f)):
                raise ValueError(f"ParkoutConfig.{f} must be finite")
        if self.margin < 0 or self.c < 0 or not 0 <= self.min_margin <= self.margin:
            raise ValueError("ParkoutConfig: need margin >= min_margin >= 0 and c >= 0")
        if self.scan_rows < 2:
            raise ValueError("ParkoutConfig.scan_rows must be >= 2")
        if self.cols + 1 > 32767:
            raise ValueError("ParkoutConfig.cols must be below 32767 (int16 cell tables)")
        if not self.steer_levels or any(not (math.isfinite(s) and -1 <= s <= 1) for s in self.steer_levels):
            raise ValueError("ParkoutConfig.steer_levels: fractions of max_steer in [-1, 1], at least one")
        if self.back_steps > self.steps or self.arc_steps > self.steps:
            raise ValueError("ParkoutConfig: back_steps and arc_steps must not exceed steps")

    @property
    def x_max(self):
        return self.x_min + self.cols * self.cell

    @property
    def y_max(self):
        return self.y_min + self.rows * self.cell

    @property
    def theta1(self):
        return math.radians(self.theta1_deg)

    @property
    def theta2(self):
        return math.radians(self.theta2_deg)

    @property
    def out_heading(self):
        return math.radians(self.out_heading_deg)

    @property
    def out_tol(self):
        return math.radians(self.out_tol_deg)

    def check_vehicle(self, vehicle) -> None:
        """Host-side: ``scan_rows`` covers the inflated footprint of ``vehicle``."""
        import numpy as np

        diag = np.hypot(np.max(vehicle.length) + 2 * self.margin, np.max(vehicle.width) + 2 * self.margin)
        need = int(np.ceil(diag / self.cell)) + 3
        if self.scan_rows < need:
            raise ValueError(
                f"ParkoutConfig.scan_rows={self.scan_rows} does not cover a footprint of "
                f"diagonal {diag:.2f} m on {self.cell} m cells; use at least {need}"
            )

    @classmethod
    def for_vehicle(cls, vehicle, **overrides) -> ParkoutConfig:
        """A config whose grid and scan rows fit ``vehicle`` (host side, concrete sizes).

        The grid spans what the moves can reach, with ``R`` the smallest turning
        radius and ``d = width + c`` the stop line: ahead ``2 R + length`` (a
        forward exit turns through two quarter circles at most, the front bumper
        beyond them), behind ``2 R + rear_overhang`` (a reverse exit), towards the
        road ``d + length - rear_overhang`` (the front corner swinging out above
        the stop line), towards the curb ``width / 2 + 1.5`` m; each rounded out
        to whole metres (half metres at the curb). The default config is this
        for the default car.
        """
        import numpy as np

        base = cls(**overrides)
        L, W = float(np.max(vehicle.length)), float(np.max(vehicle.width))
        R = float(np.max(vehicle.wheelbase / np.tan(vehicle.max_steer)))
        ro = float(np.max(vehicle.rear_overhang))
        h = base.cell
        x_min = -math.ceil(2 * R + ro)
        x_max = math.ceil(2 * R + L)
        y_min = -math.ceil(2 * (0.5 * W + 1.5)) / 2
        y_max = math.ceil(W + base.c + L - ro)
        diag = math.hypot(L + 2 * base.margin, W + 2 * base.margin)
        fields: dict[str, Any] = dict(
            x_min=float(x_min),
            y_min=float(y_min),
            cols=int(round((x_max - x_min) / h)),
            rows=int(round((y_max - y_min) / h)),
            scan_rows=int(math.ceil(diag / h)) + 3,
        )
        fields.update(overrides)
        return dataclasses.replace(base, **fields)
