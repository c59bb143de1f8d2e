"""``jaxplan drive`` over many scenes: resuming a killed run, refusing another run's folder, the
verdict's words, strict JSON, per-folder and per-location tables, the chunked rollout."""
import dataclasses
import json

import jax
import numpy as np
import pytest

from jaxplan.baselines import BrakePlanner, IDMPlanner
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.sim import SimConfig, rollout
from jaxplan.sim import drive as drive_mod
from jaxplan.sim.rollout import ChunkedRollout
from jaxplan.sim.store import RunMismatch
from test_sim import _record, _road_dict

CFG = SimConfig(n_steps=60)


def _records():
    """Three small scenes: a free road, a parked car in the lane, a slower car ahead."""
    t = np.arange(200)
    free = _record(_road_dict(goal_t=(0.0, 5.0)))
    parked = dataclasses.replace(_record(_road_dict(obstacles=[(40.0, 0.0, "static")], goal_t=(0.0, 6.0))),
                                 name="PARKED")
    slow = dataclasses.replace(_record(_road_dict(obstacles=[(35.0 + 0.5 * t, np.zeros(200))], goal_t=(0.0, 6.0))),
                               name="SLOW")
    return [free, parked, slow]


def _strict(text: str):
    def no(c):
        raise AssertionError(f"not strict JSON: {c}")

    return json.loads(text, parse_constant=no)


def test_killed_run_resumes_without_repeating_or_mixing(tmp_path, monkeypatch):
    recs = _records()
    ref = drive_mod.drive(recs, ["brake"], str(tmp_path / "ref"), CFG, progress=False, batch_size=2)
    written = []
    real = drive_mod.write_drive

    def dies_on_third(*a, **kw):
        if len(written) == 2:
            raise KeyboardInterrupt  # the run is killed while writing its third drive
        written.append(a[1].name)
        return real(*a, **kw)

    monkeypatch.setattr(drive_mod, "write_drive", dies_on_third)
    with pytest.raises(KeyboardInterrupt):
        drive_mod.drive(recs, ["brake"], str(tmp_path / "run"), CFG, progress=False, batch_size=2)
    lines = (tmp_path / "run" / "rows.jsonl").read_text().splitlines()
    assert len(lines) == 2
    # started again with the same settings and scenes: only the missing drive is driven
    again = []

    def counts(*a, **kw):
        again.append(a[1].name)
        return real(*a, **kw)

    monkeypatch.setattr(drive_mod, "write_drive", counts)
    res = drive_mod.drive(recs, ["brake"], str(tmp_path / "run"), CFG, progress=False, batch_size=2)
    assert len(again) == 1 and again[0] not in written
    rows = [json.loads(x) for x in (tmp_path / "run" / "rows.jsonl").read_text().splitlines()]
    assert sorted(r["scenario"] for r in rows) == sorted(r.name for r in recs)  # each drive once
    assert res.timing["resumed_drives"] == 2 and res.timing["drives"] == 1
    keep = lambda r: {k: v for k, v in r.items() if k != "why"}  # noqa: E731
    assert [keep(r) for r in res.rows["brake"]] == [keep(r) for r in ref.rows["brake"]]
    # another run's folder is refused, naming what differs; --fresh starts over
    with pytest.raises(RunMismatch, match="replan_every|other settings"):
        drive_mod.drive(recs, ["brake"], str(tmp_path / "run"), dataclasses.replace(CFG, replan_every=2),
                        progress=False)
    with pytest.raises(RunMismatch, match="other scenes"):
        drive_mod.drive(recs[:2], ["brake"], str(tmp_path / "run"), CFG, progress=False)
    fresh = drive_mod.drive(recs[:2], ["brake"], str(tmp_path / "run"), CFG, progress=False, fresh=True)
    assert len(fresh.rows["brake"]) == 2 and fresh.timing["resumed_drives"] == 0


def test_report_tables_strict_json_and_why(tmp_path):
    recs = _records()
    res = drive_mod.drive(recs, ["brake", "idm"], str(tmp_path), CFG, progress=False, batch_size=2, plots="failed")
    m = _strict((tmp_path / "metrics.json").read_text())
    assert set(m["by_folder"]["brake"]) == {"builtin"} and "ZAM" not in m["by_location"]["brake"]
    assert m["timing"]["drives"] == 6 and m["timing"]["drive_s"] > 0
    rows = {(r["planner"], r["scenario"]): r for r in m["rows"]}
    brake_free = rows[("brake", "TEST")]
    # braking from t = 0 stands long before the goal region: the words say so
    assert not brake_free["success"] and "stood for the last" in brake_free["why"]
    assert "nothing ahead" in brake_free["why"]
    # the idm baseline stands behind the parked car: the words name what stood ahead
    assert "behind car obstacle 0" in rows[("idm", "PARKED")]["why"] and "standing" in rows[("idm", "PARKED")]["why"]
    for r in m["rows"]:
        assert r["success"] == (r["goal.reached"] and not r["overlap.collided"] and not r["offroad.offroad"])
        assert (r["why"] == "") == r["success"]
        assert (tmp_path / r["planner"] / r["scenario"] / "drive.png").exists() == (not r["success"])
    report = (tmp_path / "report.md").read_text()
    assert report.index("| planner | drives | success |") < report.index("## Per location")
    assert "## Drives that did not succeed" in report
    assert res.summary["brake"]["success_share"] == pytest.approx(np.mean([rows[("brake", r.name)]["success"]
                                                                            for r in recs]))


def test_the_report_describes_the_plans_that_drove_the_last_steps():
    """``describe_last_plans`` hands a planner's ``describe`` the cycles that drove the car up to its
    last step, at most seven: cycle ``c`` plans at step ``3 c`` and drives steps ``3 c + 1 .. 3 c + 3``,
    so a plan made at the drive's last step (never driven) is left out; none without ``describe``."""

    class Says:
        def describe(self, info):
            return ",".join(str(int(c)) for c in info["cycle"])

    info = {"cycle": np.arange(20)}
    assert drive_mod.describe_last_plans(Says(), info, 33, 3) == "4,5,6,7,8,9,10"  # step 33 by cycle 10
    assert drive_mod.describe_last_plans(Says(), info, 34, 3) == "5,6,7,8,9,10,11"
    assert drive_mod.describe_last_plans(Says(), info, 2, 3) == "0"
    assert drive_mod.describe_last_plans(Says(), info, 0, 3) == "0"
    assert drive_mod.describe_last_plans(Says(), info, 300, 3) == "13,14,15,16,17,18,19"
    assert drive_mod.describe_last_plans(object(), info, 33, 3) == ""
    # the report describes the plans up to the drive's first collision or step off the road
    from jaxplan.sim.verdict import first_miss_step

    ok = {"overlap.collided": False, "offroad.offroad": False}
    assert first_miss_step(ok, 33) == 33
    assert first_miss_step({**ok, "overlap.collided": True, "overlap.first_step": 21}, 33) == 21
    assert first_miss_step({**ok, "offroad.offroad": True, "offroad.first_step": 6}, 33) == 6
    both = {"overlap.collided": True, "overlap.first_step": 21, "offroad.offroad": True, "offroad.first_step": 25}
    assert first_miss_step(both, 33) == 21


def test_goal_off_map_is_flagged():
    """A goal region past the map's end is flagged (shown apart); one on the road is not."""
    from jaxplan.sim.metrics.goal import region_on_road

    d = _road_dict()
    on = _record(d)
    far = json.loads(json.dumps(d))
    c = np.asarray(far["planning_problems"][0]["goals"][0]["rectangle"]["center"])
    far["planning_problems"][0]["goals"][0]["rectangle"]["center"] = (c + 5000.0).tolist()
    off = _record(far)
    for rec, want in ((on, True), (off, False)):
        sc = jax.tree_util.tree_map(np.asarray, rec.scene)
        assert bool(region_on_road(sc.goal, sc)) == want


def test_chunked_rollout_equals_rollout():
    """Driven chunk by chunk with a host loop between (stopping once every drive has ended), a batch
    drives exactly as in one scan; a cycle limit ends the drives there."""
    recs = _records()
    batch = stack_scenes([r.scene for r in recs])
    for planner in (IDMPlanner(), BrakePlanner()):
        one = jax.tree_util.tree_map(np.asarray, rollout(planner, batch, CFG))
        chunked = ChunkedRollout(planner, CFG, chunk_cycles=4)
        assert chunked.compile(batch) > 0 and chunked.compile(batch) == 0.0  # compiled once per shape
        got = chunked(batch)
        assert np.array_equal(got.valid, one.valid) and np.array_equal(got.end_step, one.end_step)
        v = one.valid
        for k in ("x", "y", "heading", "v"):
            np.testing.assert_allclose(getattr(got, k)[v], getattr(one, k)[v], atol=1e-5)
        np.testing.assert_array_equal(got.plan_ok[:, :3], one.plan_ok[:, :3])
    short = ChunkedRollout(IDMPlanner(), CFG, chunk_cycles=4)(batch, cycles=4)
    assert int(np.max(short.end_step)) <= 12


def test_new_params_drive_differently_without_compiling_again():
    """A planner's params are traced: other values drive differently through the same compiled
    programs (``rollout``'s jit cache and ``ChunkedRollout``'s), and params of another shape are
    refused naming the planner."""
    from jaxplan.sim.rollout import planner_program

    recs = _records()
    batch = stack_scenes([r.scene for r in recs])
    planner = IDMPlanner()
    slow = dict(a_max=0.5, time_gap=3.0)
    program = planner_program(planner)
    base = rollout(planner, batch, CFG)
    n = program._cache_size()
    other = rollout(planner, batch, CFG, params=planner.init_params(slow))
    again = rollout(planner, batch, CFG, params=planner.init_params())
    assert program._cache_size() == n  # neither compiled another program
    np.testing.assert_array_equal(np.asarray(again.x), np.asarray(base.x))
    assert float(np.min(np.asarray(other.v) - np.asarray(base.v))) < -0.5  # a gentler driver: slower somewhere
    chunked = ChunkedRollout(planner, CFG, chunk_cycles=4)
    chunked.compile(batch)
    got = chunked(batch, params=planner.init_params(slow))
    assert len(chunked._programs) == 1 and chunked.compile(batch) == 0.0
    v = np.asarray(other.valid)
    np.testing.assert_allclose(got.x[v], np.asarray(other.x)[v], atol=1e-4)
    bad = dataclasses.replace(planner.init_params(), a_max=np.ones(3))
    with pytest.raises(ValueError, match="IDMPlanner params"):
        rollout(planner, batch, CFG, params=bad)
    with pytest.raises(TypeError, match="a_maxx"):
        planner.init_params({"a_maxx": 1.0})


def test_gradient_of_a_drive_by_its_params_matches_finite_differences():
    """``jax.grad`` through ``rollout`` with respect to the planner's params (the IDM driver's
    acceleration and time gap: the distance it covers) agrees with central differences in float64."""
    recs = _records()[:2]
    planner = IDMPlanner()
    with jax.enable_x64(True):
        batch = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64) if np.asarray(a).dtype == np.float32 else a,
                                       stack_scenes([r.scene for r in recs]))
        p0 = planner.init_params()
        assert p0.a_max.dtype == np.float64

        def distance(p):
            log = rollout(planner, batch, CFG, params=p)
            return jax.numpy.sum(log.x[:, -1] - log.x[:, 0])

        g = jax.grad(distance)(p0)
        for name in ("a_max", "time_gap"):
            h = 1e-4
            up = distance(dataclasses.replace(p0, **{name: getattr(p0, name) + h}))
            down = distance(dataclasses.replace(p0, **{name: getattr(p0, name) - h}))
            fd = float(up - down) / (2 * h)
            assert abs(float(getattr(g, name)) - fd) <= 1e-2 * max(abs(fd), 1e-3), (name, float(getattr(g, name)), fd)
        assert abs(float(g.a_max)) > 1e-3  # the check is not of a flat function


def test_drive_takes_params_by_planner_and_the_cli_refuses_names_a_planner_lacks(tmp_path, capsys):
    """``drive(planner_params=...)`` drives a planner with other params (a run with other params in the
    same folder is another run); ``jaxplan drive --weights`` refuses, before any work, a file naming
    a param the planner does not have."""
    from jaxplan.cli import main

    recs = _records()
    base = drive_mod.drive(recs, ["idm"], str(tmp_path / "a"), CFG, progress=False)
    gentle = drive_mod.drive(recs, ["idm"], str(tmp_path / "b"), CFG, progress=False,
                             planner_params={"idm": {"a_max": 0.5, "time_gap": 3.0}})
    route = lambda res: [r["progress.route_m"] for r in res.rows["idm"]]  # noqa: E731
    assert sum(route(gentle)) < sum(route(base)) - 1.0
    with pytest.raises(RunMismatch):
        drive_mod.drive(recs, ["idm"], str(tmp_path / "a"), CFG, progress=False,
                        planner_params={"idm": {"a_max": 0.5}})
    w = tmp_path / "w.json"
    w.write_text(json.dumps({"weights": {"alpha": 1.0, "beta": 5.0}}))
    assert main(["drive", "--builtin", "--quick", "--planner", "idm", "--weights", str(w), "--out",
                 str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "planner idm" in err and "alpha" in err and not (tmp_path / "c").exists()
