"""``Scene``: what every road planner and the simulator consume (one pytree, static shapes).

A ``Scene`` is built on the host from a loaded ``Scenario`` (shared JSON or CommonRoad XML,
``build_scene``) or by the built-in generators (``jaxplan.scenarios.builtin``), in the
scenario's local frame (the ego start at the origin). Scenes of different sizes stack into
one batch with ``stack_scenes`` (every array padded to the largest, with masks).

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
  here so that no planner projects them every cycle (``obstacles.window_of`` windows it);
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
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine, to_frenet
from jaxplan.scenarios.lane_paths import lane_paths
from jaxplan.scenarios.lights import no_lights, pad_lights, route_lights
from jaxplan.scenarios.polylines import arc_length, nearest_on_polyline, resample_polyline, smooth_polyline
from jaxplan.scenarios.route import Route, RouteError, neighbour_map, plan_route
from jaxplan.types import Obstacles, check_coordinates, check_finite, pytree_dataclass

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
INF = float("inf")


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Sizes and defaults of ``build_scene`` (host side).

    Attributes:
        route_points: ``R``, points of the resampled route.
        lanes_per_side: ``n``, lanes kept on each side of the route lane (``L = 2 n + 1``).
        default_speed_limit: m/s where the map gives no limit (90 km/h).
        simplify_tol: metres; lanelet outlines are simplified (Douglas-Peucker) within this.
        back, ahead_min, ahead_past_goal, ahead_max: metres of route kept behind the start and
            ahead of it (``trim_route``).
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


# ----------------------------------------------------------------------------- host helpers


def simplify(xy: np.ndarray, tol: float) -> np.ndarray:
    """Douglas-Peucker simplification of a polyline ``(P, 2)`` within ``tol`` metres (keeps ends)."""
    xy = np.asarray(xy, float)
    if len(xy) <= 2 or tol <= 0:
        return xy
    keep = np.zeros(len(xy), bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(xy) - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = xy[i], xy[j]
        d = b - a
        n = np.linalg.norm(d)
        p = xy[i + 1 : j]
        if n < 1e-12:
            dist = np.linalg.norm(p - a, axis=1)
        else:
            dist = np.abs(d[0] * (p[:, 1] - a[1]) - d[1] * (p[:, 0] - a[0])) / n
        k = int(np.argmax(dist))
        if dist[k] > tol:
            m = i + 1 + k
            keep[m] = True
            stack += [(i, m), (m, j)]
    return xy[keep]


def simplified_outline(lane, tol: float) -> np.ndarray:
    """A lanelet's outline with each bound simplified on its own (``simplify``), so that a bound
    two lanelets share stays vertex-identical in both outlines."""
    return np.concatenate([simplify(lane.left, tol), simplify(lane.right, tol)[::-1]])


def _frenet(xy: np.ndarray, s: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Host Frenet coordinates of ``p`` on polyline ``xy`` with arc lengths ``s``."""
    j, along, _ = nearest_on_polyline(xy, p)
    seg = xy[j + 1] - xy[j]
    t = seg / max(np.linalg.norm(seg), 1e-12)
    r = p - xy[j]
    # beyond the ends the nearest point clamps; extend along the end chords
    along = float(np.dot(r, t)) if j in (0, len(xy) - 2) else along
    return float(s[j] + along), float(t[0] * r[1] - t[1] * r[0])


class _LaneProjector:
    """Every route point's projection onto lanelet centre lines, computed once per lanelet for all
    points (vectorised ``nearest_on_polyline``): ``at(lid, i)`` is what ``_lane_at`` reads."""

    def __init__(self, by_id, xy: np.ndarray):
        self.by_id, self.xy = by_id, xy
        self.cache: dict[Any, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}

    def at(self, lid, i):
        """``(j, u, centre point (2,), width)`` of route point ``i`` on lanelet ``lid``'s centre line."""
        if lid not in self.cache:
            ln = self.by_id[lid]
            poly, p = ln.center, self.xy
            seg = poly[1:] - poly[:-1]  # (P-1, 2)
            L2 = np.maximum(np.sum(seg * seg, 1), 1e-12)
            rel = p[:, None, :] - poly[None, :-1]  # (R, P-1, 2)
            u = np.clip(np.sum(rel * seg, 2) / L2, 0, 1)
            d = np.linalg.norm(poly[None, :-1] + u[..., None] * seg - p[:, None, :], axis=2)
            j = np.argmin(d, axis=1)
            uj = u[np.arange(len(p)), j]
            # the formulas of nearest_on_polyline and the previous per-point code, vectorised
            along = uj * np.sqrt(L2[j])
            uu = along / np.maximum(np.linalg.norm(seg[j], axis=1), 1e-12)
            c = poly[j] + uu[:, None] * seg[j]
            lw = ln.left[j] + uu[:, None] * (ln.left[j + 1] - ln.left[j])
            rw = ln.right[j] + uu[:, None] * (ln.right[j + 1] - ln.right[j])
            self.cache[lid] = (j, c, np.linalg.norm(lw - rw, axis=1), seg[j])
        j, c, w, sg = self.cache[lid]
        return c[i], float(w[i]), sg[i]


def _lane_at(proj: _LaneProjector, lid, i, t):
    """Offset, width, along-track error of lanelet ``lid`` (or its successor / predecessor,
    whichever covers the route point best) at route point ``i`` with unit tangent ``t``."""
    best = None
    by_id = proj.by_id
    p = proj.xy[i]
    ln0 = by_id[lid]
    for cand in (lid, *ln0.successors, *ln0.predecessors):
        if cand not in by_id:
            continue
        c, width, seg = proj.at(cand, i)
        r = c - p
        err = abs(float(np.dot(r, t)))
        if best is None or err < best[2]:
            best = (float(t[0] * r[1] - t[1] * r[0]), width, err, cand, float(np.dot(seg, t)) > 0)
    return best


def _walk(adjacency, lid, side):
    """Neighbour lanelets of ``lid`` on ``side`` ("left"/"right", seen from the route's
    direction), outward: [(id, same_direction)]. An opposite-direction lanelet's own left is our right."""
    out, cur, flipped, seen = [], lid, False, {lid}
    while True:
        want = side if not flipped else ("right" if side == "left" else "left")
        nb = adjacency.get((cur, want))
        if nb is None or nb[0] in seen:
            return out
        nxt, same = nb
        flipped = flipped != (not same)
        seen.add(nxt)
        out.append((nxt, not flipped))
        cur = nxt


def _polygon_array(polys: list, pad_vertices: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Stack polygons ``[(P_i, 2)]`` to ``(M, V, 2)`` with a prefix mask ``(M, V)``."""
    M = max(1, len(polys))
    V = max([3] + [len(p) for p in polys] + [pad_vertices or 0])
    arr = np.zeros((M, V, 2))
    ok = np.zeros((M, V), bool)
    for i, p in enumerate(polys):
        arr[i, : len(p)] = p
        arr[i, len(p) :] = p[-1]
        ok[i, : len(p)] = True
    return arr, ok


def _goal_polygons(scenario, by_id, tol):
    g = scenario.goal
    polys = []
    if "rectangle" in g:
        r = g["rectangle"]
        c, s = math.cos(r["orientation"]), math.sin(r["orientation"])
        hl, hw = 0.5 * r["length"], 0.5 * r["width"]
        polys.append(
            np.array(
                [
                    [r["center"][0] + c * dx - s * dy, r["center"][1] + s * dx + c * dy]
                    for dx, dy in ((hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw))
                ]
            )
        )
    if "polygon" in g:
        polys.append(np.asarray(g["polygon"], float))
    if "circle" in g:
        a = np.linspace(0, 2 * np.pi, 17)[:-1]
        c, rad = np.asarray(g["circle"]["center"], float), g["circle"]["radius"]
        polys.append(c + rad * np.column_stack([np.cos(a), np.sin(a)]))
    for lid in g.get("lanelets", []):
        if lid not in by_id:
            raise RouteError(f"scenario {scenario.id}: goal lanelet {lid} is not in the map")
        polys.append(simplified_outline(by_id[lid], tol))
    return polys


def build_scene(scenario, config: SceneConfig = SceneConfig(), route: Route | None = None) -> tuple[Scene, Route]:
    """A ``Scene`` (numpy leaves, unbatched) and its ``Route`` from a loaded ``Scenario``.

    Raises:
        RouteError (a ``ValueError``): no lanelets, no lanelet under the start, or a goal
            lanelet missing from the map.
    """
    by_id = {ln.id: ln for ln in scenario.lanes}
    adjacency = neighbour_map(scenario)
    route = trim_route(route or plan_route(scenario), _goal_polygons(scenario, by_id, 0.0), config)
    dense_s = arc_length(route.xy)
    R = config.route_points
    s = np.linspace(0.0, dense_s[-1], R)
    xy = smooth_polyline(resample_polyline(route.xy, dense_s, s), config.route_smoothing, config.route_max_dev)
    # owner lanelet of each resampled point: that of the dense vertex at or before it
    idx = np.clip(np.searchsorted(dense_s, s, side="right") - 1, 0, len(dense_s) - 1)
    owner = route.owner[idx]
    known = np.where(owner >= 0)[0]
    n = config.lanes_per_side
    L = 2 * n + 1
    off = np.zeros((L, R))
    width = np.full((L, R), 3.5)
    valid = np.zeros((L, R), bool)
    same = np.ones((L, R), bool)
    limit = np.full(R, config.default_speed_limit)
    tang = np.gradient(xy, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
    proj = _LaneProjector(by_id, xy)
    for i in range(R):
        if not len(known):
            break
        inside = owner[i] >= 0
        o = owner[i] if inside else owner[known[np.argmin(np.abs(known - i))]]
        if by_id[o].speed_limit is not None:
            limit[i] = by_id[o].speed_limit
        if not inside:  # beyond the map (route extensions): no lanes
            continue
        base = _lane_at(proj, o, i, tang[i])
        off[n, i], width[n, i], valid[n, i] = base[0], base[1], True
        for sign, side in ((1, "left"), (-1, "right")):
            for k, (lid, is_same) in enumerate(_walk(adjacency, base[3], side)[:n]):
                lo, lw, err, _, _ = _lane_at(proj, lid, i, tang[i])
                if err < 1.0:
                    off[n + sign * (k + 1), i], width[n + sign * (k + 1), i] = lo, lw
                    valid[n + sign * (k + 1), i] = True
                    same[n + sign * (k + 1), i] = is_same
    edge_l = np.where(valid, off + 0.5 * width, -INF).max(0)
    edge_r = np.where(valid, off - 0.5 * width, INF).min(0)
    # beyond the map the corridor is the route lane's nominal width
    edge_l = np.where(np.isfinite(edge_l), edge_l, 1.75)
    edge_r = np.where(np.isfinite(edge_r), edge_r, -1.75)
    drv, drv_ok = _polygon_array([simplified_outline(ln, config.simplify_tol) for ln in scenario.lanes])

    g = scenario.goal
    gpolys = _goal_polygons(scenario, by_id, config.simplify_tol)
    region, region_ok = _polygon_array(gpolys)
    if gpolys:
        fr = np.array([_frenet(xy, s, p) for poly in gpolys for p in poly])
        s_rng, l_rng = [fr[:, 0].min(), fr[:, 0].max()], [fr[:, 1].min(), fr[:, 1].max()]
    else:
        s_rng, l_rng = [route.start_s, INF], [-INF, INF]
    heading = g.get("orientation")
    goal = Goal(
        region,
        region_ok,
        np.asarray(bool(gpolys)),
        np.asarray(g.get("time", [0.0, INF]), float),
        np.asarray(g.get("velocity", [-INF, INF]), float),
        np.asarray(heading if heading is not None else [-INF, INF], float),
        np.asarray(heading is not None),
        np.asarray(s_rng, float),
        np.asarray(l_rng, float),
    )

    obs = scenario.obstacles
    types = np.array(
        [
            OBSTACLE_TYPES.index(t) if t in OBSTACLE_TYPES else OBSTACLE_TYPES.index("unknown")
            for t in scenario.obstacle_types
        ],
        np.int32,
    ).reshape(-1)
    e = scenario.ego
    ref = _ref_numpy(xy)
    boxes = np.asarray(obs.boxes, float)
    scene = Scene(
        np.array([e.x, e.y, e.heading, e.v, e.a], float),
        ref,
        np.asarray(route.start_s),
        np.asarray(route.end_s),
        off,
        width,
        valid,
        same,
        edge_l,
        edge_r,
        limit,
        drv,
        drv_ok,
        Obstacles(boxes, np.asarray(obs.valid, bool), np.asarray(obs.t, float), np.asarray(obs.static, bool)),
        frenet_of(ref, boxes[..., :2]),
        types,
        goal,
        np.asarray(scenario.dt, float),
        lights=route_lights(scenario, route, ref.xy, ref.s),
    )
    paths, paths_ok = lane_paths(scenario.lanes)
    scene = dataclasses.replace(scene, lane_paths=paths, lane_path_valid=paths_ok)
    return scene, route


def frenet_of(ref: ReferenceLine, xy: np.ndarray) -> np.ndarray:
    """``(..., 2)`` Frenet ``(s, l)`` of points ``xy (..., 2)`` on ``ref`` (the geometry core's
    ``to_frenet``, jitted, as numpy)."""
    if xy.size == 0:
        return np.zeros(xy.shape)
    flat = np.asarray(xy, float).reshape(-1, 2)
    n = len(flat)
    size = 1 << max(8, (n - 1).bit_length())  # a few padded sizes: one compiled program each
    pts = np.concatenate([flat, np.repeat(flat[-1:], size - n, axis=0)])
    s, l = _to_frenet_jit(jax.tree_util.tree_map(jnp.asarray, ref), jnp.asarray(pts))
    return np.stack([np.asarray(s, float)[:n], np.asarray(l, float)[:n]], -1).reshape(xy.shape)


_to_frenet_jit = jax.jit(to_frenet)


def trim_route(route: Route, goal_polygons: list, config: SceneConfig) -> Route:
    """The route cut to ``[start - back, far end]``: ``config.back`` metres behind the start and
    ``config.ahead_past_goal`` past the goal region's far end (without a region, ``config.ahead_min``),
    at least ``config.ahead_min`` and at most ``config.ahead_max`` metres ahead of the start."""
    s = arc_length(route.xy)
    far = route.start_s + config.ahead_min
    for poly in goal_polygons:
        for p in poly:
            far = max(far, _frenet(route.xy, s, p)[0] + config.ahead_past_goal)
    lo = max(0.0, route.start_s - config.back)
    hi = min(s[-1], route.start_s + min(far - route.start_s, config.ahead_max))
    keep = (s > lo) & (s < hi)
    xy = np.concatenate([resample_polyline(route.xy, s, [lo]), route.xy[keep], resample_polyline(route.xy, s, [hi])])
    i_lo = max(0, int(np.searchsorted(s, lo, side="right")) - 1)
    i_hi = min(len(s) - 1, int(np.searchsorted(s, hi, side="right")) - 1)
    owner = np.concatenate([route.owner[i_lo : i_lo + 1], route.owner[keep], route.owner[i_hi : i_hi + 1]])
    return dataclasses.replace(
        route,
        xy=xy,
        owner=owner,
        start_s=route.start_s - lo,
        end_s=route.end_s - lo if route.end_s <= hi else float("inf"),
    )


def _ref_numpy(xy: np.ndarray) -> ReferenceLine:
    """``ReferenceLine`` fields as numpy (the jittable constructor's formulas, host side)."""
    ref = ReferenceLine.from_polyline(xy)
    return ReferenceLine(*(np.asarray(getattr(ref, f.name), float) for f in dataclasses.fields(ReferenceLine)))


# ----------------------------------------------------------------------------- batching


def _pad_axis(a: np.ndarray, axis: int, size: int, fill) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[axis] >= size:
        return a
    pad = [(0, 0)] * a.ndim
    pad[axis] = (0, size - a.shape[axis])
    if isinstance(fill, str) and fill == "edge":
        return np.pad(a, pad, mode="edge") if a.shape[axis] else np.pad(a, pad)
    return np.pad(a, pad, constant_values=fill)


def pad_scene(
    scene: Scene, K: int, T: int, M: int, V: int, G: int, W: int, NL: int = 0, P: int = 1, LP: int | None = None
) -> Scene:
    """Pad one (numpy) scene to ``K`` obstacles over ``T`` steps, ``M x V`` drivable and
    ``G x W`` goal polygons, ``NL`` stop lines with ``P`` steps of colors. Padding is invalid
    (obstacles, stop lines) or repeats the last vertex (polygons). ``LP``: pad the lane paths to
    ``LP`` (invalid paths) when given."""
    if LP is not None and scene.lane_paths is not None:
        scene = dataclasses.replace(
            scene,
            lane_paths=_pad_axis(scene.lane_paths, 0, LP, 0.0),
            lane_path_valid=_pad_axis(scene.lane_path_valid, 0, LP, False),
        )
    o = scene.obstacles
    b = _pad_axis(_pad_axis(o.boxes, 1, T, "edge"), 0, K, 0.0)
    if K > o.boxes.shape[0]:
        b[o.boxes.shape[0] :, :, 2:4] = 1.0  # padding: unit boxes, never valid
    v = _pad_axis(_pad_axis(o.valid, 1, T, False), 0, K, False)
    t = np.arange(T) * float(scene.dt)
    obs = Obstacles(b, v, t, _pad_axis(o.static, 0, K, False))
    sl = _pad_axis(_pad_axis(scene.obstacle_sl, 1, T, "edge"), 0, K, 0.0)
    ty = _pad_axis(scene.obstacle_type, 0, K, OBSTACLE_TYPES.index("unknown"))

    def polys(p, ok, m, w):
        p = _pad_axis(p, 1, w, "edge")
        ok = _pad_axis(ok, 1, w, False)
        return _pad_axis(p, 0, m, 0.0), _pad_axis(ok, 0, m, False)

    drv, drv_ok = polys(scene.drivable, scene.drivable_valid, M, V)
    reg, reg_ok = polys(scene.goal.region, scene.goal.region_valid, G, W)
    goal = dataclasses.replace(scene.goal, region=reg, region_valid=reg_ok)
    lights = pad_lights(no_lights() if scene.lights is None else scene.lights, NL, P)
    return dataclasses.replace(
        scene,
        drivable=drv,
        drivable_valid=drv_ok,
        obstacles=obs,
        obstacle_sl=sl,
        obstacle_type=ty,
        goal=goal,
        lights=lights,
    )


SIZE_NAMES = ("K", "T", "M", "V", "G", "W", "NL", "P", "LP")


def scene_sizes(scene: Scene) -> dict:
    """The counts of an unbatched (numpy) scene that padding changes (``SIZE_NAMES``): obstacles ``K``
    over ``T`` steps, ``M`` lanelet outlines of ``V`` vertices, ``G`` goal polygons of ``W``
    vertices, ``NL`` stop lines with ``P`` steps of colours, ``LP`` lane paths."""
    b = np.shape(scene.obstacles.boxes)
    nl, p = np.shape(scene.lights.color) if scene.lights is not None else (0, 1)
    return {
        "K": b[0],
        "T": b[1],
        "M": np.shape(scene.drivable)[0],
        "V": np.shape(scene.drivable)[1],
        "G": np.shape(scene.goal.region)[0],
        "W": np.shape(scene.goal.region)[1],
        "NL": nl,
        "P": p,
        "LP": np.shape(scene.lane_paths)[0] if scene.lane_paths is not None else 0,
    }


def stack_scenes(scenes: list, min_steps: int = 1, min_sizes=None) -> Scene:
    """One batched ``Scene`` (jnp leaves with a leading scene axis) from unbatched numpy scenes
    of any sizes (same route points and lanes).

    Args:
        min_steps: pad obstacles to at least this many steps.
        min_sizes: optional lower bounds of the padded sizes (one compiled shape for several
            batches): a dict over ``SIZE_NAMES`` (missing ones: the largest scene's), or a tuple
            ``(K, T, M, V, G, W)`` optionally followed by ``(NL, P)``.
    """
    if not scenes:
        raise ValueError("stack_scenes: no scenes")
    if min_sizes is not None and not isinstance(min_sizes, dict):
        min_sizes = dict(zip(SIZE_NAMES, min_sizes))
    bad = set(min_sizes or ()) - set(SIZE_NAMES)
    if bad:
        raise ValueError(f"stack_scenes: min_sizes has unknown sizes {sorted(bad)}; known: {', '.join(SIZE_NAMES)}")
    have = [scene_sizes(s) for s in scenes]
    size = {k: max([h[k] for h in have] + [int((min_sizes or {}).get(k, 0))]) for k in SIZE_NAMES}
    size["K"] = max(size["K"], 1)  # one invalid obstacle at least: no zero-size arrays in the kernels
    size["T"] = max(size["T"], min_steps)
    size["P"] = max(size["P"], 1)
    size["LP"] = max(size["LP"], 1)
    padded = [
        pad_scene(
            s, size["K"], size["T"], size["M"], size["V"], size["G"], size["W"], size["NL"], size["P"], LP=size["LP"]
        )
        for s in scenes
    ]
    f = jnp.result_type(float)

    def stack(*xs):
        a = np.stack([np.asarray(x) for x in xs])
        return jnp.asarray(a, f) if np.issubdtype(a.dtype, np.floating) else jnp.asarray(a)

    return jax.tree_util.tree_map(stack, *padded)


def index_scene(batch: Scene, i: int) -> Scene:
    """Scene ``i`` of a batch."""
    return jax.tree_util.tree_map(lambda x: x[i], batch)


# ----------------------------------------------------------------------------- loading


def load_records(paths: list, config: SceneConfig = SceneConfig(), horizon: float | None = None) -> list:
    """``SceneRecord``s from scenario files (``.json`` shared format, ``.xml`` CommonRoad, either
    gzip-compressed: ``jaxplan.scenarios.files.load_file``).

    Names are the scenario ids; give several files to ``unique_names`` to make them unique.

    Raises:
        ValueError: naming the file, for unreadable files, scenarios without a planning
            problem, without lanelets, or with a goal region of an unknown kind.
    """
    from jaxplan.scenarios.files import load_file
    from jaxplan.scenarios.loader import ScenarioError

    recs = []
    for p in paths:
        sc = load_file(p, horizon)
        try:
            scene, route = build_scene(sc, config)
        except RouteError as e:
            raise ScenarioError(f"{p}: {e}") from None
        recs.append(SceneRecord(sc.id, scene, sc, route, p))
    return recs


def load_scenes(paths: list, config: SceneConfig = SceneConfig(), horizon: float | None = None) -> list:
    """The ``Scene`` of each scenario file, in order: ``[r.scene for r in load_records(paths, ...)]``
    (``load_records`` also keeps the scenario, its route and a name).

    Args:
        paths: scenario files (``.json`` shared format, ``.xml`` CommonRoad, either gzip-compressed).
        config: ``SceneConfig``; horizon: seconds of obstacle recording kept (default all).

    Returns:
        unbatched numpy ``Scene``s of their own sizes (obstacles ``(K, T, 5)``, ``drivable (M, V, 2)``,
        ...; the module docstring); ``stack_scenes`` pads them into one batch with a leading scene axis.

    Raises:
        ValueError: naming the file (as ``load_records``).
    """
    return [r.scene for r in load_records(paths, config, horizon)]


def unique_names(records: list) -> list:
    """The records renamed as ``jaxplan.scenarios.files.scenario_keys`` keys files: the first of
    each id keeps it, later ones become ``<id>@<file name>``."""
    import os

    seen, out = set(), []
    for r in records:
        name = r.name if r.name not in seen else f"{r.name}@{os.path.basename(r.path)}"
        seen.add(name)
        out.append(dataclasses.replace(r, name=name))
    return out


def world_route(path: str) -> np.ndarray:
    """The route a jaxplan planner drives on in scenario ``path``, in world coordinates ``(R, 2)``
    (for other planners run on the same route, ``experiments/compare_peers.py``)."""
    rec = load_records([path])[0]
    return np.asarray(rec.scene.route.xy, float) + np.asarray(rec.scenario.origin, float)
