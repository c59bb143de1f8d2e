"""``jaxplan drive`` over many scenes: resuming a killed run, refusing another run's folder, the
verdict's words, strict JSON, per-folder and per-location tables, the chunked rollout."""
import dataclasses
import json

import jax
import numpy as np
import pytest

from jaxplan.baselines import BrakePlanner, IDMPlanner
from jaxplan.scenarios.scene import stack_scenes
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
