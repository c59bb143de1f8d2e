"""The independent referee (commonroad-drivability-checker + commonroad-io) on hand-made drives.

Drives in ZAM_Over-1_1 (shared JSON: a 6 m x 3.5 m static obstacle reaching into the ego lane,
the goal 58 m ahead); expected verdicts from shapely and plain geometry, not from the referee's tools.
"""
import functools
import json
import math
import os

import numpy as np
import pytest

from conftest import shared_data_or_skip

pytest.importorskip("commonroad", reason="commonroad-io not installed (extra jaxplan[referee])")
from jaxplan.eval import referee as R  # noqa: E402

try:
    R.require_referee()
except ImportError as e:
    pytest.skip(str(e), allow_module_level=True)

shapely = pytest.importorskip("shapely")
L, W, DT = 4.508, 1.61, 0.1


@functools.lru_cache(maxsize=None)
def _scene():
    path = os.path.join(shared_data_or_skip("commonroad2018a"), "ZAM_Over-1_1.json")
    with open(path) as f:
        d = json.load(f)
    return path, d, R.Referee.from_file(path)


def _box(x, y, th, length=L, width=W):
    c, s = math.cos(th), math.sin(th)
    pts = [(sx * length / 2, sy * width / 2) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    return shapely.Polygon([(x + c * u - s * v, y + s * u + c * v) for u, v in pts])


def _lane_drive(d, s_of_t, n):
    """Rows along lane 1000's centre line at arc lengths ``s_of_t(t)`` from the ego start."""
    ln = next(lane for lane in d["lanelets"] if lane["id"] == 1000)
    c = 0.5 * (np.asarray(ln["left"]) + np.asarray(ln["right"]))
    sc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])
    p0 = np.asarray(d["planning_problems"][0]["initial_state"]["position"])
    s0 = sc[np.argmin(np.linalg.norm(c - p0, axis=1))]
    rows = []
    for k in range(n):
        t = k * DT
        s = s0 + s_of_t(t)
        x, y = np.interp(s, sc, c[:, 0]), np.interp(s, sc, c[:, 1])
        h = 0.5
        th = math.atan2(np.interp(s + h, sc, c[:, 1]) - np.interp(s - h, sc, c[:, 1]),
                        np.interp(s + h, sc, c[:, 0]) - np.interp(s - h, sc, c[:, 0]))
        rows.append([t, x, y, th, 0.0, 0.0])
    return np.asarray(rows)


def _obstacle(d):
    o = next(o for o in d["obstacles"] if o["role"] == "static")
    return o["id"], _box(*o["center"], o["orientation"], o["length"], o["width"])


def test_drive_through_the_static_obstacle_is_a_collision_with_it():
    _, d, ref = _scene()
    rows = _lane_drive(d, lambda t: 20.0 * t, 31)  # 20 m/s in lane, never brakes
    oid, obst = _obstacle(d)
    first = next(k for k, r in enumerate(rows) if _box(*r[1:4]).intersects(obst))  # shapely oracle
    v = ref.judge(rows, L, W)
    assert v["collided"] and v["collision_obstacles"] == [oid]
    assert v["first_collision_time"] == pytest.approx(first * DT)


def test_drive_that_stops_behind_the_static_obstacle_is_clean():
    _, d, ref = _scene()
    a, v0 = 9.0, 20.0  # stops after 22.2 m, front bumper ~2.5 m behind the obstacle
    rows = _lane_drive(d, lambda t: v0 * min(t, v0 / a) - 0.5 * a * min(t, v0 / a) ** 2, 31)
    _, obst = _obstacle(d)
    assert min(_box(*r[1:4]).distance(obst) for r in rows) > 1.0
    v = ref.judge(rows, L, W)
    assert not v["collided"] and v["first_collision_time"] is None and v["collision_obstacles"] == []
    assert not v["off_road"] and not v["goal_reached"]


def test_drive_off_the_road_is_flagged_when_the_box_reaches_the_edge():
    _, d, ref = _scene()
    p0 = np.asarray(d["planning_problems"][0]["initial_state"]["position"])
    th = -0.3  # veer right across the lane edge at 10 m/s
    rows = np.asarray([[k * DT, *(p0 + 10.0 * k * DT * np.array([math.cos(th), math.sin(th)])), th, 10.0, 0.0]
                       for k in range(31)])
    road = shapely.unary_union([shapely.Polygon(np.vstack([ln["left"], ln["right"][::-1]])) for ln in d["lanelets"]])
    leaves = next(k for k, r in enumerate(rows) if not road.contains(_box(*r[1:4])))
    v = ref.judge(rows, L, W)
    assert v["off_road"] and not v["collided"]
    # the referee buffers the lanelets by ROAD_TOL (5 cm): at most a step either side of the exact union
    assert leaves - 1 <= round(v["first_off_road_time"] / DT) <= leaves + 1


def _goal_rect(d):
    g = d["planning_problems"][0]["goals"][0]
    r = g["rectangle"]
    return r, g


def _in_goal(d, x, y, th, t):
    """The goal rule written out: rectangle, orientation interval, time interval."""
    r, g = _goal_rect(d)
    c, s = math.cos(r["orientation"]), math.sin(r["orientation"])
    u, w = (x - r["center"][0]) * c + (y - r["center"][1]) * s, -(x - r["center"][0]) * s + (y - r["center"][1]) * c
    o = math.remainder(th - g["orientation"][0], 2 * math.pi) % (2 * math.pi)
    return (abs(u) <= r["length"] / 2 and abs(w) <= r["width"] / 2 and o <= g["orientation"][1] - g["orientation"][0]
            and g["time"][0] - 1e-9 <= t <= g["time"][1] + 1e-9)


@pytest.mark.parametrize("speed,heading_offset", [(35.0, 0.0), (35.0, 0.8), (15.0, 0.0)])
def test_goal_verdict_agrees_with_the_goal_rule_written_out(speed, heading_offset):
    """Straight at the goal centre: reached at 35 m/s; not with the heading 0.8 rad off its interval;
    not at 15 m/s (the goal's time window, 0..3 s, closes 7 m short of it)."""
    _, d, ref = _scene()
    r, _ = _goal_rect(d)
    p0 = np.asarray(d["planning_problems"][0]["initial_state"]["position"])
    u = np.asarray(r["center"]) - p0
    th = math.atan2(u[1], u[0]) + heading_offset
    rows = np.asarray([[k * DT, *(p0 + speed * k * DT * u / np.linalg.norm(u)), th, speed, 0.0] for k in range(41)])
    expected = next((k for k, q in enumerate(rows) if _in_goal(d, q[1], q[2], q[3], q[0])), None)
    assert (expected is not None) == (heading_offset == 0.0 and speed == 35.0)
    v = ref.judge(rows, L, W)
    assert v["goal_reached"] == (expected is not None)
    assert v["goal_time"] == (None if expected is None else pytest.approx(expected * DT))


def _write(tmp, key, rows, **over):
    d = {"scenario": key, "planner": "test", "dt": DT, "vehicle": {"length": L, "width": W},
         "states": np.asarray(rows).tolist(), **over}
    os.makedirs(tmp / key, exist_ok=True)
    (tmp / key / "driven.json").write_text(json.dumps(d))
    return tmp / key / "driven.json"


def test_judge_folders_counts_and_reports_missing_drives(tmp_path):
    path, d, _ = _scene()
    rows = _lane_drive(d, lambda t: 20.0 * t, 31)
    _write(tmp_path / "a", "ZAM_Over-1_1", rows)
    res = R.judge_folders({"a": str(tmp_path / "a"), "b": str(tmp_path / "b")}, {"ZAM_Over-1_1": path})
    assert res["summary"]["a"]["collided"] == 1 and res["summary"]["a"]["judged"] == 1
    assert res["summary"]["b"]["judged"] == 0 and res["drives"]["b"][0]["missing"]
    assert res["summary"]["b"]["goal_share"] == 0.0


@pytest.mark.parametrize("change,message", [
    (lambda r: {"states": r[:, :5].tolist()}, "field states should be rows"),
    (lambda r: {"states": np.delete(r, 5, axis=0).tolist()}, "one row per dt"),
    (lambda r: {"vehicle": {"length": L}}, "field vehicle"),
    (lambda r: {"dt": 0.2, "states": (r * np.array([2.0, 1, 1, 1, 1, 1])).tolist()}, "field dt is 0.2"),
    (lambda r: {"scenario": "other"}, "field scenario is 'other'"),
    (lambda r: {"states": (r + np.array([0.5, 0, 0, 0, 0, 0])).tolist()}, "starts at t = 0.5"),
])
def test_bad_drive_files_get_one_clear_line(tmp_path, change, message):
    _, d, ref = _scene()
    rows = _lane_drive(d, lambda t: 10.0 * t, 11)
    f = _write(tmp_path, "ZAM_Over-1_1", rows, **change(rows))
    with pytest.raises(R.DriveError, match=message) as e:
        R.judge_file(ref, str(f), "ZAM_Over-1_1")
    assert str(f) in str(e.value) and "\n" not in str(e.value)


AGREEMENT_SCENES = ("USA_US101-10_1_T-1", "USA_US101-5_1_T-1", "ZAM_Over-1_1", "DEU_Muc-2_1_T-1", "ZAM_ZAMRamp11T1-1")


def test_jaxplan_drive_metrics_agree_with_the_referee(tmp_path):
    """``jaxplan drive``'s own metrics (collision and its time, off road and its time, goal and its time)
    agree with the referee on every drive: recorded scenes with a map seam (US101-10, a 4 cm gap between
    two lanes), a rear-end collision (US101-5 braking), a static obstacle (ZAM_Over), non-identical shared
    bounds (DEU_Muc-2) and a reachable goal (ZAMRamp), driven by the brake and IDM baselines."""
    from jaxplan.scenarios.files import load_records, scenario_keys, unique_names
    from jaxplan.sim import SimConfig
    from jaxplan.sim.drive import drive

    keys = scenario_keys([shared_data_or_skip("commonroad2018a"), shared_data_or_skip("commonroad2020a")])
    paths = [keys[k] for k in AGREEMENT_SCENES]
    records = unique_names(load_records(paths))
    res = drive(records, ["brake", "idm"], str(tmp_path), SimConfig(n_steps=90), progress=False)
    verdicts = R.judge_folders({p: str(tmp_path / p) for p in ("brake", "idm")}, {k: keys[k] for k in AGREEMENT_SCENES})
    seen = {"collided": 0, "off_road": 0, "goal_reached": 0}
    for p in ("brake", "idm"):
        rows = {r["scenario"]: r for r in res.rows[p]}
        for v in verdicts["drives"][p]:
            r = rows[v["scenario"]]
            step = lambda key, ok: round(r[key] * DT, 6) if ok else None  # noqa: E731
            ours = {"collided": (bool(r["overlap.collided"]), step("overlap.first_step", r["overlap.collided"])),
                    "off_road": (bool(r["offroad.offroad"]), step("offroad.first_step", r["offroad.offroad"])),
                    "goal_reached": (bool(r["goal.reached"]), step("goal.step", r["goal.reached"]))}
            theirs = {"collided": (v["collided"], v["first_collision_time"]),
                      "off_road": (v["off_road"], v["first_off_road_time"]),
                      "goal_reached": (v["goal_reached"], v["goal_time"])}
            assert ours == theirs, (p, v["scenario"])
            for k in seen:
                seen[k] += theirs[k][0]
    assert seen["collided"] >= 1 and seen["goal_reached"] >= 1, seen
