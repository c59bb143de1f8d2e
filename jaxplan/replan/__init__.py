"""Lazy replanning: plan points and gear-shift split, tracking point search, the
collision-point queue and brake-stop point, time-aware obstacle prediction, a drivable
Dubins planner, the supervisor (one safety layer; lazy, periodic and immediate
strategies) and a closed-loop simulator with a planner callback."""
from jaxplan.replan.dubins import DubinsPath
from jaxplan.replan.longitudinal import MotionLimits, advance, arrival_times, profile_speed, profile_times, speed_step
from jaxplan.replan.path_planner import ApproachPlanner, max_curvature, nominal_forward_path
from jaxplan.replan.planner import Plan, PlanRequest, finish_plan
from jaxplan.replan.prediction import first_contact, plan_separation, swept_boxes
from jaxplan.replan.queue import (
                                  BrakeStop,
                                  CollisionQueue,
                                  ObstacleMemory,
                                  brake_init,
                                  collision_arc_length,
                                  first_collision_point,
                                  memory_init,
                                  memory_update,
                                  queue_clear,
                                  queue_expire,
                                  queue_init,
                                  queue_nearest,
                                  queue_push,
                                  queue_reanchor,
                                  queue_size,
                                  update_brake_stop,
)
from jaxplan.replan.scenarios import sample_scenarios
from jaxplan.replan.simulator import (
                                  Scenario,
                                  SimConfig,
                                  StepLog,
                                  WorldState,
                                  init_state,
                                  run_summary,
                                  simulate,
                                  simulate_host,
                                  step_post,
                                  step_pre,
)
from jaxplan.replan.supervisor import (
                                  GOAL,
                                  IMMEDIATE,
                                  LAZY,
                                  LOST,
                                  NO_REPLAN,
                                  OBSTACLE,
                                  PERIOD,
                                  PERIODIC,
                                  REASON_NAMES,
                                  REJECT_COLLISION,
                                  REJECT_GEAR,
                                  REJECT_NAMES,
                                  REJECT_STALE,
                                  STRATEGY_NAMES,
                                  CarState,
                                  Decision,
                                  Perception,
                                  SupervisorConfig,
                                  SupervisorState,
                                  check_new_plan,
                                  goal_moved,
                                  replan_decision,
                                  submit,
                                  supervise,
)
from jaxplan.replan.tracking import TrackingPoint, find_tracking_point, find_tracking_point_directional
from jaxplan.replan.trajectory import (
                                  BRAKE_STOP,
                                  COLLISION,
                                  END,
                                  GEAR_SHIFT,
                                  NORMAL,
                                  START,
                                  arc_length,
                                  gear_shift_points,
                                  index_at_s,
                                  interpolate_pose,
                                  point_types,
                                  split_at_gear_shifts,
                                  sub_trajectories,
)

__all__ = ["BRAKE_STOP", "COLLISION", "END", "GEAR_SHIFT", "GOAL", "IMMEDIATE", "LAZY", "LOST", "NORMAL", "NO_REPLAN",
           "OBSTACLE", "PERIOD", "PERIODIC", "REASON_NAMES", "REJECT_COLLISION", "REJECT_GEAR", "REJECT_NAMES",
           "REJECT_STALE", "START", "STRATEGY_NAMES", "ApproachPlanner", "BrakeStop", "CarState", "CollisionQueue",
           "Decision", "DubinsPath", "MotionLimits", "ObstacleMemory", "Perception", "Plan", "PlanRequest", "Scenario",
           "SimConfig", "StepLog", "SupervisorConfig", "SupervisorState", "TrackingPoint", "WorldState", "advance",
           "arc_length", "arrival_times", "brake_init", "check_new_plan", "collision_arc_length",
           "find_tracking_point", "find_tracking_point_directional", "finish_plan", "first_collision_point",
           "first_contact", "gear_shift_points", "goal_moved", "index_at_s", "init_state", "interpolate_pose",
           "max_curvature", "memory_init", "memory_update", "nominal_forward_path", "plan_separation", "point_types",
           "profile_speed", "profile_times", "queue_clear", "queue_expire", "queue_init", "queue_nearest",
           "queue_push", "queue_reanchor", "queue_size", "replan_decision", "run_summary", "sample_scenarios",
           "simulate", "simulate_host", "speed_step", "split_at_gear_shifts", "step_post", "step_pre",
           "sub_trajectories", "submit", "supervise", "swept_boxes", "update_brake_stop"]
