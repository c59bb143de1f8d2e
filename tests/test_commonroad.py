"""CommonRoad XML importer and solution writer (optional extra, tested when installed)."""
import glob
import os

import numpy as np
import pytest

from conftest import shared_data_or_skip

pytest.importorskip("commonroad", reason="commonroad-io not installed (extra jaxplan[commonroad])")

from jaxplan.scenarios.commonroad import load_commonroad, write_solution  # noqa: E402
from jaxplan.scenarios.loader import ScenarioError, load_scenario  # noqa: E402
from jaxplan.types import Trajectory  # noqa: E402


def _files():
    return sorted(glob.glob(os.path.join(shared_data_or_skip("commonroad2020a"), "*.xml")))


def test_all_native_files_load_into_the_local_frame():
    files = _files()
    assert len(files) == 4
    for f in files:
        sc = load_commonroad(f)
        assert sc.ego.x == 0.0 and sc.ego.y == 0.0 and len(sc.lanes) > 0
        b = np.asarray(sc.obstacles.boxes)
        assert b.shape[0] > 0 and np.all(np.isfinite(b)) and np.all(b[..., 2:4] > 0)


def test_same_scenario_in_both_formats_agrees():
    xml = os.path.join(shared_data_or_skip("commonroad2020a"), "ZAM_Over-1_1.xml")
    js = os.path.join(shared_data_or_skip("commonroad2018a"), "ZAM_Over-1_1.json")
    a, b = load_commonroad(xml), load_scenario(js)
    np.testing.assert_allclose(a.origin, b.origin, atol=1e-6)
    np.testing.assert_allclose(np.asarray(a.obstacles.boxes[:, 0]), np.asarray(b.obstacles.boxes[:, 0]), atol=1e-4)
    assert a.ego.heading == pytest.approx(b.ego.heading) and a.ego.v == pytest.approx(b.ego.v)
    for la, lb in zip(sorted(a.lanes, key=lambda l: l.id), sorted(b.lanes, key=lambda l: l.id)):
        np.testing.assert_allclose(la.center, lb.center, atol=1e-3)  # 2018a vs 2020a rounding


def test_solution_round_trip(tmp_path):
    from commonroad.common.solution import CommonRoadSolutionReader

    sc = load_commonroad(os.path.join(shared_data_or_skip("commonroad2020a"), "DEU_Test-1_1_T-1.xml"))
    t = np.arange(30) * sc.dt
    x, y = 12.0 * t, 0.1 * t ** 2
    traj = Trajectory(x=x, y=y, theta=np.arctan2(0.2 * t, 12.0), kappa=np.full(30, 0.001), v=np.full(30, 12.0),
                      a=np.zeros(30), t=t, s=12.0 * t, gear=np.ones(30))
    path = write_solution(sc, traj, str(tmp_path))
    sol = CommonRoadSolutionReader.open(path)
    states = sol.planning_problem_solutions[0].trajectory.state_list
    pos = np.array([s.position for s in states])
    np.testing.assert_allclose(pos, np.column_stack([x, y]) + sc.origin, atol=1e-6)
    assert [s.time_step for s in states] == list(range(30))
    assert sol.planning_problem_solutions[0].planning_problem_id == sc.problem_id


def test_malformed_xml_is_a_scenario_error(tmp_path):
    bad = tmp_path / "bad.xml"
    good = open(_files()[0]).read()
    bad.write_text(good[: len(good) // 2])  # truncated
    with pytest.raises(ScenarioError, match="bad.xml"):
        load_commonroad(str(bad))
    empty = tmp_path / "empty.xml"
    empty.write_text("")
    with pytest.raises(ScenarioError, match="empty.xml"):
        load_commonroad(str(empty))


def _same_goal(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for key in ("time", "orientation", "velocity"):
        if key in a:
            np.testing.assert_allclose(b[key], a[key], atol=1e-9)
    if "rectangle" in a:
        for f in ("length", "width", "orientation"):
            assert b["rectangle"][f] == pytest.approx(a["rectangle"][f])
        np.testing.assert_allclose(b["rectangle"]["center"], a["rectangle"]["center"])
    if "lanelets" in a:
        assert b["lanelets"] == a["lanelets"]


def test_shared_json_round_trips_through_commonroad():
    """dict -> commonroad-io -> dict keeps every obstacle (static ones as StaticObstacle), lanelet and goal."""
    import json

    from jaxplan.scenarios.commonroad import commonroad_to_dict, dict_to_commonroad
    from jaxplan.scenarios.loader import parse_scenario

    files = sorted(glob.glob(os.path.join(shared_data_or_skip("commonroad2018a"), "*.json")))
    assert len(files) == 46
    statics = 0
    for f in files:
        with open(f) as fh:
            d = json.load(fh)
        id_map = {}
        sc, pps = dict_to_commonroad(d, f, id_map)
        back = commonroad_to_dict(sc, pps, id_map)
        assert back["id"] == d["id"] and back["dt"] == d["dt"]
        # obstacles: what the loader makes of them (boxes per step, valid, static flag, ids, types)
        a, b = parse_scenario(d, f), parse_scenario(back, f)
        assert list(b.obstacle_ids) == list(a.obstacle_ids) and b.obstacle_types == a.obstacle_types, f
        np.testing.assert_array_equal(np.asarray(b.obstacles.valid), np.asarray(a.obstacles.valid))
        np.testing.assert_array_equal(np.asarray(b.obstacles.static), np.asarray(a.obstacles.static))
        np.testing.assert_allclose(np.asarray(b.obstacles.boxes), np.asarray(a.obstacles.boxes), atol=1e-4)
        n_static = sum(o["role"] == "static" for o in d["obstacles"])
        assert len(sc.static_obstacles) == n_static == sum(o["role"] == "static" for o in back["obstacles"]), f
        statics += n_static
        # dynamic obstacles keep every recorded row
        rows = {o["id"]: o["states"] for o in back["obstacles"] if o["role"] == "dynamic"}
        for o in d["obstacles"]:
            if o["role"] == "dynamic" and o.get("states"):
                want, got = np.asarray(o["states"], dtype=float)[:, :5], np.asarray(rows[o["id"]], dtype=float)[:, :5]
                known = np.isfinite(want)  # the files leave some speeds out (null)
                np.testing.assert_allclose(got[known], want[known], atol=1e-9)
        # lanelets: bounds, topology, adjacency with direction, speed limits
        mine = {ln["id"]: ln for ln in back["lanelets"]}
        assert set(mine) == {ln["id"] for ln in d["lanelets"]}
        for ln in d["lanelets"]:
            m = mine[ln["id"]]
            np.testing.assert_allclose(m["left"], ln["left"])
            np.testing.assert_allclose(m["right"], ln["right"])
            assert sorted(m["successors"]) == sorted(ln["successors"])
            assert sorted(m["predecessors"]) == sorted(ln["predecessors"])
            for side in ("adjacentLeft", "adjacentRight", "speed_limit"):
                assert m.get(side) == ln.get(side), (f, ln["id"], side)
        # goals and start
        p, q = d["planning_problems"][0], back["planning_problems"][0]
        assert q["id"] == p["id"] and len(q["goals"]) == len(p["goals"])
        for ga, gb in zip(p["goals"], q["goals"]):
            _same_goal(ga, gb)
        for key in ("position", "orientation", "velocity"):
            np.testing.assert_allclose(q["initial_state"][key], p["initial_state"][key])
    assert statics == 3  # ZAM_Over-1_1, DEU_Muc-2_1_T-1, DEU_B471-1_1_T-1


def test_dict_to_commonroad_rejects_what_commonroad_cannot_hold():
    from jaxplan.scenarios.commonroad import dict_to_commonroad

    base = {"id": "ZAM_Test-1_1_T-1", "dt": 0.1, "lanelets": [
        {"id": 1, "left": [[0, 2], [50, 2]], "right": [[0, -2], [50, -2]], "predecessors": [], "successors": []}],
        "obstacles": [], "planning_problems": [{"id": 9, "initial_state": {
            "position": [1.0, 0.0], "orientation": 0.0, "velocity": 5.0}, "goals": [{"time": [0.0, 2.0]}]}]}
    sc, pps = dict_to_commonroad(base)
    assert len(sc.lanelet_network.lanelets) == 1 and 9 in pps.planning_problem_dict
    cases = [
        ({"obstacles": [{"id": 5, "role": "dynamic", "type": "spaceship", "length": 4, "width": 2,
                         "states": [[0, 1, 1, 0, 1, 0]]}]}, "obstacles\\[0\\].type 'spaceship'"),
        ({"obstacles": [{"id": 5, "role": "dynamic", "type": "car", "length": 4, "width": 2,
                         "states": [[0, 1, 1, 0, 1, 0], [0.3, 2, 1, 0, 1, 0]]}]}, "without gaps"),
        ({"planning_problems": [{**base["planning_problems"][0], "goals": [{"lanelets": [77], "time": [0, 1]}]}]},
         "lanelets that do not exist"),
        ({"planning_problems": [{**base["planning_problems"][0], "goals": [{"lanelets": [1]}]}]}, "goals\\[0\\].time"),
        ({"dt": -0.1}, "dt must be positive"),
    ]
    for change, message in cases:
        with pytest.raises(ScenarioError, match=message):
            dict_to_commonroad({**base, **change}, "bad.json")


def test_load_folder_reads_every_format_in_a_folder_and_its_sub_folders(tmp_path):
    """``load_folder`` (the loader of every command and suite that reads ``--scenarios DIR``) reads
    what ``jaxplan drive`` reads: shared JSON and CommonRoad XML, either gzip-compressed, in the
    folder and its sub-folders, a pattern matching the name without the suffix; a file that does
    not load is named and counted. ``--scenarios`` takes a folder of XML alone."""
    import gzip
    import io
    import json

    from test_loader import _minimal

    from jaxplan.cli_args import scenario_dir
    from jaxplan.scenarios.commonroad import write_commonroad
    from jaxplan.scenarios.files import file_stem, first_loadable, load_folder

    d = _minimal()
    d["planning_problems"][0]["goals"][0]["time"] = [0.0, 10.0]  # CommonRoad goals need a time interval
    (tmp_path / "sub").mkdir()
    (tmp_path / "A_1.json").write_text(json.dumps({**d, "id": "A_1"}))
    write_commonroad({**d, "id": "B_1"}, str(tmp_path / "sub" / "B_1.xml"))
    with gzip.open(tmp_path / "C_1.json.gz", "wt") as f:
        f.write(json.dumps({**d, "id": "C_1"}))
    with open(tmp_path / "sub" / "B_1.xml", "rb") as f, gzip.open(tmp_path / "sub" / "D_1.xml.gz", "wb") as g:
        g.write(f.read())
    (tmp_path / "E_1.xml").write_text("<commonRoad/>")
    (tmp_path / "notes.txt").write_text("not a scenario")
    err = io.StringIO()
    folder = load_folder(str(tmp_path), stderr=err)
    assert sorted(file_stem(f) for f in folder.files) == ["A_1", "B_1", "C_1", "D_1"]
    assert [file_stem(f) for f, _ in folder.skipped] == ["E_1"] and "E_1.xml" in err.getvalue()
    assert [len(sc.obstacle_ids) for sc in folder.scenarios] == [len(d["obstacles"])] * 4
    assert [file_stem(f) for f in load_folder(str(tmp_path), pattern="B_*").files] == ["B_1"]
    with pytest.raises(ScenarioError, match="no scenario files named Z_"):
        load_folder(str(tmp_path), pattern="Z_*")
    assert file_stem(first_loadable(str(tmp_path / "sub"))) == "B_1"
    assert scenario_dir(str(tmp_path / "sub")) == str(tmp_path / "sub")  # XML only: taken
