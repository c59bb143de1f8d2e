"""Parallel park-out on an occupancy grid: frames, grids, reference circles, pure pursuit, the maneuver loop."""
from jaxplan.parking.circles import (
    Curve,
    backward_curve,
    curve_point,
    forward_curve,
    front_corner_radius,
    make_curve,
    min_front_gap,
    min_slot_length,
    reference_circles,
    stop_line,
    turning_radius,
)
from jaxplan.parking.config import ParkoutConfig
from jaxplan.parking.grid import (
    Grid,
    box_covers_occupied,
    cell_centres,
    cell_to_world,
    compose,
    footprint_boxes,
    footprint_hits_grid,
    from_frame,
    occupied_at,
    polygon_covers_occupied,
    relative,
    row_prefix,
    to_frame,
    world_to_cell,
)
from jaxplan.parking.parkout import ParkoutResult, Plan, is_out, park_out, plan_parkout, select_forward
from jaxplan.parking.pursuit import Rollout, bicycle_step, pursuit_steer, rollout
from jaxplan.parking.scenes import Scene, box_gap, make_scenes, render_grid
from jaxplan.parking.two_corner import footprint_hits_points, two_corner_points
