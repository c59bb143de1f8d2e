"""``report.md`` of a drive: the headline table (one line per planner), the definitions of
its figures, and one compact line per scenario."""
from __future__ import annotations

import math
import os

HEADLINE = (  # column, figure, format
    ("goal reached", "goal_share", "{:.0%}"),
    ("collisions at fault", "at_fault_collisions", "{:.0f}"),
    ("collisions not at fault", "not_at_fault_collisions", "{:.0f}"),
    ("off road", "offroad_share", "{:.0%}"),
    ("max abs accel (m/s^2)", "max_abs_accel", "{:.1f}"),
    ("max abs lat accel (m/s^2)", "max_abs_lat_accel", "{:.1f}"),
    ("max curvature (1/m)", "max_abs_curvature", "{:.3f}"),
    ("min TTC (s)", "min_ttc", "{:.1f}"),
    ("re-plans per drive", "replans_per_drive", "{:.1f}"),
    ("plan ms (median)", "plan_ms_median", "{:.1f}"),
    ("scenario-steps/s", "scenario_steps_per_s", "{:.0f}"),
)

DEFINITIONS = """\
- **goal reached**: share of drives that, at one step, had the box centre in the goal region, the
  time in the goal's interval, speed and heading in their ranges (CommonRoad's rule).
- **collisions at fault**: drives whose first contact was with a static obstacle or one whose centre
  was ahead of the car along its heading; **not at fault**: another road user drove into the car
  (recorded traffic does not react).
- **off road**: drives where a point of the car's outline left the union of the lanelets.
- **max abs accel / lat accel / curvature**: largest |dv/dt|, |v dtheta/dt|, |dtheta/ds| of the
  driven states (finite differences over 0.1 s).
- **min TTC**: smallest constant-velocity time to collision with an obstacle ahead or static (3 s cap).
- **re-plans per drive**: plans installed (periodic: every cycle; lazy: only when needed).
- **plan ms**: wall time of one planning call for one scene (compile excluded), median over scenes.
- **scenario-steps/s**: simulated steps per second of the whole batched closed loop (compile excluded).
"""


def _fmt(fmt: str, v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return fmt.format(v)


def headline_table(summary: dict) -> list:
    """Markdown lines: one row per planner of ``summary {planner: {figure: value}}``."""
    cols = ["planner", "drives"] + [c for c, _, _ in HEADLINE]
    lines = ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    for p, s in summary.items():
        vals = [p, _fmt("{:.0f}", s.get("scenes"))] + [_fmt(fmt, s.get(k)) for _, k, fmt in HEADLINE]
        lines.append("| " + " | ".join(vals) + " |")
    return lines


def _cell(r: dict) -> str:
    out = "goal" if r["goal.reached"] else "-"
    if r["overlap.collided"]:
        out += ", HIT" if r["overlap.at_fault"] else ", hit (not at fault)"
    if r["offroad.offroad"]:
        out += ", off road"
    return out


def write_drive_report(out: str, summary: dict, rows: dict, run: dict) -> str:
    """Write ``out/report.md``."""
    planners = list(summary)
    lines = ["# jaxplan drive", "",
             f"{len(run['scenarios'])} scenarios, {run.get('replan', 'periodic')} re-planning checked every "
             f"{run['replan_every']} steps ({run['replan_every'] * run['dt']:.1f} s), {run['tracking']} tracking, "
             f"up to {run['n_steps']} steps.", ""]
    lines += headline_table(summary) + ["", DEFINITIONS, "## Per scenario", ""]
    lines += ["| scenario | " + " | ".join(planners) + " |", "|" + " --- |" * (len(planners) + 1)]
    by = {p: {r["scenario"]: r for r in rows[p]} for p in planners}
    for name in run["scenarios"]:
        lines.append(f"| {name} | " + " | ".join(_cell(by[p][name]) for p in planners) + " |")
    if run.get("skipped_files"):
        lines += ["", "Skipped files: " + ", ".join(run["skipped_files"])]
    path = os.path.join(out, "report.md")
    with open(path + ".tmp", "w") as f:
        f.write("\n".join(lines) + "\n")
    os.replace(path + ".tmp", path)
    return path
