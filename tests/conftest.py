import os

import numpy as np
import pytest

# ../shared beside the repository; JAXPLAN_SHARED points elsewhere (a git worktree has no ../shared)
SHARED = os.environ.get("JAXPLAN_SHARED") or os.path.join(os.path.dirname(__file__), "..", "..", "shared")
DATA_DIR = os.path.abspath(os.path.join(SHARED, "data"))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


# The test files whose tests take longest (seconds of a full run on the 2-core CI machine), longest
# first. `make test` runs `--dist loadfile --no-loadscope-reorder`: the two workers take files in
# this order, so the long ones start first and the workers finish close together (xdist's own
# order, by the number of tests, started the longest file last). Files not named keep their order.
SLOW_FIRST = (  # seconds per file in a full run at 6a93215: 170 168 138 120 109 102 95 90 66 66 57 39 38 30 26 22
    "test_speed_planner.py", "test_bounds_path.py", "test_sim.py", "test_speed_dp.py", "test_notebooks.py",
    "test_lattice_core.py", "test_lattice_road.py", "test_bounds_core.py", "test_parking_core.py", "test_inputs.py",
    "test_parking_planner.py", "test_replan_sim.py", "test_geometry_core.py", "test_speed_boundaries.py",
    "test_robustness_planners.py", "test_cli.py",
)


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda it: rank.get(os.path.basename(str(it.path)), len(rank)))  # stable: files stay whole


def shared_data_or_skip(sub="commonroad2018a"):
    path = os.path.join(DATA_DIR, sub)
    if not os.path.isdir(path):
        pytest.skip(f"../shared/data/{sub} not present (only in CI and the developers' workplace)")
    return path
