"""The comparison's report: ``render_report`` writes the tables of ``compare_peers.json`` as Markdown
(``report.md``), ``plot_drives`` draws every planner's drive on each scenario (``plots/``)."""

from __future__ import annotations

import json
import math
import os
import sys

import numpy as np

from .config import ROOT
from .settings import render_settings


def render_report(res: dict) -> str:
    fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
    lines = [
        "# Peers in jaxplan's closed-loop harness",
        "",
        f"{len(res['scenarios'])} scenarios, re-plan every {res['args']['replan']} steps of 0.1 s, perfect tracking, "
        f"route: {res['route_source']}. Referee: commonroad-drivability-checker (collision with every obstacle, "
        "the box inside the lanelets) and commonroad-io's goal check, on every driven state.",
        "",
        "| planner | success | goal share (CommonRoad rule) | goals | collisions | off road | judged drives | "
        "plan time per cycle, median (ms) | CPU per cycle, median (ms) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for label, s in res["summary"].items():
        lines.append(
            f"| {label} | {s.get('success', '-')}/{s['scenarios']} | {fmt(s['goal_share'], '.1%')} | "
            f"{s['goal_reached']}/{s['scenarios']} | "
            f"{s['collided']} | {s['off_road']} | {s['judged']} | {fmt(s['plan_ms_median'], '.1f')} | "
            f"{fmt(s['cpu_ms_median'], '.1f')} |"
        )
    if res.get("verdict"):
        lines += [
            "",
            "## jaxplan's verdict: the same code for every planner",
            "",
            "Success: goal reached (CommonRoad's rule), no collision at any step, never off road. At fault: some "
            "obstacle's first contact was not a moving obstacle hitting the car squarely from behind "
            "(`jaxplan.sim.metrics.overlap`).",
            "",
            "| planner | drives | success | goal | collisions | at fault | off road | goal off map | referee agrees |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for label, o in res["verdict"].items():
            s_ = o["summary"]
            ag = res.get("agreement", {}).get(label, {})
            lines.append(
                f"| {label} | {fmt(s_.get('scenes'), '.0f')} | {fmt(s_.get('success_share'), '.1%')} | "
                f"{fmt(s_.get('goal_share'), '.1%')} | {fmt(s_.get('collisions'), '.0f')} | "
                f"{fmt(s_.get('at_fault_collisions'), '.0f')} | {fmt(s_.get('offroad_share'), '.1%')} | "
                f"{fmt(s_.get('goal_off_map'), '.0f')} | {ag.get('agree', '-')}/{ag.get('judged', '-')} |"
            )
        lines += [
            "",
            "Per folder (success / goal / collisions / at fault):",
            "",
            "| planner | " + " | ".join(sorted({g for o in res["verdict"].values() for g in o["by_folder"]})) + " |",
        ]
        groups = sorted({g for o in res["verdict"].values() for g in o["by_folder"]})
        lines.append("| --- |" + " --- |" * len(groups))
        for label, o in res["verdict"].items():
            cells = []
            for g in groups:
                b = o["by_folder"].get(g)
                cells.append(
                    "-"
                    if not b
                    else f"{fmt(b.get('success_share'), '.0%')} / {fmt(b.get('goal_share'), '.0%')} / "
                    f"{fmt(b.get('collisions'), '.0f')} / {fmt(b.get('at_fault_collisions'), '.0f')} "
                    f"({fmt(b.get('scenes'), '.0f')})"
                )
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        dis = [(label, d) for label, a in res.get("agreement", {}).items() for d in a["disagreements"]]
        if dis:
            lines += ["", "Where the referee and jaxplan's verdict disagree:", ""]
            lines += [
                f"- {label} {d['scenario']}: "
                + "; ".join(
                    f"{k} jaxplan {v['jaxplan']} referee {v['referee']}" for k, v in d.items() if k != "scenario"
                )
                for label, d in dis
            ]
    if res.get("by_folder"):
        lines += [
            "",
            "## Per folder (referee)",
            "",
            "Success: a judged drive that reached the goal without a collision and "
            "without leaving the road (count over the folder's scenarios).",
            "",
            "| planner | folder | scenarios | success | goals | collisions | off road | judged |",
            "| --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for label, groups in res["by_folder"].items():
            for g, c in groups.items():
                lines.append(
                    f"| {label} | {g} | {c['scenarios']} | {c['success']} ({fmt(c['success_share'], '.1%')}) | "
                    f"{c['goal_reached']} | {c['collided']} | {c['off_road']} | {c['judged']} |"
                )
    lines += [
        "",
        "Goal share: drives whose state reached the goal (position, time, orientation, speed) at some step, "
        "over all scenarios (no drive = not reached). Collisions, off road: judged drives with a collision / "
        "with the car's box not inside the union of the lanelets (buffered 5 cm: map seams are road). "
        "Plan time: median over scenarios of each drive's "
        "median wall time of one planning call (CPU: process time); shared 2-core machine, rough.",
        "",
    ]
    for label, s in res["summary"].items():
        if s["not_judged"]:
            lines += ["", f"Not judged ({label}, {len(s['not_judged'])}):", ""]
            lines += [f"- {k}: {v}" for k, v in s["not_judged"].items()]
    for label, t in res["timing"].items():
        bad = {
            k: r
            for k, r in t.items()
            if isinstance(r, dict) and (r.get("status") not in (None, "goal", "ok") or r.get("braked_steps"))
        }
        if bad:
            lines += ["", f"Drives where {label} had no plan (the car braked on the fallback), or did not run:", ""]
            lines += [
                f"- {k}: {r['status']}, {r.get('braked_steps', 0)} steps braking, "
                f"{r.get('cycles_without_plan', 0)} of {r.get('cycles', 0)} planning calls without a plan"
                + (f" (first error: {r['first_error']})" if r.get("first_error") else "")
                for k, r in bad.items()
            ]
    if res.get("settings"):
        lines += ["", "## Settings", "", render_settings(res["settings"])]
    lines += [
        "",
        "## Per scenario",
        "",
        "| scenario | v_set (m/s) | " + " | ".join(res["summary"]) + " |",
        "| --- | --- | " + " | ".join("---" for _ in res["summary"]) + " |",
    ]
    by = {label: {r["scenario"]: r for r in rows} for label, rows in res["verdicts"].items()}
    for k, s in res["scenarios"].items():
        cells = []
        for label in res["summary"]:
            r = by[label].get(k, {})
            if "goal_reached" not in r:
                cells.append("no drive" if r.get("missing") else "error")
                continue
            c = f"goal {r['goal_time']:.1f}s" if r["goal_reached"] else "no goal"
            if r["collided"]:
                hit = ",".join(map(str, r["collision_obstacles"])) or "?"
                c += f" · hit {hit} at {r['first_collision_time']:.1f}s"
            if r["off_road"]:
                c += f" · off road {r['first_off_road_time']:.1f}s"
            cells.append(c)
        lines.append(f"| {k} | {fmt(s.get('v_set'), '.1f')} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot_drives(res: dict, folders: dict, out: str) -> list:
    """A bird's-eye plot per scenario: lanes, obstacles at t = 0 (static filled), recorded paths,
    every planner's driven path, where it collided (x) and where it reached the goal (*)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon as Patch

    sys.path.insert(0, ROOT)
    from jaxplan.scenarios.commonroad import load_commonroad
    from jaxplan.scenarios.loader import load_scenario

    by = {label: {r["scenario"]: r for r in rows} for label, rows in res["verdicts"].items()}
    colours = dict(zip(folders, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    written = []
    for key, s in res["scenarios"].items():
        try:
            sc = load_scenario(s["path"]) if s["path"].endswith(".json") else load_commonroad(s["path"])
        except Exception:  # noqa: BLE001 - no plot for a scenario the loader refuses
            continue
        o = np.asarray(sc.origin)
        fig, ax = plt.subplots(figsize=(9, 6))
        for ln in sc.lanes:
            ax.add_patch(Patch(np.vstack([ln.left, ln.right[::-1]]) + o, closed=True, fc="0.93", ec="0.7", lw=0.5))
        boxes, valid, static = (
            np.asarray(sc.obstacles.boxes),
            np.asarray(sc.obstacles.valid),
            np.asarray(sc.obstacles.static),
        )
        for i in range(len(boxes)):
            ok = valid[i]
            if ok.any():
                b = boxes[i, np.argmax(ok)]
                c, sn = math.cos(b[4]), math.sin(b[4])
                corners = (
                    np.array(
                        [
                            [c * u - sn * v, sn * u + c * v]
                            for u, v in (
                                (b[2] / 2, b[3] / 2),
                                (-b[2] / 2, b[3] / 2),
                                (-b[2] / 2, -b[3] / 2),
                                (b[2] / 2, -b[3] / 2),
                            )
                        ]
                    )
                    + b[:2]
                    + o
                )
                ax.add_patch(Patch(corners, closed=True, fc="0.35" if static[i] else "none", ec="0.35", lw=0.8))
                if not static[i]:
                    ax.plot(boxes[i, ok, 0] + o[0], boxes[i, ok, 1] + o[1], color="0.6", lw=0.5)
        lo, hi = np.array([np.inf, np.inf]), -np.array([np.inf, np.inf])
        for label, folder in folders.items():
            f = os.path.join(folder, key, "driven.json")
            if not os.path.exists(f):
                continue
            with open(f) as fh:
                st = np.asarray(json.load(fh)["states"], float)
            v = by.get(label, {}).get(key, {})
            tag = (
                ("goal" if v.get("goal_reached") else "no goal")
                + (", collision" if v.get("collided") else "")
                + (", off road" if v.get("off_road") else "")
            )
            ax.plot(st[:, 1], st[:, 2], color=colours[label], lw=1.8, label=f"{label} ({tag})")
            for when, marker in ((v.get("first_collision_time"), "x"), (v.get("goal_time"), "*")):
                if when is not None:
                    j = int(np.argmin(np.abs(st[:, 0] - when)))
                    ax.plot(st[j, 1], st[j, 2], marker, color=colours[label], ms=11, mew=2)
            lo, hi = np.minimum(lo, st[:, 1:3].min(0)), np.maximum(hi, st[:, 1:3].max(0))
        if np.all(np.isfinite(lo)):
            pad = max(25.0, 0.15 * float(np.max(hi - lo)))
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
        else:
            ax.autoscale()
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{key}: closed-loop drives (set speed {s.get('v_set', float('nan')):.1f} m/s)")
        ax.legend(loc="best", fontsize=8)
        path = os.path.join(out, "plots", key.replace("@", "_at_") + ".png")
        os.makedirs(os.path.dirname(path), exist_ok=True)
        fig.savefig(path, dpi=90, bbox_inches="tight")
        plt.close(fig)
        written.append(path)
    return written
