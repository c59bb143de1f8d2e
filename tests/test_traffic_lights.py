"""Traffic lights (loader, Scene, the planners' stop targets, the red-light metric), set-based
predictions and obstacle shapes of CommonRoad files."""
import math
import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import shared_data_or_skip
from jaxplan.planner import EgoState, make_planner
from jaxplan.scenarios.batch import index_scene, stack_scenes
from jaxplan.scenarios.build import build_scene
from jaxplan.scenarios.lights import GREEN, INACTIVE, RED, YELLOW, colors_at, line_colors, movement
from jaxplan.scenarios.loader import Lane, ScenarioError, TrafficLight, parse_scenario

LINE_X = 40.0  # the stop line, metres ahead of the ego start
DT = 0.1


def _road(cycle, offset=0.0, line_x=LINE_X, direction="all", v0=10.0, t_goal=(0.0, 60.0)):
    """Two same-direction lanes along x; lanelets 1 and 3 end at a stop line at ``x = line_x`` governed by
    light 7 (``cycle``: ``[(color, seconds)]`` from ``offset`` s on), lanelets 2 and 4 continue to x = 500;
    the car starts at the origin in lane 1 at ``v0``, the goal lies 250 m ahead."""
    def lane(lid, x0, x1, y, succ, pred, left=None, right=None, lights=False):
        xs = np.linspace(x0, x1, int(round((x1 - x0) / 5)) + 1)
        d = {"id": lid, "left": [[x, y + 1.75] for x in xs], "right": [[x, y - 1.75] for x in xs],
             "predecessors": pred, "successors": succ, "speed_limit": 15.0}
        if left:
            d["adjacentLeft"] = {"ref": left, "drivingDir": "same"}
        if right:
            d["adjacentRight"] = {"ref": right, "drivingDir": "same"}
        if lights:
            d["traffic_lights"] = [7]
            d["stop_line"] = {"traffic_lights": [7]}
        return d

    lanes = [lane(1, -60, line_x, 0.0, [2], [], left=3, lights=True),
             lane(3, -60, line_x, 3.5, [4], [], right=1, lights=True),
             lane(2, line_x, 500, 0.0, [], [1], left=4), lane(4, line_x, 500, 3.5, [], [3], right=2)]
    return {"id": "TEST_light-1", "dt": DT, "lanelets": lanes, "obstacles": [],
            "traffic_lights": [{"id": 7, "direction": direction, "active": True, "time_offset": offset,
                                "position": [line_x, -2.5], "cycle": [{"color": c, "duration": s} for c, s in cycle]}],
            "planning_problems": [{"id": 1, "initial_state": {"position": [0.0, 0.0], "orientation": 0.0,
                                                              "velocity": v0, "t": 0.0},
                                   "goals": [{"rectangle": {"center": [250.0, 1.75], "length": 20.0, "width": 7.0,
                                                            "orientation": 0.0}, "time": list(t_goal)}]}]}


RED_20S = [("green", 30.0), ("yellow", 3.0), ("red", 20.0)]  # with offset 20: red for the first 20 s, then green
ALWAYS_GREEN = [("green", 100.0)]


def _scene(cycle, offset=0.0, **kw):
    return build_scene(parse_scenario(_road(cycle, offset, **kw), "test"))[0]


# ----------------------------------------------------------------------------- loading

def test_lanker_file_gives_its_lights_and_the_routes_stop_line():
    pytest.importorskip("commonroad")
    from jaxplan.scenarios.commonroad import load_commonroad, read_commonroad

    path = os.path.join(shared_data_or_skip("commonroad"), "ngsim", "USA_Lanker-1_13_T-1.xml.gz")
    cr, pps = read_commonroad(path)
    sc = load_commonroad(path)
    assert len(sc.traffic_lights) == 8
    mine = {tl.id: tl for tl in sc.traffic_lights}
    t0 = next(iter(pps.planning_problem_dict.values())).initial_state.time_step
    for tl in cr.lanelet_network.traffic_lights:  # every light's color at every step, as commonroad-io says
        m = mine[tl.traffic_light_id]
        assert m.direction == tl.direction.value and m.period == 1000
        assert [m.color_at(k) for k in range(-40, 2100, 3)] == \
            [tl.get_state_at_time_step(k + t0).value for k in range(-40, 2100, 3)]
    for ln in cr.lanelet_network.lanelets:
        want = set(ln.traffic_lights or ()) | set(ln.stop_line.traffic_light_ref if ln.stop_line else ())
        assert set(sc.lane(ln.lanelet_id).traffic_lights) == want
    assert sc.lane(3448).traffic_lights == (11130,)
    np.testing.assert_allclose(sc.lane(3448).stop_line, [sc.lane(3448).left[-1], sc.lane(3448).right[-1]])
    scene, route = build_scene(sc)
    scene.validate()
    L = scene.lights
    # the route runs straight on from lanelet 3448 to 3610: its straightRight light 11130 governs, red throughout
    assert list(L.lanelet) == [3448] and list(L.valid) == [True] and int(L.period[0]) == 1000
    assert float(L.s[0] - scene.route_start_s) == pytest.approx(18.7, abs=0.1)
    np.testing.assert_array_equal(L.color[0], mine[11130].color_codes(np.arange(1000)))
    assert np.all(L.color[0, :250] == RED)
    # a file whose route crosses no stop line: no lines
    other = build_scene(load_commonroad(path.replace("_13_", "_1_")))[0]
    assert other.lights.s.shape == (0,)


@pytest.mark.parametrize("mutate,field", [
    (lambda d: d["traffic_lights"][0]["cycle"][0].__setitem__("color", "blue"), "traffic_lights[0].cycle[0].color"),
    (lambda d: d["traffic_lights"][0]["cycle"][1].__setitem__("duration", 0.0), "traffic_lights[0].cycle[1].duration"),
    (lambda d: d["traffic_lights"][0]["cycle"][1].__setitem__("duration", "long"),
     "traffic_lights[0].cycle[1].duration"),
    (lambda d: d["traffic_lights"][0].__setitem__("direction", "up"), "traffic_lights[0].direction"),
    (lambda d: d["traffic_lights"][0].__setitem__("active", "yes"), "traffic_lights[0].active"),
    (lambda d: d["traffic_lights"][0].__setitem__("cycle", []), "traffic_lights[0].cycle"),
    (lambda d: d["traffic_lights"][0].__setitem__("time_offset", float("inf")), "traffic_lights[0].time_offset"),
    (lambda d: d["traffic_lights"].append(dict(d["traffic_lights"][0])), "traffic_lights[1].id"),
    (lambda d: d["lanelets"][2].__setitem__("traffic_lights", [8]), "lanelets[2].traffic_lights"),
    (lambda d: d["lanelets"][0]["stop_line"].__setitem__("start", [40, 2]), "lanelets[0].stop_line"),
    (lambda d: d["lanelets"][0]["stop_line"].__setitem__("traffic_lights", [9]), "lanelets[0].traffic_lights"),
    (lambda d: d.__setitem__("traffic_lights", {"id": 7}), "scenario.traffic_lights"),
])
def test_bad_light_fields_are_one_error_naming_file_and_field(mutate, field):
    d = _road(RED_20S, 20.0)
    parse_scenario(d, "fine.json")
    mutate(d)
    with pytest.raises(ScenarioError) as e:
        parse_scenario(d, "bad.json")
    assert str(e.value).startswith("bad.json: ") and field in str(e.value) and "\n" not in str(e.value)


def _light(lid, direction, cycle, offset=0):
    return TrafficLight(lid, direction, True, tuple(c for c, _ in cycle), tuple(n for _, n in cycle), offset)


def test_the_light_for_the_routes_movement_governs():
    left_red = _light(1, "left", [("red", 10)])
    straight_green = _light(2, "straightRight", [("green", 10)])
    main = _light(3, "all", [("red", 10)])
    arrow = _light(4, "right", [("green", 4), ("inactive", 6)])  # a right-turn arrow, dark after 4 steps
    colors, period = line_colors([left_red, straight_green], "straight")
    assert period == 10 and np.all(colors == GREEN)
    assert np.all(line_colors([left_red, straight_green], "left")[0] == RED)
    # the most specific light that is on: the arrow while lit, the main light while the arrow is dark
    np.testing.assert_array_equal(line_colors([main, arrow], "right")[0], [GREEN] * 4 + [RED] * 6)
    # no movement known: every light, the most restrictive one on
    assert np.all(line_colors([left_red, straight_green], None)[0] == RED)
    # periods of 4 and 6 steps: the line repeats every 12
    c, p = line_colors([_light(5, "all", [("green", 2), ("red", 2)]), _light(6, "all", [("green", 3), ("yellow", 3)])],
                       None)
    assert p == 12 and list(c) == [GREEN, GREEN, RED, RED, YELLOW, YELLOW, RED, RED, GREEN, YELLOW, RED, RED]
    assert _light(7, "all", [("inactive", 5)]).color_at(3) == "inactive"

    def lane(heading):  # a centre line ending along ``heading``
        end = np.array([math.cos(heading), math.sin(heading)])
        return Lane(1, None, None, np.array([-end, [0.0, 0.0]]), (), (), None, None, None)

    assert movement(lane(0.0), lane(0.2)) == "straight"
    assert movement(lane(0.0), lane(math.pi / 2)) == "left"
    assert movement(lane(0.0), lane(-math.pi / 2)) == "right"
    assert movement(lane(0.0), None) is None


def test_scenes_with_and_without_lights_stack_padded():
    lit = _scene(RED_20S, 20.0)
    unlit = [{k: v for k, v in ln.items() if k not in ("traffic_lights", "stop_line")}
             for ln in _road(RED_20S)["lanelets"]]
    plain = build_scene(parse_scenario({**_road(RED_20S), "traffic_lights": [], "lanelets": unlit}, "t"))[0]
    assert plain.lights.s.shape == (0,) and lit.lights.s.shape == (1,)
    assert int(lit.lights.period[0]) == 530 and lit.lights.color.shape == (1, 530)
    assert float(lit.lights.s[0] - lit.route_start_s) == pytest.approx(LINE_X, abs=0.05)
    batch = stack_scenes([plain, lit])
    batch.validate()
    assert batch.lights.color.shape == (2, 1, 530) and list(np.asarray(batch.lights.valid[:, 0])) == [False, True]
    c = np.asarray(jax.vmap(lambda s: colors_at(s.lights, jnp.array([0, 199, 200, 499, 500, 529, 530, 730])))(batch))
    np.testing.assert_array_equal(c[0, :, 0], [INACTIVE] * 8)
    np.testing.assert_array_equal(c[1, :, 0], [RED, RED, GREEN, GREEN, YELLOW, YELLOW, RED, GREEN])
    bad = jax.tree_util.tree_map(np.array, index_scene(batch, 1))
    bad.lights.color[0, 3] = 9
    with pytest.raises(ValueError, match="lights.color"):
        bad.validate()


# ----------------------------------------------------------------------------- the planners' stop target

def test_road_context_makes_stop_targets_of_red_and_stoppable_yellow():
    from jaxplan.planner import SIM_VEHICLE
    from jaxplan.plan_context import LIGHT_DEPTH, road_context

    scene = jax.tree_util.tree_map(jnp.asarray, _scene(RED_20S, 20.0))
    H = 50
    front = 0.5 * SIM_VEHICLE.length

    def ctx(x, v, step):
        ego = EgoState.from_box_centre(jnp.array([x, 0.0, 0.0, v, 0.0]), SIM_VEHICLE)
        c = road_context(scene, ego, step, H, SIM_VEHICLE)
        assert c.obstacles.boxes.shape == (scene.obstacles.boxes.shape[0] + 1, H, 5)
        return c, np.asarray(c.obstacles.valid[-1])

    c, valid = ctx(0.0, 10.0, 0)  # red for the whole horizon: a stopped box across the road at the line
    assert valid.all() and int(c.leader_index) == c.obstacles.boxes.shape[0] - 1
    box = np.asarray(c.obstacles.boxes[-1, 0])
    assert box[0] - 0.5 * box[2] == pytest.approx(LINE_X, abs=0.05) and box[2] == LIGHT_DEPTH
    assert box[1] - 0.5 * box[3] <= -1.75 and box[1] + 0.5 * box[3] >= 5.25  # both lanes
    assert float(c.leader_gap) == pytest.approx(LINE_X - front, abs=0.1)
    assert not ctx(0.0, 10.0, 200)[1].any()  # green
    assert list(ctx(0.0, 10.0, 180)[1]) == [True] * 20 + [False] * 30  # red, then green from step 200
    # yellow from step 500: stop while the car can at 4 m/s^2 (12.5 m at 10 m/s), through when it cannot
    assert ctx(LINE_X - front - 20.0, 10.0, 500)[1].all()
    assert list(ctx(LINE_X - front - 8.0, 10.0, 500)[1]) == [False] * 30 + [True] * 20  # the red after it counts
    assert not ctx(LINE_X - front + 0.5, 1.0, 0)[1].any()  # past the line: a red no longer holds the car


def _front(log, vehicle):
    return np.asarray(log.x) + 0.5 * vehicle.length * np.cos(np.asarray(log.heading))


@pytest.mark.parametrize("name", ["lattice", "idm"])
def test_planner_stops_at_red_and_goes_on_green(name):
    """Red for the first 20 s with the car arriving at about 5 s: it waits before the line and crosses
    once the light is green; with a green light the same drive does not slow down."""
    from jaxplan.sim.metrics.registry import evaluate_batch
    from jaxplan.sim.rollout import SimConfig, rollout

    planner = make_planner(name)
    cfg = SimConfig(n_steps=250)
    batch = stack_scenes([_scene(RED_20S, 20.0), _scene(ALWAYS_GREEN)], min_steps=cfg.n_steps + 1)
    log = rollout(planner, batch, cfg)
    front, v = _front(log, planner.vehicle), np.asarray(log.v)
    green_at = 200
    assert front[0, :green_at + 1].max() < LINE_X  # never past the line while red
    assert v[0, 100:green_at].min() < 0.5  # it waited at the line
    assert front[0, -1] > LINE_X + 10.0  # and went on once green
    assert front[1, -1] > LINE_X and v[1, :60].min() > 9.0  # green: no stop
    m = evaluate_batch(log, batch, planner.vehicle, names=("redlight", "overlap"))
    assert list(np.asarray(m["redlight.crossings"])) == [0, 0] and not np.asarray(m["overlap.collided"]).any()


# ----------------------------------------------------------------------------- the metric

def _straight_log(v, n=80, x0=0.0):
    from jaxplan.sim.rollout import DriveLog

    t = jnp.arange(n) * DT
    x = x0 + jnp.asarray(v, jnp.float32) * t
    z = jnp.zeros(n)
    return DriveLog(t=t, x=x, y=z, heading=z, v=jnp.full(n, v), a=z, kappa=z, valid=jnp.ones(n, bool),
                    end_step=jnp.asarray(n - 1), plan_ok=jnp.ones(1, bool), fallback=jnp.zeros(1, bool),
                    replanned=jnp.ones(1, bool), info={})


def test_redlight_metric_counts_a_red_run_only():
    from jaxplan.planner import SIM_VEHICLE
    from jaxplan.sim.metrics import METRICS
    from jaxplan.sim.metrics.registry import evaluate

    assert "redlight" in METRICS
    red = jax.tree_util.tree_map(jnp.asarray, _scene(RED_20S, 20.0))
    green = jax.tree_util.tree_map(jnp.asarray, _scene(ALWAYS_GREEN))
    run = _straight_log(10.0)  # the front (2.3 m ahead of the centre) passes x = 40 between steps 37 and 38
    m = evaluate(run, red, SIM_VEHICLE, names=("redlight",))
    assert int(m["redlight.crossings"]) == 1 and bool(m["redlight.crossed"]) and int(m["redlight.first_step"]) == 38
    m = evaluate(run, green, SIM_VEHICLE, names=("redlight",))
    assert int(m["redlight.crossings"]) == 0 and not bool(m["redlight.crossed"]) and int(m["redlight.first_step"]) == -1
    stops = _straight_log(0.0, x0=LINE_X - 3.0)  # waiting before the line
    assert int(evaluate(stops, red, SIM_VEHICLE, names=("redlight",))["redlight.crossings"]) == 0


# ----------------------------------------------------------------------------- CommonRoad files

def _write_xml(sc, pps, path):
    from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        CommonRoadFileWriter(sc, pps, author="jaxplan", affiliation="", source="",
                             tags=set()).write_to_file(str(path), OverwriteExistingFile.ALWAYS)
    return str(path)


def test_lights_round_trip_through_commonroad_xml(tmp_path):
    pytest.importorskip("commonroad")
    from jaxplan.scenarios.commonroad import load_commonroad, write_commonroad

    d = _road(RED_20S, 20.0, direction="straightRight")
    d["lanelets"][1]["stop_line"].update(start=[LINE_X - 2.0, 1.75], end=[LINE_X - 2.0, 5.25])
    del d["lanelets"][0]["stop_line"]  # lanelet 1 references the light only: its line lies across its end
    a = parse_scenario(d, "t")
    b = load_commonroad(write_commonroad(d, str(tmp_path / "lights.xml")))
    (x,), (y,) = a.traffic_lights, b.traffic_lights
    assert (y.id, y.direction, y.active, y.colors, y.durations, y.offset) == \
        (7, "straightRight", True, ("green", "yellow", "red"), (300, 30, 200), 200)
    assert (x.id, x.direction, x.active, x.colors, x.durations, x.offset) == \
        (y.id, y.direction, y.active, y.colors, y.durations, y.offset)
    np.testing.assert_allclose(y.position, x.position)
    for lid in (1, 3):
        assert b.lane(lid).traffic_lights == (7,)
        np.testing.assert_allclose(b.lane(lid).stop_line, a.lane(lid).stop_line, atol=1e-6)
    np.testing.assert_allclose(b.lane(3).stop_line, [[LINE_X - 2.0, 1.75], [LINE_X - 2.0, 5.25]], atol=1e-6)
    np.testing.assert_allclose(b.lane(1).stop_line, [[LINE_X, 1.75], [LINE_X, -1.75]], atol=1e-6)
    assert b.lane(2).stop_line is None and b.lane(2).traffic_lights == ()


def _set_based_scenario():
    """The light road with a set-based obstacle 900 (rectangles, a polygon, a shape group and a circle
    over an interval of steps) and a polygon-shaped car 901 with a trajectory."""
    from commonroad.common.util import Interval
    from commonroad.geometry.shape import Circle, Polygon, Rectangle, ShapeGroup
    from commonroad.prediction.prediction import Occupancy, SetBasedPrediction, TrajectoryPrediction
    from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
    from commonroad.scenario.state import CustomState, InitialState
    from commonroad.scenario.trajectory import Trajectory

    from jaxplan.scenarios.commonroad import dict_to_commonroad

    sc, pps = dict_to_commonroad(_road(RED_20S, 20.0), "t")
    init = InitialState(time_step=0, position=np.array([30.0, 3.5]), orientation=0.0, velocity=5.0, acceleration=0.0,
                        yaw_rate=0.0, slip_angle=0.0)
    occ = [Occupancy(k, Rectangle(4.0 + 0.2 * k, 2.0, np.array([30.0 + 0.5 * k, 3.5]), 0.1 * k)) for k in (1, 2, 3)]
    occ.append(Occupancy(4, Polygon(np.array([[31.0, 2.5], [37.0, 2.5], [37.0, 4.5], [31.0, 4.5]]))))
    occ.append(Occupancy(5, ShapeGroup([Rectangle(2.0, 2.0, np.array([32.0, 3.5]), 0.0),
                                        Rectangle(2.0, 2.0, np.array([38.0, 3.5]), 0.0)])))
    occ.append(Occupancy(Interval(6, 8), Circle(1.5, np.array([40.0, 3.5]))))
    occ.append(Occupancy(8, Rectangle(2.0, 1.0, np.array([45.0, 3.5]), 0.0)))  # shares step 8 with the circle
    sc.add_objects(DynamicObstacle(900, ObstacleType.CAR, Rectangle(4.0, 2.0), init, SetBasedPrediction(1, occ)))
    poly = Polygon(np.array([[-2.0, -1.0], [2.0, -1.0], [2.5, 0.0], [2.0, 1.0], [-2.0, 1.0]]))
    states = [CustomState(time_step=k, position=np.array([10.0 + k, -3.5]), orientation=0.3, velocity=10.0,
                          acceleration=0.0) for k in (1, 2, 3)]
    init2 = InitialState(time_step=0, position=np.array([10.0, -3.5]), orientation=0.3, velocity=10.0,
                         acceleration=0.0, yaw_rate=0.0, slip_angle=0.0)
    sc.add_objects(DynamicObstacle(901, ObstacleType.TAXI, poly, init2,
                                   TrajectoryPrediction(Trajectory(1, states), poly)))
    return sc, pps


def test_set_based_prediction_loads_its_occupancies_at_their_steps(tmp_path):
    pytest.importorskip("commonroad")
    from jaxplan.scenarios.commonroad import load_commonroad

    sc = load_commonroad(_write_xml(*_set_based_scenario(), tmp_path / "DEU_Test-1_1_S-1.xml"))
    k = list(sc.obstacle_ids).index(900)
    b, valid = np.asarray(sc.obstacles.boxes[k]), np.asarray(sc.obstacles.valid[k])
    assert not bool(sc.obstacles.static[k])
    assert list(valid[:9]) == [True] * 9 and not valid[9:].any()  # steps 0 .. 8, then gone
    np.testing.assert_allclose(b[0], [30.0, 3.5, 4.0, 2.0, 0.0], atol=1e-5)  # the initial state's box
    for j in (1, 2, 3):
        np.testing.assert_allclose(b[j], [30.0 + 0.5 * j, 3.5, 4.0 + 0.2 * j, 2.0, 0.1 * j], atol=1e-5)
    np.testing.assert_allclose(b[4], [34.0, 3.5, 6.0, 2.0, 0.0], atol=1e-5)  # the polygon's box
    np.testing.assert_allclose(b[5], [35.0, 3.5, 8.0, 2.0, 0.0], atol=1e-5)  # one box over the whole group
    for j in (6, 7):  # a time interval: every step in it
        np.testing.assert_allclose(b[j], [40.0, 3.5, 3.0, 3.0, 0.0], atol=1e-5)
    # step 8: the circle and a rectangle, one box covering both
    a = np.linspace(0, 2 * np.pi, 64)
    both = np.concatenate([np.column_stack([40.0 + 1.5 * np.cos(a), 3.5 + 1.5 * np.sin(a)]),
                           [[44.0, 3.0], [46.0, 3.0], [46.0, 4.0], [44.0, 4.0]]])
    c, s = math.cos(b[8, 4]), math.sin(b[8, 4])
    rel = both - b[8, :2]
    assert np.all(np.abs(rel @ [c, s]) <= 0.5 * b[8, 2] + 1e-4)
    assert np.all(np.abs(rel @ [-s, c]) <= 0.5 * b[8, 3] + 1e-4)
    assert b[8, 2] * b[8, 3] < 1.1 * 7.5 * 3.0  # and not much more


def test_dynamic_polygon_is_its_covering_box_and_unknown_types_are_named(tmp_path, capsys):
    pytest.importorskip("commonroad")
    from jaxplan.scenarios.commonroad import load_commonroad

    path = _write_xml(*_set_based_scenario(), tmp_path / "poly.xml")
    capsys.readouterr()
    sc = load_commonroad(path)
    k = list(sc.obstacle_ids).index(901)
    b = np.asarray(sc.obstacles.boxes[k])
    # x from -2 to 2.5 along the car, y +-1: a 4.5 x 2 box whose centre is 0.25 m ahead of the state's point
    for j in range(4):
        np.testing.assert_allclose(b[j], [10.0 + j + 0.25 * math.cos(0.3), -3.5 + 0.25 * math.sin(0.3), 4.5, 2.0, 0.3],
                                   atol=1e-5)
    assert list(np.asarray(sc.obstacles.valid[k])[:5]) == [True] * 4 + [False]
    assert sc.obstacle_types[k] == "unknown"  # a taxi: no type of its own in the Scene
    err = capsys.readouterr().err
    assert err.count("jaxplan:") == 1 and "poly.xml" in err and "taxi" in err


def test_a_shape_that_cannot_be_covered_is_refused_naming_the_obstacle():
    pytest.importorskip("commonroad")
    from jaxplan.scenarios.commonroad import commonroad_to_dict

    sc, pps = _set_based_scenario()
    occ = sc.obstacle_by_id(900).prediction.occupancy_set[0]
    occ._shape = object()  # a shape kind the converter does not know
    with pytest.raises(ScenarioError, match="dynamic obstacle 900: occupancy at time step 1"):
        commonroad_to_dict(sc, pps)
