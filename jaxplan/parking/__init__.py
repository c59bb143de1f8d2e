"""Parallel park-out on an occupancy grid: frames, grids, reference circles, pure pursuit, the seed's
maneuver loop, the search fallback, the batch driver, scene files and the ``jaxplan parkout`` command."""
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
from jaxplan.parking.driver import park_out, plan_grids, render_scenes
from jaxplan.parking.grid import (
    Grid,
    box_covers_occupied,
    cell_centres,
    cell_table,
    cell_to_world,
    compose,
    footprint_boxes,
    footprint_hits_grid,
    from_frame,
    occupied_at,
    polygon_covers_occupied,
    relative,
    to_frame,
    world_to_cell,
)
from jaxplan.parking.heuristic import CostToGo, cost_to_go
from jaxplan.parking.parkout import (
    GridModel,
    ParkoutResult,
    Plan,
    PointModel,
    grid_model,
    hits_fn,
    is_out,
    park_out_grid,
    plan_parkout,
    seed_loop,
    select_forward,
)
from jaxplan.parking.pursuit import Rollout, bicycle_step, pursuit_steer, rollout
from jaxplan.parking.render import Layers, render_grid, render_grids, render_layers, sensor_poses
from jaxplan.parking.scenes import ParkingScene, box_gap, boxes_to_polygons, make_scenes
from jaxplan.parking.search import arc_poses, primitives, search_parkout
from jaxplan.parking.two_corner import footprint_hits_points, two_corner_points

__all__ = ["CostToGo", "Curve", "Grid", "GridModel", "Layers", "ParkingScene", "ParkoutConfig", "ParkoutResult",
           "Plan", "PointModel", "Rollout", "arc_poses", "backward_curve", "bicycle_step", "box_covers_occupied",
           "box_gap", "boxes_to_polygons", "cell_centres", "cell_table", "cell_to_world", "compose", "cost_to_go",
           "curve_point", "footprint_boxes", "footprint_hits_grid", "footprint_hits_points", "forward_curve",
           "from_frame", "front_corner_radius", "grid_model", "hits_fn", "is_out", "make_curve", "make_scenes",
           "min_front_gap", "min_slot_length", "occupied_at", "park_out", "park_out_grid", "plan_grids",
           "plan_parkout", "polygon_covers_occupied", "primitives", "pursuit_steer", "reference_circles", "relative",
           "render_grid", "render_grids", "render_layers", "render_scenes", "rollout", "search_parkout", "seed_loop",
           "select_forward", "sensor_poses", "stop_line", "to_frame", "turning_radius", "two_corner_points",
           "world_to_cell"]
