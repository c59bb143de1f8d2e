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


def run_notebook(path: str) -> list:
    """Execute every code cell of ``path`` in one namespace; returns each cell's last value."""
    nb = nbformat.read(path, as_version=4)
    ns = {"__name__": "__main__"}
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
