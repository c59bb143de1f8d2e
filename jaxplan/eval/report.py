"""``jaxplan report RESULTS_DIR``: one Markdown page with a run's figures and plots.

The page shows the figures of ``metrics.json`` and the plots the run recorded in
``run.json`` (``outputs``), never other images lying in the folder. Its last line is a
marker with the hash of the page; an existing ``report.md`` without a matching marker
(written by someone else, or edited since) is not overwritten unless ``force``.
"""

from __future__ import annotations

import hashlib
import os
from collections import defaultdict
from typing import Any

from jaxplan.eval.claims import claims_table
from jaxplan.eval.registry import METRICS, RUN, read_json, sha256_file

MARK = "<!-- written by jaxplan report; sha256 of the text above: "


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _ours(path: str) -> bool:
    """True when ``path`` is a report written by ``write_report`` and unchanged since."""
    with open(path, "rb") as f:
        text = f.read().decode("utf-8", "replace")
    body, _, last = text.rstrip("\n").rpartition("\n")
    return last.startswith(MARK) and last == f"{MARK}{hashlib.sha256(body.encode()).hexdigest()} -->"


def _drive_summary(metrics: dict) -> dict:
    """``{planner: {figure: value}}`` from a drive's ``metrics.json`` (figures ``drive.<planner>.<figure>``)."""
    out: dict = {}
    for k, v in metrics.items():
        head, _, rest = k.partition(".")
        planner, _, fig = rest.partition(".")
        if head == "drive" and fig:
            out.setdefault(planner, {})[fig] = v
    return {p: out[p] for p in metrics.get("run", {}).get("planners", sorted(out)) if p in out}


def _drive_headlines(results_dir: str) -> list:
    """The headline: one table per closed-loop run (``jaxplan drive``) in a sub-folder, a line per planner."""
    from jaxplan.sim.report import headline_table

    lines = []
    for name in sorted(os.listdir(results_dir)):
        path = os.path.join(results_dir, name, METRICS)
        if not os.path.isfile(path):
            continue
        m = read_json(path)
        summary = _drive_summary(m) if isinstance(m, dict) and "rows" in m else {}
        if summary:
            n = len({r.get("scenario") for r in m["rows"]})
            lines += [f"## Closed loop: `{name}/` ({n} scenes; per-scene lines in `{name}/report.md`)", ""]
            lines += headline_table(summary) + [""]
    return lines


def _bench_lines(results_dir: str) -> list:
    """Benchmark figures of ``bench_*.json`` files in the folder (``make bench``): throughput keyed by batch
    size and every ratio."""
    lines = []
    for name in sorted(os.listdir(results_dir)):
        if not (name.startswith("bench_") and name.endswith(".json")):
            continue
        try:
            b = read_json(os.path.join(results_dir, name))
        except ValueError as e:
            lines.append(f"- `{name}`: not readable ({e})")
            continue
        if not isinstance(b, dict):
            continue
        parts = []
        for k, v in sorted(b.items()):
            if k.endswith("_per_s") and isinstance(v, dict):
                parts.append(f"{k} " + ", ".join(f"{n}: {_fmt(x)}" for n, x in v.items()))
            elif "ratio" in k and isinstance(v, (int, float)):
                parts.append(f"{k} {_fmt(v)}")
        if parts:
            lines.append(f"- `{name}`: " + "; ".join(parts))
    return ["## Benchmarks", "", *lines, ""] if lines else []


def write_report(results_dir: str, filename: str = "report.md", force: bool = False) -> str:
    """Write ``RESULTS_DIR/report.md`` from ``metrics.json`` and the plots listed in ``run.json``.

    Raises:
        ValueError: naming the folder or file: no such folder, no ``metrics.json``, an unreadable
            file, a ``run.json`` that describes another ``metrics.json``, or a ``report.md`` this
            function did not write (pass ``force=True`` to replace it).

    Returns:
        The path of the report.
    """
    if not os.path.isdir(results_dir):
        raise ValueError(f"{results_dir}: no such folder")
    path = os.path.join(results_dir, METRICS)
    if not os.path.exists(path):
        raise ValueError(f"{results_dir}: no {METRICS} (run `jaxplan eval ...` first)")
    metrics = read_json(path)
    if not isinstance(metrics, dict):
        raise ValueError(f"{path}: expected an object of named figures")
    out = os.path.join(results_dir, filename)
    if os.path.exists(out) and not force and not _ours(out):
        raise ValueError(
            f"{out}: exists and was not written by `jaxplan report` (or was edited since); "
            f"move it away, or pass --force to replace it"
        )
    run_path = os.path.join(results_dir, RUN)
    run = read_json(run_path) if os.path.exists(run_path) else None
    if run is not None and run.get("metrics_sha256") not in (None, sha256_file(path)):
        raise ValueError(
            f"{run_path}: describes another {METRICS} (an interrupted or mixed run); "
            f"run `jaxplan eval` into this folder again"
        )
    by_suite: defaultdict[str, dict[str, Any]] = defaultdict(dict)
    for k, v in metrics.items():
        suite, _, name = k.partition(".")
        by_suite[suite][name or suite] = v
    recorded = [] if run is None else [p for p in run.get("outputs", []) if isinstance(p, str)]
    pngs = sorted(p for p in recorded if p.endswith(".png") and os.path.isfile(os.path.join(results_dir, p)))
    lines = ["# jaxplan evaluation report", "", f"Results folder: `{os.path.abspath(results_dir)}`", ""]
    lines += ["## Claims", "", *claims_table(metrics), ""]
    lines += _drive_headlines(results_dir)
    lines += _bench_lines(results_dir)
    if run is None:
        lines += [f"No `{RUN}` in this folder (not written by `jaxplan eval`): its plots are not shown.", ""]
    else:
        lines += [f"Suites run: {', '.join(run.get('suites', []))} (jaxplan {run.get('jaxplan', '?')}).", ""]
    shown = set()
    for suite in sorted(by_suite):
        lines += [f"## {suite}", "", "| figure | value |", "| --- | --- |"]
        lines += [f"| {k} | {_fmt(v)} |" for k, v in sorted(by_suite[suite].items())]
        lines.append("")
        for p in pngs:
            if os.path.basename(p).startswith(suite):
                lines += [f"![{p}]({p})", ""]
                shown.add(p)
    rest = [p for p in pngs if p not in shown]
    if rest:
        lines += ["## other plots of this run", ""] + [f"![{p}]({p})\n" for p in rest]
    body = "\n".join(lines)
    text = f"{body}\n{MARK}{hashlib.sha256(body.encode()).hexdigest()} -->\n"
    with open(out + ".tmp", "w") as f:
        f.write(text)
    os.replace(out + ".tmp", out)
    return out
