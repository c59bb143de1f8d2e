import glob
import os

import numpy as np

from conftest import shared_data_or_skip
from jaxplan.scenarios.loader import load_scenario
from jaxplan.tuning.demos import DemoConfig, is_validation, load_demos, scenario_demos


def test_demos_from_recorded_traffic():
    files = sorted(glob.glob(os.path.join(shared_data_or_skip(), "USA_US101-1*_1_T-1.json")))[:2]
    scs = [load_scenario(f) for f in files]
    cfg = DemoConfig(horizon=3.0, n_obstacles=8, ref_points=48)
    demos = scenario_demos(scs[0], cfg)
    assert len(demos) > 5
    for d in demos:
        assert d.human_xy.shape == (31, 2) and d.obstacles.shape == (8, 31, 5) and d.ref_xy.shape == (48, 2)
        np.testing.assert_allclose(d.human_xy[0], 0.0, atol=1e-9)
        # The human future is a recorded vehicle's track, shifted by the start position.
        v = np.linalg.norm(np.diff(d.human_xy, axis=0), axis=1) / 0.1
        np.testing.assert_allclose(v, d.human_v[:-1], rtol=1e-9)
        # The start lies near the reference line, 10 m from its first sample (or less if clipped).
        dist = np.min(np.linalg.norm(d.ref_xy - d.human_xy[0], axis=1))
        assert dist < cfg.max_lane_offset + np.max(np.linalg.norm(np.diff(d.ref_xy, axis=0), axis=1))
        # Valid obstacles are the others, sorted nearest first at the start.
        ok = d.obstacle_valid[:, 0]
        r = np.linalg.norm(d.obstacles[ok, 0, :2], axis=1)
        assert np.all(np.diff(r) >= 0) and np.all(r > 0.5)
    train, val, info = load_demos(scs, cfg)
    assert sum(info.values()) == (0 if train is None else len(train.ego)) + (0 if val is None else len(val.ego))
    assert [is_validation(s.id) for s in scs] == [is_validation(s.id) for s in scs]
