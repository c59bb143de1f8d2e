"""Benchmark: ``jaxplan drive`` over a whole scenario collection, and over one unseen file.

Runs the command line as a user does (a fresh process each time) and reads the run's own timing
(``metrics.json``: parsing, compiling, driving, metrics, writing) beside the process's wall time:

1. ``cold``: the collection with empty caches (a new ``JAXPLAN_CACHE_DIR``): every file parsed,
   every program compiled;
2. ``warm``: the same command again into a new output folder: parsed scenes and compiled
   programs come from the caches;
3. ``single``: each of ``--single`` files, unseen (not in the scene cache) with the compiled
   programs of run 1 (the XLA cache copied into a fresh cache folder), one process per file.

Prints a table and writes JSON (``--out``). Not a test: the figures depend on the machine.

Usage::

    python experiments/bench_drive.py --scenarios ../shared/data/commonroad --planner lattice \\
        --out results/bench_drive.json [--skip-cold] [--single 3]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def _drive(paths: list, planner: str, out: str, cache: str, extra: list) -> dict:
    env = dict(os.environ, JAXPLAN_CACHE_DIR=cache)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    cmd = [sys.executable, "-m", "jaxplan", "drive", *paths, "--planner", planner, "--out", out, "--plots", "none",
           *extra]
    t = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        raise SystemExit(f"bench_drive: {' '.join(cmd)} failed:\n{r.stderr[-3000:]}")
    with open(os.path.join(out, "metrics.json")) as f:
        m = json.load(f)
    timing = m["timing"]
    return {"process_wall_s": wall, **{k: timing[k] for k in ("parse_s", "compile_s", "drive_s", "metrics_s",
                                                                "write_s", "wall_s", "drives")},
            "success_share": m.get(f"drive.{planner}.success_share"), "scenes": m.get(f"drive.{planner}.scenes")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", required=True, nargs="+", help="scenario files or folders")
    ap.add_argument("--planner", default="lattice")
    ap.add_argument("--out", required=True, help="JSON file to write")
    ap.add_argument("--work", default=None, help="folder for the runs' outputs and caches (default: a temporary one)")
    ap.add_argument("--skip-cold", action="store_true", help="only the warm and single-file runs (a cache in --work)")
    ap.add_argument("--single", type=int, default=3, help="unseen single files to time (default 3)")
    ap.add_argument("--max-steps", type=int, default=300)
    args = ap.parse_args(argv)
    sys.path.insert(0, ROOT)
    from jaxplan.scenarios.files import expand_paths, sample_files

    work = args.work or tempfile.mkdtemp(prefix="jaxplan-bench-drive-")
    cache = os.path.join(work, "cache")
    extra = ["--max-steps", str(args.max_steps)]
    res = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
           "planner": args.planner, "scenarios": args.scenarios, "max_steps": args.max_steps}
    if not args.skip_cold:
        shutil.rmtree(cache, ignore_errors=True)
        res["cold"] = _drive(args.scenarios, args.planner, os.path.join(work, "cold"), cache, extra + ["--fresh"])
        print(f"cold: {res['cold']}", flush=True)
    res["warm"] = _drive(args.scenarios, args.planner, os.path.join(work, "warm"), cache, extra + ["--fresh"])
    print(f"warm: {res['warm']}", flush=True)
    singles = []
    for i, f in enumerate(sample_files(expand_paths(args.scenarios), args.single, seed=1)):
        fresh = os.path.join(work, f"single-cache-{i}")
        shutil.rmtree(fresh, ignore_errors=True)
        shutil.copytree(os.path.join(cache, "xla"), os.path.join(fresh, "xla"))  # compiled programs, no scenes
        r = _drive([f], args.planner, os.path.join(work, f"single-{i}"), fresh, extra + ["--fresh"])
        r["file"] = f
        singles.append(r)
        print(f"single: {r}", flush=True)
    res["single"] = singles
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as fh:
        json.dump(res, fh, indent=1)
    rows = [("cold", res.get("cold")), ("warm", res["warm"])] + [(f"single {os.path.basename(s['file'])}", s)
                                                                  for s in singles]
    print("| run | drives | process wall (s) | parse | compile | drive | metrics | write |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name, r in rows:
        if r:
            print(f"| {name} | {r['drives']} | {r['process_wall_s']:.1f} | {r['parse_s']:.1f} | {r['compile_s']:.1f} | "
                  f"{r['drive_s']:.1f} | {r['metrics_s']:.1f} | {r['write_s']:.1f} |")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
