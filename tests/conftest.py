import os

import numpy as np
import pytest

# ../shared beside the repository; JAXPLAN_SHARED points elsewhere (a git worktree outside the checkout)
SHARED = os.environ.get("JAXPLAN_SHARED") or os.path.join(os.path.dirname(__file__), "..", "..", "shared")
DATA_DIR = os.path.abspath(os.path.join(SHARED, "data"))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def shared_data_or_skip(sub="commonroad2018a"):
    path = os.path.join(DATA_DIR, sub)
    if not os.path.isdir(path):
        pytest.skip(f"../shared/data/{sub} not present (only in CI and the developers' workplace)")
    return path
