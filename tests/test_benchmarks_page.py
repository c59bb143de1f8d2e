"""The benchmarks page counts each planner's drives on the scenes plain braking survives."""
import importlib.util
import json
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _page():
    spec = importlib.util.spec_from_file_location("benchmarks_page", os.path.join(ROOT, "experiments",
                                                                                "benchmarks_page.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write(folder, rows):
    os.makedirs(folder)
    with open(os.path.join(folder, "rows.jsonl"), "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")


def _row(planner, scenario, collided=False, at_fault=False, success=True):
    return {"planner": planner, "scenario": scenario, "overlap.collided": collided, "overlap.at_fault": at_fault,
            "success": success}


def test_brake_survivable_scenes_and_the_planners_collisions_there(tmp_path):
    brake = [_row("brake", "A"), _row("brake", "B", collided=True), _row("brake", "C"), _row("brake", "D")]
    dev = [_row("lattice", "A"), _row("lattice", "B", collided=True, at_fault=True, success=False),
           _row("lattice", "C", collided=True, at_fault=True, success=False),
           _row("lattice", "D", collided=True, success=False), _row("idm", "A", success=False)]
    _write(tmp_path / "brake", brake)
    _write(tmp_path / "dev", dev)
    got = _page()._brake_survivable(str(tmp_path / "dev"), str(tmp_path / "brake"))
    assert got["survivable"] == 3 and got["brake_drives"] == 4
    lat = got["planners"]["lattice"]
    # B is not survivable by braking: its at-fault collision is not counted here
    assert (lat["scenes"], lat["success"], lat["collisions"], lat["at_fault"]) == (3, 1, 2, 1)
    assert lat["at_fault_scenarios"] == ["C"]
    assert got["planners"]["idm"]["scenes"] == 1 and got["planners"]["idm"]["success"] == 0


def test_a_missing_run_folder_is_one_line(tmp_path):
    import pytest

    with pytest.raises(SystemExit, match="rows.jsonl not found"):
        _page()._brake_survivable(str(tmp_path / "dev"), str(tmp_path / "nowhere"))


def test_built_in_scenes_are_summed_apart_from_the_scenario_files(tmp_path):
    """A run with ``--builtin``: the development set's table, its location split and the brake
    survivable scenes count the scenario files only; the built-in drives get a table of their own."""
    def row(planner, scenario, folder, success=True, collided=False):
        return {**_row(planner, scenario, collided=collided, success=success), "folder": folder, "location": scenario,
                "goal.reached": success, "offroad.offroad": False, "redlight.crossings": 0, "goal.off_map": 0}

    rows = [row("lattice", "DEU_A-1", "sumo"), row("lattice", "DEU_B-1", "sumo", success=False, collided=True),
            row("lattice", "JAXPLAN_x-0", "builtin"), row("brake", "DEU_A-1", "sumo"),
            row("brake", "DEU_B-1", "sumo", success=False), row("brake", "JAXPLAN_x-0", "builtin", success=False)]
    _write(tmp_path / "dev", rows)
    with open(tmp_path / "dev" / "metrics.json", "w") as f:
        json.dump({"run": {"planners": ["lattice", "brake"], "scenarios": ["DEU_A-1", "DEU_B-1", "JAXPLAN_x-0"]}}, f)
    page = _page()
    d = page._drive_summary(str(tmp_path / "dev"))
    assert d["scenes"] == 2
    assert d["summary"]["lattice"]["scenes"] == 2 and d["summary"]["lattice"]["success_share"] == 0.5
    assert d["summary"]["lattice"]["collisions"] == 1
    assert d["builtin"]["lattice"] == {**d["builtin"]["lattice"], "scenes": 1, "success_share": 1.0}
    assert d["builtin"]["brake"]["success_share"] == 0.0
    split = page._split_summary(str(tmp_path / "dev"))
    assert sum(v["scenes"] for v in split["lattice"].values()) == 2
    bs = page._brake_survivable(str(tmp_path / "dev"), str(tmp_path / "dev"))
    assert bs["brake_drives"] == 2 and bs["survivable"] == 2 and bs["planners"]["lattice"]["scenes"] == 2
