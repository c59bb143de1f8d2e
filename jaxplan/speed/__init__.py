"""ST-graph speed planning: blocking and non-blocking ST boundaries, DP, composition."""
from jaxplan.speed.compose import compose, compose_plan, speed_profile_at
from jaxplan.speed.dp import (
    CostWeights,
    SpeedConfig,
    SpeedCostWeights,
    SpeedPlan,
    SpeedScene,
    build_scene,
    dp_from_costs,
    expected_speed_profile,
    make_scene,
    obstacle_cost,
    plan_speed,
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
    side_probes,
)
from jaxplan.speed.path_profile import (
    PathProfile,
    first_trajectory,
    path_from_polyline,
    path_from_trajectory,
    path_profile,
    resample_obstacles,
)
from jaxplan.speed.st_boundary import STBoundary, blocking_boundaries, car_probes, station_intervals
