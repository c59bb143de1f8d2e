"""Write ``docs/benchmarks.md`` (and the JSON it is made of) from benchmark outputs.

Reads what the runs wrote and nothing else:

- ``--dev DIR [DIR ...]``: ``jaxplan drive`` folders over the development set (``metrics.json``: every
  planner's summary, per-folder and per-location tables, the timing split; ``rows.jsonl``: the
  drives, split into the location split's train and validation parts, ``files.split_of``); several
  folders are runs of the same scenes and settings with different planners (each planner from one
  run), e.g. one planner's new version beside a run of the others at the same code;
- ``--sample DIR``: a ``jaxplan drive`` folder of every planner on a seeded sample of it;
- ``--combo LABEL=DIR``: more ``jaxplan drive`` folders of the same scenes with other
  ``--agents`` / ``--prediction`` settings (their ``metrics.json``);
- ``--peers DIR``: ``experiments/compare_peers.py``'s output (``compare_peers.json``: the peers and
  jaxplan's planners on the same sample, judged by jaxplan's verdict and by the referee);
- ``--bench FILE``: ``experiments/bench_drive.py``'s JSON (cold, warm and single-file timings);
- ``--keep SECTION ...``: sections of the existing ``--json`` carried over as they are, where their
  runs' folders are gone (``peers``, ``combos``, ``sample``, ``bench``);
- ``--brake DIR``: a ``jaxplan drive --planner brake`` folder over the ``--dev`` scenes: the scenes
  where braking in lane from t = 0 touches nothing, and every ``--dev`` planner's collisions there.

Writes ``--json`` (the figures the page shows, so the page can be made again) and ``--out``.

Usage::

    python experiments/benchmarks_page.py --dev R/dev-all --combo idm+cv=R/dev-idm-cv ... \\
        --peers R/peers200 --bench R/bench_drive.json --json docs/benchmarks.json --out docs/benchmarks.md
"""
from __future__ import annotations

import argparse
import json
import os

COLS = (("success", "success_share", "{:.1%}"), ("goal", "goal_share", "{:.1%}"),
        ("collisions", "collisions", "{:.0f}"), ("at fault", "at_fault_collisions", "{:.0f}"),
        ("off road", "offroad_share", "{:.1%}"), ("red lights run", "red_light_crossings", "{:.0f}"),
        ("goal off map", "goal_off_map", "{:.0f}"))


def _fmt(fmt, v):
    return "-" if v is None else fmt.format(v)


def _table(rows: dict, label: str, cols=COLS) -> list:
    head = [label, "drives"] + [c for c, _, _ in cols]
    out = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for name, s in rows.items():
        out.append("| " + " | ".join([str(name), _fmt("{:.0f}", s.get("scenes"))] +
                                     [_fmt(f, s.get(k)) for _, k, f in cols]) + " |")
    return out


def _load(path: str) -> dict:
    if not os.path.isfile(path):
        raise SystemExit(f"benchmarks_page: {path} not found (give the folder a run wrote)")
    with open(path) as f:
        return json.load(f)


def _drive_summary(folder: str) -> dict:
    """A run's settings, timing and tables. Its CommonRoad scenes and its built-in ones (``--builtin``)
    are summed apart (``summary``, ``builtin``): the development set's figures are its files'."""
    m = _load(os.path.join(folder, "metrics.json"))
    planners = m["run"]["planners"]
    rows = _rows(folder)
    files = [r for r in rows if r.get("folder") != BUILTIN]
    built = [r for r in rows if r.get("folder") == BUILTIN]
    if built:
        summary = _summary_of(files)
    else:  # the run's own summary (it holds the timing-free figures of every drive)
        summary = {p: {k[len(f"drive.{p}."):]: v for k, v in m.items() if k.startswith(f"drive.{p}.")} for p in planners}
    return {"planners": planners, "summary": summary, "builtin": _summary_of(built),
            "by_folder": m.get("by_folder", {}), "by_location": m.get("by_location", {}), "timing": m.get("timing", {}),
            "settings": {k: m["run"].get(k) for k in ("agents", "prediction", "n_steps", "replan_every", "tracking")},
            "scenes": len({r["scenario"] for r in files}) if built else len(m["run"].get("scenarios", []))}


def _dev_summary(folders: list) -> dict:
    """``_drive_summary`` of the runs in ``folders`` merged: the same scenes and settings in each,
    every planner from one run; ``runs`` names each run's planners and timing."""
    parts = [_drive_summary(f) for f in folders]
    runs = [{"folder": os.path.basename(os.path.normpath(f)), "planners": list(p["planners"]), "timing": p["timing"]}
            for f, p in zip(folders, parts)]
    out = {**parts[0], "runs": runs}  # the first run's summary, extended in place by the others'
    for f, p in zip(folders[1:], parts[1:]):
        if p["settings"] != out["settings"] or p["scenes"] != out["scenes"]:
            raise SystemExit(f"benchmarks_page: --dev {f} drove other scenes or settings than {folders[0]}")
        twice = set(p["planners"]) & set(out["planners"])
        if twice:
            raise SystemExit(f"benchmarks_page: --dev {f}: planner {sorted(twice)[0]} is in an earlier --dev run too")
        out["planners"] = out["planners"] + p["planners"]
        for k in ("summary", "builtin", "by_folder", "by_location"):
            out[k].update(p[k])
    if len(parts) > 1:
        out["timing"] = {}
    return out


def _merged(fn, items: list) -> dict:
    """``fn(item)`` (``{planner: ...}``) of each of ``items`` (run folders, their summaries), merged."""
    out: dict = {}
    for item in items:
        out.update(fn(item))
    return out


def _rows(folder: str) -> list:
    path = os.path.join(folder, "rows.jsonl")
    if not os.path.isfile(path):
        raise SystemExit(f"benchmarks_page: {path} not found (give the folder a run wrote)")
    with open(path) as f:
        return [json.loads(line) for line in f]


BUILTIN = "builtin"  # the folder name of the built-in scenes' rows


def _summary_of(rows: list) -> dict:
    """``{planner: summary}`` of drive rows (the keys of a run's own ``drive.PLANNER.*`` figures)."""
    groups: dict = {}
    for r in rows:
        groups.setdefault(r["planner"], []).append(r)
    out: dict = {}
    for p, rs in groups.items():
        n = len(rs)
        out[p] = {
            "scenes": n, "success_share": sum(r["success"] for r in rs) / n,
            "goal_share": sum(r["goal.reached"] for r in rs) / n,
            "collisions": sum(r["overlap.collided"] for r in rs),
            "at_fault_collisions": sum(r["overlap.at_fault"] for r in rs),
            "offroad_share": sum(r["offroad.offroad"] for r in rs) / n,
            "red_light_crossings": sum(r["redlight.crossings"] for r in rs),
            "goal_off_map": sum(r["goal.off_map"] for r in rs)}
    return out


def _split_summary(folder: str) -> dict:
    """``{planner: {split: summary}}`` of a run's drives of scenario files over the location split
    (``files.split_of``; the built-in scenes are not part of it)."""
    import sys

    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from jaxplan.scenarios.files import split_of

    splits: dict = {}
    for r in _rows(folder):
        if r.get("folder") != BUILTIN:
            splits.setdefault(split_of(r["location"]), []).append(r)
    out: dict = {}
    for name, rs in sorted(splits.items()):
        for p, summary in _summary_of(rs).items():
            out.setdefault(p, {})[name] = summary
    return out


def _brake_survivable(dev: str, brake: str) -> dict:
    """The scenes of ``brake``'s drives without a collision, and per planner of ``dev`` its drives,
    successes, collisions and at-fault collisions on them."""
    braked = [r for r in _rows(brake) if r["planner"] == "brake" and r.get("folder") != BUILTIN]
    safe = {r["scenario"] for r in braked if not r["overlap.collided"]}
    out: dict = {"brake_drives": len(braked), "survivable": len(safe), "planners": {}}
    for r in _rows(dev):
        if r["scenario"] in safe:
            p = out["planners"].setdefault(r["planner"], {"scenes": 0, "success": 0, "collisions": 0, "at_fault": 0,
                                                          "at_fault_scenarios": []})
            p["scenes"] += 1
            p["success"] += bool(r["success"])
            p["collisions"] += bool(r["overlap.collided"])
            if r["overlap.at_fault"]:
                p["at_fault"] += 1
                p["at_fault_scenarios"].append(r["scenario"])
    return out


def collect(args) -> dict:
    out: dict = {}
    if args.dev:
        out["dev"] = _dev_summary(args.dev)
        out["dev"]["by_split"] = _merged(_split_summary, args.dev)
        if args.brake:
            parts = [_brake_survivable(f, args.brake) for f in args.dev]
            out["dev"]["brake_survivable"] = {**parts[0], "planners": _merged(lambda b: b["planners"], parts)}
    if args.sample:
        out["sample"] = _drive_summary(args.sample)
        out["sample"]["caveat"] = args.sample_caveat
    out["combos"] = {}
    for item in args.combo or []:
        label, folder = item.split("=", 1)
        out["combos"][label] = _drive_summary(folder)
    if args.peers:
        p = _load(os.path.join(args.peers, "compare_peers.json"))
        out["peers"] = {"verdict": p.get("verdict", {}), "agreement": {
            k: {"agree": v["agree"], "judged": v["judged"], "disagreements": v["disagreements"]}
            for k, v in p.get("agreement", {}).items()}, "settings": p.get("settings", {}),
            "scenarios": len(p.get("scenarios", {})), "caveat": args.peers_caveat}
    if args.bench:
        out["bench"] = _load(args.bench)
    return out


def render(d: dict) -> str:
    lines = ["# Benchmarks", "",
             "Every figure below is a closed-loop drive judged by one verdict (`jaxplan.sim.verdict`): "
             "**success** = the goal reached by CommonRoad's rule, no collision at any step, never off road; "
             "**at fault** = some obstacle's first contact was not a moving obstacle hitting the car squarely "
             "from behind. This page is written by `experiments/benchmarks_page.py` from the runs' own JSON "
             "(`docs/benchmarks.json`).", ""]
    dev = d.get("dev")
    if dev:
        s = dev["settings"]
        lines += ["## The development set", "",
                  f"{dev['scenes']} CommonRoad 2020a scenarios (`../shared/data/commonroad`), recorded traffic replayed "
                  f"(`--agents {s.get('agents')}`), planners see the recorded future (`--prediction "
                  f"{s.get('prediction')}`), re-plan every {s.get('replan_every')} steps, {s.get('tracking')} tracking, "
                  f"each scene to the end of its goal's window, at most {s.get('n_steps')} steps.", ""]
        lines += _table(dev["summary"], "planner") + [""]
        if dev.get("builtin"):
            n_b = max(v["scenes"] for v in dev["builtin"].values())
            whose = "runs'" if len(dev.get("runs", [])) > 1 else "run's"
            lines += [f"The same {whose} {n_b} built-in scenes (`--builtin --quick`: synthetic scenes that braking "
                      "survives):", ""] + _table(dev["builtin"], "planner") + [""]
        for p in dev["planners"]:
            lines += [f"Per folder, `{p}`:", ""] + _table(dev["by_folder"].get(p, {}), "folder") + [""]
            if dev.get("by_location", {}).get(p):
                lines += [f"<details><summary>Per location, <code>{p}</code></summary>", ""]
                lines += _table(dev["by_location"][p], "location") + ["", "</details>", ""]
            if dev.get("by_split", {}).get(p):
                lines += [f"Per part of the location split (`jaxplan.scenarios.files.split_of`: whole locations held "
                          f"out as validation by a salted hash of the location's name), `{p}`:", ""]
                lines += _table(dev["by_split"][p], "part") + [""]
        bs = dev.get("brake_survivable")
        if bs:
            lines += [f"Scenes where braking in lane from t = 0 (`--planner brake`, the same settings) touches nothing: "
                      f"{bs['survivable']} of {bs['brake_drives']} (in the others the recorded traffic, which does not "
                      "react, runs into a braking car). Each planner's drives on those scenes:", "",
                      "| planner | scenes | success | collisions | at fault | at fault in |", "| --- | --- | --- | --- | --- | --- |"]
            lines += [f"| {p} | {v['scenes']} | {v['success'] / max(v['scenes'], 1):.1%} | {v['collisions']} | "
                      f"{v['at_fault']} | {', '.join(v['at_fault_scenarios']) or '-'} |" for p, v in bs["planners"].items()]
            lines.append("")
        if len(dev.get("runs", [])) > 1:
            lines += ["These figures come from " + str(len(dev["runs"])) + " runs of the same scenes and settings: " +
                      "; ".join(f"{', '.join(r['planners'])} (run `{r['folder']}`, wall time "
                                f"{r['timing'].get('wall_s', 0):.0f} s)" for r in dev["runs"]) + ".", ""]
        t = dev.get("timing", {})
        if t and t.get("drives"):
            lines += [f"Wall time of that run ({', '.join(dev['planners'])}, one after another): {t.get('wall_s', 0):.0f} s "
                      f"(parsing {t.get('parse_s', 0):.0f}, compiling {t.get('compile_s', 0):.0f}, driving "
                      f"{t.get('drive_s', 0):.0f}, metrics {t.get('metrics_s', 0):.0f}, writing {t.get('write_s', 0):.0f}).",
                      ""]
    sample = d.get("sample")
    if sample:
        s = sample["settings"]
        lines += ["## Every planner on a seeded sample", "",
                  f"{sample['scenes']} scenarios sampled from the development set (`--sample {sample['scenes']} --seed 0`, "
                  f"stratified by folder), the same settings.", ""]
        if sample.get("caveat"):
            lines += [sample["caveat"], ""]
        lines += _table(sample["summary"], "planner") + [""]
        t = sample.get("timing", {})
        if t and t.get("drives"):
            lines += [f"Wall time of that run ({', '.join(sample['planners'])}): {t.get('wall_s', 0):.0f} s (parsing "
                      f"{t.get('parse_s', 0):.0f}, compiling {t.get('compile_s', 0):.0f}, driving {t.get('drive_s', 0):.0f}, "
                      f"metrics {t.get('metrics_s', 0):.0f}, writing {t.get('write_s', 0):.0f}).", ""]
    if d.get("combos"):
        rows = {}
        # the run over the same scenes as the combos (the sample's or the development set's)
        n = {c["scenes"] for c in d["combos"].values()}
        base = next((r for r in (sample, dev) if r and {r["scenes"]} == n), None)
        if base and "lattice" in base["summary"]:
            s = base["settings"]
            rows[f"{s.get('agents')} + {s.get('prediction')}"] = base["summary"]["lattice"]
        for label, c in d.get("combos", {}).items():
            if "lattice" in c["summary"]:
                rows[label] = c["summary"]["lattice"]
        if base and len(rows) > 1:
            lines += ["## The lattice with reactive traffic and without the recorded future", "",
                      f"The same {base['scenes']} scenes in each row.", "",
                      "`--agents log` replays the recording (traffic drives through the car); `--agents idm` moves every "
                      "vehicle along its recorded path with an IDM gap to what is ahead, the car included. `--prediction "
                      "oracle` shows planners the recorded future (CommonRoad's convention); `--prediction cv` only the "
                      "present, extrapolated at constant speed along each obstacle's lane.", ""]
            lines += _table(rows, "agents + prediction") + [""]
    peers = d.get("peers")
    if peers and peers.get("verdict"):
        lines += ["## Peers on a seeded sample", "",
                  f"{peers['scenarios']} scenarios sampled from the development set (seed 0, stratified by folder); "
                  "the CommonRoad reactive planner and Frenetix drive in jaxplan's harness (same route, re-plan period, "
                  "tracking, step cap, vehicle; the settings that differ are listed in the peers' report), and every "
                  "planner's drives are judged by the same verdict code.", ""]
        if peers.get("caveat"):
            lines += [peers["caveat"], ""]
        rows = {k: v["summary"] for k, v in peers["verdict"].items()}
        lines += _table(rows, "planner") + [""]
        ag = peers.get("agreement", {})
        if ag:
            lines += ["The independent referee (commonroad-drivability-checker's collision and road checks, "
                      "commonroad-io's goal check) against jaxplan's verdict, drive by drive (collision and its time, off "
                      "road and its time, goal and its time):", "", "| planner | agree | drives |", "| --- | --- | --- |"]
            lines += [f"| {k} | {v['agree']} | {v['judged']} |" for k, v in ag.items()]
            dis = [(k, x) for k, v in ag.items() for x in v["disagreements"]]
            if dis:
                lines += ["", "Disagreements:", ""] + [f"- {k} {x['scenario']}: " + "; ".join(
                    f"{f} jaxplan {v['jaxplan']} referee {v['referee']}" for f, v in x.items() if f != "scenario")
                    for k, x in dis]
            lines.append("")
    b = d.get("bench")
    if b:
        lines += ["## Time to drive the development set", "",
                  f"`experiments/bench_drive.py`, planner `{b.get('planner')}`, on a {b['machine']['cpus']}-core machine "
                  f"({b['machine']['platform']}): each run a fresh `jaxplan drive` process.", "",
                  "| run | drives | process wall (s) | parsing | compiling | driving | metrics | writing |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        runs = [("cold caches", b.get("cold")), ("warm caches", b.get("warm"))] + \
            [(f"one unseen file ({os.path.basename(s['file'])})", s) for s in b.get("single", [])]
        for name, r in runs:
            if r:
                lines.append(f"| {name} | {r['drives']} | {r['process_wall_s']:.1f} | {r['parse_s']:.1f} | "
                             f"{r['compile_s']:.1f} | {r['drive_s']:.1f} | {r['metrics_s']:.1f} | {r['write_s']:.1f} |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dev", nargs="+")
    ap.add_argument("--sample")
    ap.add_argument("--combo", nargs="*")
    ap.add_argument("--peers")
    ap.add_argument("--peers-caveat", help="a sentence printed under the peers' table's introduction (e.g. where "
                                           "their drives come from an earlier run)")
    ap.add_argument("--sample-caveat", help="a sentence printed under the sample's table's introduction (e.g. "
                                            "which version of the planners drove it)")
    ap.add_argument("--bench")
    ap.add_argument("--brake", help="a jaxplan drive --planner brake folder over the --dev scenes")
    ap.add_argument("--keep", nargs="*", default=[], choices=("sample", "combos", "peers", "bench"),
                    help="sections carried over from the existing --json as they are (their runs' folders gone); "
                         "give each a caveat (--peers-caveat, --sample-caveat) where its versions differ")
    ap.add_argument("--json", default="docs/benchmarks.json")
    ap.add_argument("--out", default="docs/benchmarks.md")
    ap.add_argument("--from-json", action="store_true", help="render --out from --json alone (no runs needed)")
    args = ap.parse_args(argv)
    if args.from_json:
        d = _load(args.json)
    else:
        kept = _load(args.json) if args.keep else {}
        d = collect(args)
        for k in args.keep:
            if k not in kept:
                raise SystemExit(f"benchmarks_page: --keep {k}: {args.json} has no such section")
            d[k] = kept[k]
            caveat = {"peers": args.peers_caveat, "sample": args.sample_caveat}.get(k)
            if caveat and isinstance(d[k], dict):
                d[k]["caveat"] = caveat
        with open(args.json, "w") as f:
            json.dump(d, f, indent=1)
    with open(args.out, "w") as f:
        f.write(render(d))
    print(f"wrote {args.out}" + ("" if args.from_json else f" and {args.json}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
