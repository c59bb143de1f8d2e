"""The tuning notebooks run top to bottom at a small size, so they never rot.

They run in the test process (cell by cell, IPython magics skipped, the last expression
of a cell kept as its output), not in a Jupyter kernel: the jitted kernels they use are
then compiled once for the whole test session instead of once per notebook.
"""
import ast
import os

import matplotlib
import nbformat
import pytest

NB_DIR = os.path.join(os.path.dirname(__file__), "..", "notebooks")


def run_notebook(path: str, ns: dict | None = None) -> list:
    """Execute every code cell of ``path`` in one namespace (``ns``, where given: the caller then
    reads what the notebook left in it); returns each cell's last value."""
    nb = nbformat.read(path, as_version=4)
    ns = {"__name__": "__main__"} if ns is None else ns
    values = []
    for i, cell in enumerate(c for c in nb.cells if c.cell_type == "code"):
        src = "\n".join(line for line in cell.source.splitlines() if not line.lstrip().startswith("%"))
        tree = ast.parse(src, filename=f"{os.path.basename(path)} cell {i}")
        last = tree.body.pop() if tree.body and isinstance(tree.body[-1], ast.Expr) else None
        exec(compile(tree, f"{os.path.basename(path)} cell {i}", "exec"), ns)
        values.append(eval(compile(ast.Expression(last.value), f"cell {i}", "eval"), ns) if last else None)
    return values


@pytest.mark.parametrize("name", ["tune_lattice_weights.ipynb", "tune_speed_weights.ipynb"])
def test_notebook_runs(name, monkeypatch):
    import matplotlib.pyplot as plt

    monkeypatch.setenv("JAXPLAN_NB_SMALL", "1")
    monkeypatch.chdir(NB_DIR)
    matplotlib.use("Agg")
    values = run_notebook(os.path.join(NB_DIR, name))
    figs = [v for v in values if isinstance(v, matplotlib.figure.Figure)]
    assert len(figs) >= 3  # the plots were drawn
    for f in figs:
        assert f.axes and all(ax.get_xlabel() or ax.get_ylabel() for ax in f.axes)  # labelled axes
        plt.close(f)


def test_closed_loop_notebook_tunes_and_judges(monkeypatch):
    """``tune_closed_loop.ipynb`` at its small size: a finite training objective per Adam step (and at
    the tuned weights), tuned weights that are finite, positive and moved off the hand-set ones, the
    default and tuned drives judged on both batches, labelled plots; no outputs are stored."""
    import math

    import matplotlib.pyplot as plt

    path = os.path.join(NB_DIR, "tune_closed_loop.ipynb")
    assert all(not c.get("outputs") for c in nbformat.read(path, as_version=4).cells if c.cell_type == "code")
    monkeypatch.setenv("JAXPLAN_NB_SMALL", "1")
    monkeypatch.chdir(NB_DIR)
    matplotlib.use("Agg")
    ns = {"__name__": "__main__"}
    values = run_notebook(path, ns)
    steps = ns["ADAM_STEPS"]
    for curve in ("soft", "exact"):
        h = ns["history"][curve]
        assert len(h) == steps + 1 and all(math.isfinite(v) for v in h), (curve, h)
    default, tuned = ns["default_weights"], ns["tuned_weights"]
    assert set(tuned) == set(default) == set(ns["TUNED"])
    assert all(math.isfinite(v) and v > 0 for v in tuned.values())
    assert max(abs(math.log(tuned[k] / default[k])) for k in tuned) > 1e-3  # the steps moved them
    for results in (ns["before"], ns["after"]):
        assert set(results) == {"train", "held-out"}
        for r in results.values():
            assert math.isfinite(r["objective"]) and len(r["outcomes"]) == len(r["rows"]) > 0
    assert set(ns["names"][ns["split"]["train"]]).isdisjoint(ns["names"][ns["split"]["held-out"]])
    figs = [v for v in values if isinstance(v, matplotlib.figure.Figure)]
    assert len(figs) >= 2
    for f in figs:
        assert all(ax.get_xlabel() and ax.get_ylabel() for ax in f.axes)
        assert all(ax.get_legend() is not None for ax in f.axes)
        plt.close(f)
