"""Construction of a ``Scene`` (numpy leaves, unbatched) on the host from a loaded ``Scenario``:
``build_scene``; the fields' layout is ``jaxplan.scenarios.scene``'s.

The route (``jaxplan.scenarios.route.plan_route``, or one given) is cut to the stretch around the
start and the goal (``trim_route``), resampled to ``SceneConfig.route_points`` evenly spaced points
and smoothed (``polylines.smooth_polyline``). Each route point is projected onto the centre lines
of its route lanelet and of the neighbours beside it (walked outward on both sides, up to
``SceneConfig.lanes_per_side`` each): the lanes' offsets, widths and directions, and from them the
drivable corridor's edges; the route lanelet gives the speed limit. Lanelet outlines (each bound
simplified on its own: ``simplified_outline``) are packed into the drivable polygons, the goal
region (rectangle, polygon, circle, lanelets) into the goal polygons with their arc-length and
lateral ranges on the route; obstacle centres are projected onto the route once (``frenet_of``);
the route's stop lines (``jaxplan.scenarios.lights.route_lights``) and the lanelets' lane paths
(``jaxplan.scenarios.lane_paths``) complete the scene.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.geometry.frenet import ReferenceLine, to_frenet
from jaxplan.scenarios.batch import pad_scene, scene_sizes
from jaxplan.scenarios.lane_paths import lane_paths
from jaxplan.scenarios.lights import route_lights
from jaxplan.scenarios.polylines import (
    arc_length,
    nearest_on_polyline,
    resample_polyline,
    simplify,
    smooth_polyline,
)
from jaxplan.scenarios.route import Route, RouteError, neighbour_map, plan_route
from jaxplan.scenarios.scene import OBSTACLE_TYPES, Goal, Scene, SceneConfig
from jaxplan.types import Obstacles

INF = float("inf")


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
    if boxes.shape[0] == 0:  # one invalid obstacle at least: no zero-size arrays in the kernels
        scene = pad_scene(scene, **dict(scene_sizes(scene), K=1))
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
