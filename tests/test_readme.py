"""The README's code example runs as written."""
import os
import re


def test_readme_example_runs():
    text = open(os.path.join(os.path.dirname(__file__), "..", "README.md")).read()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    ns = {}
    exec(compile(code, "README.md", "exec"), ns)
    assert ns["best"].x.shape == (51,)
    assert ns["hit"].shape == (51,) and not bool(ns["hit"].any())  # the chosen trajectory avoids the lead car
