"""Lazy replanning supervisor and the two usual baselines, as one pure decision function.

Strategies (int codes, traced, so one compiled simulator serves all three):

* ``LAZY``: re-plan only at an *intermediate destination* with the car (near)
  stopped: at a gear-shift point when the freshly observed goal moved or turned
  more than a threshold (``GOAL``); at a brake-stop point, because the obstacle
  is real (``OBSTACLE``, at most once per ``retry_s`` while blocked). Never while moving.
* ``PERIODIC``: re-plan every ``1 / periodic_hz`` seconds, moving or not.
* ``IMMEDIATE``: re-plan at once whenever a new collision point is detected
  (``OBSTACLE``) or the observed goal moved more than the threshold (``GOAL``).

All strategies re-plan when the tracking point has been lost for ``lost_time``
and the car has stopped (``LOST``), and when the car stands at the end of a plan
that the planner flagged as not reaching the goal (``OBSTACLE``, once per
``retry_s``); none re-plans once the run is done.
"""
from __future__ import annotations

import dataclasses

import jax.numpy as jnp

LAZY, PERIODIC, IMMEDIATE = 0, 1, 2
STRATEGY_NAMES = ("lazy", "periodic", "immediate")
NO_REPLAN, GOAL, OBSTACLE, LOST, PERIOD = 0, 1, 2, 3, 4
REASON_NAMES = ("none", "goal", "obstacle", "lost", "periodic")


@dataclasses.dataclass(frozen=True)
class SupervisorConfig:
    """Supervisor settings (static, hashable). Times in s, distances in m, angles in rad."""

    dt: float = 0.1
    collision_hz: float = 10.0
    window_s: float = 2.0
    brake_safety: float = 0.5
    queue_size: int = 32
    v_stopped: float = 0.05
    at_point_tol: float = 0.3
    goal_pos_thresh: float = 0.2
    goal_yaw_thresh: float = 0.1
    lost_time: float = 1.0
    track_window: int = 32
    track_max_dist: float = 1.0
    periodic_hz: float = 1.0
    retry_s: float = 1.0
    max_sub: int = 8

    def __post_init__(self):
        for f in ("dt", "collision_hz", "periodic_hz", "v_stopped", "at_point_tol", "track_max_dist"):
            if not float(getattr(self, f)) > 0:
                raise ValueError(f"SupervisorConfig.{f} must be positive, got {getattr(self, f)}")
        for f in ("window_s", "brake_safety", "goal_pos_thresh", "goal_yaw_thresh", "lost_time", "retry_s"):
            if not float(getattr(self, f)) >= 0:
                raise ValueError(f"SupervisorConfig.{f} must be >= 0, got {getattr(self, f)}")
        for f in ("queue_size", "track_window", "max_sub"):
            if int(getattr(self, f)) < 1:
                raise ValueError(f"SupervisorConfig.{f} must be >= 1, got {getattr(self, f)}")

    @property
    def collision_every(self) -> int:
        """Collision check every this many simulation steps."""
        return max(1, int(round(1.0 / (self.collision_hz * self.dt))))


def goal_moved(goal_est, plan_goal, cfg: SupervisorConfig):
    """Whether the believed goal ``(..., 3)`` moved or turned more than the thresholds from the plan's."""
    d = jnp.linalg.norm(goal_est[..., :2] - plan_goal[..., :2], axis=-1)
    dy = jnp.abs(jnp.arctan2(jnp.sin(goal_est[..., 2] - plan_goal[..., 2]), jnp.cos(goal_est[..., 2] - plan_goal[..., 2])))
    return (d > cfg.goal_pos_thresh) | (dy > cfg.goal_yaw_thresh)


def replan_decision(strategy, cfg: SupervisorConfig, *, stopped, at_gear_shift, at_brake_stop, goal_moved,
                    new_collision, lost_stopped, since_replan, done, at_blocked_end=False):
    """Whether to re-plan now and why.

    Args (all ``(...)`` arrays): strategy (int code); stopped (speed below
    ``v_stopped``); at_gear_shift / at_brake_stop (the car is at that point);
    goal_moved (fresh goal differs from the plan's); new_collision (a collision
    point was detected this tick); lost_stopped (tracking lost long enough and
    stopped); since_replan (s since the last re-plan); done (run over).

    Returns:
        (replan ``(...)`` bool, reason ``(...)`` int).
    """
    lazy_obstacle = stopped & at_brake_stop & (since_replan >= cfg.retry_s - 1e-6)
    lazy_goal = stopped & at_gear_shift & goal_moved
    lazy_reason = jnp.where(lazy_obstacle, OBSTACLE, jnp.where(lazy_goal, GOAL, NO_REPLAN))
    periodic_reason = jnp.where(since_replan >= 1.0 / cfg.periodic_hz - 1e-6, PERIOD, NO_REPLAN)
    immediate_reason = jnp.where(new_collision, OBSTACLE, jnp.where(goal_moved, GOAL, NO_REPLAN))
    reason = jnp.where(strategy == LAZY, lazy_reason, jnp.where(strategy == PERIODIC, periodic_reason,
                                                                  immediate_reason))
    blocked_end = stopped & at_blocked_end & (since_replan >= cfg.retry_s - 1e-6)
    reason = jnp.where(blocked_end & (reason == NO_REPLAN), OBSTACLE, reason)
    reason = jnp.where(lost_stopped, LOST, reason)
    reason = jnp.where(done, NO_REPLAN, reason)
    return reason != NO_REPLAN, reason.astype(jnp.int32)
