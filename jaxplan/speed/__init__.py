"""ST-graph speed planning: blocking and non-blocking ST boundaries, DP, smoothing QP,
composition, and the ``pathspeed`` road planner (``jaxplan.speed.planner``)."""
from jaxplan.speed.compose import compose, compose_plan, compose_profile
from jaxplan.speed.dp import (
    CostWeights,
    DPCosts,
    SpeedConfig,
    SpeedCostWeights,
    SpeedPlan,
    SpeedRoad,
    SpeedScene,
    band_widths,
    build_scene,
    dp_from_costs,
    expected_speed_profile,
    make_scene,
    plan_speed,
    profile_at,
    profile_cost,
    soft_value,
    stage_costs,
)
from jaxplan.speed.nonblocking import (
    LEFT,
    NONE,
    RIGHT,
    Classified,
    classify,
    keep_clear_intervals,
    obstacle_speed,
)
from jaxplan.speed.path_profile import (
    PathProfile,
    first_trajectory,
    path_from_polyline,
    path_from_trajectory,
    path_profile,
    resample_obstacles,
)
from jaxplan.speed.smooth import SmoothWeights, SpeedProfile, smooth_plan
from jaxplan.speed.st_boundary import (
    ObstaclesSL,
    STBoundary,
    blocking_boundaries,
    car_probes,
    project_obstacles,
    side_boundaries,
    station_intervals,
    strip_boundaries,
    strip_extent,
)

__all__ = ["LEFT", "NONE", "RIGHT", "Classified", "CostWeights", "DPCosts", "ObstaclesSL", "PathProfile", "STBoundary",
           "SmoothWeights", "SpeedConfig", "SpeedCostWeights", "SpeedPlan", "SpeedProfile", "SpeedRoad", "SpeedScene",
           "band_widths", "blocking_boundaries", "build_scene", "car_probes", "classify", "compose", "compose_plan",
           "compose_profile", "dp_from_costs", "expected_speed_profile", "first_trajectory", "keep_clear_intervals",
           "make_scene", "obstacle_speed", "path_from_polyline", "path_from_trajectory", "path_profile", "plan_speed",
           "profile_at", "profile_cost", "project_obstacles", "resample_obstacles", "side_boundaries", "smooth_plan",
           "soft_value", "stage_costs", "station_intervals", "strip_boundaries", "strip_extent"]
