"""``ParkoutConfig``: the static sizes and thresholds of the park-out planner."""
from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class ParkoutConfig:
    """Sizes, counts and thresholds (hashable, static under ``jit``).

    Lengths in metres, angles in degrees where the name says ``_deg``.

    Attributes:
        rows, cols, cell: the surround-view grid, ``rows x cols`` cells of ``cell``
            metres, centred on the rear-axle centre, rows along the car's Y axis.
        c: stop line at ``y = d = vehicle.width + c`` in the initial frame.
        dl: step length of the rollout; ``steps`` points per trajectory.
        look_ahead: pure-pursuit look-ahead distance along the reference curve.
        steer_rate: largest change of the front steering angle per step [rad].
        steer_in_place: the wheels may be turned at standstill before the first
            step (the first step is not rate limited).
        theta1_deg: below this heading the backward curve is the line ``y = 0``.
        back_cap: length cap of that line.
        theta2_deg: the backward circle O2 stops once the heading exceeds this.
        out_heading_deg, out_tol_deg: full park-out needs ``y >= d`` and
            ``|heading - out_heading| < out_tol``. The default 0 is the heading at
            which the forward reference curve meets the stop line (see the notes).
        overshoot: the forward curve aims ``overshoot`` above the stop line so that
            the rollout crosses it instead of approaching it asymptotically.
        margin: the footprint is inflated by this much on every side in the
            collision check.
        shrink_margin: if the current pose is already within ``margin`` of an
            occupied cell (a car parked close to the curb), plan with the largest
            of four margins from ``margin`` down to ``min_margin`` that is clear at
            the current pose (else ``min_margin``, which then stops the car).
        min_margin: the floor; it should cover the grid's error (half a cell
            diagonal plus the sensor's edge noise) or the exact footprint may
            touch a true obstacle by that much.
        scan_rows: grid rows scanned per pose in the footprint check; must cover
            the inflated footprint's diagonal (``hypot(L + 2m, W + 2m) / cell + 2``).
        max_moves: drive / re-plan cycles before ``park_out`` gives up.
        min_progress: a chosen move shorter than this counts as stuck.
        ref_samples: samples of the reference curve used for the projection.
        outside_occupied: how cells beyond the grid count in the check.
    """

    rows: int = 200
    cols: int = 400
    cell: float = 0.05
    c: float = 1.0
    dl: float = 0.05
    steps: int = 160
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
    max_moves: int = 8
    min_progress: float = 0.05
    ref_samples: int = 160
    outside_occupied: bool = False

    def __post_init__(self):
        for f in ("rows", "cols", "steps", "max_moves", "ref_samples"):
            if int(getattr(self, f)) < 1:
                raise ValueError(f"ParkoutConfig.{f} must be >= 1")
        for f in ("cell", "dl", "look_ahead", "steer_rate", "back_cap"):
            v = getattr(self, f)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"ParkoutConfig.{f} must be positive, got {v}")
        if self.margin < 0 or self.c < 0 or not 0 <= self.min_margin <= self.margin:
            raise ValueError("ParkoutConfig: need margin >= min_margin >= 0 and c >= 0")
        if self.scan_rows < 2:
            raise ValueError("ParkoutConfig.scan_rows must be >= 2")

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
            raise ValueError(f"ParkoutConfig.scan_rows={self.scan_rows} does not cover a footprint of "
                             f"diagonal {diag:.2f} m on {self.cell} m cells; use at least {need}")
