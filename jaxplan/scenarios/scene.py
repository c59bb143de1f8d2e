"""``Scene``: what every road planner and the simulator consume (one pytree, static shapes).

A ``Scene`` is built on the host from a loaded ``Scenario`` (shared JSON or CommonRoad XML,
``jaxplan.scenarios.build.build_scene``) or by the built-in generators (``jaxplan.scenarios.builtin``),
in the scenario's local frame (the ego start at the origin). Scenes of different sizes stack into
one batch with ``jaxplan.scenarios.batch.stack_scenes`` (every array padded to the largest, with
masks). This module holds the types: ``Scene``, its ``Goal``, the ``SceneConfig`` of its
construction, the host-side ``SceneRecord`` and ``OBSTACLE_TYPES``.

Layout (``R`` route points, ``L = 2 n + 1`` lanes, ``M`` drivable polygons of ``V``
vertices, ``K`` obstacles over ``T`` steps, ``G`` goal polygons of ``W`` vertices):

- ``start (5,)``: the ego's box centre ``[x, y, heading, v, a]`` at ``t = 0``.
- ``route``: the ``ReferenceLine`` of the route (``R`` points, uniform spacing), from
  ``jaxplan.scenarios.route.plan_route``, smoothed within ``SceneConfig.route_max_dev`` so that
  its curvature is continuous (lanelet centre lines are kinked polylines); ``route_start_s``: the start's arc length on it;
  ``route_end_s``: where the mapped road ends on the route (a lanelet without successor; the line
  continues straight after); ``inf`` where the road goes on past the line's end.
- lanes beside the route, per route point: ``lane_offset (L, R)`` Frenet ``l`` of each lane's
  centre, ``lane_width (L, R)``, ``lane_valid (L, R)``, ``lane_same_dir (L, R)``; lane ``n`` is
  the route's own lane, ``n + k`` the ``k``-th to its left, ``n - k`` to its right.
- ``road_left, road_right (R,)``: Frenet ``l`` of the drivable corridor's edges about the
  route (the outer bounds of the lanes beside it, both directions).
- ``speed_limit (R,)``: the route lanelet's limit (m/s), ``SceneConfig.default_speed_limit``
  where the map gives none.
- ``drivable (M, V, 2)`` with ``drivable_valid (M, V)``: lanelet outlines (the drivable area
  is their union), for off-road checks.
- ``obstacles``: ``Obstacles`` ``(K, T, 5)`` at ``t = k dt`` with ``valid`` and ``static``;
  ``obstacle_sl (K, T, 2)``: their centres' Frenet ``(s, l)`` on the route, projected once
  at construction so that no planner projects them every cycle (``obstacles.window_of`` windows it);
  ``obstacle_type (K,)`` int (index into ``OBSTACLE_TYPES``).
- ``goal``: ``Goal`` (region polygons, time / speed / heading intervals, and the region's
  arc-length and lateral ranges on the route, for planners' targets).
- ``dt ()``: the step (s).
- ``lights``: ``TrafficLights`` (``jaxplan.scenarios.lights``, ``NL`` stop lines the route crosses,
  ``P`` steps of colors): ``line (NL, 2, 2)`` the stop line, ``s (NL,)`` its arc length on the
  route, ``color (NL, P)`` int the governing light's color (``LIGHT_COLORS`` index) at scene steps
  ``0 .. period - 1`` (repeating), ``period (NL,)``, ``lanelet (NL,)`` and ``valid (NL,)`` (padding invalid).
- ``lane_paths (LP, Q, 2)`` with ``lane_path_valid (LP, Q)``: where a road user on a lanelet drives
  next (``jaxplan.scenarios.lane_paths``): one path per lanelet (and per 50 m of a long one), its
  centre line followed by the straightest chain of successors, up to 150 m, ``Q`` points evenly
  spaced in arc length (a valid path's points are all valid; padding paths none). The simulator's
  constant-velocity predictions follow them.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from jaxplan.scenarios.route import Route
from jaxplan.types import check_coordinates, check_finite, pytree_dataclass

OBSTACLE_TYPES = (
    "car",
    "truck",
    "bus",
    "motorcycle",
    "bicycle",
    "pedestrian",
    "parkedVehicle",
    "constructionZone",
    "unknown",
)


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Sizes and defaults of ``build_scene`` (host side).

    Attributes:
        route_points: ``R``, points of the resampled route.
        lanes_per_side: ``n``, lanes kept on each side of the route lane (``L = 2 n + 1``).
        default_speed_limit: m/s where the map gives no limit (90 km/h).
        simplify_tol: metres; lanelet outlines are simplified (Douglas-Peucker) within this.
        back, ahead_min, ahead_past_goal, ahead_max: metres of route kept behind the start and
            ahead of it (``build.trim_route``).
        route_smoothing, route_max_dev: metres; the resampled route is smoothed
            (``polylines.smooth_polyline``: wiggles shorter than ``route_smoothing`` damped, no point
            moved more than ``route_max_dev``), so that its curvature is continuous; 0 = raw.
    """

    route_points: int = 384
    lanes_per_side: int = 3
    default_speed_limit: float = 25.0
    simplify_tol: float = 0.01
    back: float = 30.0
    ahead_min: float = 250.0
    ahead_past_goal: float = 100.0
    ahead_max: float = 800.0
    route_smoothing: float = 15.0
    route_max_dev: float = 0.1


@pytree_dataclass(
    data_fields=(
        "region",
        "region_valid",
        "has_region",
        "time",
        "speed",
        "heading",
        "has_heading",
        "s_range",
        "l_range",
    )
)
class Goal:
    """A planning problem's goal (CommonRoad semantics: reached when, at one step, the
    position is in the region, the time in ``time`` and speed / heading in their ranges).

    Attributes:
        region: ``(G, W, 2)`` polygons (rectangle corners or lanelet outlines, CCW or CW).
        region_valid: ``(G, W)`` vertex masks (prefix); a polygon with no valid vertex is padding.
        has_region: ``()`` bool; False = any position.
        time: ``(2,)`` seconds from the scenario start.
        speed: ``(2,)`` m/s (``[-inf, inf]`` when the goal gives none).
        heading: ``(2,)`` radians, an interval on the circle; used when ``has_heading``.
        s_range, l_range: ``(2,)`` the region's extent in route coordinates (``[start, inf]``
            and ``[-inf, inf]`` without a region).
    """

    region: Any
    region_valid: Any
    has_region: Any
    time: Any
    speed: Any
    heading: Any
    has_heading: Any
    s_range: Any
    l_range: Any


@pytree_dataclass(
    data_fields=(
        "start",
        "route",
        "route_start_s",
        "route_end_s",
        "lane_offset",
        "lane_width",
        "lane_valid",
        "lane_same_dir",
        "road_left",
        "road_right",
        "speed_limit",
        "drivable",
        "drivable_valid",
        "obstacles",
        "obstacle_sl",
        "obstacle_type",
        "goal",
        "dt",
        "lights",
        "lane_paths",
        "lane_path_valid",
    )
)
class Scene:
    """One road scene (see the module docstring for every field's shape). Add a leading
    axis to every leaf for a batch (``stack_scenes``)."""

    start: Any
    route: Any
    route_start_s: Any
    route_end_s: Any
    lane_offset: Any
    lane_width: Any
    lane_valid: Any
    lane_same_dir: Any
    road_left: Any
    road_right: Any
    speed_limit: Any
    drivable: Any
    drivable_valid: Any
    obstacles: Any
    obstacle_sl: Any
    obstacle_type: Any
    goal: Any
    dt: Any
    lights: Any = None  # TrafficLights; None: no stop lines
    lane_paths: Any = None  # (LP, Q, 2); None: none (constant-velocity predictions then go straight)
    lane_path_valid: Any = None  # (LP, Q)

    @property
    def n_lanes(self) -> int:
        return self.lane_offset.shape[-2]

    @property
    def own_lane(self) -> int:
        """Index of the route's own lane in the lane axis."""
        return self.lane_offset.shape[-2] // 2

    def validate(self) -> Scene:
        """Host-side checks of shapes and values (clear ``ValueError`` naming the field)."""
        st = check_finite("Scene.start", self.start)
        if st.shape[-1:] != (5,):
            raise ValueError(f"Scene.start: expected shape (..., 5) [x, y, heading, v, a], got {st.shape}")
        check_coordinates("Scene.start", st[..., :2])
        if np.any(st[..., 3] < 0):
            raise ValueError("Scene.start: the start speed must be >= 0")
        xy = check_finite("Scene.route.xy", self.route.xy)
        R = xy.shape[-2]
        if R < 2:
            raise ValueError("Scene.route: needs at least two points")
        check_coordinates("Scene.route.xy", xy)
        for name in ("lane_offset", "lane_width", "lane_valid", "lane_same_dir"):
            a = np.asarray(getattr(self, name))
            if a.shape[-1] != R or a.shape[:-2] != xy.shape[:-2]:
                raise ValueError(f"Scene.{name}: expected shape (..., L, {R}), got {a.shape}")
        for name in ("road_left", "road_right", "speed_limit"):
            a = check_finite(f"Scene.{name}", getattr(self, name))
            if a.shape[-1] != R:
                raise ValueError(f"Scene.{name}: expected shape (..., {R}), got {a.shape}")
        if np.any(np.asarray(self.speed_limit) <= 0):
            raise ValueError("Scene.speed_limit must be positive")
        if np.any(np.asarray(self.road_left) < np.asarray(self.road_right)):
            raise ValueError("Scene.road_left must be >= road_right")
        dv = check_finite("Scene.drivable", self.drivable)
        if dv.shape[-1] != 2 or np.asarray(self.drivable_valid).shape != dv.shape[:-1]:
            raise ValueError(f"Scene.drivable: expected (..., M, V, 2) with a (..., M, V) mask, got {dv.shape}")
        self.obstacles.validate()
        ty = np.asarray(self.obstacle_type)
        if ty.shape != np.asarray(self.obstacles.static).shape or np.any((ty < 0) | (ty >= len(OBSTACLE_TYPES))):
            raise ValueError(
                f"Scene.obstacle_type: expected ints in [0, {len(OBSTACLE_TYPES)}) of shape "
                f"{np.asarray(self.obstacles.static).shape}"
            )
        g = self.goal
        for name in ("time", "speed", "heading", "s_range", "l_range"):
            a = np.asarray(getattr(g, name), float)
            if a.shape[-1:] != (2,) or np.any(np.isnan(a)) or np.any(a[..., 0] > a[..., 1]):
                raise ValueError(f"Scene.goal.{name}: expected an interval (..., 2) with low <= high, got {a}")
        check_finite("Scene.goal.region", g.region)
        if self.lights is not None:
            self.lights.validate()
        if self.lane_paths is not None:
            lp = check_finite("Scene.lane_paths", self.lane_paths)
            if lp.ndim < 3 or lp.shape[-1] != 2 or np.asarray(self.lane_path_valid).shape != lp.shape[:-1]:
                raise ValueError(
                    f"Scene.lane_paths: expected (..., LP, Q, 2) with a (..., LP, Q) mask, got "
                    f"{lp.shape} and {np.asarray(self.lane_path_valid).shape}"
                )
        d = check_finite("Scene.dt", self.dt)
        if np.any(d <= 0):
            raise ValueError("Scene.dt must be positive")
        return self


@dataclasses.dataclass(frozen=True)
class SceneRecord:
    """A built scene with what stays on the host: the scenario it came from, its route,
    and a name for its outputs (the scenario id, or the file name when ids repeat)."""

    name: str
    scene: Scene
    scenario: Any
    route: Route
    path: str = ""
