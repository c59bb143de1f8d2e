"""The tuning notebooks run top to bottom at a small size, so they never rot."""
import os

import nbformat
import pytest
from nbclient import NotebookClient

NB_DIR = os.path.join(os.path.dirname(__file__), "..", "notebooks")


@pytest.mark.parametrize("name", ["tune_lattice_weights.ipynb", "tune_speed_weights.ipynb"])
def test_notebook_runs(name, monkeypatch):
    monkeypatch.setenv("JAXPLAN_NB_SMALL", "1")
    nb = nbformat.read(os.path.join(NB_DIR, name), as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": NB_DIR}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs)  # the plots rendered
