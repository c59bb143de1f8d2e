"""The route of a planning problem: the lanelet sequence from the start to the goal, and its
reference line (host side, numpy).

Search: a shortest path (Dijkstra, cost = metres driven) over the lanelet graph whose
edges are successors (cost: the lanelet's length) and lane changes to a same-direction
neighbour (cost: ``LANE_CHANGE_COST`` metres), from the lanelets under the start to a goal
lanelet: the goal's own lanelets when it names them, else the lanelets under the goal
region's centre (heading-compatible with the goal's orientation range when it gives one).
A goal without a position (survival scenarios) routes along successors, straight ahead
where a lanelet forks.

Reference line: the centre lines of the sequence. Where the route changes lane, the
line blends from one centre line to the other with a smooth step over
``LANE_CHANGE_TIME`` seconds at the start speed, at least ``LANE_CHANGE_LENGTH`` metres
(``blend_lane_change``, continuing on the target lane's successors where the lanelet is
shorter; a line that changes lane in 30 m at 33 m/s asks for 25 m/s^2 of lateral
acceleration from whoever follows it), from the start of the lanelet (or from the car's
position on its first lanelet). Behind the start and past the last lanelet the line is
extended (``BACK`` metres behind along predecessors or straight; ``AHEAD_MIN`` metres past
the goal lanelet along successors, ``SURVIVAL_AHEAD`` from the start lanelet when the goal has
no position, then ``AHEAD_MIN`` straight), so that a planner's horizon never runs off it;
``Route.end_s`` says where the mapped road ends (a dead end), ``inf`` where it goes on.
"""

from __future__ import annotations

import dataclasses
import heapq
import math

import numpy as np

from jaxplan.scenarios.polylines import arc_length, nearest_on_polyline, resample_polyline

LANE_CHANGE_COST = 15.0  # metres a lane change costs in the search (fewer changes for equal length)
LANE_CHANGE_LENGTH = 30.0  # metres over which the reference line moves to the next lane, at least
LANE_CHANGE_TIME = 4.0  # seconds at the start speed over which it moves
BACK = 30.0  # metres of reference line behind the start
AHEAD_MIN = 80.0  # metres of reference line past the route's last lanelet (successors first)
SURVIVAL_AHEAD = 300.0  # metres of successors walked from the start lanelet when the goal has no position
HEADING_OK = math.cos(math.radians(60.0))  # a lanelet fits a heading within 60 degrees


class RouteError(ValueError):
    """No route: the message names the scenario and why."""


@dataclasses.dataclass(frozen=True)
class Route:
    """A route in the scenario's local frame.

    Attributes:
        lanelets: lanelet ids from the start lanelet to the goal lanelet (lane changes included).
        xy: ``(P, 2)`` reference polyline (dense: the lanelets' own vertices, blends resampled).
        owner: ``(P,)`` the route lanelet each vertex belongs to.
        start_s: arc length of the start's projection on the line.
        end_s: arc length where the mapped road ends on the route: the route's last lanelet has no
            successor there (the line continues straight after). ``inf`` when the road goes on
            past the lanelets the route took (a dead end is a stop target, the walk's end is not).
        reaches_goal: False when no lanelet path to the goal exists (the route then follows
            successors from the start; the goal may still be reachable off the route).
    """

    lanelets: tuple
    xy: np.ndarray
    owner: np.ndarray
    start_s: float
    end_s: float
    reaches_goal: bool


def _length(pts: np.ndarray) -> float:
    return float(arc_length(pts)[-1])


def _direction_at(center: np.ndarray, xy: np.ndarray) -> tuple[float, float]:
    """(distance of ``xy`` to the centre line, heading of the line there)."""
    j, _, dist = nearest_on_polyline(center, xy)
    seg = center[j + 1] - center[j]
    return dist, math.atan2(seg[1], seg[0])


def point_in_polygon(poly: np.ndarray, p: np.ndarray) -> bool:
    """Even-odd rule for a simple polygon ``(N, 2)`` (host side)."""
    x, y = p
    inside = False
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        if (y1 > y) != (y2 > y):
            xc = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
            if xc > x:
                inside = not inside
    return inside


def lanelet_polygon(lane) -> np.ndarray:
    """The lanelet's outline ``(2P, 2)``: left bound forward, right bound backward."""
    return np.concatenate([lane.left, lane.right[::-1]])


def lanelets_at(scenario, xy, heading: float | None = None, tol: float = 0.5) -> list:
    """Ids of lanelets containing ``xy`` (or within ``tol`` m of their centre line region),
    heading-compatible with ``heading`` when given, nearest centre line first."""
    found = []
    for ln in scenario.lanes:
        dist, th = _direction_at(ln.center, np.asarray(xy, float))
        if heading is not None and math.cos(th - heading) < HEADING_OK:
            continue
        half = 0.5 * float(np.min(np.linalg.norm(ln.left - ln.right, axis=1)))
        if point_in_polygon(lanelet_polygon(ln), np.asarray(xy, float)) or dist <= half + tol:
            found.append((dist, ln.id))
    return [i for _, i in sorted(found)]


def _has_position(goal: dict) -> bool:
    return any(k in goal for k in ("rectangle", "polygon", "circle", "lanelets"))


def _goal_lanelets(scenario) -> list:
    goal = scenario.goal
    if goal.get("lanelets"):
        return [int(i) for i in goal["lanelets"] if any(ln.id == int(i) for ln in scenario.lanes)]
    if "rectangle" in goal:
        centre = goal["rectangle"]["center"]
    elif "circle" in goal:
        centre = goal["circle"]["center"]
    elif "polygon" in goal:
        centre = np.mean(np.asarray(goal["polygon"], float), axis=0)
    else:
        return []
    heading = None
    if goal.get("orientation"):
        a, b = goal["orientation"]
        heading = 0.5 * (a + b)
    ids = lanelets_at(scenario, centre, heading)
    if not ids and heading is not None:
        ids = lanelets_at(scenario, centre, None)
    return ids


def neighbour_map(scenario) -> dict:
    """``{(lanelet id, "left"|"right"): (neighbour id, same direction)}`` seen from each
    lanelet's own direction: the map's adjacency, and where the map gives none, a lanelet
    that shares the bound on that side (mean distance of the bounds under ``SHARED_BOUND``
    metres, e.g. two parallel lanes the map forgot to link)."""
    by_id = {ln.id: ln for ln in scenario.lanes}
    out = {}
    for ln in scenario.lanes:
        for side, same, opp in (
            ("left", ln.adjacent_left, ln.opposite_left),
            ("right", ln.adjacent_right, ln.opposite_right),
        ):
            if same is not None and same in by_id:
                out[(ln.id, side)] = (same, True)
            elif opp is not None and opp in by_id:
                out[(ln.id, side)] = (opp, False)
    lanes = list(scenario.lanes)
    # every lanelet's bounding box (both bounds), for a cheap reject before comparing bounds
    lo = np.array([np.minimum(ln.left.min(0), ln.right.min(0)) for ln in lanes]).reshape(-1, 2)
    hi = np.array([np.maximum(ln.left.max(0), ln.right.max(0)) for ln in lanes]).reshape(-1, 2)
    reach = 5.0 + SHARED_BOUND
    for ln in lanes:
        for side in ("left", "right"):
            if (ln.id, side) in out:
                continue
            mine = ln.left if side == "left" else ln.right
            m = _midpoint(mine)
            near = np.nonzero(np.all((lo - reach <= m) & (m <= hi + reach), axis=1))[0]
            for j in near:
                other = lanes[j]
                if other.id == ln.id:
                    continue
                # same direction: my left bound is its right bound (and my right its left);
                # opposite direction: my left bound is its left bound reversed (my right, its right)
                for bound, same in (
                    ((other.right, True), (other.left, False))
                    if side == "left"
                    else ((other.left, True), (other.right, False))
                ):
                    if np.min(np.linalg.norm(bound - m, axis=1)) > reach:  # cheap reject
                        continue
                    if _bounds_shared(mine, bound if same else bound[::-1]):
                        out[(ln.id, side)] = (other.id, same)
                        break
                if (ln.id, side) in out:
                    break
    return out


def _midpoint(xy: np.ndarray) -> np.ndarray:
    s = arc_length(xy)
    return resample_polyline(xy, s, [0.5 * s[-1]])[0]


SHARED_BOUND = 0.3


def _bounds_shared(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether polylines ``a`` and ``b`` run along each other (same direction) within SHARED_BOUND."""
    da, db = a[-1] - a[0], b[-1] - b[0]
    if np.dot(da, db) <= 0 or np.linalg.norm(da) < 1e-6:
        return False
    sa, sb = arc_length(a), arc_length(b)
    u = np.linspace(0.1, 0.9, 9)
    pa = resample_polyline(a, sa / sa[-1], u)
    pb = resample_polyline(b, sb / max(sb[-1], 1e-9), u)
    return float(np.mean(np.linalg.norm(pa - pb, axis=1))) < SHARED_BOUND


def _neighbours(scenario, by_id, lid, adjacency):
    ln = by_id[lid]
    for s in ln.successors:
        if s in by_id:
            yield s, _length(by_id[s].center), "succ"
    for side in ("left", "right"):
        nb = adjacency.get((lid, side))
        if nb is not None and nb[1]:  # lane changes into same-direction neighbours only
            yield nb[0], LANE_CHANGE_COST, "lat"


def _search(scenario, by_id, starts, goals, adjacency):
    """Dijkstra from any start lanelet to any goal lanelet. Returns [(id, kind)] or None."""
    goal_set = set(goals)
    heap = [(0.0, i, s) for i, s in enumerate(starts)]
    prev = {s: None for s in starts}
    kind = {s: "start" for s in starts}
    dist = {s: 0.0 for s in starts}
    count = len(starts)
    while heap:
        d, _, u = heapq.heappop(heap)
        if d > dist.get(u, math.inf):
            continue
        if u in goal_set:
            path = []
            while u is not None:
                path.append((u, kind[u]))
                u = prev[u]
            return path[::-1]
        for v, w, k in _neighbours(scenario, by_id, u, adjacency):
            if d + w < dist.get(v, math.inf):
                dist[v], prev[v], kind[v] = d + w, u, k
                count += 1
                heapq.heappush(heap, (d + w, count, v))
    return None


def _straight_successor(by_id, lid, seen):
    """The successor that continues most nearly straight (None at the map's end)."""
    ln = by_id[lid]
    end_dir = ln.center[-1] - ln.center[-2]
    best, best_cos = None, -2.0
    for s in ln.successors:
        if s in by_id and s not in seen:
            c = by_id[s].center
            d = c[min(len(c) - 1, 1)] - c[0]
            cos = float(np.dot(end_dir, d) / max(1e-9, np.linalg.norm(end_dir) * np.linalg.norm(d)))
            if cos > best_cos:
                best, best_cos = s, cos
    return best


def blend_lane_change(before: np.ndarray, after: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """The reference line of a lane change: ``after (Q, 2)``, the target lane's line from beside
    the last point of ``before (P, 2)`` on (across as many lanelets as it runs), moved sideways
    towards that point and blended back onto itself over its first ``length`` metres.

    A point at arc length ``u`` of ``after`` within the blend is ``after(u) + n(u) d (1 - w)``
    with ``n`` the line's left normal, ``d`` the signed lateral distance of ``before[-1]`` from
    ``after[0]`` and the smooth step ``w = 3 r^2 - 2 r^3``, ``r = u / length``; the blend is
    sampled every metre and shortened only where ``after`` is shorter than ``length``. So a
    lane change takes ``length`` metres whatever the lanelets' lengths (a change on a short
    lanelet continues on the target lane's successors).

    Returns:
        (``(n, 2)`` points replacing ``after``, ``(n,)`` index of the point of ``after`` at or
        before each).
    """
    s = arc_length(after)
    if len(after) < 2 or s[-1] < 1e-6:
        return after, np.arange(len(after))
    t = after[1] - after[0]
    t = t / max(np.linalg.norm(t), 1e-9)
    d = float(np.dot(before[-1] - after[0], [-t[1], t[0]]))
    span = min(float(length), float(s[-1]))
    u = np.linspace(0.0, span, max(2, int(np.ceil(span)) + 1))
    pts = resample_polyline(after, s, u)
    tan = np.gradient(pts, axis=0)
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-9)
    r = u / max(span, 1e-9)
    w = 3 * r**2 - 2 * r**3
    pts = pts + np.column_stack([-tan[:, 1], tan[:, 0]]) * (d * (1 - w))[:, None]
    rest = np.nonzero(s > span + 1e-6)[0]
    idx = np.clip(np.searchsorted(s, u, side="right") - 1, 0, len(after) - 1)
    return np.concatenate([pts, after[rest]]), np.concatenate([idx, rest])


def plan_route(scenario) -> Route:
    """The route from the scenario's start to its goal (see the module docstring).

    Raises:
        RouteError: the scenario has no lanelets, or no lanelet near the start.
    """
    if not scenario.lanes:
        raise RouteError(f"scenario {scenario.id}: has no lanelets, so there is no road to plan on")
    by_id = {ln.id: ln for ln in scenario.lanes}
    start = np.array([scenario.ego.x, scenario.ego.y])
    starts = lanelets_at(scenario, start, scenario.ego.heading)
    if not starts:
        starts = lanelets_at(scenario, start, scenario.ego.heading, tol=3.0)
    if not starts:
        raise RouteError(
            f"scenario {scenario.id}: no lanelet under the start {start.round(2).tolist()} "
            f"that runs along its heading {scenario.ego.heading:.2f} rad"
        )
    goals = _goal_lanelets(scenario)
    path = _search(scenario, by_id, starts, goals, neighbour_map(scenario)) if goals else None
    reaches = path is not None or not _has_position(scenario.goal)
    if path is None:  # survival goal, or no path: straight ahead along successors
        path = [(starts[0], "start")]
    # continue past the last lanelet along successors for AHEAD_MIN metres (SURVIVAL_AHEAD without a
    # goal position: the drive goes wherever the road leads until its time is up)
    seen = {i for i, _ in path}
    ahead, cur = 0.0, path[-1][0]
    want = AHEAD_MIN if _has_position(scenario.goal) else SURVIVAL_AHEAD
    dead_end = False
    while True:
        nxt = _straight_successor(by_id, cur, seen)
        if nxt is None:
            dead_end = not any(q in by_id for q in by_id[cur].successors)
            break
        if ahead >= want:
            break
        path.append((nxt, "succ"))
        seen.add(nxt)
        ahead += _length(by_id[nxt].center)
        cur = nxt
    return _build(scenario, by_id, path, start, reaches, dead_end)


def _build(scenario, by_id, path, start, reaches, dead_end: bool = True) -> Route:
    # runs of successor lanelets; a run after a lane change starts beside the point where the
    # change starts (the car's position on the first lanelet, else the start of the lanelet left)
    runs: list[tuple[np.ndarray | None, list[tuple[np.ndarray, int]]]] = [(None, [])]
    i = 0
    while i < len(path):
        lid, _ = path[i]
        # a run of lane changes: lid -> ... -> last lateral neighbour
        j = i
        while j + 1 < len(path) and path[j + 1][1] == "lat":
            j += 1
        a = by_id[lid].center
        if j > i:
            sa = arc_length(a)
            at = 0.0
            if i == 0:  # change lane after the start, not behind it
                jj, along, _ = nearest_on_polyline(a, start)
                at = float(sa[jj] + along)
                if at > 1e-3:
                    runs[-1][1].append((resample_polyline(a, sa, np.linspace(0.0, at, 6)), lid))
            origin = resample_polyline(a, sa, [at])[0]
            b = by_id[path[j][0]].center
            sb = arc_length(b)
            jb, along, _ = nearest_on_polyline(b, origin)
            ub = float(sb[jb] + along)
            runs.append((origin, [(np.concatenate([resample_polyline(b, sb, [ub]), b[sb > ub + 1e-6]]), path[j][0])]))
        else:
            runs[-1][1].append((a, lid))
        i = j + 1
    change = max(LANE_CHANGE_LENGTH, LANE_CHANGE_TIME * abs(float(scenario.ego.v)))
    xy, owner = np.zeros((0, 2)), np.zeros(0, int)
    for origin, pieces in runs:
        if not pieces:
            continue
        pts_list, own_list = [pieces[0][0]], [np.full(len(pieces[0][0]), pieces[0][1])]
        for p, lid in pieces[1:]:  # successor lanelets share their first point with the previous one's last
            p = p[1:] if np.linalg.norm(p[0] - pts_list[-1][-1]) < 1e-6 else p
            pts_list.append(p)
            own_list.append(np.full(len(p), lid))
        pts, own = np.concatenate(pts_list), np.concatenate(own_list)
        if origin is not None:
            pts, idx = blend_lane_change(xy if len(xy) else origin[None], pts, change)
            own = own[idx]
        elif len(xy) and np.linalg.norm(pts[0] - xy[-1]) < 1e-6:
            pts, own = pts[1:], own[1:]
        xy, owner = np.concatenate([xy, pts]), np.concatenate([owner, own])
    keep = np.concatenate([[True], np.linalg.norm(np.diff(xy, axis=0), axis=1) > 1e-3])
    xy, owner = xy[keep], owner[keep]
    # behind: the first lanelet's predecessors (straightest), else straight
    first = by_id[path[0][0]]
    back_pts: list[np.ndarray] = []
    prev_len, cur = 0.0, first
    seen = {i for i, _ in path}
    while prev_len < BACK and cur.predecessors:
        pred = next((by_id[q] for q in cur.predecessors if q in by_id and q not in seen), None)
        if pred is None:
            break
        back_pts.insert(0, pred.center[:-1] if np.linalg.norm(pred.center[-1] - xy[0]) < 1e-3 else pred.center)
        seen.add(pred.id)
        prev_len += _length(pred.center)
        cur = pred
    if back_pts:
        bp = np.concatenate(back_pts)
        xy = np.concatenate([bp, xy])
        owner = np.concatenate([np.full(len(bp), -1), owner])
    s = arc_length(xy)
    j, along, _ = nearest_on_polyline(xy, start)
    start_s = float(s[j] + along)
    if start_s < BACK:  # straight extension behind
        ext = resample_polyline(xy, s, np.linspace(start_s - BACK, 0.0, 8)[:-1])
        xy = np.concatenate([ext, xy])
        owner = np.concatenate([np.full(len(ext), -1), owner])
        s = arc_length(xy)
        start_s += float(s[len(ext)])
    last = float(s[-1])
    ext = resample_polyline(xy, s, last + np.linspace(0.0, AHEAD_MIN, 9)[1:])
    xy = np.concatenate([xy, ext])
    owner = np.concatenate([owner, np.full(len(ext), -1)])
    return Route(tuple(i for i, _ in path), xy, owner, start_s, last if dead_end else float("inf"), reaches)
