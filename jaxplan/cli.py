"""Command line: ``jaxplan eval SUITE``, ``jaxplan tune PLANNER``, ``jaxplan report DIR`` (also ``python -m jaxplan``)."""
from __future__ import annotations

import argparse
import json
import sys

from jaxplan.parking import cli as parkout_cli


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="jaxplan", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("eval", help="run an evaluation suite and write OUT/metrics.json and plots")
    e.add_argument("suite", help="suite name, or 'all'")
    e.add_argument("--scenarios", help="directory of scenario JSON files (shared format)")
    e.add_argument("--out", default="results", help="output directory (default: results)")
    e.add_argument("--n", type=int, help="number of scenes / cases")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--quick", action="store_true", help="small sizes, for a demo or a smoke test")
    e.add_argument("--weights", help="cost weights JSON written by `jaxplan tune` (suites that use them)")
    t = sub.add_parser("tune", help="learn cost weights from demonstrations and write them as JSON")
    t.add_argument("planner", choices=("lattice", "speed"))
    t.add_argument("--scenarios", help="directory of recorded scenarios (default: synthetic demonstrations)")
    t.add_argument("--out", default="weights.json", help="weights file to write (default: weights.json)")
    t.add_argument("--steps", type=int, help="optimiser steps (default: 200 lattice, 40 speed)")
    t.add_argument("--seed", type=int, default=0)
    r = sub.add_parser("report", help="write RESULTS_DIR/report.md from its metrics and plots")
    r.add_argument("results_dir")
    parkout_cli.add_parser(sub)
    args = p.parse_args(argv)
    if args.cmd == "report":
        from jaxplan.eval.report import write_report

        try:
            print(f"wrote {write_report(args.results_dir)}")
        except ValueError as err:
            print(f"jaxplan: error: {err}", file=sys.stderr)
            return 2
        return 0
    if args.cmd == "tune":
        return _tune(args)
    if args.cmd == "parkout":
        return parkout_cli.run(args)
    if args.cmd == "eval":
        from jaxplan.eval.registry import SuiteArgs, run_suite

        try:
            m = run_suite(args.suite, SuiteArgs(out=args.out, n=args.n, seed=args.seed,
                                                quick=args.quick, scenarios=args.scenarios,
                                                weights=args.weights))
        except ValueError as err:
            print(f"jaxplan: error: {err}", file=sys.stderr)
            return 2
        json.dump(m, sys.stdout, indent=1, sort_keys=True)
        print(f"\nwrote {args.out}/metrics.json")
    return 0


def _tune(args) -> int:
    from jaxplan.tuning.run import demonstrations, tune_lattice, tune_speed
    from jaxplan.tuning.train import save_weights

    try:
        train, val, source = demonstrations(args.scenarios, seed=args.seed)
    except ValueError as err:
        print(f"jaxplan: error: {err}", file=sys.stderr)
        return 2
    if args.planner == "lattice":
        res = tune_lattice(train, val, steps=args.steps or 200, seed=args.seed)
    else:
        res = tune_speed(train, val, steps=args.steps or 40, seed=args.seed)
    save_weights(args.out, res.weights, meta={"planner": args.planner, "source": source, **res.metrics})
    json.dump(res.metrics, sys.stdout, indent=1, sort_keys=True)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
