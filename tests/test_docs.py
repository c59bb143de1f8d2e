"""The documentation site builds with ``mkdocs build --strict`` (mkdocs.yml: every page of docs/ in the
nav, no broken link or anchor, the API reference rendered from the docstrings by mkdocstrings without a
warning), and the reference page documents the public names.

Needs the docs extra (``pip install -e ".[docs]"``); skipped without it.
"""
import importlib.util
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

# a few of jaxplan.__all__ (documented in the modules that define them) and of the planner packages
PUBLIC_NAMES = ("make_planner", "rollout", "Scene", "ReferenceLine", "Obstacles", "LatticeConfig", "plan_speed",
                "path_bounds", "park_out", "supervise", "IDMPlanner")


def _missing_docs_tools():
    need = {"mkdocs": "mkdocs", "mkdocstrings": "mkdocstrings", "mkdocstrings_handlers.python": "mkdocstrings-python"}
    missing = []
    for module, package in need.items():
        try:
            found = importlib.util.find_spec(module) is not None
        except ModuleNotFoundError:  # a missing parent package
            found = False
        if not found:
            missing.append(package)
    return missing


def test_docs_build_strict(tmp_path):
    missing = _missing_docs_tools()
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (the docs extra: pip install -e '.[docs]')")
    site = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml"),
         "--site-dir", str(site)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{log}"
    assert "WARNING" not in log, log

    reference = (site / "reference" / "index.html").read_text()
    absent = [name for name in PUBLIC_NAMES if name not in reference]
    assert not absent, f"the API reference does not mention {absent}"
    # rendered by mkdocstrings (an object heading with its full path as id), not only named in prose
    for obj in ("jaxplan.planner.make_planner", "jaxplan.sim.rollout.rollout", "jaxplan.lattice.LatticeConfig"):
        assert f'id="{obj}"' in reference, f"{obj} has no entry in the API reference"
    # every page of docs/ was built
    pages = sorted(p.relative_to(ROOT / "docs").with_suffix("") for p in (ROOT / "docs").rglob("*.md"))
    assert len(pages) > 10
    for page in pages:
        out = site / ("index.html" if page.name == "index" else page / "index.html")
        assert out.is_file(), f"docs/{page}.md was not built"
