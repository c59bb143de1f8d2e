"""The peer harness: the command line, the scenario files it drives (``select_files``), their facts
and routes (kept in ``prep.json``), the set speed, the child processes that run each peer in its
own virtual environment (``child``: this repository's ``experiments/compare_peers.py --worker``),
resuming finished drives, and ``main``, which drives, judges and writes the outputs."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from .config import CAR_LENGTH, CAR_WIDTH, DEFAULT_SCENARIOS, ENTRY, PEERS, ROOT, ROUTE_BUILDER, VENVS
from .files import _write_json, _write_json_atomic
from .report import plot_drives, render_report
from .settings import render_settings, settings_table
from .summary import _by_folder, _jaxplan_timing, _summary, agreement, jaxplan_verdicts
from .workers import worker_main


def child(python: str, worker: str, job, tmp: str, timeout: float | None = None):
    """Run ``experiments/compare_peers.py`` as ``worker`` under ``python`` with ``job`` (JSON); its JSON result."""
    fd, out = tempfile.mkstemp(suffix=f".{worker}.json", dir=tmp)
    os.close(fd)
    with open(out + ".in", "w") as f:
        json.dump(job, f)
    cmd = [python, ENTRY, "--worker", worker, "--worker-in", out + ".in", "--worker-out", out]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"{worker} child ran past {timeout:.0f} s") from None
    try:
        with open(out) as f:
            return json.load(f)
    except (OSError, ValueError):
        err = "\n".join(ln for ln in r.stderr.splitlines() if "leaked" not in ln and "nanobind" not in ln)
        raise RuntimeError(f"{worker} child exited {r.returncode}: {err[-800:]}") from None


def _stats(cycles: list) -> dict:
    w = np.array([c["wall_s"] for c in cycles]) * 1e3
    errors = [c["error"] for c in cycles if c.get("error")]
    failed = sum(not c["found"] for c in cycles)
    if not len(w):
        return {"cycles": 0}
    extra = {"cycles_without_plan": int(failed), **({"first_error": errors[0][:200]} if errors else {})}
    cpu = np.array([c["cpu_s"] for c in cycles]) * 1e3
    return {
        "cycles": int(len(w)),
        "plan_ms_median": float(np.median(w)),
        "plan_ms_mean": float(w.mean()),
        "plan_ms_p90": float(np.percentile(w, 90)),
        "cpu_ms_median": float(np.median(cpu)),
        **extra,
    }


def select_files(paths: list, sample: int | None, seed: int) -> list:
    """The scenario files to drive: ``paths`` expanded (folders recursively, sorted), then, with
    ``sample``, ``jaxplan.scenarios.files.sample_files`` of them (seeded, stratified by folder)."""
    sys.path.insert(0, ROOT)
    from jaxplan.scenarios.files import expand_paths, sample_files

    try:
        files = [os.path.abspath(f) for f in expand_paths(paths)]
    except ValueError as e:
        sys.exit(f"--scenarios: {e}")
    if sample is not None:
        files = sample_files(files, sample, seed)
    return files


def _prep_cached(referee_py: str, files: list, out: str, tmp: str) -> dict:
    """``prep_worker`` over ``files``, kept in ``<out>/prep.json`` and reused while the file list is
    the same (a resumed run does not read every scenario again)."""
    cache = os.path.join(out, "prep.json")
    if os.path.exists(cache):
        try:
            with open(cache) as f:
                c = json.load(f)
            if c.get("files") == files and c.get("route_builder") == ROUTE_BUILDER:
                return c["info"]
        except (OSError, ValueError):
            pass
    info = child(referee_py, "prep", {"paths": files, "out": out}, tmp)
    _write_json_atomic(cache, {"files": files, "route_builder": ROUTE_BUILDER, "info": info})
    return info


def _finished(out: str, peer: str, key: str) -> dict | None:
    """The timing row of a drive already finished in ``out`` (its ``cycles.json``), else None."""
    f = os.path.join(out, peer, key, "cycles.json")
    try:
        with open(f) as fh:
            c = json.load(fh)
    except (OSError, ValueError):
        return None
    return {
        "status": c["status"],
        "braked_steps": c.get("braked_steps", 0),
        **_stats(c["cycles"]),
        **({"drive_wall_s": c["drive_wall_s"]} if "drive_wall_s" in c else {}),
    }


def set_speed(facts: dict, route) -> tuple[float, str]:
    """The set speed every planner gets (see ``experiments/compare_peers.py``'s docstring) and where it came from."""
    gv = facts.get("goal_velocity")
    if gv is not None:
        v = 0.5 * (gv[0] + gv[1])
        if facts.get("speed_limit") is not None:
            v = min(v, facts["speed_limit"])
        return float(v), "goal speed interval"
    if facts.get("speed_limit") is not None:
        return float(facts["speed_limit"]), "speed limit"
    gs, centre = facts.get("goal_steps"), facts.get("goal_centre")
    if gs is not None and centre is not None and route is not None and len(route) > 1:
        r = np.asarray(route, float)
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))])
        s_goal = s[int(np.argmin(np.linalg.norm(r - np.asarray(centre), axis=1)))]
        s_start = s[int(np.argmin(np.linalg.norm(r - np.asarray(facts["start"]), axis=1)))]
        t_mid = 0.5 * (gs[0] + gs[1]) * facts["dt"] - facts["t0_step"] * facts["dt"]
        if t_mid > 0 and s_goal > s_start:
            return float(np.clip((s_goal - s_start) / t_mid, 2.0, 36.0)), "route distance to goal / goal time"
    return float(facts["v0"]), "start speed (no speed limit or goal given)"


def _python_ok(p: str, what: str) -> str:
    if not os.path.exists(p):
        sys.exit(f"{p} not found: the {what} runs there; see the setup in this script's docstring")
    return p


def main(argv=None, description: str | None = None) -> dict:
    """The command line (``description``: its help's first line); ``--worker`` runs one child job."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument(
        "--scenarios",
        nargs="+",
        default=DEFAULT_SCENARIOS,
        help="scenario files (.json, .xml, either .gz) or folders of them (searched recursively)",
    )
    ap.add_argument(
        "--sample",
        type=int,
        metavar="N",
        help="drive a seeded sample of N of the files, stratified by folder (written to sample.json)",
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of --sample (default 0)")
    ap.add_argument(
        "--redo",
        action="store_true",
        help="drive again the scenes a peer has already finished in --out (default: skip them)",
    )
    ap.add_argument("--out", default="results/peers")
    ap.add_argument("--peers", nargs="*", default=list(PEERS), choices=PEERS)
    ap.add_argument("--reactive-python", default=VENVS["reactive"])
    ap.add_argument("--frenetix-python", default=VENVS["frenetix"])
    ap.add_argument(
        "--referee-python",
        default=None,
        help=f"interpreter with jaxplan and jaxplan[referee] (default {VENVS['referee']} where it exists, "
        "else this interpreter)",
    )
    ap.add_argument("--routes", help="routes JSON {routes: {key: [[x, y], ...]}} (default: build them)")
    ap.add_argument("--drives", nargs="*", default=[], metavar="LABEL=DIR", help="more drive folders to judge")
    ap.add_argument(
        "--jaxplan",
        nargs="*",
        default=[],
        metavar="PLANNER",
        help="run `jaxplan drive --planner PLANNER` first (this interpreter) and judge it too",
    )
    ap.add_argument("--judge-only", action="store_true", help="drive nothing; judge the folders already there")
    ap.add_argument("--only", nargs="*", help="scenario keys to run (default all)")
    ap.add_argument("--replan", type=int, default=3, help="re-plan every this many 0.1 s steps")
    ap.add_argument("--max-steps", type=int, default=300, help="step cap of a drive")
    ap.add_argument("--reactive-horizon-steps", type=int, default=20)
    ap.add_argument("--reactive-t-min", type=float, default=1.0)
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per peer drive")
    ap.add_argument("--worker", choices=("prep", "route", "reactive", "frenetix", "judge"), help=argparse.SUPPRESS)
    ap.add_argument("--worker-in", help=argparse.SUPPRESS)
    ap.add_argument("--worker-out", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker_main(args)
    drives = {}
    for d in args.drives:
        if "=" not in d:
            sys.exit(f"--drives {d}: expected LABEL=DIR")
        label, folder = d.split("=", 1)
        if not os.path.isdir(folder):
            sys.exit(f"--drives {d}: {folder} is not a folder")
        drives[label] = folder
    if args.sample is not None and args.sample < 1:
        sys.exit(f"--sample {args.sample}: expected a sample size >= 1")
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix="compare_peers_")
    if args.referee_python is None:
        args.referee_python = VENVS["referee"] if os.path.exists(VENVS["referee"]) else sys.executable
    referee_py = _python_ok(args.referee_python, "referee (jaxplan + jaxplan[referee])")

    t_start = time.time()
    files = select_files(args.scenarios, args.sample, args.seed)
    info = _prep_cached(referee_py, files, out, tmp)
    if args.only:
        unknown = sorted(set(args.only) - set(info))
        if unknown:
            sys.exit(f"--only: no scenario {', '.join(unknown)} among the {len(info)} selected")
    keys = [k for k in info if not args.only or k in args.only]
    _write_json(
        os.path.join(out, "sample.json"),
        {
            "scenarios": [os.path.abspath(p) for p in args.scenarios],
            "sample": args.sample,
            "seed": args.seed if args.sample is not None else None,
            "n_files": len(files),
            "files": files,
            "keys": {k: info[k]["path"] for k in info},
            "drive_with": f"jaxplan drive $(cat {out}/sample.txt) --planner NAME --out DIR "
            f"--replan-every {args.replan} --max-steps {args.max_steps}",
        },
    )
    with open(os.path.join(out, "sample.txt"), "w") as f:
        f.write("".join(p + "\n" for p in files))
    print(f"{len(keys)} scenarios (file list: {out}/sample.json, sample.txt)", flush=True)
    folders0 = list(args.peers) + list(drives) + [f"jaxplan-{n}" for n in args.jaxplan]
    print(render_settings(settings_table(args, folders0)), flush=True)

    if args.routes:
        with open(args.routes) as f:
            given = json.load(f)["routes"]
        routes = {k: {"route": given[k]} if k in given else {"error": f"no route in {args.routes}"} for k in keys}
        source = args.routes
    elif ROUTE_BUILDER:
        routes = {
            k: {"route": info[k]["route"]}
            if "route" in info[k]
            else {"error": info[k].get("route_error", info[k].get("error"))}
            for k in keys
        }
        source = ROUTE_BUILDER
    else:
        xmls = {k: info[k]["xml"] for k in keys if "xml" in info[k]}
        routes = child(_python_ok(args.reactive_python, "route planner"), "route", {"xmls": xmls}, tmp)
        source = "commonroad-route-planner (shortest reference path)"
    _write_json(
        os.path.join(out, "routes.json"),
        {"source": source, "routes": {k: r["route"] for k, r in routes.items() if "route" in r}},
    )
    scen = {}
    for k in keys:
        f = info[k]
        row = {"path": f["path"], "xml": f.get("xml")}
        notes = [n for n in (f.get("error"), routes.get(k, {}).get("error")) if n]
        if "error" not in f:
            v, why = set_speed(f, routes.get(k, {}).get("route"))
            end = f["goal_steps"][1] if f["goal_steps"] else f["t0_step"] + args.max_steps
            row.update(
                v_set=v,
                v_set_from=why,
                steps=int(max(1, min(args.max_steps, end - f["t0_step"]))),
                **{n: f[n] for n in ("goal_steps", "goal_velocity", "speed_limit", "v0")},
            )
        row["notes"] = notes
        row["route_from"] = routes.get(k, {}).get("route_from", source)
        scen[k] = row
    _write_json(os.path.join(out, "scenarios.json"), scen)

    timing = {}
    if not args.judge_only:
        pythons = {"reactive": args.reactive_python, "frenetix": args.frenetix_python}
        for peer in args.peers:
            py = _python_ok(pythons[peer], peer)
            timing[peer] = {}
            done = 0
            for k in keys:
                s = scen[k]
                if s["notes"]:
                    timing[peer][k] = {"status": "not run: " + "; ".join(s["notes"])}
                    continue
                prev = _finished(out, peer, k)
                if prev is not None and not args.redo:  # resume: this scene is driven already
                    timing[peer][k] = prev
                    done += 1
                    continue
                job = {
                    "xml": s["xml"],
                    "route": routes[k]["route"],
                    "v_set": s["v_set"],
                    "steps": s["steps"],
                    "v0": s["v0"],
                    "replan": args.replan,
                    "horizon_steps": args.reactive_horizon_steps,
                    "t_min": args.reactive_t_min,
                }
                t0 = time.time()
                try:
                    res = child(py, peer, job, tmp, args.timeout)
                except RuntimeError as e:
                    res = {"status": f"peer process failed: {e}", "cycles": [], "rows": []}
                driven = os.path.join(out, peer, k, "driven.json")
                if res["rows"]:
                    _write_json_atomic(
                        driven,
                        {
                            "scenario": k,
                            "planner": peer,
                            "dt": info[k]["dt"],
                            "vehicle": {"length": CAR_LENGTH, "width": CAR_WIDTH},
                            "states": res["rows"],
                        },
                    )
                elif os.path.exists(driven):  # --redo: no stale drive from an earlier run
                    os.remove(driven)
                braked = int(res.get("braked_steps", 0))
                # written last: a scene with cycles.json is finished (resume skips it)
                _write_json_atomic(
                    os.path.join(out, peer, k, "cycles.json"),
                    {
                        "status": res["status"],
                        "cycles": res["cycles"],
                        "braked_steps": braked,
                        "drive_wall_s": round(time.time() - t0, 3),
                    },
                )
                timing[peer][k] = {
                    "status": res["status"],
                    "braked_steps": braked,
                    **_stats(res["cycles"]),
                    "drive_wall_s": round(time.time() - t0, 3),
                }
                print(
                    f"{peer:9s} {k:40s} {res['status'][:60]:60s} {len(res['rows']):4d} rows "
                    f"{timing[peer][k].get('plan_ms_median', float('nan')):8.1f} ms/cycle ({time.time() - t0:.0f} s)",
                    flush=True,
                )
            if done:
                print(
                    f"{peer}: {done} scenes already driven in {out}/{peer} (kept; --redo drives them again)", flush=True
                )
        for name in args.jaxplan:
            folder = os.path.join(out, f"jaxplan-{name}")
            cmd = [
                sys.executable,
                "-m",
                "jaxplan",
                "drive",
                *files,
                "--planner",
                name,
                "--out",
                folder,
                "--replan-every",
                str(args.replan),
                "--max-steps",
                str(args.max_steps),
            ]
            print("running", " ".join(cmd[:4]), f"({len(files)} files)", " ".join(cmd[4 + len(files) :]), flush=True)
            r = subprocess.run(cmd, cwd=ROOT)
            if r.returncode != 0:
                sys.exit(f"jaxplan drive --planner {name} exited {r.returncode}")
            drives[f"jaxplan-{name}"] = folder
    else:
        for peer in args.peers:
            for k in keys:
                prev = _finished(out, peer, k)
                if scen[k]["notes"]:
                    timing.setdefault(peer, {})[k] = {"status": "not run: " + "; ".join(scen[k]["notes"])}
                elif prev is not None:
                    timing.setdefault(peer, {})[k] = prev
                else:
                    timing.setdefault(peer, {})[k] = {"status": "not driven yet (no cycles.json in the output)"}
    folders = {p: os.path.join(out, p) for p in args.peers}
    folders.update(drives)
    verdicts = child(referee_py, "judge", {"folders": folders, "scenarios": {k: info[k]["path"] for k in keys}}, tmp)
    for label, folder in drives.items():  # jaxplan's own plan time per cycle, where its metrics say it
        timing[label] = _jaxplan_timing(folder, label)
    own = jaxplan_verdicts(folders, {k: info[k]["path"] for k in keys}, args.max_steps)
    result = {
        "scenarios": scen,
        "route_source": source,
        "verdicts": verdicts["drives"],
        "summary": _summary(verdicts, timing, scen),
        "by_folder": _by_folder(verdicts, scen),
        "verdict": {label: {k: v for k, v in o.items() if k != "rows"} for label, o in own.items()},
        "verdict_rows": {label: o["rows"] for label, o in own.items()},
        "agreement": agreement(verdicts["drives"], own),
        "settings": settings_table(args, list(folders)),
        "timing": timing,
        "args": vars(args),
        "cpu_count": os.cpu_count(),
        "wall_s": time.time() - t_start,
        "drive_wall_s": {
            p: round(sum(r.get("drive_wall_s", 0.0) for r in timing.get(p, {}).values() if isinstance(r, dict)), 1)
            for p in args.peers
        },
    }
    _write_json(os.path.join(out, "compare_peers.json"), result)
    try:
        plots = plot_drives(result, folders, out)
        print(f"{len(plots)} plots in {out}/plots")
    except ImportError as e:  # the plots need jaxplan's loader and matplotlib (this interpreter)
        print(f"no plots: {e}")
    report = render_report(result)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write(report)
    print(report)
    print(f"wrote {out}/compare_peers.json and {out}/report.md")
    return result
