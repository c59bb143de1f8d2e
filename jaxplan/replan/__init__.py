"""Lazy replanning: plan points and gear-shift split, tracking point search, the
collision-point queue and brake-stop point, the supervisor (lazy, periodic,
immediate) and a closed-loop simulator with a planner callback."""
from jaxplan.replan.planner import Plan, PlanRequest, SimplePlanner, finish_plan
from jaxplan.replan.queue import (BrakeStop, CollisionQueue, brake_init, collision_arc_length, first_collision_point,
                                  queue_clear, queue_expire, queue_init, queue_nearest, queue_push, queue_size,
                                  update_brake_stop)
from jaxplan.replan.scenarios import sample_scenarios
from jaxplan.replan.simulator import (Scenario, SimConfig, SimState, StepLog, init_state, run_one, run_summary,
                                      simulate, simulate_host, step_post, step_pre)
from jaxplan.replan.supervisor import (GOAL, IMMEDIATE, LAZY, LOST, NO_REPLAN, OBSTACLE, PERIOD, PERIODIC,
                                       REASON_NAMES, STRATEGY_NAMES, SupervisorConfig, goal_moved, replan_decision)
from jaxplan.replan.tracking import TrackingPoint, find_tracking_point, find_tracking_point_directional
from jaxplan.replan.trajectory import (BRAKE_STOP, COLLISION, END, GEAR_SHIFT, NORMAL, START, arc_length,
                                       gear_shift_points, index_at_s, interpolate_pose, point_types,
                                       split_at_gear_shifts, sub_trajectories)
