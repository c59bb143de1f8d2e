"""The route's reference line (``jaxplan.scenarios.route``): lane changes blend smoothly over their
length whatever the lanelets' lengths."""
import numpy as np
import pytest

from jaxplan.scenarios.loader import parse_scenario
from jaxplan.scenarios.polylines import arc_length, resample_polyline
from jaxplan.scenarios.route import LANE_CHANGE_LENGTH, plan_route


def _lane(lid, x0, x1, y, succ=(), pred=(), left=None, right=None):
    xs = np.linspace(x0, x1, max(2, int(round((x1 - x0) / 5)) + 1))
    d = {"id": lid, "left": [[x, y + 1.75] for x in xs], "right": [[x, y - 1.75] for x in xs],
         "predecessors": list(pred), "successors": list(succ), "speed_limit": 15.0}
    if left:
        d["adjacentLeft"] = {"ref": left, "drivingDir": "same"}
    if right:
        d["adjacentRight"] = {"ref": right, "drivingDir": "same"}
    return d


def _merge(short: float, x_car: float):
    """Lane 1 (y = 0) ends ``short`` metres after x = 0 without successor; lane 3 beside it (y = 3.5)
    continues as lane 4 to x = 300, where the goal lies. The car starts in lane 1 at ``x_car`` (the
    scenario's origin)."""
    lanes = [_lane(1, 0.0, short, 0.0, left=3), _lane(3, 0.0, short, 3.5, succ=[4], right=1),
             _lane(4, short, 300.0, 3.5, pred=[3])]
    return parse_scenario({"id": "TEST_merge-1", "dt": 0.1, "lanelets": lanes, "obstacles": [],
                           "planning_problems": [{"id": 1, "initial_state": {"position": [x_car, 0.0], "orientation": 0.0,
                                                                             "velocity": 5.0, "t": 0.0},
                                                  "goals": [{"rectangle": {"center": [280.0, 3.5], "length": 20.0,
                                                                           "width": 3.0, "orientation": 0.0},
                                                             "time": [0.0, 60.0]}]}]}, "test")


def _curvature(xy):
    a, b, c = xy[:-2], xy[1:-1], xy[2:]
    cross = (b - a)[:, 0] * (c - b)[:, 1] - (b - a)[:, 1] * (c - b)[:, 0]
    den = np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - b, axis=1) * np.linalg.norm(c - a, axis=1)
    return 2 * cross / np.maximum(den, 1e-12)


@pytest.mark.parametrize("short, x_car", [(12.0, 8.0), (12.0, 0.5), (60.0, 2.0), (60.0, 50.0)])
def test_lane_change_takes_its_length_even_on_a_short_lanelet(short, x_car):
    route = plan_route(_merge(short, x_car))
    assert route.lanelets == (1, 3, 4)
    s = arc_length(route.xy)
    xy = resample_polyline(route.xy, s, np.arange(route.start_s, route.start_s + 80.0, 2.0))
    # from the car (y = 0) to the target lane (y = 3.5) over LANE_CHANGE_LENGTH metres (the start speed
    # is slow), a smooth step whose peak curvature is 6 d / L^2
    # (the scenario's frame has the car at the origin)
    np.testing.assert_allclose(xy[0], [0.0, 0.0], atol=1e-6)
    done = xy[:, 0] >= LANE_CHANGE_LENGTH - 1e-6
    np.testing.assert_allclose(xy[done, 1], 3.5, atol=1e-6)
    assert np.all(np.diff(xy[:, 0]) > 0)
    assert abs(np.interp(LANE_CHANGE_LENGTH / 2, xy[:, 0], xy[:, 1]) - 1.75) < 0.05
    assert np.max(np.abs(_curvature(xy))) < 1.1 * 6 * 3.5 / LANE_CHANGE_LENGTH ** 2


def _chain(n: int, goal=True):
    """Lanelets 1..n of 50 m each along x, each the successor of the one before; the car at x = 5;
    the goal (when given) on lanelet 1 at x = 40."""
    lanes = [_lane(i, 50.0 * (i - 1), 50.0 * i, 0.0, succ=[i + 1] if i < n else [], pred=[i - 1] if i > 1 else [])
             for i in range(1, n + 1)]
    problem = {"id": 1, "initial_state": {"position": [5.0, 0.0], "orientation": 0.0, "velocity": 5.0, "t": 0.0},
               "goals": [{"rectangle": {"center": [40.0, 0.0], "length": 6.0, "width": 3.0, "orientation": 0.0},
                          "time": [0.0, 20.0]} if goal else {"time": [0.0, 20.0]}]}
    return parse_scenario({"id": "TEST_chain-1", "dt": 0.1, "lanelets": lanes, "obstacles": [],
                           "planning_problems": [problem]}, "test")


def test_route_end_is_the_dead_end_of_the_road_not_where_the_route_stops_walking():
    """``Route.end_s`` is where the road ends (a lanelet without successor), ``inf`` where it goes on
    past the lanelets the route took; a goal without a position walks the road further."""
    short = plan_route(_chain(3))  # 150 m of road: it ends within the walk
    assert short.lanelets == (1, 2, 3)
    np.testing.assert_allclose(short.end_s - short.start_s, 145.0, atol=1e-6)
    long = plan_route(_chain(12))  # 600 m: the walk stops while the road goes on
    assert not np.isfinite(long.end_s) and len(long.lanelets) < 12
    survival = plan_route(_chain(12, goal=False))
    assert len(survival.lanelets) > len(long.lanelets) and not np.isfinite(survival.end_s)
    from jaxplan.scenarios.build import build_scene

    assert not np.isfinite(float(build_scene(_chain(12))[0].route_end_s))
    assert float(build_scene(_chain(3))[0].route_end_s) < 200.0
