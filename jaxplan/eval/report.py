"""``jaxplan report RESULTS_DIR``: one Markdown page with every suite's figures and plots."""
from __future__ import annotations

import json
import os
from collections import defaultdict


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def write_report(results_dir: str, filename: str = "report.md") -> str:
    """Write ``RESULTS_DIR/report.md`` from ``metrics.json`` and the PNGs there.

    Returns:
        The path of the report.
    """
    path = os.path.join(results_dir, "metrics.json")
    if not os.path.exists(path):
        raise ValueError(f"{results_dir}: no metrics.json (run `jaxplan eval ...` first)")
    with open(path) as f:
        metrics = json.load(f)
    by_suite = defaultdict(dict)
    for k, v in metrics.items():
        suite, _, name = k.partition(".")
        by_suite[suite][name or suite] = v
    pngs = sorted(p for p in os.listdir(results_dir) if p.endswith(".png"))
    lines = ["# jaxplan evaluation report", "", f"Results folder: `{os.path.abspath(results_dir)}`", ""]
    shown = set()
    for suite in sorted(by_suite):
        lines += [f"## {suite}", "", "| figure | value |", "| --- | --- |"]
        lines += [f"| {k} | {_fmt(v)} |" for k, v in sorted(by_suite[suite].items())]
        lines.append("")
        for p in pngs:
            if p.startswith(suite):
                lines += [f"![{p}]({p})", ""]
                shown.add(p)
    rest = [p for p in pngs if p not in shown]
    if rest:
        lines += ["## other plots", ""] + [f"![{p}]({p})\n" for p in rest]
    out = os.path.join(results_dir, filename)
    with open(out + ".tmp", "w") as f:
        f.write("\n".join(lines))
    os.replace(out + ".tmp", out)
    return out
