"""A loaded scenario and its parts (host side, numpy, local frame): ``Scenario``, ``Lane``,
``EgoRecord``, ``TrafficLight`` (CommonRoad's cycles on the scene's clock), and the lane lookups
on a scenario (``lane_at``, ``lane_polyline``, ``lane_reference``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxplan.geometry.frenet import ReferenceLine
from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.polylines import nearest_on_polyline
from jaxplan.types import Obstacles

# CommonRoad's traffic light colors and directions (the values its XML and commonroad-io use).
LIGHT_COLORS = ("green", "yellow", "red", "redYellow", "inactive")
LIGHT_DIRECTIONS = {
    "right": ("right",),
    "straight": ("straight",),
    "left": ("left",),
    "leftStraight": ("left", "straight"),
    "straightRight": ("straight", "right"),
    "leftRight": ("left", "right"),
    "all": ("left", "straight", "right"),
}


@dataclasses.dataclass(frozen=True)
class Lane:
    """A lanelet: bounds and centre line ``(P, 2)`` in the local frame.

    ``adjacent_left`` / ``adjacent_right``: the neighbour driven the same way (a lane one
    may change into); ``opposite_left`` / ``opposite_right``: a neighbour driven the other way.
    """

    id: int
    left: np.ndarray
    right: np.ndarray
    center: np.ndarray
    successors: tuple
    predecessors: tuple
    adjacent_left: int | None
    adjacent_right: int | None
    speed_limit: float | None
    opposite_left: int | None = None  # the neighbour on the left driven the other way
    opposite_right: int | None = None
    traffic_lights: tuple = ()  # ids of the lights governing the lanelet (its own and its stop line's)
    stop_line: np.ndarray | None = None  # (2, 2) where they govern: the stop line, else the lanelet's end


@dataclasses.dataclass(frozen=True)
class EgoRecord:
    x: float
    y: float
    heading: float
    v: float
    a: float = 0.0
    t: float = 0.0


@dataclasses.dataclass(frozen=True)
class TrafficLight:
    """A traffic light on the scene's clock (step 0 = the ego's start).

    Attributes:
        id: its id.
        direction: one of ``LIGHT_DIRECTIONS`` (the movements it governs).
        active: False: ``inactive`` at every step.
        colors: the colors of the cycle's phases (``LIGHT_COLORS``).
        durations: each phase's length in steps (>= 1).
        offset: the step at which a cycle begins (the cycle repeats before and after it).
        position: ``(2,)`` where the light stands (local frame), or None.
    """

    id: int
    direction: str
    active: bool
    colors: tuple
    durations: tuple
    offset: int
    position: np.ndarray | None = None

    @property
    def period(self) -> int:
        """Steps of one cycle."""
        return int(sum(self.durations))

    def color_codes(self, steps) -> np.ndarray:
        """``(...)`` indices into ``LIGHT_COLORS`` of the light's color at integer scene ``steps (...)``
        (commonroad-io's ``TrafficLightCycle.get_state_at_time_step`` on the scene's clock)."""
        steps = np.asarray(steps, np.int64)
        if not self.active or not self.colors:
            return np.full(steps.shape, LIGHT_COLORS.index("inactive"), np.int32)
        ends = np.cumsum(self.durations)
        phase = np.searchsorted(ends, np.mod(steps - self.offset, self.period), side="right")
        return np.array([LIGHT_COLORS.index(c) for c in self.colors], np.int32)[phase]

    def color_at(self, step: int) -> str:
        """The light's color at scene step ``step``."""
        return LIGHT_COLORS[int(self.color_codes(step))]


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One scenario in the local frame.

    Attributes:
        obstacles: ``Obstacles`` with boxes ``(K, T, 5)`` at times ``t = k * dt``
            from the ego start; static obstacles (role ``static``, or given by a polygon
            or centre) repeat their box and carry ``static = True``, so they are held
            over any horizon; dynamic ones are invalid where their recording has no state.
        obstacle_ids: ``(K,)`` ids of the recorded vehicles.
        origin: ``(2,)`` the world position moved to the origin.
        goal: the first goal of the planning problem, coordinates shifted.
        skipped: ids of obstacles without a usable shape or trajectory.
        problem_id: id of the planning problem whose start is the ego.
        traffic_lights: ``TrafficLight``s of the map (lanelets name the ones governing them).
    """

    id: str
    source: str
    tags: tuple
    dt: float
    lanes: tuple
    obstacles: Obstacles
    obstacle_ids: np.ndarray
    obstacle_types: tuple
    ego: EgoRecord
    goal: dict
    origin: np.ndarray
    skipped: tuple = ()
    problem_id: int = 0
    traffic_lights: tuple = ()

    def lane(self, lane_id: int) -> Lane:
        for ln in self.lanes:
            if ln.id == lane_id:
                return ln
        raise KeyError(lane_id)


def lane_at(scenario: Scenario, xy, heading: float | None = None) -> Lane:
    """The lane whose centre line passes closest to ``xy`` (heading-compatible if given)."""
    xy = np.asarray(xy, float)
    best, best_d = None, np.inf
    for ln in scenario.lanes:
        j, _, dist = nearest_on_polyline(ln.center, xy)
        if heading is not None:
            seg = ln.center[j + 1] - ln.center[j]
            if math.cos(math.atan2(seg[1], seg[0]) - heading) < 0.5:
                continue
        if dist < best_d:
            best, best_d = ln, dist
    if best is None:
        raise ScenarioError(f"scenario {scenario.id}: no lane near {xy.tolist()}")
    return best


def lane_polyline(
    scenario: Scenario, lane: Lane | int | None = None, max_length: float = 500.0, back: float = 20.0
) -> np.ndarray:
    """Centre-line points ``(P, 2)`` along a lane, following one predecessor back (when
    ``back > 0``) and successors forward (first unvisited one each time) up to ``max_length``.

    Default lane: the one at the ego start.
    """
    if lane is None:
        lane = lane_at(scenario, [scenario.ego.x, scenario.ego.y], scenario.ego.heading)
    elif isinstance(lane, int):
        lane = scenario.lane(lane)
    by_id = {ln.id: ln for ln in scenario.lanes}
    pts = [lane.center]
    seen = {lane.id}
    cur = lane
    if cur.predecessors and cur.predecessors[0] in by_id and back > 0:
        pts.insert(0, by_id[cur.predecessors[0]].center)
        seen.add(cur.predecessors[0])
    total = sum(np.linalg.norm(np.diff(p, axis=0), axis=1).sum() for p in pts)
    while total < max_length and cur.successors:
        nxt = next((by_id[s] for s in cur.successors if s in by_id and s not in seen), None)
        if nxt is None:
            break
        pts.append(nxt.center)
        seen.add(nxt.id)
        total += np.linalg.norm(np.diff(nxt.center, axis=0), axis=1).sum()
        cur = nxt
    return np.concatenate(pts)


def lane_reference(
    scenario: Scenario, lane: Lane | int | None = None, max_length: float = 500.0, back: float = 20.0
) -> ReferenceLine:
    """``ReferenceLine`` along ``lane_polyline(scenario, lane, max_length, back)``."""
    return ReferenceLine.from_polyline(lane_polyline(scenario, lane, max_length, back))
