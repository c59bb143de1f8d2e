"""The README's "Use it as a library" example runs as written (and docs/api.md shows the same code):
built-in scenes -> one batched Scene -> a jitted, vmapped plan -> a closed-loop rollout -> metrics."""
import math
import pathlib
import re

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
HEADING = "## Use it as a library"


def _code(path: pathlib.Path, heading: str | None) -> str:
    text = path.read_text()
    if heading is not None:
        assert heading in text, f"{path.name} has no section {heading!r}"
        text = text.split(heading, 1)[1]
        text = re.split(r"\n## ", text, maxsplit=1)[0]  # that section only
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks, f"no python code block in {path.name} under {heading!r}"
    return blocks[0]


def test_docs_show_the_readme_example():
    code = _code(ROOT / "README.md", HEADING)
    api = (ROOT / "docs" / "api.md").read_text()
    assert code in api


def test_readme_library_example_runs():
    code = _code(ROOT / "README.md", HEADING)
    ns = {}
    exec(compile(code, "README.md (Use it as a library)", "exec"), ns)
    planner, plan, log, metrics, success = (ns[k] for k in ("planner", "plan", "log", "metrics", "success"))
    B, H = 2, planner.horizon_steps
    for f in ("x", "y", "theta", "v", "a", "t"):
        assert getattr(plan.trajectory, f).shape == (B, H), f
    assert np.all(np.isfinite(np.asarray(plan.trajectory.x))) and np.asarray(plan.ok).shape == (B,)
    assert np.asarray(plan.ok).all()
    assert log.x.shape == (B, 101) and log.end_step.shape == (B,)
    assert metrics and all(np.shape(v) == (B,) for v in metrics.values())
    success = np.asarray(success)
    assert success.shape == (B,) and success.dtype == bool  # one verdict per scene
    assert success.all()  # both drives reach their goal without a collision and on the road
    assert not np.asarray(metrics["overlap.collided"]).any()
    progress = np.asarray(metrics["progress.route_m"])
    assert np.all(np.isfinite(progress)) and np.all(progress > 0)
    assert all(math.isfinite(float(t)) for t in np.asarray(metrics["goal.time"]))
