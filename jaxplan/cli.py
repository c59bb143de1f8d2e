"""Command line: ``jaxplan drive PATHS``, ``jaxplan eval SUITE``, ``jaxplan tune PLANNER``, ``jaxplan report DIR``
(also ``python -m jaxplan``).

Every argument is checked before any heavy work (``jaxplan.cli_args``); a bad one gets one
line ``jaxplan: error: ...`` naming it, and exit status 2.
"""
from __future__ import annotations

import argparse
import json
import sys

from jaxplan import cli_args as ca


def _suites_epilog() -> str:
    from jaxplan.eval.registry import suite_summaries

    rows = suite_summaries()
    w = max(map(len, rows), default=0)
    return "suites:\n" + "\n".join(f"  {n.ljust(w)}  {line}" for n, line in rows.items())


def _suite_spec(text: str) -> str:
    from jaxplan.eval.registry import suite_names

    try:
        suite_names(text)
    except ValueError as e:
        raise ca.BadArgument(str(e)) from None
    return text


def parser() -> argparse.ArgumentParser:
    from jaxplan import __version__

    p = ca.ArgumentParser(prog="jaxplan", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"jaxplan {__version__}")
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("eval", help="run an evaluation suite and write OUT/metrics.json and plots",
                       epilog=_suites_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("suite", type=_suite_spec, help="suite name (below), several joined by commas, or 'all'")
    e.add_argument("--scenarios", type=ca.scenario_dir, help="directory of scenario JSON files (shared format)")
    e.add_argument("--out", type=ca.output_dir, default="results",
                   help="output directory (default: results); a run replaces the metrics of an earlier run there")
    e.add_argument("--n", type=ca.positive_int, help="number of scenes / cases")
    e.add_argument("--seed", type=ca.nonnegative_int, default=0)
    e.add_argument("--quick", action="store_true", help="small sizes, for a demo or a smoke test")
    e.add_argument("--weights", type=ca.weights_file("lattice"),
                   help="cost weights JSON written by `jaxplan tune lattice` (suites that use them)")
    t = sub.add_parser("tune", help="learn cost weights from demonstrations and write them as JSON")
    t.add_argument("planner", choices=("lattice", "speed"))
    t.add_argument("--scenarios", type=ca.scenario_dir,
                   help="directory of recorded scenarios (default: synthetic demonstrations)")
    t.add_argument("--out", type=ca.output_file, default="weights.json",
                   help="weights file to write (default: weights.json)")
    t.add_argument("--steps", type=ca.positive_int, help="optimiser steps (default: 200 lattice, 40 speed)")
    t.add_argument("--seed", type=ca.nonnegative_int, default=0)
    r = sub.add_parser("report", help="write RESULTS_DIR/report.md from its metrics and plots")
    r.add_argument("results_dir", type=ca.existing_dir)
    r.add_argument("--force", action="store_true", help="replace a report.md that `jaxplan report` did not write")
    from jaxplan.sim import cli as drive_cli

    drive_cli.add_parser(sub)
    return p


def main(argv=None) -> int:
    args, status = ca.parse(parser(), argv)
    if args is None:
        return status
    if args.cmd == "drive":
        from jaxplan.sim import cli as drive_cli

        return drive_cli.run(args)
    try:
        if args.cmd == "report":
            from jaxplan.eval.report import write_report

            print(f"wrote {write_report(args.results_dir, force=args.force)}")
            return 0
        if args.cmd == "tune":
            return _tune(args)
        if args.cmd == "eval":
            from jaxplan.eval.registry import SuiteArgs, run_suite

            m = run_suite(args.suite, SuiteArgs(out=args.out, n=args.n, seed=args.seed, quick=args.quick,
                                                scenarios=args.scenarios, weights=args.weights))
            json.dump(m, sys.stdout, indent=1, sort_keys=True)
            print(f"\nwrote {args.out}/metrics.json")
    except ValueError as err:
        print(f"jaxplan: error: {err}", file=sys.stderr)
        return 2
    return 0


def _tune(args) -> int:
    from jaxplan.tuning.run import demonstrations, tune_lattice, tune_speed
    from jaxplan.tuning.train import save_weights

    folder = None
    if args.scenarios:
        from jaxplan.scenarios.loader import load_folder

        folder = load_folder(args.scenarios)
    train, val, source = demonstrations(folder, seed=args.seed)
    if args.planner == "lattice":
        res = tune_lattice(train, val, steps=args.steps or 200, seed=args.seed)
    else:
        res = tune_speed(train, val, steps=args.steps or 40, seed=args.seed)
    meta = {"planner": args.planner, "source": source, **res.metrics}
    if folder is not None:
        meta["skipped_files"] = len(folder.skipped)
    save_weights(args.out, res.weights, meta=meta)
    json.dump(res.metrics, sys.stdout, indent=1, sort_keys=True)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
