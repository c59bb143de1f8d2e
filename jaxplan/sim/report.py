"""``report.md`` of a drive run: the headline table (one line per planner, success first), where
the time went, per-folder and per-location tables, why each failed drive failed, and one
compact line per scenario."""

from __future__ import annotations

import math
import os

from jaxplan.planner import EMERGENCY_DECEL, EMERGENCY_LAT_ACCEL

LAT_OVER = f"lat accel > {EMERGENCY_LAT_ACCEL:g} where the road allows <= {EMERGENCY_LAT_ACCEL:g}"

HEADLINE = (  # column, figure, format
    ("success", "success_share", "{:.1%}"),
    ("goal reached", "goal_share", "{:.1%}"),
    ("collisions", "collisions", "{:.0f}"),
    ("at fault", "at_fault_collisions", "{:.0f}"),
    ("off road", "offroad_share", "{:.1%}"),
    ("red lights run", "red_light_crossings", "{:.0f}"),
    ("goal off map", "goal_off_map", "{:.0f}"),
    ("max abs accel (m/s^2)", "max_abs_accel", "{:.1f}"),
    ("max abs lat accel (m/s^2)", "max_abs_lat_accel", "{:.1f}"),
    (LAT_OVER, "lat_accel_over_limit_avoidable", "{:.0f}"),
    ("in blind zones (s)", "blind_zone_s", "{:.1f}"),
    ("plan not ok", "plan_not_ok_share", "{:.1%}"),
)

GROUP_COLUMNS = (  # the per-folder / per-location tables
    ("success", "success_share", "{:.1%}"),
    ("goal", "goal_share", "{:.1%}"),
    ("collisions", "collisions", "{:.0f}"),
    ("at fault", "at_fault_collisions", "{:.0f}"),
    ("off road", "offroad_share", "{:.1%}"),
    ("red lights run", "red_light_crossings", "{:.0f}"),
    ("goal off map", "goal_off_map", "{:.0f}"),
)

DEFINITIONS = f"""\
- **success**: the goal reached (CommonRoad's rule: at one step the box centre in the goal region,
  the time in the goal's interval, speed and heading in their ranges), no collision at any step and
  never off road: what makes a CommonRoad solution valid.
- **collisions**: drives in which the car's box overlapped an obstacle's at some step; **at fault**:
  drives in which some obstacle's first contact was not a moving obstacle hitting the car squarely
  from behind (``jaxplan.sim.metrics.overlap``).
- **off road**: drives where the car's box left the union of the lanelets (map seams up to 10 cm wide
  count as road; the referee's rule).
- **red lights run**: stop lines crossed while their light showed red.
- **goal off map**: drives whose goal region lies off the lanelets (reaching it means leaving the road);
  counted in the other columns too, and shown here apart.
- **max abs accel / lat accel**: largest |dv/dt| and |v dtheta/dt| of the driven states.
- **{LAT_OVER}**: drives whose lateral acceleration passed the emergency limit
  ({EMERGENCY_LAT_ACCEL:g} m/s^2) although braking at {EMERGENCY_DECEL:g} m/s^2 from the start keeps v^2 |kappa| along
  the route's centre line within it (``comfort.lat_accel_floor``).
- **plan not ok**: share of planning cycles in which the planner reported no good plan.
"""


def _fmt(fmt: str, v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return fmt.format(v)


def headline_table(summary: dict, columns=HEADLINE, label: str = "planner") -> list:
    """Markdown lines: one row per key of ``summary {name: {figure: value}}``."""
    cols = [label, "drives"] + [c for c, _, _ in columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    for p, s in summary.items():
        vals = [str(p), _fmt("{:.0f}", s.get("scenes"))] + [_fmt(fmt, s.get(k)) for _, k, fmt in columns]
        lines.append("| " + " | ".join(vals) + " |")
    return lines


def timing_lines(timing: dict) -> list:
    """One line on where the run's time went."""
    if not timing:
        return []
    f = lambda k: timing.get(k) or 0.0  # noqa: E731
    return [
        f"Wall time {f('wall_s'):.0f} s: parsing {f('parse_s'):.0f} s, compiling {f('compile_s'):.0f} s, "
        f"driving {f('drive_s'):.0f} s, metrics {f('metrics_s'):.0f} s, writing outputs {f('write_s'):.0f} s "
        f"({int(f('drives'))} drives this run, {int(f('resumed_drives'))} from an earlier run in this folder)."
    ]


def _cell(r: dict) -> str:
    out = "success" if r.get("success") else ("goal" if r.get("goal.reached") else "-")
    if r.get("overlap.collided"):
        out += ", HIT" if r.get("overlap.at_fault") else ", hit from behind"
    if r.get("offroad.offroad"):
        out += ", off road"
    if r.get("redlight.crossings"):
        out += ", ran a red light"
    return out


def write_drive_report(
    out: str,
    summary: dict,
    rows: dict,
    run: dict,
    timing: dict | None = None,
    by_folder: dict | None = None,
    by_location: dict | None = None,
) -> str:
    """Write ``out/report.md``; returns its path."""
    planners = list(summary)
    n = len(run["scenarios"])
    setting = (
        f"{n} scenarios, {run.get('replan', 'periodic')} re-planning every {run['replan_every']} steps "
        f"({run['replan_every'] * run['dt']:.1f} s), {run['tracking']} tracking, each scene driven to the end "
        f"of its goal's time window, at most {run['n_steps']} steps"
    )
    if run.get("agents"):
        setting += f"; traffic: {run['agents']}, predictions: {run.get('prediction', 'oracle')}"
    lines = ["# jaxplan drive", "", setting + ".", ""]
    lines += headline_table(summary) + [""] + timing_lines(timing or {}) + ["", DEFINITIONS]
    for title, table in (("folder", by_folder), ("location", by_location)):
        if not table:
            continue
        lines += [f"## Per {title}", ""]
        for p in planners:
            if len(table.get(p, {})) <= 1 and title == "folder":
                continue
            lines += [f"`{p}`:", ""] + headline_table(table.get(p, {}), GROUP_COLUMNS, title) + [""]
    failed = [(p, r) for p in planners for r in rows[p] if not r.get("success")]
    if failed:
        lines += ["## Drives that did not succeed", "", "| planner | scenario | why |", "| --- | --- | --- |"]
        lines += [f"| {p} | {r['scenario']} | {r.get('why') or r.get('outcome', '')} |" for p, r in failed]
        lines.append("")
    lines += [
        "## Per scenario",
        "",
        "| scenario | " + " | ".join(planners) + " |",
        "|" + " --- |" * (len(planners) + 1),
    ]
    by = {p: {r["scenario"]: r for r in rows[p]} for p in planners}
    for name in run["scenarios"]:
        lines.append(
            f"| {name} | " + " | ".join(_cell(by[p][name]) if name in by[p] else "not driven" for p in planners) + " |"
        )
    if run.get("skipped_files"):
        lines += ["", "Files that could not be loaded: " + ", ".join(run["skipped_files"])]
    path = os.path.join(out, "report.md")
    with open(path + ".tmp", "w") as f:
        f.write("\n".join(lines) + "\n")
    os.replace(path + ".tmp", path)
    return path
