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
