"""The verdicts summed up: counts per planner and per scenario folder, jaxplan's own verdict on every
folder (``jaxplan.sim.drive.judge_drives``), where it and the referee agree, and the plan time per
cycle (the peers' ``cycles.json``, jaxplan's ``metrics.json``)."""

from __future__ import annotations

import json
import os
import sys

import numpy as np

from .config import DT, ROOT


def _folder_of(scen_row: dict) -> str:
    return os.path.basename(os.path.dirname(scen_row["path"]))


def _by_folder(verdicts: dict, scen: dict) -> dict:
    """Each planner's counts per scenario folder (``hand-crafted``, ``sumo``, ...)."""
    out: dict = {}
    for label, rows in verdicts["drives"].items():
        groups: dict = {}
        for r in rows:
            groups.setdefault(_folder_of(scen[r["scenario"]]), []).append(r)
        out[label] = {g: _counts(rs) for g, rs in sorted(groups.items())}
    return out


def _counts(rows: list) -> dict:
    """Counts as ``jaxplan.eval.referee.summarize`` gives them, plus ``success``: a judged drive
    that reached the goal with no collision and without leaving the road."""
    judged = [r for r in rows if "goal_reached" in r]
    c = lambda k: sum(bool(r[k]) for r in judged)  # noqa: E731
    ok = sum(r["goal_reached"] and not r["collided"] and not r["off_road"] for r in judged)
    return {
        "scenarios": len(rows),
        "judged": len(judged),
        "success": ok,
        "goal_reached": c("goal_reached"),
        "collided": c("collided"),
        "off_road": c("off_road"),
        "success_share": ok / len(rows) if rows else None,
    }


def jaxplan_verdicts(folders: dict, paths: dict, max_steps: int) -> dict:
    """Every folder's drives judged by jaxplan's verdict (``jaxplan.sim.drive.judge_drives``: the
    metrics and the success rule ``jaxplan drive`` uses), the same code for every planner:
    ``{label: {"rows", "summary", "by_folder", "by_location", "missing"}}``."""
    sys.path.insert(0, ROOT)
    import dataclasses

    from jaxplan.scenarios.cache import load_many
    from jaxplan.sim.drive import judge_drives, summarize, summarize_by

    keys = list(paths)
    loaded = load_many([paths[k] for k in keys], progress=False)
    by_path = {r.path: r for r in loaded.records}
    records = [dataclasses.replace(by_path[paths[k]], name=k) for k in keys if paths[k] in by_path]
    out = {}
    for label, folder in folders.items():
        driven = {}
        for k in keys:
            f = os.path.join(folder, k, "driven.json")
            if os.path.exists(f):
                with open(f) as fh:
                    driven[k] = json.load(fh)
        rows = judge_drives(records, driven, label, max_steps)
        out[label] = {
            "rows": rows,
            "summary": summarize(rows),
            "by_folder": summarize_by(rows, "folder"),
            "by_location": summarize_by(rows, "location"),
            "missing": [k for k in keys if k not in driven],
        }
    return out


def agreement(referee_rows: dict, own: dict) -> dict:
    """Per planner: the drives on which the referee and jaxplan's verdict agree on collision (and its
    time), off road (and its time) and goal (and its time), and the disagreements."""
    out = {}
    for label, rows in referee_rows.items():
        mine = {r["scenario"]: r for r in own.get(label, {}).get("rows", [])}
        agree, differ = 0, []
        for v in rows:
            r = mine.get(v["scenario"])
            if r is None or "goal_reached" not in v:
                continue
            t = lambda key, ok: round(r[key] * DT, 6) if ok and r[key] is not None else None  # noqa: E731
            ours = {
                "collided": (bool(r["overlap.collided"]), t("overlap.first_step", r["overlap.collided"])),
                "off_road": (bool(r["offroad.offroad"]), t("offroad.first_step", r["offroad.offroad"])),
                "goal_reached": (bool(r["goal.reached"]), t("goal.step", r["goal.reached"])),
            }
            theirs = {
                "collided": (bool(v["collided"]), v["first_collision_time"]),
                "off_road": (bool(v["off_road"]), v["first_off_road_time"]),
                "goal_reached": (bool(v["goal_reached"]), v["goal_time"]),
            }
            diff = {k: {"jaxplan": ours[k], "referee": theirs[k]} for k in ours if ours[k] != theirs[k]}
            if diff:
                differ.append({"scenario": v["scenario"], **diff})
            else:
                agree += 1
        out[label] = {"agree": agree, "judged": agree + len(differ), "disagreements": differ}
    return out


def _jaxplan_timing(folder: str, label: str) -> dict:
    """Plan time per cycle from ``jaxplan drive``'s ``metrics.json`` (``drive.<planner>.plan_ms_median``)."""
    f = os.path.join(folder, "metrics.json")
    if not os.path.exists(f):
        return {}
    with open(f) as fh:
        m = json.load(fh)
    flat, todo = {}, [("", m)]
    while todo:  # flat ("drive.lattice.plan_ms_median": ...) or nested metrics alike
        pre, d = todo.pop()
        for k, v in d.items() if isinstance(d, dict) else ():
            (todo.append((f"{pre}{k}.", v)) if isinstance(v, dict) else flat.__setitem__(f"{pre}{k}", v))
    vals = {k: v for k, v in flat.items() if k.endswith("plan_ms_median") and isinstance(v, (int, float))}
    return {"_all": {"plan_ms_median": next(iter(vals.values()))}} if vals else {}


def _summary(verdicts: dict, timing: dict, scen: dict) -> dict:
    out = {}
    for label, s in verdicts["summary"].items():
        t = timing.get(label, {})
        if "_all" in t:
            ms, cpu = t["_all"].get("plan_ms_median"), None
        else:
            ms, cpu = _median_over_cycles(t), _median_over_cycles(t, "cpu_ms_median")
        rows = verdicts["drives"][label]
        failed = {
            r["scenario"]: r.get("error") or timing.get(label, {}).get(r["scenario"], {}).get("status", "no drive")
            for r in rows
            if "goal_reached" not in r
        }
        out[label] = {
            **s,
            "success": _counts(rows)["success"],
            "plan_ms_median": ms,
            "cpu_ms_median": cpu,
            "not_judged": failed,
        }
    return out


def _median_over_cycles(t: dict, key: str = "plan_ms_median"):
    """Median over scenarios of each drive's median time per planning cycle."""
    v = [r[key] for r in t.values() if isinstance(r, dict) and r.get(key) is not None]
    return float(np.median(v)) if v else None
