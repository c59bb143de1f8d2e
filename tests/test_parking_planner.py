"""Park-out planner: grid extent, both road sides, walls and stopped
cars (the search), the batch driver, the renderer, the speed profile, scene files and ``jaxplan parkout``.

Results are judged by shapely (``parking_oracle``), not by the planner's own grid check. All
``park_out`` calls use batches of at most 8 scenes, so they share one compiled two-curve loop and search.
"""
import copy
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

import jaxplan.parking as pk
from jaxplan.cli import main
from jaxplan.parking.families import family_scenes, scene_dicts
from jaxplan.parking.profile import speed_profile_jit
from jaxplan.parking.scene_file import problem_from_dict, result_states, stack_parking_scenes
from jaxplan.types import VehicleParams
from parking_oracle import collisions, world_collision

CAR = VehicleParams()
CFG = pk.ParkoutConfig()
D = float(pk.stop_line(CAR, CFG.c))


def test_wall_just_beyond_the_old_grid_is_seen():
    """A wall across the road at y = 5.0 m (just beyond the old +-5 m grid, whose outside
    read free) gave success and a collision at once. Now the grid covers it and outside is occupied."""
    rng = np.random.default_rng(0)
    walls = np.array([5.0, 5.05, 5.1])
    scene, _ = pk.make_scenes(rng, 3, CAR, front_gap=2.5, rear_gap=1.0, wall_y=walls)
    assert CFG.outside_occupied and CFG.y_max > walls.max() + 0.5
    res = pk.park_out(scene, 0, CFG, CAR)
    assert not collisions(res.poses, res.valid, scene.polygons, scene.valid, CAR).any()
    assert np.all(res.success)


@pytest.fixture(scope="module")
def heldout():
    """Scenes of the right / wall / stopped families as world-frame scene files, read back and planned."""
    rng = np.random.default_rng(2024)
    probs, dicts = [], []
    for fam, k in (("right", 2), ("wall", 3), ("stopped", 3)):
        sc, info = family_scenes(fam, rng, k, CAR)
        for d in scene_dicts(sc, info, CAR, rng):
            dicts.append(d)
            probs.append(problem_from_dict(d))
    scene = stack_parking_scenes([p.scene for p in probs])
    res = pk.park_out(scene, 0, CFG, CAR)
    return dicts, probs, scene, res


def test_heldout_families_world_frame(heldout):
    dicts, probs, scene, res = heldout
    assert {d["side"] for d in dicts} == {"left", "right"}
    v, t = speed_profile_jit(res.steer, res.valid, res.gear, CFG)
    for i, (d, p) in enumerate(zip(dicts, probs)):
        one = jax.tree_util.tree_map(lambda a: a[i], res)
        states, _, _ = result_states(one, p, CFG, (v[i], t[i]))
        obstacles = [o["polygon"] for o in d["obstacles"]]
        assert bool(one.success), f"scene {i} ({d['side']})"
        assert not world_collision(states, obstacles, CAR)
        step = np.linalg.norm(np.diff(states[:, :2], axis=0), axis=1)
        assert step.max() <= 0.25 and set(np.unique(states[:, 3])) <= {-1.0, 1.0}
        # the end pose is level with the road and beyond the stop line, in world terms
        car0 = np.array([d["start"]["x"], d["start"]["y"]])
        road = np.array([np.cos(d["road_heading"]), np.sin(d["road_heading"])])
        normal = np.array([-road[1], road[0]]) * (1 if d["side"] == "left" else -1)
        back = (CAR.length / 2 - CAR.rear_overhang)
        axle = lambda s: s[:2] - back * np.array([np.cos(s[2]), np.sin(s[2])])  # noqa: E731
        assert (axle(states[-1]) - axle(np.array([*car0, d["start"]["heading"]]))) @ normal >= D - 1e-3
        assert abs(np.sin(states[-1, 2] - d["road_heading"])) < np.sin(CFG.out_tol)
    assert np.asarray(res.searched).any()  # walls and stopped cars need more than the two reference curves
    # no driven footprint comes within margin + one cell of the grid's edge: the edge never cut a move
    q = np.asarray(res.poses)[np.asarray(res.valid)]
    corners = np.asarray(pk.boxes_to_polygons(pk.footprint_boxes(jnp.asarray(q), CAR)))
    room = CFG.margin + CFG.cell
    assert corners[..., 0].min() > CFG.x_min + room and corners[..., 0].max() < CFG.x_max - room
    assert corners[..., 1].min() > CFG.y_min + room and corners[..., 1].max() < CFG.y_max - room


def test_road_on_the_right_mirrors_the_left():
    rng = np.random.default_rng(7)
    sc, info = family_scenes("standard", rng, 1, CAR)
    probs = []
    for side in ("left", "right"):
        info["side"] = np.array([side])
        probs.append(problem_from_dict(scene_dicts(sc, info, CAR, np.random.default_rng(3))[0]))
    for p in probs:  # both read back to the same slot-frame scene
        assert np.allclose(np.asarray(p.scene.polygons), np.asarray(sc.polygons[0])[np.asarray(sc.valid[0])],
                           atol=1e-4)
        assert np.allclose(np.asarray(p.scene.start), np.asarray(sc.start[0]), atol=1e-6)
    left, right = probs
    w = left.frame.to_world_pose(np.array([1.0, 2.0, 0.3]))
    assert np.allclose(right.frame.to_slot_pose(right.frame.to_world_pose(np.array([1.0, 2.0, 0.3]))),
                       [1.0, 2.0, 0.3])
    assert np.allclose(left.frame.to_slot_pose(w), [1.0, 2.0, 0.3])
    # a point on the road side of the car is on its right in the world when side = right
    h = right.frame.heading
    p = right.frame.to_world_xy(np.array([0.0, 1.0])) - np.asarray(right.frame.origin)
    assert np.cos(h) * p[1] - np.sin(h) * p[0] < 0


def test_refill_lanes_match_one_scene_per_call(heldout):
    """8 scenes through the driver's lanes (4 two-curve lanes and 4 search lanes, refilled from the queue)
    plan exactly what each scene gets alone, searched ones too."""
    _, _, scene, res = heldout
    grids = pk.render_scenes(scene, 0, CFG, CAR)
    searched = np.asarray(res.searched)
    assert 0 < searched.sum() < 8 and np.all(np.asarray(res.success))
    for i in range(8):
        alone = pk.plan_grids(scene.start[i:i + 1], pk.Grid(grids.cells[i:i + 1], grids.pose[i:i + 1]), CFG, CAR)
        for a, b in zip(jax.tree_util.tree_leaves(alone), jax.tree_util.tree_leaves(res)):
            assert np.array_equal(np.asarray(a)[0], np.asarray(b)[i])
    from jaxplan.parking.driver import run_search, run_two_curve

    assert run_two_curve._cache_size() == 1 and run_search._cache_size() == 1  # one compile each for all of it


def test_speed_profile(heldout):
    _, _, _, res = heldout
    v, t = map(np.asarray, speed_profile_jit(res.steer, res.valid, res.gear, CFG))
    valid, gear, steer = np.asarray(res.valid), np.asarray(res.gear), np.asarray(res.steer)
    n = valid.sum(-1)
    for b, m in zip(*np.nonzero(n > 1)):
        k = n[b, m]
        s = np.abs(v[b, m, :k])
        assert s[0] == 0 and s[-1] == 0 and np.all(np.sign(v[b, m, 1:k - 1]) == gear[b, m])
        vmax = CFG.v_forward if gear[b, m] > 0 else CFG.v_reverse
        assert s.max() <= vmax + 1e-6
        assert np.all(np.abs(np.diff(s ** 2)) <= 2 * CFG.accel * CFG.dl + 1e-5)  # accel and brake limits
        dsteer = np.abs(np.diff(steer[b, m, :k]))
        assert np.all(s[:-1] * dsteer <= CFG.steer_speed * CFG.dl + 1e-5)  # steering rate
        assert np.all(np.diff(t[b, m, :k]) > 0)
    # moves follow each other in time, with the standstill wheel turn in between
    for b in range(len(n)):
        ends = [t[b, m, n[b, m] - 1] for m in range(len(gear[b])) if n[b, m] > 0]
        starts = [t[b, m, 0] for m in range(len(gear[b])) if n[b, m] > 0]
        assert all(s >= e for s, e in zip(starts[1:], ends[:-1]))


def test_renderer_matches_shapely(rng):
    """Scan-line fill equals shapely's containment of cell centres (convex and non-convex outlines);
    occlusion equals shapely's line-of-sight from the four sensors."""
    polys = [np.array([[1.0, 3.0], [4.0, 3.2], [3.5, 5.5], [0.8, 4.9]]),  # convex
             np.array([[-6.0, 2.0], [-2.0, 2.0], [-2.0, 2.6], [-5.2, 2.6], [-5.2, 5.0], [-6.0, 5.0]]),  # L shape
             np.array([[6.0, -0.5], [9.0, -0.5], [9.0, 0.9], [6.0, 0.9]]),
             np.array([[-8.0, -2.2], [12.0, -2.2], [12.0, -1.3], [-8.0, -1.3]])]
    from jaxplan.parking.scene_file import slot_scene

    scene = slot_scene([p + rng.normal(0, 0.01, p.shape) for p in polys], np.array([0.0, 0.0, 0.05]),
                       occlusion=True, sensor_range=9.0)
    lay = jax.jit(lambda s: pk.render_layers(s, jnp.zeros(3), 0, CFG, CAR))(scene)
    occ, unk = np.asarray(lay.occupied), np.asarray(lay.unknown)
    cen = np.asarray(pk.cell_centres(CFG), float).reshape(-1, 2)
    obs = [shapely.Polygon(p) for p in np.asarray(scene.polygons)]
    inside = np.zeros(len(cen), bool)
    near = np.zeros(len(cen), bool)
    for o in obs:
        inside |= shapely.contains_xy(o, cen[:, 0], cen[:, 1])
        near |= shapely.contains_xy(o.boundary.buffer(1e-4), cen[:, 0], cen[:, 1])
    car = shapely.Polygon(np.asarray(pk.boxes_to_polygons(pk.footprint_boxes(scene.start, CAR))))
    under = shapely.contains_xy(car, cen[:, 0], cen[:, 1])
    assert np.all(((occ.reshape(-1) == (inside & ~under)) | near)) and occ.sum() > 1000
    # line of sight, on a sample of cells
    sensors = np.asarray(pk.sensor_poses(scene.start, CAR))
    pick = rng.choice(len(cen), 3000, replace=False)
    union = shapely.union_all(obs)
    seen = np.zeros(len(pick), bool)
    for s in sensors:
        ray = shapely.linestrings(np.stack([np.broadcast_to(s[:2], (len(pick), 2)), cen[pick]], 1))
        rel = (cen[pick] - s[:2]) @ np.array([np.cos(s[2]), np.sin(s[2])])
        seen |= ~shapely.intersects(ray, union) & (rel >= 0) & (np.linalg.norm(cen[pick] - s[:2], axis=1) <= 9.0)
    expect = ~seen & ~inside[pick] & ~under[pick]
    border = near[pick] | np.array([min(abs(np.linalg.norm(cen[i] - s[:2]) - 9.0) for s in sensors) < 0.05
                                    for i in pick])
    got = unk.reshape(-1)[pick]
    # a non-convex outline casts the shadow of its hull: more unknown there, never less
    hull = shapely.contains_xy(obs[1].convex_hull, cen[pick, 0], cen[pick, 1]) & ~inside[pick]
    assert np.all(got[hull] >= expect[hull])
    assert np.mean(((got == expect) | border)[~hull]) > 0.995 and expect.sum() > 200


def test_cost_to_go_table():
    tab = pk.cost_to_go(CAR, CFG)
    from jaxplan.parking.heuristic import lookup

    poses = np.array([[0.0, D + 0.1, 0.0], [0.0, D, 0.05], [0.0, 0.0, 0.0], [0.0, 1.0, 0.4], [0.0, 0.0, np.pi]])
    h = np.asarray(lookup(tab, jnp.asarray(poses, jnp.float32)))
    assert h[0] == 0 and h[1] == 0 and np.all(h[2:] > 0)
    # from the start pose no path to the stop line is shorter than the lateral distance, and the
    # two-arc S at the smallest radius (ending level at y = d) is one path
    R = float(pk.turning_radius(CAR))
    s_curve = 2 * R * np.arccos(1 - D / (2 * R))
    assert D < h[2] <= s_curve + 0.3 and h[4] > h[2]


BASE = {"vehicle": {"length": 4.8, "width": 1.9, "wheelbase": 2.9, "rear_overhang": 0.95, "max_steer": 0.55},
        "start": {"x": 10.0, "y": 5.0, "heading": 3.0}, "road_heading": 3.1, "side": "right",
        "obstacles": [{"polygon": [[4.0, 4.0], [6.0, 4.0], [6.0, 6.0]]}]}


def _set(d, path, value):
    d = copy.deepcopy(d)
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


BAD = [
    (("vehicle", "length"), -1.0, "vehicle.length"),
    (("vehicle", "width"), "wide", "vehicle.width"),
    (("vehicle", "wheelbase"), 5.0, "vehicle.wheelbase"),
    (("vehicle", "max_steer"), 35.0, "vehicle.max_steer"),
    (("vehicle", "rear_overhang"), KeyError, "vehicle.rear_overhang"),
    (("vehicle", "mass"), 1500, "vehicle.mass"),
    (("start", "x"), float("nan"), "start.x"),
    (("start", "heading"), True, "start.heading"),
    (("start", "heading"), 4.7, "start.heading"),
    (("road_heading",), None, "road_heading"),
    (("side",), "up", "side"),
    (("sides",), "left", "sides"),
    (("obstacles",), {"polygon": []}, "obstacles"),
    (("obstacles", 0, "polygon"), [[0, 0], [1, 1]], "obstacles[0].polygon"),
    (("obstacles", 0, "polygon"), [[0, 0], [1, 1], [2, 2]], "obstacles[0].polygon"),
    (("obstacles", 0, "polygon"), [[0, 0], [2, 0], [0, 2], [2, 2]], "obstacles[0].polygon"),
    (("obstacles", 0, "polygon"), [[0, 0], [2, 0], ["a", 2]], "obstacles[0].polygon[2][0]"),
    (("obstacles", 0, "polygon"), [[9, 4], [11, 4], [11, 6], [9, 6]], "obstacles[0]"),
    (("obstacles", 0, "shape"), 1, "obstacles[0].shape"),
    (("vehicle",), [4.8, 1.9], "vehicle"),
]


def test_scene_file_errors(tmp_path, capsys):
    path = tmp_path / "s.json"
    for keys, value, field in BAD:
        path.write_text(json.dumps(_set(BASE, keys, value)))
        assert main(["parkout", str(path), "--out", str(tmp_path / "o")]) == 2, field
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and f": {field}:" in err, (field, err)
    path.write_text("{not json")
    assert main(["parkout", str(path), "--out", str(tmp_path / "o")]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    for missing in (str(tmp_path / "nope.json"), str(tmp_path)):
        assert main(["parkout", missing, "--out", str(tmp_path / "o")]) == 2
        assert missing in capsys.readouterr().err
    path.write_text(json.dumps(BASE))
    (tmp_path / "file").write_text("x")
    assert main(["parkout", str(path), "--out", str(tmp_path / "file")]) == 2
    assert "--out" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "o")


def test_cli_parkout(heldout, tmp_path, capsys):
    dicts, probs, _, res = heldout
    i = 4  # a wall scene
    path = tmp_path / "wall.json"
    path.write_text(json.dumps(dicts[i]))
    out = tmp_path / "out"
    assert main(["parkout", str(path), "--out", str(out)]) == 0
    doc = json.load(open(out / "parkout.json"))
    assert set(doc) == {"success", "moves", "states", "v", "t"}
    assert doc["success"] is True and doc["moves"] == int(res.moves[i])
    states = np.asarray(doc["states"])
    assert states.shape[1] == 4 and len(doc["v"]) == len(states) == len(doc["t"])
    assert np.linalg.norm(np.diff(states[:, :2], axis=0), axis=1).max() <= 0.25
    assert not world_collision(states, [o["polygon"] for o in dicts[i]["obstacles"]], CAR)
    assert np.all(np.diff(doc["t"]) >= 0) and os.path.getsize(out / "parkout.png") > 10000
    assert "wrote" in capsys.readouterr().out


def test_documented_scene_example_is_valid():
    import re

    text = open(os.path.join(os.path.dirname(__file__), "..", "docs", "planners", "parkout.md")).read()
    block = re.search(r"## Park-out scene files.*?```json\n(.*?)```", text, re.S).group(1)
    p = problem_from_dict(json.loads(block), "parkout.md")
    assert len(p.polygons) == 2 and p.frame.sign == 1


def test_search_with_a_beam_wider_than_the_first_depth():
    """The root has 2 x len(steer_levels) x 2 children; a wider beam pads them (it failed with a shape
    error before). The plan is judged by shapely."""
    from jaxplan.parking.heuristic import cost_to_go
    from jaxplan.parking.parkout import GridModel
    from jaxplan.parking.search import search_parkout

    cfg = pk.ParkoutConfig(steer_levels=(1.0, -1.0), beam=12)
    scene, _ = pk.make_scenes(np.random.default_rng(5), 1, CAR, front_gap=0.8, rear_gap=0.8)
    cells = pk.render_scenes(scene, 0, cfg, CAR).cells[0]
    tab = cost_to_go(CAR, cfg)
    res = jax.jit(lambda c, s: search_parkout(s, GridModel(pk.cell_table(c), jnp.zeros(3)), cfg, CAR, tab))(
        cells, jnp.asarray(scene.start[0]))
    assert bool(res.success) and int(res.moves) >= 2
    assert not collisions(np.asarray(res.poses)[None], np.asarray(res.valid)[None], scene.polygons, scene.valid,
                          CAR).any()
