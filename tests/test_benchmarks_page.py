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


def test_development_runs_of_different_planners_are_merged_and_a_planner_twice_is_refused(tmp_path):
    """``--dev A B``: one planner's run beside a run of the others (same scenes, same settings) gives
    one table with every planner, each planner's split and brake figures from its own run; a planner
    in both runs, or runs of other settings, are refused."""
    import pytest

    def row(planner, scenario, success=True, collided=False):
        return {**_row(planner, scenario, collided=collided, success=success), "folder": "sumo", "location": scenario,
                "goal.reached": success, "offroad.offroad": False, "redlight.crossings": 0, "goal.off_map": 0}

    def run(name, rows, planners, settings=None):
        _write(tmp_path / name, rows + [{**r, "folder": "builtin", "scenario": "JAXPLAN_x-0"} for r in rows[:1]])
        with open(tmp_path / name / "metrics.json", "w") as f:
            json.dump({"run": {"planners": planners, "agents": "log", **(settings or {})},
                       "timing": {"wall_s": 10.0, "drives": len(rows)}}, f)
        return str(tmp_path / name)

    a = run("a", [row("pathspeed", "DEU_A-1"), row("pathspeed", "DEU_B-1", success=False, collided=True)], ["pathspeed"])
    b = run("b", [row("lattice", "DEU_A-1", success=False), row("lattice", "DEU_B-1"), row("brake", "DEU_A-1"),
                  row("brake", "DEU_B-1", success=False, collided=True)], ["lattice", "brake"])
    page = _page()
    d = page._dev_summary([a, b])
    assert d["planners"] == ["pathspeed", "lattice", "brake"]
    assert d["summary"]["pathspeed"]["success_share"] == 0.5 and d["summary"]["lattice"]["success_share"] == 0.5
    assert d["summary"]["pathspeed"]["collisions"] == 1 and d["summary"]["lattice"]["collisions"] == 0
    assert [r["planners"] for r in d["runs"]] == [["pathspeed"], ["lattice", "brake"]]
    args = page.argparse.Namespace(dev=[a, b], brake=b, sample=None, combo=None, peers=None, bench=None)
    got = page.collect(args)["dev"]
    assert set(got["by_split"]) == {"pathspeed", "lattice", "brake"}
    bs = got["brake_survivable"]
    assert bs["survivable"] == 1 and bs["planners"]["pathspeed"]["scenes"] == 1
    assert bs["planners"]["pathspeed"]["success"] == 1 and bs["planners"]["lattice"]["success"] == 0
    assert "from 2 runs of the same scenes" in page.render(page.collect(args))
    with pytest.raises(SystemExit, match="planner pathspeed is in an earlier"):
        page._dev_summary([a, a])
    c = run("c", [row("idm", "DEU_A-1"), row("idm", "DEU_B-1")], ["idm"], {"agents": "idm"})
    with pytest.raises(SystemExit, match="other scenes or settings"):
        page._dev_summary([a, c])


def test_kept_sections_come_from_the_existing_json_and_a_missing_one_is_one_line(tmp_path):
    """``--keep peers`` carries the peers' section of the existing JSON over (with the caveat given)
    while the rest is collected anew; a section the JSON lacks is refused with one line."""
    import pytest

    js, out = tmp_path / "b.json", tmp_path / "b.md"
    peers = {"verdict": {"frenetix": {"summary": {"scenes": 2, "success_share": 0.5}}},
             "agreement": {}, "settings": {}, "scenarios": 2, "caveat": None}
    js.write_text(json.dumps({"peers": peers, "combos": {}}))
    page = _page()
    assert page.main(["--keep", "peers", "--peers-caveat", "An earlier run.", "--json", str(js), "--out", str(out)]) == 0
    d = json.loads(js.read_text())
    assert d["peers"]["verdict"] == peers["verdict"] and d["peers"]["caveat"] == "An earlier run."
    assert "An earlier run." in out.read_text() and "| frenetix | 2 | 50.0% |" in out.read_text()
    js.write_text(json.dumps({"combos": {}}))
    with pytest.raises(SystemExit, match="--keep peers: .* has no such section"):
        page.main(["--keep", "peers", "--json", str(js), "--out", str(out)])
