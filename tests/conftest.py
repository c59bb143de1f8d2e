import os

# The suite compiles as jaxplan's commands do: with XLA's default options but for the CPU loop emitters
# (`jaxplan.compile_options.use_fast_compile`; the workers and child processes inherit XLA_FLAGS), and
# without JAX's persistent compilation cache (the CLI turns it on for users; child processes inherit
# this): with jaxlib 0.10.2 one full run lost a worker aborting inside XLA while it serialised an
# executable for the cache. Workers also crashed compiling without it, a different test each time: a
# worker that has compiled a few thousand programs reaches the kernel's limit on memory maps and XLA
# aborts (`_release_compiled_programs` below); `pytest_handlecrashitem` reruns a crashed worker's test.
os.environ["JAX_ENABLE_COMPILATION_CACHE"] = "false"

from jaxplan.compile_options import release_compiled, use_fast_compile  # noqa: E402

use_fast_compile()

import numpy as np  # noqa: E402
import pytest  # noqa: E402

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
# seconds per file in a full run with ../shared, compiled as the commands compile (2026-12-07):
# 146 143 137 112 99 81 68 64 64 61 52 48 45 36 34 33 30 29 27 26 26 23 21
SLOW_FIRST = (
    "test_speed_planner.py", "test_notebooks.py", "test_bounds_path.py", "test_sim.py", "test_speed_dp.py",
    "test_closed_loop.py", "test_agents.py", "test_referee.py", "test_drive_runner.py", "test_lattice_road.py",
    "test_bounds_core.py", "test_lattice_core.py", "test_speed_boundaries.py", "test_parking_core.py",
    "test_traffic_lights.py", "test_lattice_drives.py", "test_readme_example.py", "test_inputs.py",
    "test_replan_sim.py", "test_public_api.py", "test_cli.py", "test_tuning_lattice.py", "test_geometry_core.py",
)


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda it: rank.get(os.path.basename(str(it.path)), len(rank)))  # stable: files stay whole


# A worker that crashes is replaced (`--max-worker-restart` in the Makefile) and the test it was
# running runs again on the new worker, once: the crash is reported as a rerun, and the test's second
# run decides. A test that crashes twice, or a third crash in one run, fails the run.
CRASH_RERUNS = 2
_crashed: list = []
_config: list = []


def pytest_configure(config):
    _config.append(config)


@pytest.hookimpl(optionalhook=True)
def pytest_handlecrashitem(crashitem, report, sched):
    first = crashitem not in _crashed
    _crashed.append(crashitem)
    if first and len(_crashed) <= CRASH_RERUNS:
        report.outcome = "rerun"  # xdist's load-file scheduler queues the unfinished test again
        _config[-1].pluginmanager.get_plugin("terminalreporter").write_line(
            f"{report.longrepr}: it runs again on a new worker"
        )


@pytest.fixture(autouse=True)
def _release_compiled_programs():
    """After each test: free JAX's compiled programs once the worker maps half the memory regions
    the kernel allows (``jaxplan.compile_options.release_compiled``): a worker that had compiled
    a few thousand programs aborted inside XLA when it reached the limit."""
    yield
    release_compiled()


def cpu_devices_env(devices: int) -> dict:
    """The environment of a child process with ``devices`` host CPU devices and this process's XLA
    flags (so that it compiles the same arithmetic)."""
    flags = os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={devices}"
    return dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=flags)


def shared_data_or_skip(sub="commonroad2018a"):
    path = os.path.join(DATA_DIR, sub)
    if not os.path.isdir(path):
        pytest.skip(f"../shared/data/{sub} not present (only in CI and the developers' workplace)")
    return path
