import json

import numpy as np
import pytest

from conftest import shared_data_or_skip
from jaxplan.scenarios.loader import ScenarioError, lane_reference, load_dir, load_scenario


def _write(tmp_path, obj, name="s.json"):
    p = tmp_path / name
    p.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return str(p)


def _minimal():
    return {
        "id": "T", "source": "test", "tags": [], "dt": 0.1,
        "lanelets": [{"id": 1, "left": [[0, 2], [50, 2]], "right": [[0, -2], [50, -2]],
                      "predecessors": [], "successors": [2]},
                     {"id": 2, "left": [[50, 2], [100, 2]], "right": [[50, -2], [100, -2]],
                      "predecessors": [1], "successors": []}],
        "obstacles": [{"id": 7, "role": "dynamic", "type": "car", "length": 4.0, "width": 2.0,
                       "states": [[0.0, 20, 0, 0, 10, 0], [0.1, 21, 0, 0, 10, 0], [0.2, 22, 0, 0, 10, 0]]},
                      {"id": 8, "role": "static", "type": "unknown", "length": 4.8, "width": 2.0,
                       "center": [40, 3], "orientation": 0.1}],
        "planning_problems": [{"id": 1, "initial_state": {"t": 0.0, "position": [10.0, 0.5],
                                                          "orientation": 0.0, "velocity": 5.0},
                               "goals": [{"lanelets": [2]}]}],
    }


def test_minimal_scenario_local_frame(tmp_path):
    sc = load_scenario(_write(tmp_path, _minimal()))
    assert np.allclose(sc.origin, [10, 0.5])
    b = np.asarray(sc.obstacles.boxes)
    assert b.shape == (2, 3, 5) and np.allclose(b[0, :, 0], [10, 11, 12]) and np.allclose(b[0, :, 1], -0.5)
    assert np.allclose(b[1, :, :2], [30, 2.5])  # static: held at every time
    assert np.asarray(sc.obstacles.valid).all()
    ref = lane_reference(sc)
    assert float(ref.length) == pytest.approx(100.0, abs=1e-3)  # followed the successor


@pytest.mark.parametrize("mutate,field", [
    (lambda d: d.pop("dt"), "scenario.dt"),
    (lambda d: d["lanelets"][1].pop("left"), "lanelets[1].left"),
    (lambda d: d["lanelets"][0].__setitem__("right", [[0, 1]]), "lanelets[0].right"),
    (lambda d: d["obstacles"][0].__setitem__("length", "long"), "obstacles[0].length"),
    (lambda d: d["obstacles"][0].__setitem__("length", -1.0), "obstacles[0].length"),
    (lambda d: d["planning_problems"][0]["initial_state"].pop("velocity"), "initial_state.velocity"),
    (lambda d: d["planning_problems"][0]["initial_state"].__setitem__("orientation", float("nan")),
     "initial_state.orientation"),
])
def test_malformed_files_name_file_and_field(tmp_path, mutate, field):
    d = _minimal()
    mutate(d)
    p = _write(tmp_path, json.dumps(d).replace("NaN", "NaN"))
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    assert p in str(e.value) and field in str(e.value)


def test_truncated_json(tmp_path):
    p = _write(tmp_path, json.dumps(_minimal())[:100])
    with pytest.raises(ScenarioError, match="not valid JSON"):
        load_scenario(p)


def test_shared_data_loads():
    path = shared_data_or_skip()
    scs = load_dir(path)
    assert len(scs) >= 40
    for sc in scs:
        sc.obstacles.validate()
        # Local frame: ego start at the origin, obstacles within a few hundred metres.
        b = np.asarray(sc.obstacles.boxes)[np.asarray(sc.obstacles.valid)]
        assert b.size == 0 or np.abs(b[:, :2]).max() < 2000
    us101 = [s for s in scs if s.id.startswith("USA_US101")]
    assert us101 and all(s.obstacles.boxes.shape[0] > 0 for s in us101)
    ref = lane_reference(us101[0])
    assert float(ref.length) > 50


def test_polyline_tools_against_brute_force(rng):
    from jaxplan.scenarios.polylines import nearest_on_polyline, uniform_resample

    xy = np.cumsum(rng.normal(size=(12, 2)), axis=0)
    xy = np.insert(xy, 5, xy[4], axis=0)  # a repeated point
    out = uniform_resample(xy, 40)
    steps = np.linalg.norm(np.diff(out, axis=0), axis=1)
    np.testing.assert_allclose(out[[0, -1]], xy[[0, -1]], atol=1e-9)
    spacing = np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1)) / 39
    assert np.all(steps <= spacing + 1e-9)  # chords never exceed the arc-length spacing
    for p in rng.normal(size=(50, 2)) * 5:
        j, along, d = nearest_on_polyline(xy, p)
        dense = np.concatenate([a + np.linspace(0, 1, 2001)[:, None] * (b - a) for a, b in zip(xy[:-1], xy[1:])])
        assert d == pytest.approx(np.linalg.norm(dense - p, axis=1).min(), abs=1e-2)
        seg = xy[j + 1] - xy[j]
        q = xy[j] + along * seg / max(np.linalg.norm(seg), 1e-12)
        assert np.linalg.norm(q - p) == pytest.approx(d, abs=1e-9)


def test_scenario_keys_are_unique_per_file(tmp_path):
    import json as _json

    from jaxplan.scenarios.files import expand_paths, scenario_keys

    folder = shared_data_or_skip("commonroad2018a")
    keys = scenario_keys([folder])
    assert len(keys) == 46 and len(set(keys.values())) == 46
    # two files carry the id DEU_Muc-3_1_T-1: the second is told apart by its file name
    assert keys["DEU_Muc-3_1_T-1"].endswith("DEU_Muc-3_1_T-1.json")
    assert keys["DEU_Muc-3_1_T-1@DEU_Muc-3_1_T-1_Pedo.json"].endswith("_Pedo.json")
    for key, path in keys.items():
        with open(path) as f:
            assert key.split("@")[0] == _json.load(f)["id"]
    (tmp_path / "notes.txt").write_text("x")
    for bad, message in (([str(tmp_path / "missing.json")], "no such file"), ([str(tmp_path / "notes.txt")],
                         "not a scenario file"), ([str(tmp_path)], "holds no scenario files")):
        with pytest.raises(ValueError, match=message):
            expand_paths(bad)
