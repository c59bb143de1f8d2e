"""Benchmark: closed-loop throughput of ``jaxplan.sim.rollout`` (scenario-steps per second).

Batches of 1 / 100 / 1,000 scenes (the built-in scenes, repeated) in one jitted call
each, every planner given; compile time reported apart. Prints figures and writes JSON:
``steps_per_s`` maps planner -> {batch size (as a string) -> scenario-steps/s}, and per
planner the wall time of one planning call for one scene (``plan_ms``), the figure to set
against a peer's wall time per planning cycle.

    python experiments/bench_sim.py [--planners lattice pathspeed idm] [--sizes 1 100 1000]
        [--steps 100] [--reps 2] [--out results/bench_sim.json]
"""
from __future__ import annotations

import argparse
import os
import platform

import jax
import numpy as np

from jaxplan.eval.timing import best_time, timed, write_figures
from jaxplan.planner import make_planner
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.scenarios.builtin import builtin_records
from jaxplan.sim.drive import time_plans
from jaxplan.sim.rollout import SimConfig, rollout


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--planners", nargs="+", default=["lattice", "pathspeed", "idm"])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 100, 1000])
    ap.add_argument("--steps", type=int, default=100, help="simulated steps per drive (dt 0.1 s)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--out", default="results/bench_sim.json")
    args = ap.parse_args(argv)
    if min(args.sizes) < 1 or args.steps < 1:
        ap.error("--sizes and --steps must be >= 1")
    recs = builtin_records(quick=True)
    cfg = SimConfig(n_steps=args.steps, stop_at_goal=False)  # every drive runs all its steps
    res = {"device": str(jax.devices()[0]), "devices": jax.device_count(), "cpu_count": os.cpu_count(),
           "machine": platform.machine(), "steps_per_drive": args.steps, "replan_every": cfg.replan_every,
           "steps_per_s": {}, "compile_s": {}, "plan_ms": {}}
    for name in args.planners:
        planner = make_planner(name)
        res["steps_per_s"][name], res["compile_s"][name] = {}, {}
        for n in args.sizes:
            batch = stack_scenes([recs[i % len(recs)].scene for i in range(n)], min_steps=args.steps + 1)
            _, first = timed(lambda: jax.block_until_ready(rollout(planner, batch, cfg).x))
            best = best_time(lambda: jax.block_until_ready(rollout(planner, batch, cfg).x), args.reps)
            res["steps_per_s"][name][str(n)] = n * args.steps / best
            res["compile_s"][name][str(n)] = max(first - best, 0.0)
            print(f"{name:10s} batch {n:5d}: {n * args.steps / best:10.0f} scenario-steps/s "
                  f"({best:.2f} s per call, compile {first - best:.1f} s)", flush=True)
        batch = stack_scenes([r.scene for r in recs], min_steps=args.steps + 1)
        res["plan_ms"][name] = time_plans(planner, batch, len(recs))["plan_ms_median"]
        print(f"{name:10s} one planning call, one scene: {res['plan_ms'][name]:.2f} ms (median)", flush=True)
    write_figures(res, args.out)


if __name__ == "__main__":
    main()
